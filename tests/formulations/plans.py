"""Random feasible plans (late visits, depot detours and splits included) for the tests."""

from __future__ import annotations

import random

from tsac_bench.model import Instance, Route
from tsac_bench.model.evaluator import CostEvaluator
from tsac_bench.planning.insertion import best_insertion


def random_plan(instance: Instance, seed: int) -> tuple[Route, ...]:
    """Insert tasks in random order into random AAVs at their cheapest feasible position,
    whether or not that lowers J, with random residuals (so amounts split and overshoot)."""
    rng = random.Random(seed)
    plan = CostEvaluator(instance).state(tuple(() for _ in instance.aavs))
    for _ in range(2 * instance.n_tasks):
        task = rng.randrange(instance.n_tasks)
        n = rng.randrange(instance.n_aavs)
        residual = rng.randint(1, instance.tasks[task].demand + 2)
        proposal = best_insertion(plan, n, task, residual=residual)
        if proposal is not None:
            plan.apply(proposal)
    return plan.routes
