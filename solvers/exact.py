"""``exact`` (Pyomo MILP solved by HiGHS), ``exact-cpsat`` (OR-Tools CP-SAT) and ``exact-bp``
(branch-and-price, formulations/branch_price/): the optimum of Problem 1 behind the
Allocator protocol.

Both start from the ``greedy`` plan (a MIP start for HiGHS, a hint for CP-SAT) and return it
when the solver finds nothing better in time. ``PlanResult.stats`` records status (optimal |
feasible | no-solution | error), the solver's objective, the evaluator's J of the returned
routes, lower bound, relative MIP gap, solver name and version, threads, seed, wall time and
the solver's stop reason.

``exact`` is exact for a dynamic PlanningState too: the committed prefixes are fixed arcs and
amounts of the MILP (a late committed visit keeps its C_time = 1), only visible tasks are
added. ``exact-cpsat`` solves static states (no committed visits) over the visible tasks and
refuses others: it is the independent cross-check of the offline optimum. ``exact-bp``
solves both kinds of state (each AAV's schedule starts at the end of its prefix) and starts
from the best of the greedy plan, the ``dga`` plan (2 000 generations from 20 tasks up), the
best of 100 ``hocf`` games and those games run as a dynamic run, each plan's routes columns
of its master.
"""

from __future__ import annotations

import time
from collections.abc import Sequence
from dataclasses import dataclass, fields
from typing import Any, ClassVar

from tsac_bench.errors import TsacBenchError
from tsac_bench.formulations.branch_price.options import BranchPriceOptions
from tsac_bench.model import Route
from tsac_bench.model.evaluator import CostEvaluator, costs_agree
from tsac_bench.planning import (
    Boolean,
    Interval,
    NoneOr,
    Options,
    PlanningState,
    PlanResult,
    Settings,
    declare,
    mip_gap,
)
from tsac_bench.planning.budget import TIME_LIMIT
from tsac_bench.solvers.greedy import GreedyAllocator

#: The share of exact-bp's time limit its start games may take at most (and, apart, the
#: incumbent method's run and the games' dynamic run each).
START_SHARE = 0.1
#: From this many tasks up exact-bp's incumbent method (DGA) runs INCUMBENT_GENERATIONS
#: generations, below it its own default: chosen on validation instances apart from
#: paper-mc (docs/formulations.md, "Branching and search").
INCUMBENT_FROM_TASKS = 20
INCUMBENT_GENERATIONS = 2000


def _limit(own: float | None, call: float | None) -> float | None:
    limits = [x for x in (own, call) if x is not None]
    return min(limits) if limits else None


def _greedy(state: PlanningState) -> tuple:
    return GreedyAllocator().plan(state).routes


class ExactAllocator(Settings):
    """The MILP of formulations/milp.py solved by HiGHS."""

    name = "exact"
    proves_optimality = True
    budget_use: ClassVar[str] = TIME_LIMIT
    setting_constraints = declare(
        time_limit=NoneOr(Interval(float, 0, None, closed="neither")),
        threads=Interval(int, 1, None),
        mip_rel_gap=Interval(float, 0, 1),
        **{option: Boolean() for option in ("warm_start", "symmetry", "capacity_cuts",
                                            "range_time_link", "time_flow", "cover_cuts")},
    )

    def __init__(self, time_limit: float | None = None, threads: int = 1,
                 mip_rel_gap: float = 1e-9, warm_start: bool = True,
                 symmetry: bool = True, capacity_cuts: bool = True,
                 range_time_link: bool = True, time_flow: bool = True,
                 cover_cuts: bool = True) -> None:
        self.time_limit = time_limit
        self.threads = threads
        self.mip_rel_gap = mip_rel_gap
        self.warm_start = warm_start
        self.symmetry = symmetry
        self.capacity_cuts = capacity_cuts
        self.range_time_link = range_time_link
        self.time_flow = time_flow
        self.cover_cuts = cover_cuts

    def plan(self, state: PlanningState, *, seed: int = 0,
             time_limit: float | None = None) -> PlanResult:
        from tsac_bench.formulations.milp import (
            MilpOptions,
            build_milp,
            canonical_warm_start,
            decode,
            solve_milp,
        )
        from tsac_bench.formulations.network import UnsupportedPrefix

        began = time.perf_counter()
        limit = _limit(self.time_limit, time_limit)
        instance = state.instance
        evaluator = state.evaluator()
        start = _greedy(state)
        stats: dict[str, Any] = {"warm_start_J": evaluator.cost(start)}
        try:
            # Every MilpOptions field is a setting of this method under the same name.
            options = MilpOptions(**{f.name: getattr(self, f.name) for f in fields(MilpOptions)})
            model = build_milp(instance, state.visible, state.committed, options, state.time)
        except UnsupportedPrefix as exc:
            stats.update(status="error", stop_reason=str(exc), J=stats["warm_start_J"])
            return PlanResult.from_solver(start, stats)
        built = time.perf_counter() - began
        warm = False
        if self.warm_start:
            canonical_warm_start(model, start, state.committed)
            warm = True
        remaining = None if limit is None else max(0.01, limit - (time.perf_counter() - began))
        report = solve_milp(model, time_limit=remaining, threads=self.threads,
                            mip_rel_gap=self.mip_rel_gap, seed=seed, warm=warm)
        routes = decode(model) if report.has_solution else start
        stats.update(report.as_stats())
        stats["build_time"] = built
        stats["wall_time"] = time.perf_counter() - began
        return _checked(state, evaluator, routes, stats)


class CpSatAllocator(Settings):
    """The CP-SAT model of formulations/cpsat.py (static states)."""

    name = "exact-cpsat"
    proves_optimality = True
    budget_use: ClassVar[str] = TIME_LIMIT
    modes = ("static",)
    setting_constraints = declare(
        time_limit=NoneOr(Interval(float, 0, None, closed="neither")),
        threads=Interval(int, 1, None),
        rel_gap=Interval(float, 0, 1),
        warm_start=Boolean(),
    )

    def __init__(self, time_limit: float | None = None, threads: int = 1,
                 rel_gap: float = 0.0, warm_start: bool = True) -> None:
        self.time_limit = time_limit
        self.threads = threads
        self.rel_gap = rel_gap
        self.warm_start = warm_start

    def plan(self, state: PlanningState, *, seed: int = 0,
             time_limit: float | None = None) -> PlanResult:
        from tsac_bench.formulations.cpsat import solve_cpsat_isolated
        from tsac_bench.formulations.network import canonical_routes

        if not state.at_start:
            raise TsacBenchError("exact-cpsat solves static planning states only (no "
                                 "committed visits, nothing planned after t = 0); use "
                                 "'exact' in a dynamic run")
        began = time.perf_counter()
        instance = state.instance
        evaluator = CostEvaluator(instance)
        start = _greedy(state)
        stats: dict[str, Any] = {"warm_start_J": evaluator.cost(start)}
        outcome = solve_cpsat_isolated(
            instance, sorted(state.visible), time_limit=_limit(self.time_limit, time_limit),
            threads=self.threads, seed=seed, rel_gap=self.rel_gap,
            hint_routes=canonical_routes(instance, start) if self.warm_start else None)
        routes = outcome.routes if outcome.routes is not None else start
        stats.update(outcome.stats)
        stats["wall_time"] = time.perf_counter() - began
        return _checked(state, evaluator, routes, stats, objective_key="scaled_objective",
                        check_objective=False)


@dataclass(frozen=True)
class BranchPriceAllocator(BranchPriceOptions, Settings):
    """Branch-and-price of formulations/branch_price/ (static and dynamic states): every
    field of BranchPriceOptions is a setting of this method under the same name."""

    name: ClassVar[str] = "exact-bp"
    proves_optimality: ClassVar[bool] = True
    budget_use: ClassVar[str] = TIME_LIMIT
    setting_constraints: ClassVar[Any] = declare(
        time_limit=NoneOr(Interval(float, 0, None, closed="neither")),
        incumbent=Options("dga", "greedy"),
        incumbent_generations=NoneOr(Interval(int, 0, None)),
        start_games=Interval(int, 0, None),
        rolling_start=Boolean(),
        **BranchPriceOptions.setting_constraints,
    )

    time_limit: float | None = None
    #: A method whose plan is a start besides greedy's ("greedy": none besides it).
    incumbent: str = "dga"
    #: Generations of the incumbent method's run (DGA's ``generations``), counted, not
    #: timed, so that the start is the same on any machine, and capped at START_SHARE of
    #: the time limit; None: DGA's own default below INCUMBENT_FROM_TASKS tasks and
    #: INCUMBENT_GENERATIONS from there up, where its longer run gave lower plans than the
    #: search's time would (docs/formulations.md, "Branching and search").
    incumbent_generations: int | None = None
    #: HOCF games whose best plan is a start too (0: none), counted in games, not seconds,
    #: so that the start is the same on any machine; chosen on validation instances apart
    #: from paper-mc (docs/formulations.md, "Branching and search").
    start_games: int = 100
    #: The same games run as a dynamic run plans (a rolling horizon: each release event
    #: plans again around what has been executed), the plan's stamps removed, as one more
    #: start of a static state with releases; from 16/40 up it was the best start on every
    #: validation instance measured (docs/formulations.md, "Branching and search").
    rolling_start: bool = True

    def plan(self, state: PlanningState, *, seed: int = 0,
             time_limit: float | None = None) -> PlanResult:
        return self.plan_from(state, (), seed=seed, time_limit=time_limit)

    def plan_from(self, state: PlanningState, plans: Sequence[tuple[Route, ...]], *,
                  seed: int = 0, time_limit: float | None = None) -> PlanResult:
        """``plan`` with ``plans`` among its starts, their routes columns of the master as
        every start's are: a search that begins where other runs ended (``tsac-bench bks
        improve`` gives it a set's best-known plan and the plans of earlier runs)."""
        from tsac_bench.formulations.branch_price import BranchPrice
        from tsac_bench.formulations.network import UnsupportedPrefix

        began = time.perf_counter()
        limit = _limit(self.time_limit, time_limit)
        instance = state.instance
        evaluator = state.evaluator()
        starts = self._starts(state, seed, limit) + list(plans)
        start = min(starts, key=evaluator.cost)
        stats: dict[str, Any] = {"warm_start_J": evaluator.cost(start),
                                 "warm_start_time": time.perf_counter() - began}
        options = BranchPriceOptions(**{f.name: getattr(self, f.name)
                                        for f in fields(BranchPriceOptions)})
        try:
            search = BranchPrice(instance, sorted(state.visible), state.committed, state.time,
                                 options)
        except UnsupportedPrefix as exc:
            stats.update(status="error", stop_reason=str(exc), J=stats["warm_start_J"])
            return PlanResult.from_solver(start, stats)
        remaining = None if limit is None else max(0.01, limit - (time.perf_counter() - began))
        result = search.solve(starts, remaining)
        stats.update(result.stats)
        # The master LPs are HiGHS's; the version recorded is highspy's.
        stats.update(objective=result.J, solver="branch-price", solver_version=_highs_version(),
                     threads=self.threads, seed=seed, wall_time=time.perf_counter() - began)
        return _checked(state, evaluator, result.routes, stats)

    def incumbent_settings(self, n_tasks: int) -> dict[str, Any]:
        """The incumbent method's settings for a planning state of ``n_tasks`` tasks."""
        generations = self.incumbent_generations
        if generations is None and n_tasks >= INCUMBENT_FROM_TASKS:
            generations = INCUMBENT_GENERATIONS
        return {} if generations is None else {"generations": generations}

    def _starts(self, state: PlanningState, seed: int, limit: float | None) -> list[tuple]:
        """The plans the search starts from: greedy's, the ``incumbent`` method's, the best
        of ``start_games`` HOCF games and, with ``rolling_start``, those games' dynamic run;
        the incumbent method and the games stop early only where they would take more than
        ``START_SHARE`` of the time limit each (the dynamic run's plan calls share another
        such share)."""
        from tsac_bench.planning import make_allocator
        from tsac_bench.planning.simulator import offline_routes, release_times, simulate

        starts = [_greedy(state)]
        cap = None if limit is None else START_SHARE * limit
        if self.incumbent != "greedy":
            incumbent = make_allocator(self.incumbent,
                                       **self.incumbent_settings(len(state.visible)))
            starts.append(incumbent.plan(state, seed=seed, time_limit=cap).routes)
        if self.start_games:
            games = make_allocator("hocf", samples=self.start_games)
            starts.append(games.plan(state, seed=seed, time_limit=cap).routes)
            events = release_times(state.instance)
            if (self.rolling_start and events and state.at_start
                    and len(state.visible) == state.instance.n_tasks):
                per_call = None if cap is None else cap / (1 + len(events))
                run = simulate(state.instance, games, seed=seed, time_limit=per_call)
                starts.append(offline_routes(run.routes))
        return starts


def _highs_version() -> str:
    from importlib.metadata import version

    return version("highspy")


def _checked(state: PlanningState, evaluator: CostEvaluator, routes: tuple,
             stats: dict[str, Any], objective_key: str = "objective",
             check_objective: bool = True) -> PlanResult:
    """Record the evaluator's J; an optimal solver objective that disagrees with it
    (``costs_agree``) marks the result as an error (a model bug), never silently passes.
    The lower bound is the better of the solver's and the tasks-on-their-own bound
    (formulations/task_bound.py), so a run stopped before its solver has one still has
    one; ``solver_lower_bound`` keeps the solver's own."""
    from tsac_bench.formulations.task_bound import task_lower_bound

    J = evaluator.cost(routes)
    stats["J"] = J
    objective = stats.get(objective_key)
    if (check_objective and stats.get("status") == "optimal" and objective is not None
            and not costs_agree(J, objective)):
        stats["status"] = "error"
        stats["stop_reason"] = f"solver objective {objective} != evaluator J {J}"
    stats["task_bound"] = task_lower_bound(state)
    stats["solver_lower_bound"] = stats.get("lower_bound")
    bound = max(b for b in (stats["solver_lower_bound"], stats["task_bound"]) if b is not None)
    stats["lower_bound"] = bound
    stats["mip_gap"] = mip_gap(J, bound)
    return PlanResult.from_solver(routes, stats)
