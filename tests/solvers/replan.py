"""Hand-built dynamic planning states for the market baselines' tests: what a re-plan at time
``t`` sees after a plan made earlier (the simulator's own committed-prefix rule)."""

from tsac_bench.model import Instance, Route
from tsac_bench.model.evaluator import CostEvaluator
from tsac_bench.planning import PlanningState
from tsac_bench.planning.simulator import committed_prefixes


def replan_state(instance: Instance, routes: tuple[Route, ...], t: float) -> PlanningState:
    """docs/model.md's committed prefixes at ``t`` > 0 and the tasks released by ``t``."""
    evaluator = CostEvaluator(instance)
    traces = [evaluator.trace(n, route) for n, route in enumerate(routes)]
    return PlanningState(instance, t, instance.released_by(t),
                         committed_prefixes(instance, traces, t), routes)
