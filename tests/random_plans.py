"""Random feasible plans for property tests: each task visit joins the current trip when
the evaluator allows it and a coin says so, else starts a trip of its own."""

import numpy as np

from tsac_bench.model import Instance, Route, Visit
from tsac_bench.model.evaluator import CostEvaluator


def random_route(instance: Instance, n: int, rng: np.random.Generator,
                 evaluator: CostEvaluator, max_tasks: int = 6) -> Route:
    capacity = instance.aavs[n].capacity
    count = int(rng.integers(0, min(max_tasks, instance.n_tasks) + 1))
    tasks = rng.permutation(instance.n_tasks)[:count]
    depots = list(instance.depot_nodes)
    route: list[Visit] = []
    for m in tasks:
        visit = Visit(int(m), int(rng.integers(1, min(capacity, instance.tasks[m].demand) + 1)))
        home = Visit(int(rng.choice(depots)))
        # A trip of its own is always feasible: the depot before it loads only this visit.
        separate = [*(route or [Visit(int(rng.choice(depots)))]), visit, home]
        merged = [*route[:-1], visit, home]
        share_trip = route and rng.random() < 0.5 and evaluator.trace(n, merged).feasible
        route = merged if share_trip else separate
    assert evaluator.trace(n, route).feasible
    return tuple(route)


def random_plan(instance: Instance, seed: int, max_tasks: int = 6) -> tuple[Route, ...]:
    rng = np.random.default_rng(seed)
    evaluator = CostEvaluator(instance)
    return tuple(random_route(instance, n, rng, evaluator, max_tasks)
                 for n in range(instance.n_aavs))
