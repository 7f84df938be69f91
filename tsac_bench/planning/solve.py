"""One method on one instance: plan (once, or through the release events of a dynamic run),
check every plan against its planning state, and score the result with the evaluator. The
runner and the CLI both go through ``solve``."""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

from tsac_bench.errors import TsacBenchError
from tsac_bench.model import Instance, Solution
from tsac_bench.model.evaluator import Evaluation, costs_agree
from tsac_bench.planning.allocator import (
    ALL_MODES,
    Allocator,
    PlanningState,
    PlanStatus,
    claim_entries,
    mip_gap,
    supported_modes,
)
from tsac_bench.planning.budget import budgeted_settings, check_budget, is_over_budget
from tsac_bench.planning.registry import allocator_class, make_allocator
from tsac_bench.planning.settings import MethodSpec, parse_method_spec
from tsac_bench.planning.simulator import InvalidPlan, checked_plan, simulate

__all__ = ["InvalidPlan", "SolveOutcome", "recorded_settings", "solve"]


@dataclass(frozen=True)
class SolveOutcome:
    """``stats``: the plan's recorded stats (static, ``PlanResult.recorded_stats``), or
    ``{"replans": [...]}`` with one record per planning moment (dynamic, see
    ``simulator.Replan``). ``claimed_cost`` is the J the method computed itself
    (``PlanResult.cost``), of the last plan, if any. ``budget`` is the seconds each plan call
    had (None: the method's own stopping rule) and ``plan_seconds`` what each plan call took.
    ``status`` and ``lower_bound``: the plan's claims (``PlanResult``), static runs only: a
    re-plan's bound holds for plans that keep its committed prefixes, not for the run."""

    solution: Solution
    evaluation: Evaluation
    wall_time: float
    stats: Mapping[str, Any] = field(default_factory=dict)
    claimed_cost: float | None = None
    budget: float | None = None
    plan_seconds: tuple[float, ...] = ()
    status: PlanStatus | None = None
    lower_bound: float | None = None

    @property
    def over_budget(self) -> int:
        """How many plan calls returned later than their budget allows
        (``budget.is_over_budget``); 0 without a budget."""
        return sum(is_over_budget(seconds, self.budget) for seconds in self.plan_seconds)

    @property
    def cost(self) -> float:
        assert self.evaluation.J is not None
        return self.evaluation.J

    @property
    def gap(self) -> float | None:
        """``mip_gap`` of J and the lower bound; None without a bound."""
        return None if self.lower_bound is None else mip_gap(self.cost, self.lower_bound)

    @property
    def claim_matches(self) -> bool:
        """The method's own J agrees with the evaluator's (True when it claims none)."""
        if self.claimed_cost is None:
            return True
        return costs_agree(self.claimed_cost, self.cost)


def solve(instance: Instance, method: str | MethodSpec | Allocator, *, seed: int = 0,
          time_limit: float | None = None, mode: str = "static",
          settings: Mapping[str, Any] | None = None,
          budget: float | None = None) -> SolveOutcome:
    """Run ``method`` (a name, a method spec or its text, or an allocator) and return its
    solution scored by the evaluator; ``settings`` add to the spec's (not for an allocator).

    ``time_limit`` caps each plan call's own stopping rule. ``budget`` (seconds per plan
    call, instead of a time limit) is the time limit of each plan call, and an anytime method
    named by a spec is built to spend it (``budget.budgeted_settings``). Raises InvalidPlan
    when the method breaks the rules, so that no infeasible plan is ever reported with a
    cost."""
    if mode not in ALL_MODES:
        raise TsacBenchError(f"unknown mode {mode!r}; known modes: {', '.join(ALL_MODES)}")
    if budget is not None:
        if time_limit is not None:
            raise TsacBenchError("a budget and a time limit: give one (a budget is the time "
                                 "limit of every plan call)")
        time_limit = budget = check_budget(budget)
    if isinstance(method, str | MethodSpec):
        spec = (method if isinstance(method, MethodSpec) else parse_method_spec(method)
                ).with_settings(settings or {})
        if budget is not None:
            spec = MethodSpec(spec.name, budgeted_settings(spec.name, allocator_class(spec.name),
                                                           spec.settings))
        allocator = make_allocator(spec)
    else:
        allocator = method
    if mode not in supported_modes(allocator):
        supported = " and ".join(supported_modes(allocator))
        raise TsacBenchError(f"method {allocator.name!r} plans {supported} states only, "
                             f"not {mode!r} ones")
    if mode == "static":
        plan = checked_plan(allocator, PlanningState.static(instance), seed=seed,
                            time_limit=time_limit)
        routes, evaluation, wall = plan.routes, plan.evaluation, plan.wall_time
        stats, claimed = plan.result.recorded_stats(), plan.result.cost
        plan_seconds = (plan.wall_time,)
        status, bound = plan.result.status, plan.result.lower_bound
    else:
        run = simulate(instance, allocator, seed=seed, time_limit=time_limit)
        routes, evaluation, wall = run.routes, run.evaluation, run.wall_time
        stats = {"replans": [r.to_dict() for r in run.replans]}
        # Only the last plan is the executed one; earlier claims priced other plans.
        claimed = run.replans[-1].claimed_cost
        plan_seconds = tuple(r.wall_time for r in run.replans)
        status = bound = None
    meta = {"method": allocator.name, "mode": mode, "seed": seed,
            "settings": recorded_settings(allocator)}
    if budget is not None:
        meta["budget"] = budget
    meta.update(claim_entries(status, bound))  # the solution file keeps them as a store does
    solution = Solution(instance.name, routes, evaluation.J, meta)
    return SolveOutcome(solution, evaluation, wall, stats, claimed, budget, plan_seconds,
                        status, bound)


def recorded_settings(allocator: Allocator) -> dict[str, Any]:
    """The settings a run records for ``allocator``: every constructor keyword, a value JSON
    cannot hold as its ``repr``."""
    if not hasattr(allocator, "settings"):
        return {}
    return {k: v if isinstance(v, str | int | float | bool | None) else repr(v)
            for k, v in allocator.settings().items()}
