"""One method on one instance: plan (once, or through the release events of a dynamic run),
check every plan against its planning state, and score the result with the evaluator. The
runner and the CLI both go through ``solve``."""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

from tsac_bench.allocator import (
    ALL_MODES,
    Allocator,
    PlanningState,
    make_allocator,
    supported_modes,
)
from tsac_bench.errors import TsacBenchError
from tsac_bench.evaluator import Evaluation
from tsac_bench.model import Instance, Solution
from tsac_bench.simulator import InvalidPlan, checked_plan, simulate

__all__ = ["MODES", "InvalidPlan", "SolveOutcome", "solve"]

#: "static": every task known at t = 0, one plan call. "dynamic": the simulator's run.
MODES = ALL_MODES


@dataclass(frozen=True)
class SolveOutcome:
    """``stats``: the allocator's own stats (static), or ``{"replans": [...]}`` with one
    record per planning moment (dynamic, see ``simulator.Replan``). ``claimed_cost`` is the
    J the method computed itself (``PlanResult.cost``), of the last plan, if any."""

    solution: Solution
    evaluation: Evaluation
    wall_time: float
    stats: Mapping[str, Any] = field(default_factory=dict)
    claimed_cost: float | None = None

    @property
    def cost(self) -> float:
        assert self.evaluation.J is not None
        return self.evaluation.J

    @property
    def claim_matches(self) -> bool:
        """The method's own J agrees with the evaluator's (True when it claims none)."""
        if self.claimed_cost is None:
            return True
        return math.isclose(self.claimed_cost, self.cost, rel_tol=1e-6, abs_tol=1e-6)


def solve(instance: Instance, method: str | Allocator, *, seed: int = 0,
          time_limit: float | None = None, mode: str = "static",
          settings: Mapping[str, Any] | None = None) -> SolveOutcome:
    """Run ``method`` and return its solution scored by the evaluator.

    ``time_limit`` is the budget of each plan call. Raises InvalidPlan when the method
    breaks the rules, so that no infeasible plan is ever reported with a cost."""
    if mode not in MODES:
        raise TsacBenchError(f"unknown mode {mode!r}; known modes: {', '.join(MODES)}")
    allocator = make_allocator(method, **(settings or {})) if isinstance(method, str) else method
    if mode not in supported_modes(allocator):
        supported = " and ".join(supported_modes(allocator))
        raise TsacBenchError(f"method {allocator.name!r} plans {supported} states only, "
                             f"not {mode!r} ones")
    if mode == "static":
        plan = checked_plan(allocator, PlanningState.static(instance), seed=seed,
                            time_limit=time_limit)
        routes, evaluation, wall = plan.routes, plan.evaluation, plan.wall_time
        stats, claimed = dict(plan.result.stats), plan.result.cost
    else:
        run = simulate(instance, allocator, seed=seed, time_limit=time_limit)
        routes, evaluation, wall = run.routes, run.evaluation, run.wall_time
        stats = {"replans": [r.to_dict() for r in run.replans]}
        # Only the last plan is the executed one; earlier claims priced other plans.
        claimed = run.replans[-1].claimed_cost
    meta = {"method": allocator.name, "mode": mode, "seed": seed,
            "settings": _jsonable(allocator.settings()) if hasattr(allocator, "settings") else {}}
    solution = Solution(instance.name, routes, evaluation.J, meta)
    return SolveOutcome(solution, evaluation, wall, stats, claimed)


def _jsonable(settings: Mapping[str, Any]) -> dict[str, Any]:
    return {k: v if isinstance(v, str | int | float | bool | None) else repr(v)
            for k, v in settings.items()}
