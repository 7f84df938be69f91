"""Hand-built dynamic planning states for the market baselines' tests (until the simulator
builds them): what a re-plan at time ``t`` sees after a plan made earlier."""

from tsac_bench.allocator import PlanningState
from tsac_bench.evaluator import CostEvaluator
from tsac_bench.model import Instance, Route


def replan_state(instance: Instance, routes: tuple[Route, ...], t: float) -> PlanningState:
    """MODEL.md's committed prefix at ``t``: every visit whose previous node the AAV left at
    or before ``t`` (the start counts as left at time 0); the tasks released by ``t``."""
    evaluator = CostEvaluator(instance)
    committed = []
    for n, route in enumerate(routes):
        departures = (0.0, *evaluator.trace(n, route).arrivals)
        k = 0
        while k < len(route) and departures[k] <= t:
            k += 1
        committed.append(tuple(route[:k]))
    return PlanningState(instance, t, instance.released_by(t), tuple(committed), routes)
