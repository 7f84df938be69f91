"""The cost evaluator: feasibility and J of docs/model.md, the single source of truth.

Every cost tsac-bench prints or stores is computed here from the routes alone. Allocators
may claim a cost; it is checked against this module, never trusted.

Two paths share one route walk (``CostEvaluator.trace``):
* ``CostEvaluator.evaluate`` scores a whole solution with a per-task breakdown and a per-AAV
  trace;
* ``PlanState`` keeps the per-task contributions of a plan so that the change in J caused
  by replacing one AAV's route costs O(route length + coalition sizes), which is what the
  coalition games call thousands of times.
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Sequence
from dataclasses import dataclass, field
from typing import NamedTuple

from tsac_bench.model.instance import TIME_TOLERANCE, Instance
from tsac_bench.model.solution import Route, Solution, Visit

__all__ = ["COST_TOLERANCE", "TIME_TOLERANCE", "CostEvaluator", "Evaluation", "PlanState",
           "cost_at_least", "costs_agree", "evaluate"]

#: Two costs agree when they differ by at most this, relative to max(1, |a|, |b|): how close
#: a method's own J, a solver's objective or a manifest's J* must come to the evaluator's J.
COST_TOLERANCE = 1e-6


def costs_agree(a: float, b: float) -> bool:
    return abs(a - b) <= COST_TOLERANCE * max(1.0, abs(a), abs(b))


def cost_at_least(value: float, floor: float) -> bool:
    """``value >= floor`` up to COST_TOLERANCE: a J against a lower bound or an optimum."""
    return value >= floor - COST_TOLERANCE * max(1.0, abs(value), abs(floor))


def departure(previous_arrival: float, planned_at: float | None) -> float:
    """When the AAV leaves the previous node: once it has reached it and the plan that sends
    it on has been made (dep_k = max(tau_{k-1}, planned_at_k), docs/model.md, "Time")."""
    if planned_at is not None and planned_at > previous_arrival:
        return planned_at
    return previous_arrival


def departure_and_arrival(previous_arrival: float, planned_at: float | None, travel: float,
                          t_start: float) -> tuple[float, float]:
    """Eq. 7 with the dynamic run's stamps, the one place the timing rule lives: the AAV
    leaves as ``departure`` says and waits at the next node for its window
    (tau_k = max(t_start, dep_k + L / v))."""
    leaves = departure(previous_arrival, planned_at)
    arrival = leaves + travel
    if arrival < t_start:
        arrival = t_start
    return leaves, arrival


def _is_time(value: object) -> bool:
    return type(value) in (int, float) and math.isfinite(value) and value >= 0


@dataclass(frozen=True, slots=True)
class FeasibilityError:
    """One violated rule of docs/model.md, located by AAV and visit position."""

    code: str
    aav: str
    position: int | None
    message: str

    def __str__(self) -> str:
        where = f"routes.{self.aav}" + (f"[{self.position}]" if self.position is not None else "")
        return f"{where}: {self.message} ({self.code})"


class Contribution(NamedTuple):
    """What one AAV's visit brings to a task: the inputs of C_load, C_time and C_op."""

    amount: int
    arrival: float
    op_cost: float  # q_n(m) of Eq. 9, already divided by E_base


@dataclass(frozen=True, slots=True)
class RouteTrace:
    """One AAV's route walked through Eqs. 7, 9 and 10; per-visit tuples align with the route."""

    aav: int
    route: Route
    errors: tuple[FeasibilityError, ...]
    departures: tuple[float, ...]  # when the AAV leaves the previous node
    arrivals: tuple[float, ...]
    delivery_load: tuple[int, ...]  # d after the visit
    pickup_load: tuple[int, ...]  # p after the visit
    distance_at_arrival: tuple[float, ...]  # Dcum
    op_costs: tuple[float, ...]  # q_n(m) for task visits, 0 for depots
    contributions: tuple[tuple[int, Contribution], ...]  # (task, contribution) per task visit
    distance: float

    @property
    def feasible(self) -> bool:
        return not self.errors

    @property
    def loads(self) -> tuple[int, ...]:
        return tuple(d + p for d, p in zip(self.delivery_load, self.pickup_load, strict=True))


class TaskCost(NamedTuple):
    load: float  # C_load
    time: float  # C_time
    op: float  # C_op
    total: float  # w1 C_load + w2 C_time + w3 C_op


@dataclass(frozen=True, slots=True)
class TaskBreakdown:
    task: str
    cost: TaskCost
    coalition: tuple[str, ...]
    amounts: dict[str, int]
    arrivals: dict[str, float]
    on_time: dict[str, bool]


@dataclass(frozen=True)
class Evaluation:
    """The evaluator's verdict on a solution. ``J`` is None when the solution is infeasible."""

    feasible: bool
    J: float | None
    errors: tuple[FeasibilityError, ...]
    per_task: tuple[TaskBreakdown, ...] = ()
    traces: tuple[RouteTrace, ...] = ()
    terms: dict[str, float] = field(default_factory=dict)  # weighted sums of the three terms

    def to_dict(self, instance: Instance) -> dict[str, object]:
        """The machine-readable form printed by ``tsac-bench evaluate --json``."""
        ids = instance.node_ids
        return {
            "feasible": self.feasible,
            "J": self.J,
            "terms": self.terms,
            "errors": [
                {"code": e.code, "aav": e.aav, "position": e.position, "message": e.message}
                for e in self.errors
            ],
            "per_task": [
                {
                    "task": b.task,
                    "cost": b.cost.total,
                    "C_load": b.cost.load,
                    "C_time": b.cost.time,
                    "C_op": b.cost.op,
                    "coalition": list(b.coalition),
                    "amounts": b.amounts,
                    "arrivals": b.arrivals,
                    "on_time": b.on_time,
                }
                for b in self.per_task
            ],
            "per_aav": [
                {
                    "aav": instance.aavs[t.aav].id,
                    "nodes": [ids[v.node] for v in t.route],
                    "departures": list(t.departures),
                    "arrivals": list(t.arrivals),
                    "delivery_load": list(t.delivery_load),
                    "pickup_load": list(t.pickup_load),
                    "distance_at_arrival": list(t.distance_at_arrival),
                    "distance": t.distance,
                    "range_exceeded": t.distance > instance.aavs[t.aav].max_range,
                }
                for t in self.traces
            ],
        }


class CostEvaluator:
    """Evaluates routes of one instance; build once, call many times.

    A planner at a re-plan of a dynamic run passes the time of the plan and each AAV's first
    free position: visits from there on are timed as planned at ``plan_time``, the stamp the
    simulator writes on them (docs/model.md, "The dynamic run"), so that what it prices is what
    will be executed. The default (0, nothing committed) is the offline model."""

    def __init__(self, instance: Instance, plan_time: float = 0.0,
                 first_free: Sequence[int] | None = None) -> None:
        self.instance = instance
        self.plan_time = float(plan_time)
        self.first_free = tuple(first_free) if first_free is not None else \
            (0,) * instance.n_aavs
        self.n_tasks = instance.n_tasks
        self.n_nodes = instance.n_tasks + instance.n_depots
        self.w1, self.w2, self.w3 = instance.weights
        self.horizon = instance.horizon
        self._dist = instance.dist_rows
        tasks = instance.tasks
        self._t_start = tuple(float(t.t_start) for t in tasks) + (0.0,) * instance.n_depots
        self._latest_on_time = tuple(t.latest_on_time for t in tasks)
        self._demand = tuple(t.demand for t in tasks)
        self._is_delivery = tuple(t.is_delivery for t in tasks)
        e_base = instance.e_base
        aavs = instance.aavs
        self._aav_ids = tuple(a.id for a in aavs)
        self._speed = tuple(float(a.speed) for a in aavs)
        self._capacity = tuple(a.capacity for a in aavs)
        self._range = tuple(float(a.max_range) for a in aavs)
        # q_n(m) in the two regimes of Eq. 9, pre-divided by E_base; legs are in metres.
        self._op_per_metre = tuple(a.alpha / 1000.0 / e_base for a in aavs)
        self._op_over_range = tuple(a.full_range_cost / e_base for a in aavs)
        self._start = tuple(instance.start_node(n) for n in range(len(aavs)))
        self.empty_task_cost = TaskCost(1.0, 1.0, 0.0, instance.unserved_task_cost)

    @property
    def op_per_metre(self) -> tuple[float, ...]:
        """Per AAV, q_n of Eq. 9 per metre flown within its range, divided by E_base (w3
        times it is the operating cost of a metre in J)."""
        return self._op_per_metre

    # --- one route ---------------------------------------------------------------------
    def trace(self, n: int, route: Sequence[Visit]) -> RouteTrace:
        """Walk AAV n's route: times (Eq. 7), loads (Eq. 10), distances and q_n (Eq. 9)."""
        errors: list[FeasibilityError] = []
        aav_id = self._aav_ids[n]

        def fail(code: str, position: int | None, message: str) -> None:
            errors.append(FeasibilityError(code, aav_id, position, message))

        n_tasks, n_nodes = self.n_tasks, self.n_nodes
        is_delivery = self._is_delivery
        # Omega of Eq. 10: the delivery goods each depot visit loads, found by a backward pass.
        depot_load = [0] * len(route)
        pending = 0
        for k in range(len(route) - 1, -1, -1):
            node, amount = route[k].node, route[k].amount
            if type(node) is not int or not 0 <= node < n_nodes:
                fail("unknown-node", k, f"unknown node {node!r}")
                return self._failed(n, route, errors)
            if node >= n_tasks:
                depot_load[k] = pending
                pending = 0
            elif is_delivery[node] and type(amount) is int:
                pending += amount

        speed, capacity = self._speed[n], self._capacity[n]
        max_range = self._range[n]
        op_per_metre, op_over_range = self._op_per_metre[n], self._op_over_range[n]
        dist, t_start = self._dist, self._t_start
        departures, arrivals, d_loads, p_loads, dcums, ops = [], [], [], [], [], []
        contributions = []
        seen: set[int] = set()
        plan_time = self.plan_time if self.plan_time > 0 else None
        first_free = self.first_free[n]
        prev, clock, flown, d, p = self._start[n], 0.0, 0.0, 0, 0
        for k, (node, amount, planned_at, load) in enumerate(route):
            if planned_at is not None and not _is_time(planned_at):
                fail("bad-planned-at", k, f"planned_at must be a finite number of seconds "
                     f">= 0, got {planned_at!r}")
                planned_at = None
            if plan_time is not None and k >= first_free and \
                    (planned_at is None or planned_at < plan_time):
                planned_at = plan_time
            leg = dist[prev][node]
            flown += leg
            departure, arrival = departure_and_arrival(clock, planned_at, leg / speed,
                                                       t_start[node])
            q = 0.0
            if node >= n_tasks:
                if amount != 0 or type(amount) is not int:
                    fail("depot-amount", k, f"a depot visit carries no amount, got {amount!r}")
                if load is not None:
                    if type(load) is not int or load < 0:
                        fail("bad-load", k, f"a depot visit's load must be an integer >= 0 "
                             f"kg, got {load!r}")
                    elif depot_load[k] > load:
                        fail("load-exceeded", k, f"the deliveries after depot "
                             f"{self._node_id(node)} need {depot_load[k]} kg but it loaded "
                             f"{load} kg")
                d, p = depot_load[k], 0
            else:
                if load is not None:
                    fail("bad-load", k, f"a task visit carries no load, got {load!r}")
                if node in seen:
                    fail("repeated-task", k, f"task {self._node_id(node)} is visited twice")
                seen.add(node)
                if type(amount) is not int or amount < 1:
                    fail("bad-amount", k, f"a task visit needs an integer amount >= 1 kg, "
                         f"got {amount!r}")
                    amount = 0
                if is_delivery[node]:
                    d -= amount
                    if d < 0:
                        fail("no-goods", k, f"delivery {self._node_id(node)} lacks "
                             f"{-d} kg: delivery goods come only from a depot visit before it")
                else:
                    p += amount
                q = op_per_metre * leg if flown <= max_range else op_over_range
                contributions.append((node, Contribution(amount, arrival, q)))
            if d + p > capacity:
                fail("over-capacity", k, f"load {d + p} kg exceeds the capacity {capacity} kg")
            departures.append(departure)
            arrivals.append(arrival)
            d_loads.append(d)
            p_loads.append(p)
            dcums.append(flown)
            ops.append(q)
            prev, clock = node, arrival
        if route and route[-1][0] < n_tasks:
            fail("no-final-depot", len(route) - 1, "a non-empty route must end at a depot")
        return RouteTrace(n, tuple(route), tuple(errors), tuple(departures), tuple(arrivals),
                          tuple(d_loads), tuple(p_loads), tuple(dcums), tuple(ops),
                          tuple(contributions), flown)

    def _failed(self, n: int, route: Sequence[Visit], errors: list) -> RouteTrace:
        return RouteTrace(n, tuple(route), tuple(errors), (), (), (), (), (), (), (), math.nan)

    def _node_id(self, node: int) -> str:
        return self.instance.node_ids[node]

    # --- one task ----------------------------------------------------------------------
    def task_cost(self, m: int, contributions: Iterable[Contribution]) -> TaskCost:
        """C_m of Eq. 4 from the visits of its coalition (Eqs. 5, 6, 8)."""
        t_end = self._latest_on_time[m]
        on_time_amount, latest, late, op = 0, -math.inf, False, 0.0
        any_visit = False
        for amount, arrival, q in contributions:
            any_visit = True
            op += q
            if arrival <= t_end:
                on_time_amount += amount
                if arrival > latest:
                    latest = arrival
            else:
                late = True
        if not any_visit:
            return self.empty_task_cost
        c_load = max(0.0, 1.0 - on_time_amount / self._demand[m])
        c_time = 1.0 if late else (latest - self._t_start[m]) / self.horizon
        return TaskCost(c_load, c_time, op, self.w1 * c_load + self.w2 * c_time + self.w3 * op)

    # --- a whole solution --------------------------------------------------------------
    def evaluate(self, solution: Solution | Sequence[Route]) -> Evaluation:
        routes = solution.routes if isinstance(solution, Solution) else tuple(solution)
        instance = self.instance
        if len(routes) != instance.n_aavs:
            error = FeasibilityError("route-count", "*", None, f"{len(routes)} routes for "
                                     f"{instance.n_aavs} AAVs")
            return Evaluation(False, None, (error,))
        traces = tuple(self.trace(n, route) for n, route in enumerate(routes))
        errors = tuple(e for t in traces for e in t.errors)
        if errors:
            return Evaluation(False, None, errors, traces=traces)
        by_task: list[dict[int, Contribution]] = [{} for _ in instance.tasks]
        for t in traces:
            for m, c in t.contributions:
                by_task[m][t.aav] = c
        per_task = []
        for m, members in enumerate(by_task):
            cost = self.task_cost(m, members.values())
            ids = {n: self._aav_ids[n] for n in members}
            t_end = self._latest_on_time[m]
            per_task.append(TaskBreakdown(
                task=instance.tasks[m].id,
                cost=cost,
                coalition=tuple(ids.values()),
                amounts={ids[n]: c.amount for n, c in members.items()},
                arrivals={ids[n]: c.arrival for n, c in members.items()},
                on_time={ids[n]: c.arrival <= t_end for n, c in members.items()},
            ))
        costs = [b.cost for b in per_task]
        terms = {
            "load": math.fsum(self.w1 * c.load for c in costs),
            "time": math.fsum(self.w2 * c.time for c in costs),
            "op": math.fsum(self.w3 * c.op for c in costs),
        }
        J = math.fsum(c.total for c in costs)
        return Evaluation(True, J, (), tuple(per_task), traces, terms)

    def cost(self, solution: Solution | Sequence[Route]) -> float:
        """J of a feasible solution; raises InfeasibleSolution otherwise."""
        result = self.evaluate(solution)
        if not result.feasible:
            raise InfeasibleSolution(result.errors)
        assert result.J is not None
        return result.J

    def state(self, routes: Sequence[Route]) -> PlanState:
        return PlanState(self, routes)


class InfeasibleSolution(ValueError):
    def __init__(self, errors: Sequence[FeasibilityError]) -> None:
        super().__init__("; ".join(str(e) for e in errors))
        self.errors = tuple(errors)


@dataclass(frozen=True, slots=True)
class Proposal:
    """A candidate replacement of one AAV's route, priced but not applied."""

    aav: int
    trace: RouteTrace
    delta: float  # J after minus J before
    task_costs: dict[int, TaskCost]  # new C_m of every task the change touches


class PlanState:
    """A feasible plan with its per-task contributions, for O(route) re-pricing of one AAV."""

    def __init__(self, evaluator: CostEvaluator, routes: Sequence[Route]) -> None:
        self.evaluator = evaluator
        n_tasks = evaluator.instance.n_tasks
        self.members: list[dict[int, Contribution]] = [{} for _ in range(n_tasks)]
        self.traces: list[RouteTrace] = []
        for n, route in enumerate(routes):
            trace = evaluator.trace(n, route)
            if not trace.feasible:
                raise InfeasibleSolution(trace.errors)
            self.traces.append(trace)
            for m, c in trace.contributions:
                self.members[m][n] = c
        self.task_costs = [evaluator.task_cost(m, self.members[m].values()) for m in
                           range(n_tasks)]
        # Eq. 19's sum per task, kept up to date by apply: the OCF games ask for it once per
        # visible task per decision, and a plan changes far less often than that.
        self._on_time = [self._on_time_sum(m) for m in range(n_tasks)]

    @property
    def routes(self) -> tuple[Route, ...]:
        return tuple(t.route for t in self.traces)

    @property
    def cost(self) -> float:
        return math.fsum(c.total for c in self.task_costs)

    @property
    def on_time(self) -> Sequence[int]:
        """``covered(m)`` of every task, by task index (read-only)."""
        return self._on_time

    def covered(self, m: int, exclude: int | None = None) -> int:
        """On-time kilograms of task m delivered by AAVs other than ``exclude`` (Eq. 19)."""
        own = self.members[m].get(exclude) if exclude is not None else None
        if own is None or own.arrival > self.evaluator._latest_on_time[m]:
            return self._on_time[m]
        return self._on_time[m] - own.amount

    def _on_time_sum(self, m: int) -> int:
        t_end = self.evaluator._latest_on_time[m]
        return sum(c.amount for c in self.members[m].values() if c.arrival <= t_end)

    def propose(self, n: int, route: Sequence[Visit]) -> Proposal | None:
        """Price replacing AAV n's route; None when the new route is infeasible."""
        trace = self.evaluator.trace(n, route)
        if trace.errors:
            return None
        return self.price(trace)

    def price(self, trace: RouteTrace) -> Proposal:
        n = trace.aav
        new = dict(trace.contributions)
        touched = {m for m, _ in self.traces[n].contributions} | new.keys()
        task_cost = self.evaluator.task_cost
        costs, delta = {}, 0.0
        for m in touched:
            others = [c for k, c in self.members[m].items() if k != n]
            if m in new:
                others.append(new[m])
            cost = task_cost(m, others)
            costs[m] = cost
            delta += cost.total - self.task_costs[m].total
        return Proposal(n, trace, delta, costs)

    def apply(self, proposal: Proposal) -> None:
        n = proposal.aav
        for m, _ in self.traces[n].contributions:
            del self.members[m][n]
        for m, c in proposal.trace.contributions:
            self.members[m][n] = c
        for m, cost in proposal.task_costs.items():
            self.task_costs[m] = cost
            self._on_time[m] = self._on_time_sum(m)
        self.traces[n] = proposal.trace

    def set_route(self, n: int, route: Sequence[Visit]) -> float:
        """Replace AAV n's route (must be feasible) and return the change in J."""
        proposal = self.propose(n, route)
        if proposal is None:
            raise InfeasibleSolution(self.evaluator.trace(n, route).errors)
        self.apply(proposal)
        return proposal.delta


def evaluate(instance: Instance, solution: Solution | Sequence[Route]) -> Evaluation:
    return CostEvaluator(instance).evaluate(solution)
