"""Large neighbourhood search over a plan with exact-bp as the repair (docs/formulations.md,
"Neighbourhood search"): a few related AAVs are freed, every other AAV is held to its route
(a committed prefix it may not extend), and branch-and-price re-plans the freed AAVs over
the tasks near them, from the plan as it stands. A freed set is small enough that its
search often ends proved, where a search of the whole instance at 16/40 gets no bound."""

from __future__ import annotations

import random
import time
from collections.abc import Callable
from dataclasses import dataclass

from tsac_bench.formulations.branch_price.column_generation import reaches
from tsac_bench.formulations.branch_price.options import NeighbourhoodSettings
from tsac_bench.formulations.branch_price.search import BranchPrice
from tsac_bench.formulations.network import canonical_routes
from tsac_bench.formulations.task_bound import task_lower_bounds
from tsac_bench.model import Instance, Route
from tsac_bench.model.evaluator import CostEvaluator
from tsac_bench.planning import PlanningState

Plan = tuple[Route, ...]


@dataclass(frozen=True)
class Neighbourhood:
    """The AAVs a repair re-plans and the tasks their new routes may visit."""

    free: frozenset[int]
    tasks: frozenset[int]


def _visited(instance: Instance, route: Route) -> set[int]:
    return {v.node for v in route if v.node < instance.n_tasks}


def neighbourhood(instance: Instance, plan: Plan, around: int, aavs: int, extra: int
                  ) -> Neighbourhood:
    """AAV ``around`` and the ``aavs - 1`` AAVs most related to it (those that share most
    of its tasks, then those whose tasks or start lie nearest to its own), with the tasks
    they visit and the ``extra`` other tasks nearest to those."""
    dist = instance.dist
    visited = [_visited(instance, route) for route in plan]
    places = [visited[n] or {instance.start_node(n)} for n in range(instance.n_aavs)]

    def relatedness(n: int) -> tuple[int, float, int]:
        gap = min(dist[i][j] for i in places[around] for j in places[n])
        return -len(visited[around] & visited[n]), gap, n

    others = sorted((n for n in range(instance.n_aavs) if n != around), key=relatedness)
    free = frozenset([around, *others[:aavs - 1]])
    own = set().union(*(visited[n] for n in free))
    anchors = own or {instance.start_node(n) for n in free}
    nearest = sorted((m for m in range(instance.n_tasks) if m not in own),
                     key=lambda m: (min(dist[m][j] for j in anchors), m))
    return Neighbourhood(free, frozenset(own | set(nearest[:extra])))


def repair(instance: Instance, plan: Plan, area: Neighbourhood, time_limit: float
           ) -> tuple[Plan, str]:
    """exact-bp on ``area`` (the other AAVs held to their routes of ``plan``, a canonical
    static plan) from ``plan`` for ``time_limit`` seconds: its plan and status."""
    held = tuple(() if n in area.free else route for n, route in enumerate(plan))
    reach = [area.tasks if n in area.free else frozenset() for n in range(instance.n_aavs)]
    search = BranchPrice(instance, None, held, 0.0, None, reach)
    result = search.solve([plan], time_limit)
    return result.routes, result.status


def centre_order(evaluator: CostEvaluator, plan: Plan, rng: random.Random,
                 least: list[float] | None = None) -> list[int]:
    """The AAVs that neighbourhoods are built around, in the order tried: shuffled by
    ``rng``; with ``least`` (each task's tasks-on-their-own bound), sorted by the most any
    task an AAV visits costs in ``plan`` above its bound, ties in the shuffled order (what
    a repair around it could at best take off one task; 0 for an AAV that visits none)."""
    instance = evaluator.instance
    order = list(range(instance.n_aavs))
    rng.shuffle(order)
    if least is None:
        return order
    excess = [t.cost.total - least[m] for m, t in enumerate(evaluator.evaluate(plan).per_task)]
    dearest = [max((excess[m] for m in _visited(instance, route)), default=0.0)
               for route in plan]
    return sorted(order, key=lambda n: -dearest[n])


@dataclass
class SearchReport:
    """What one ``search`` did: repairs run, those that lowered J, those proved optimal,
    and the most AAVs a neighbourhood freed."""

    repairs: int = 0
    improved: int = 0
    proved: int = 0
    largest: int = 0


def search(instance: Instance, plan: Plan, time_limit: float,
           settings: NeighbourhoodSettings | None = None, *, seed: int = 0,
           note: Callable[[str], None] | None = None) -> tuple[Plan, SearchReport]:
    """The plan of least J that repairs of ``plan`` (a static plan) reach in ``time_limit``
    seconds: neighbourhoods of ``settings.aavs`` AAVs around each AAV in turn (in
    ``settings.order``, shuffled by ``seed``), each repaired for at most
    ``settings.repair_limit`` seconds and kept where it lowers J. A neighbourhood proved
    optimal is not tried again until the plan changes; once every one of its size is, those
    of one AAV more are tried, and the search stops early when the neighbourhoods of the
    whole fleet are proved (``settings``: None, the defaults)."""
    began = time.perf_counter()
    settings = settings or NeighbourhoodSettings()
    evaluator = CostEvaluator(instance)
    plan = canonical_routes(instance, plan)
    J = evaluator.cost(plan)
    report = SearchReport(largest=settings.aavs)
    rng = random.Random(seed)
    settled: set[Neighbourhood] = set()
    size, limit = settings.aavs, settings.repair_limit
    least = (task_lower_bounds(PlanningState.static(instance))
             if settings.order == "excess" else None)
    while True:
        areas = [area for area in dict.fromkeys(
            neighbourhood(instance, plan, n, size, settings.extra)
            for n in centre_order(evaluator, plan, rng, least))
            if area not in settled]
        if not areas:
            if size >= instance.n_aavs:
                return plan, report
            # Every neighbourhood of this size is proved: larger ones (a variable
            # neighbourhood search) use the time left.
            size, limit = size + 1, settings.repair_limit
            report.largest = max(report.largest, size)
            continue
        for area in areas:
            left = time_limit - (time.perf_counter() - began)
            if left <= 0:
                return plan, report
            routes, status = repair(instance, plan, area, min(limit, left))
            report.repairs += 1
            candidate = canonical_routes(instance, routes)
            cost = evaluator.cost(candidate)
            if not reaches(cost, J):
                report.improved += 1
                if note:
                    note(f"J {J:.6f} -> {cost:.6f} (AAVs {sorted(area.free)})")
                plan, J = candidate, cost
                settled.clear()
                size, limit = settings.aavs, settings.repair_limit
                break
            if status == "optimal":
                report.proved += 1
                settled.add(area)
        else:
            # A whole round in vain: the open neighbourhoods get longer repairs.
            limit *= 2
