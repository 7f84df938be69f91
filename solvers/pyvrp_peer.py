"""``pyvrp``: the problem handed to PyVRP's iterated local search, a state-of-the-art VRP solver.

PyVRP has no split deliveries, so each task is cut into pieces no heavier than the smallest
AAV capacity; pieces share the task's location and are optional clients whose prize is the
load penalty they remove (``w1 * piece / R``). The rest maps one to one:

* one vehicle type per AAV (one vehicle each), its own profile (speed and energy rate), its
  start position as its start depot, every depot as a reload depot (multi-trip), and a virtual
  end depot reached from any node at the cost and duration of the leg to its nearest depot;
* PyVRP's trip load (deliveries loaded at the depot, pickups brought back, capacity checked
  all along) is Eq. 10; hard client time windows forbid late visits (exact: late visits never
  help, docs/model.md, "Cost"); waiting at an early arrival is Eq. 7.
* distances in PyVRP are *costs*: a leg into a task costs ``w3 * alpha * L[km] / E_base``,
  a leg into a depot nothing (only legs into tasks are charged). Durations are leg times in
  ``1 / TIME_SCALE`` s, rounded up so that a visit PyVRP finds on time is on time.

What PyVRP does not see: the timeliness term (w2 * C_time), the soft range penalty and the
w2 saved by serving a task at all. The evaluator prices the decoded routes; J is always its.
"""

from __future__ import annotations

import math
import time
from collections.abc import Mapping
from importlib.metadata import version
from types import MappingProxyType
from typing import Any, ClassVar

import pyvrp

from tsac_bench.model import Instance, Route, Visit
from tsac_bench.model.evaluator import CostEvaluator, departure_and_arrival
from tsac_bench.planning import Interval, NoneOr, PlanningState, PlanResult, Settings, declare
from tsac_bench.planning.budget import ANYTIME, require_a_stop
from tsac_bench.planning.insertion import removal_route, top_up
from tsac_bench.solvers.greedy import deadline_order, insert_cheapest

#: The share of a plan call's time limit that PyVRP's search may use; the rest is for
#: building its model and decoding and completing its solution (at 32/80 both together take
#: up to a few tenths of a second).
SEARCH_SHARE = 0.8
#: PyVRP works in integers: seconds * TIME_SCALE and cost * COST_SCALE.
TIME_SCALE = 100
COST_SCALE = 1_000_000


class PyVRPAllocator(Settings):
    """Settings: ``max_iterations`` (None: no cap) and ``time_limit`` (seconds, None: no
    cap) end PyVRP's search, whichever comes first, ``SEARCH_SHARE`` of the time left for
    the search and the rest for decoding; ``piece_size`` and ``duration_weight`` shape the
    model (module docstring). An anytime method (``tsac_bench.planning.budget``): under a
    budget only the budget ends the search, and ``max_iterations`` set to a budgeted call's
    iteration count gives the same plan without it. PyVRP hands back its best solution at
    the end only, so the incumbent trace has one point."""

    name = "pyvrp"
    setting_constraints = declare(
        max_iterations=NoneOr(Interval(int, 1, None)),
        time_limit=NoneOr(Interval(float, 0, None, closed="neither")),
        piece_size=NoneOr(Interval(int, 1, None)),
        duration_weight=Interval(float, 0, None),
    )
    budget_use: ClassVar[str] = ANYTIME
    unbounded_settings: ClassVar[Mapping[str, Any]] = MappingProxyType(
        {"max_iterations": None, "time_limit": None})
    work_setting: ClassVar[str] = "max_iterations"
    work_unit: ClassVar[str] = "iterations"

    def __init__(self, max_iterations: int | None = 1000, time_limit: float | None = 10.0,
                 piece_size: int | None = None, duration_weight: float = 10.0) -> None:
        self.max_iterations = max_iterations
        self.time_limit = time_limit
        self.piece_size = piece_size
        self.duration_weight = duration_weight

    def plan(self, state: PlanningState, *, seed: int = 0,
             time_limit: float | None = None) -> PlanResult:
        from pyvrp.stop import MaxIterations, MaxRuntime, MultipleCriteria

        limits = [t for t in (self.time_limit, time_limit) if t is not None]
        budget = min(limits) if limits else None
        require_a_stop(self.name, "max_iterations", budget, self.max_iterations)
        began = time.perf_counter()
        mapping = _Mapping(state, self.piece_size, self.duration_weight)
        # Iterations, not seconds, end a search without a budget so that a seed fixes the
        # result; under a budget the iteration count it reached reproduces it.
        criteria = []
        if self.max_iterations is not None:
            criteria.append(MaxIterations(self.max_iterations))
        if budget is not None:
            left = SEARCH_SHARE * budget - (time.perf_counter() - began)
            criteria.append(MaxRuntime(max(left, 0.01)))
        # Prizes reach w1 * COST_SCALE; PyVRP's default penalty cap (1e5 per unit of excess
        # load) would then make overloading pay, so the cap is lifted well above any prize.
        params = pyvrp.SolveParams(penalty=pyvrp.PenaltyParams(max_penalty=1e12))
        result = pyvrp.solve(mapping.problem_data(), MultipleCriteria(criteria), seed=seed,
                             display=False, params=params, collect_stats=False)
        evaluator = state.evaluator()
        decoded = tuple(_repair(state, evaluator, n, route)
                        for n, route in enumerate(mapping.decode(result.best)))
        # Pieces PyVRP served by returning to a task in another trip cannot be kept (a task
        # appears once per route): hand their residual demand to cheapest insertion.
        plan = evaluator.state(decoded)
        decoded_cost = plan.cost
        # A visit that kept only its first piece may carry more: top it up, then insert.
        top_up(plan, [state.first_free(n) for n in range(state.instance.n_aavs)])
        insertions, _ = insert_cheapest(plan, state, deadline_order(state))
        seconds = time.perf_counter() - began
        stopped_by_count = (self.max_iterations is not None
                            and result.num_iterations >= self.max_iterations)
        return PlanResult(plan.routes, {
            "solver": "pyvrp", "solver_version": version("pyvrp"),
            "pyvrp_cost": result.cost(), "pyvrp_feasible": result.is_feasible(),
            "pieces": len(mapping.pieces), "iterations": result.num_iterations,
            "stop": "iterations" if stopped_by_count else "time-limit",
            "decoded_cost": decoded_cost, "completion_insertions": insertions,
            "wall_time": seconds, "work": result.num_iterations,
            "trace": [[seconds, plan.cost]],
        })


class _Mapping:
    """Builds the PyVRP model of one planning state and decodes its solutions."""

    def __init__(self, state: PlanningState, piece_size: int | None,
                 duration_weight: float) -> None:
        self.state = state
        self.duration_weight = duration_weight
        instance = state.instance
        self.instance = instance
        smallest = min(a.capacity for a in instance.aavs)
        self.piece_size = piece_size or smallest
        # Each AAV's free part starts at a depot, so that PyVRP's "deliveries are loaded at the
        # start" holds: the depot of its committed prefix's end, or else the depot nearest to
        # where it is (the start position or the task it is flying to), reached first.
        # PyVRP's vehicle leaves its start depot no earlier than its time window opens: the
        # time the AAV can leave that depot for visits planned now.
        self.origins: list[tuple[int, float]] = []  # (depot node, time the AAV can leave it)
        for n, aav in enumerate(instance.aavs):
            anchor = state.anchor(n)
            if instance.is_depot(anchor.node):
                self.origins.append((anchor.node, anchor.time))
                continue
            depot = instance.nearest_depot(anchor.node)
            _, there = departure_and_arrival(anchor.time, None, float(
                instance.dist[anchor.node, depot]) / aav.speed, 0.0)
            self.origins.append((depot, there))
        self.pieces: list[tuple[int, int]] = []  # (task, amount)
        for m in sorted(state.visible):
            demand = instance.tasks[m].demand
            # Committed visits already cover part of the demand: cut pieces from the rest.
            covered = sum(v.amount for r in state.committed for v in r if v.node == m)
            rest = demand - covered
            while rest > 0:
                piece = min(self.piece_size, rest)
                self.pieces.append((m, piece))
                rest -= piece

    def problem_data(self):
        import numpy as np

        instance = self.instance
        w1, w2, w3 = instance.weights
        # A proxy for the timeliness term: w2 / T_hor per second of route duration, as if each
        # route served one task; ``duration_weight`` scales it.
        duration_cost = round(self.duration_weight * w2 * COST_SCALE
                              / (instance.horizon * TIME_SCALE))
        # Locations: every node of the instance (tasks, depots, starts), then the virtual end.
        positions = instance.positions.tolist()
        locations = [pyvrp.Location(x, y) for x, y in positions] + [pyvrp.Location(0.0, 0.0)]
        end = len(positions)
        depots = [pyvrp.Depot(k) for k in instance.depot_nodes]
        starts = [pyvrp.Depot(origin) for origin, _ in self.origins]
        clients = []
        for m, piece in self.pieces:
            task = instance.tasks[m]
            clients.append(pyvrp.Client(
                m,
                delivery=[piece if task.is_delivery else 0],
                pickup=[0 if task.is_delivery else piece],
                tw_early=math.ceil(task.t_start * TIME_SCALE),
                tw_late=math.floor(task.t_end * TIME_SCALE),
                prize=round(COST_SCALE * w1 * piece / task.demand),
                required=False,
            ))
        dist = np.zeros((end + 1, end + 1))
        dist[:end, :end] = instance.dist
        dist[:end, end] = instance.dist[:, list(instance.depot_nodes)].min(axis=1)
        into_task = np.zeros(end + 1, dtype=bool)
        into_task[: instance.n_tasks] = True
        e_base = instance.e_base
        distances, durations, vehicles = [], [], []
        all_depots = list(range(len(depots)))
        for n, aav in enumerate(instance.aavs):
            cost = COST_SCALE * w3 * aav.alpha / 1000.0 / e_base * dist * into_task[None, :]
            distances.append(np.round(cost).astype(np.int64))
            durations.append(np.ceil(dist / aav.speed * TIME_SCALE).astype(np.int64))
            start_time = self.origins[n][1]
            vehicles.append(pyvrp.VehicleType(
                num_available=1, capacity=[aav.capacity], start_depot=len(depots) + n,
                end_depot=len(depots) + len(starts), tw_early=math.ceil(start_time * TIME_SCALE),
                reload_depots=all_depots, profile=n, name=aav.id,
                unit_duration_cost=duration_cost,
            ))
        return pyvrp.ProblemData(locations, clients, [*depots, *starts, pyvrp.Depot(end)],
                                 vehicles, distances, durations)

    def decode(self, solution) -> tuple[Route, ...]:
        """PyVRP routes back to visits after each AAV's committed prefix (closed at its origin
        depot). Adjacent pieces of one task become one visit; a later, separate return to a task
        already in the route is dropped, since a task appears once per route (docs/model.md,
        "A solution")."""
        instance = self.instance
        routes = []
        for n, closed in enumerate(self.state.base_routes()):
            route = list(closed)
            if not route or route[-1].node != self.origins[n][0]:
                route.append(Visit(self.origins[n][0]))
            routes.append(route)
        for pyvrp_route in solution.routes():
            route = routes[pyvrp_route.vehicle_type()]
            seen = {v.node for v in route}
            for activity in list(pyvrp_route.schedule())[1:-1]:  # not the start, not the end
                if activity.is_depot():
                    if route[-1].node != instance.depot_node(activity.idx):
                        route.append(Visit(instance.depot_node(activity.idx)))
                    continue
                m, piece = self.pieces[activity.idx]
                if route[-1].node == m:
                    route[-1] = Visit(m, route[-1].amount + piece)
                elif m not in seen:
                    route.append(Visit(m, piece))
                    seen.add(m)
        closed = []
        for n, route in enumerate(routes):
            if not any(v.node < instance.n_tasks for v in route[self.state.first_free(n):]):
                route = list(self.state.base_routes()[n])  # nothing to do: no detour to a depot
            closed.append(tuple(route) + _closing(instance, tuple(route)))
        return tuple(closed)


def _closing(instance: Instance, route: Route) -> Route:
    if route and not instance.is_depot(route[-1].node):
        return (Visit(instance.nearest_depot(route[-1].node)),)
    return ()


def _repair(state: PlanningState, evaluator: CostEvaluator, n: int, route: Route) -> Route:
    """Where PyVRP's integer view and the model disagree (a merged or dropped piece), drop the
    offending task visits one by one until the evaluator accepts the route."""
    instance = state.instance
    first_free = state.first_free(n)
    trace = evaluator.trace(n, route)
    while trace.errors:
        position = trace.errors[0].position
        if position is None or position < first_free:
            return state.base_routes()[n]
        # A load error at a depot is caused by a task after it: drop the first such task.
        offender = next((v.node for v in route[position:] if v.node < instance.n_tasks), None)
        if offender is None:
            return state.base_routes()[n]
        route = removal_route(instance, route, offender, first_free)
        trace = evaluator.trace(n, route)
    return route
