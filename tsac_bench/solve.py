"""One method on one instance: plan, check the plan against the planning state, and score
it with the evaluator. The runner and the CLI both go through ``solve``."""

from __future__ import annotations

import time
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

from tsac_bench.allocator import Allocator, PlanningState, make_allocator
from tsac_bench.errors import TsacBenchError
from tsac_bench.evaluator import CostEvaluator, Evaluation
from tsac_bench.model import Instance, Solution

MODES = ("static",)


class InvalidPlan(TsacBenchError):
    """An allocator returned routes its planning state forbids, or infeasible routes."""

    exit_code = 1


@dataclass(frozen=True)
class SolveOutcome:
    solution: Solution
    evaluation: Evaluation
    wall_time: float
    stats: Mapping[str, Any] = field(default_factory=dict)

    @property
    def cost(self) -> float:
        assert self.evaluation.J is not None
        return self.evaluation.J


def solve(instance: Instance, method: str | Allocator, *, seed: int = 0,
          time_limit: float | None = None, mode: str = "static",
          settings: Mapping[str, Any] | None = None) -> SolveOutcome:
    """Run ``method`` and return its solution scored by the evaluator.

    Raises InvalidPlan when the method breaks the rules, so that no infeasible plan is ever
    reported with a cost."""
    if mode not in MODES:
        raise TsacBenchError(f"unknown mode {mode!r}; known modes: {', '.join(MODES)}")
    allocator = make_allocator(method, **(settings or {})) if isinstance(method, str) else method
    state = PlanningState.static(instance)
    began = time.perf_counter()
    result = allocator.plan(state, seed=seed, time_limit=time_limit)
    wall = time.perf_counter() - began
    problems = state.violations(result.routes)
    if problems:
        raise InvalidPlan(f"{allocator.name} on {instance.name}: " + "; ".join(problems))
    evaluation = CostEvaluator(instance).evaluate(result.routes)
    if not evaluation.feasible:
        raise InvalidPlan(f"{allocator.name} on {instance.name}: infeasible plan: "
                          + "; ".join(str(e) for e in evaluation.errors))
    meta = {"method": allocator.name, "mode": mode, "seed": seed,
            "settings": _jsonable(allocator.settings()) if hasattr(allocator, "settings") else {}}
    solution = Solution(instance.name, result.routes, evaluation.J, meta)
    return SolveOutcome(solution, evaluation, wall, dict(result.stats))


def _jsonable(settings: Mapping[str, Any]) -> dict[str, Any]:
    return {k: v if isinstance(v, str | int | float | bool | None) else repr(v)
            for k, v in settings.items()}
