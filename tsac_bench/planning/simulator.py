"""The dynamic run of docs/model.md: plan at t = 0, re-plan at every release time with the
committed prefixes fixed, evaluate the executed routes from scratch.

Rules (docs/model.md, "The dynamic run"):

* At t = 0 the allocator sees the tasks released at 0 and plans freely.
* At each distinct release time t_e > 0, AAV n's committed prefix is every visit k of the
  plan in force whose previous node it has left by t_e (dep_k <= t_e; the start position
  counts as left at time 0). The allocator then plans again and may change anything after the
  prefixes, never the prefixes.
* Physics is written into the routes (docs/model.md): every visit a plan at t_e > 0 places after
  the prefixes gets ``planned_at = t_e`` (the AAV leaves no earlier; an idle AAV leaves at
  t_e, not at its last arrival), and a depot visit the AAV has left by t_e gets ``load`` =
  the delivery goods the plan in force had it carry (a later plan may not deliver more from
  that trip). Depots left after the last re-plan load what the executed route delivers, which
  is Eq. 10 itself, so they need no record; a run without events has no stamps at all.
* The allocator sees the released tasks that are not yet finished. A task is *finished* at
  t_e when its committed visits already cover its demand on time, or when its window has
  closed (t_end < t_e): a visit made after t_e cannot lower its cost (C_load is already 0
  or the visit is late; it only adds C_op or makes C_time 1).
* Every plan is checked: it must keep every prefix (stamps included), visit only visible
  tasks, write no stamp itself and be feasible with its stamps (no delivery beyond a
  recorded load). A plan that breaks a rule stops the run with ``InvalidPlan``.
* The executed routes are the last plan's routes (nothing changes after the last event);
  they are evaluated from scratch. Tasks never served cost w1 + w2 like any other.

The release guarantee is an information guarantee: an allocator only ever sees released
tasks and cannot change a committed prefix; the stamps make the executed routes physical.
"""

from __future__ import annotations

import math
import time
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from tsac_bench.errors import TsacBenchError
from tsac_bench.model import Instance, Route, Visit
from tsac_bench.model.evaluator import CostEvaluator, Evaluation, RouteTrace
from tsac_bench.planning.allocator import Allocator, PlanningState, PlanResult


class InvalidPlan(TsacBenchError):
    """An allocator returned routes its planning state forbids, or infeasible routes."""

    exit_code = 1


@dataclass(frozen=True)
class CheckedPlan:
    """One plan call that passed every check: its routes with the stamps of its planning
    moment, and the evaluator's verdict on them."""

    result: PlanResult
    routes: tuple[Route, ...]
    evaluation: Evaluation
    wall_time: float


def checked_plan(allocator: Allocator, state: PlanningState, *, seed: int,
                 time_limit: float | None) -> CheckedPlan:
    """Call ``allocator.plan`` and reject what the state forbids or the evaluator refuses."""
    instance = state.instance
    began = time.perf_counter()
    result = allocator.plan(state, seed=seed, time_limit=time_limit)
    wall = time.perf_counter() - began
    where = f"{allocator.name} on {instance.name} at t={state.time:g}"
    problems = state.violations(result.routes)
    if problems:
        raise InvalidPlan(f"{where}: " + "; ".join(problems))
    routes = stamped(state, result.routes)
    evaluation = CostEvaluator(instance).evaluate(routes)
    if not evaluation.feasible:
        raise InvalidPlan(f"{where}: infeasible plan: "
                          + "; ".join(str(e) for e in evaluation.errors))
    return CheckedPlan(result, routes, evaluation, wall)


def stamped(state: PlanningState, routes: Sequence[Route]) -> tuple[Route, ...]:
    """``routes`` as executed from ``state.time`` on: every visit after a committed prefix
    planned then (at t = 0 that changes nothing, and none is written)."""
    if state.time <= 0:
        return tuple(routes)
    return tuple((*route[:state.first_free(n)],
                  *(v._replace(planned_at=state.time) for v in route[state.first_free(n):]))
                 for n, route in enumerate(routes))


def committed_prefixes(instance: Instance, traces: Sequence[RouteTrace],
                       t: float) -> tuple[Route, ...]:
    """Every AAV's visits already under way at time ``t`` > 0: visit k is committed when the
    AAV left the previous node by ``t`` (dep_k <= t; the start is left at time 0 unless the
    first visit was planned later). A depot visit the AAV has left records the delivery goods
    it loaded there, Omega of the plan in force, unless an earlier re-plan recorded them."""
    prefixes = []
    for trace in traces:
        length = sum(1 for dep in trace.departures if dep <= t)
        prefix = list(trace.route[:length])
        for k in range(length - 1):  # the last committed visit has not been left yet
            if instance.is_depot(prefix[k].node) and prefix[k].load is None:
                prefix[k] = prefix[k]._replace(load=trace.delivery_load[k])
        prefixes.append(tuple(prefix))
    return tuple(prefixes)


def finished_tasks(instance: Instance, traces: Sequence[RouteTrace],
                   prefixes: Sequence[Route], t: float) -> frozenset[int]:
    """Tasks a re-plan at ``t`` can no longer improve: window closed (t_end < t) or demand
    covered on time by committed visits."""
    covered = [0] * instance.n_tasks
    for trace, prefix in zip(traces, prefixes, strict=True):
        for (m, amount, *_), arrival in zip(prefix, trace.arrivals, strict=False):
            if m < instance.n_tasks and instance.tasks[m].on_time(arrival):
                covered[m] += amount
    return frozenset(m for m, task in enumerate(instance.tasks)
                     if task.t_end < t or covered[m] >= task.demand)


@dataclass(frozen=True)
class Replan:
    """One planning moment of a run: what was known, what was fixed, what the plan costs.

    ``J`` is the plan's cost over every task of the instance (docs/model.md); ``J_known`` over the
    tasks released by ``time`` and ``J_known_before`` the same for the plan in force just
    before (the new tasks still unserved): the jump and drop of the paper's Fig. 5 curve."""

    time: float
    released: tuple[str, ...]
    visible: int
    committed: int
    J: float
    J_known: float
    J_known_before: float | None
    wall_time: float
    claimed_cost: float | None = None  # the plan's J as the allocator computed it
    stats: Mapping[str, Any] = field(default_factory=dict)

    def to_dict(self) -> dict[str, Any]:
        return {"time": self.time, "released": list(self.released), "visible": self.visible,
                "committed": self.committed, "J": self.J, "J_known": self.J_known,
                "J_known_before": self.J_known_before, "wall_time": self.wall_time,
                "claimed_cost": self.claimed_cost, "stats": dict(self.stats)}


@dataclass(frozen=True)
class SimulationResult:
    routes: tuple[Route, ...]
    evaluation: Evaluation
    replans: tuple[Replan, ...]
    wall_time: float  # time spent inside the allocator's plan calls


def offline_routes(routes: Sequence[Route]) -> tuple[Route, ...]:
    """``routes`` with the dynamic run's stamps removed: an offline plan of no higher J
    (docs/model.md, "The dynamic run")."""
    return tuple(tuple(Visit(v.node, v.amount) for v in route) for route in routes)


def release_times(instance: Instance) -> list[float]:
    """The distinct release times after 0, in order: the events of a dynamic run."""
    return sorted({float(t.release) for t in instance.tasks if t.release > 0})


def simulate(instance: Instance, allocator: Allocator, *, seed: int = 0,
             time_limit: float | None = None) -> SimulationResult:
    """Run ``allocator`` through the release events of ``instance``.

    ``time_limit`` is the budget of each plan call (an online decision), not of the run.
    Equal seeds give equal runs."""
    evaluator = CostEvaluator(instance)
    released_at = [t.release for t in instance.tasks]

    def known_cost(evaluation: Evaluation, t: float) -> float:
        return math.fsum(b.cost.total for m, b in enumerate(evaluation.per_task)
                         if released_at[m] <= t)

    state = PlanningState(instance, 0.0, instance.released_by(0.0))
    replans: list[Replan] = []
    plan: CheckedPlan | None = None
    total_wall = 0.0
    for i, t in enumerate([0.0, *release_times(instance)]):
        if plan is not None:
            traces = plan.evaluation.traces
            prefixes = committed_prefixes(instance, traces, t)
            visible = instance.released_by(t) - finished_tasks(instance, traces, prefixes, t)
            # The plan in force as a warm start: the visits after the prefixes are to be
            # planned again, so they carry no stamp yet.
            incumbent = tuple((*prefix, *(v._replace(planned_at=None)
                                          for v in route[len(prefix):]))
                              for prefix, route in zip(prefixes, plan.routes, strict=True))
            state = PlanningState(instance, t, visible, prefixes, incumbent)
        before = None if plan is None else known_cost(plan.evaluation, t)
        # The first call gets the run's seed itself, so a run without events is exactly
        # the static plan call; later calls get independent seeds derived from it, kept below
        # 2**31 because some solvers (CP-SAT) take only a signed 32-bit seed.
        plan_seed = seed if i == 0 else int(np.random.SeedSequence([seed, i])
                                            .generate_state(1)[0] >> 1)
        plan = checked_plan(allocator, state, seed=plan_seed, time_limit=time_limit)
        total_wall += plan.wall_time
        assert plan.evaluation.J is not None
        replans.append(Replan(
            time=t,
            released=tuple(instance.tasks[m].id for m, r in enumerate(released_at) if r == t),
            visible=len(state.visible),
            committed=sum(len(p) for p in state.committed),
            J=plan.evaluation.J,
            J_known=known_cost(plan.evaluation, t),
            J_known_before=before,
            wall_time=plan.wall_time,
            claimed_cost=plan.result.cost,
            stats=plan.result.recorded_stats(),
        ))
    assert plan is not None
    final = evaluator.evaluate(plan.routes)
    return SimulationResult(plan.routes, final, tuple(replans), total_wall)
