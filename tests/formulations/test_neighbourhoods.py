"""Large neighbourhood search with exact-bp repairs
(formulations/branch_price/neighbourhoods.py) against brute force and proven optima."""

from __future__ import annotations

import json
import random
from pathlib import Path

import pytest
from brute_force import _enumerate, _with_amounts
from plans import random_plan
from tiny import tiny_instance

from tsac_bench.formulations.branch_price.neighbourhoods import (
    Neighbourhood,
    centre_order,
    neighbourhood,
    repair,
    search,
)
from tsac_bench.formulations.branch_price.options import NeighbourhoodSettings
from tsac_bench.formulations.network import canonical_routes
from tsac_bench.model.evaluator import CostEvaluator
from tsac_bench.model.io import read_instance, read_solution

pytest.importorskip("highspy")

REGRESSION = Path(__file__).resolve().parents[2] / "instances" / "regression"
MANIFEST = json.loads((REGRESSION / "manifest.json").read_text())["instances"]


def proved(name: str):
    entry = MANIFEST[name]
    instance = read_instance(REGRESSION / entry["file"])
    return instance, entry["J_star"], read_solution(REGRESSION / entry["best_plan"],
                                                    instance).routes


@pytest.mark.parametrize("seed", range(8))
def test_a_repair_is_the_best_plan_of_its_neighbourhood_by_brute_force(seed: int) -> None:
    # AAV 0 holds its route of a random plan; AAV 1 may fly any route over the tasks in
    # reach (all three, or two of them on odd seeds) with any amounts. The least J over all
    # of those, by the evaluator, is what the repair must prove.
    instance = tiny_instance(seed, n_aavs=2, n_tasks=3, max_demand=4 + seed % 3)
    plan = canonical_routes(instance, random_plan(instance, seed))
    tasks = frozenset(range(instance.n_tasks)) if seed % 2 == 0 else frozenset({0, 1})
    plan = (plan[0], tuple(v for v in plan[1] if v.node >= instance.n_tasks or v.node in tasks))
    plan = canonical_routes(instance, plan)
    cost = CostEvaluator(instance).cost
    free = _enumerate(instance, 1)
    brute = min(cost((plan[0], _with_amounts(instance, route, vector)))
                for route, visited, vectors in zip(free.routes, free.visited, free.vectors,
                                                   strict=True)
                if set(visited.nonzero()[0]) <= tasks for vector in vectors)
    routes, status = repair(instance, plan, Neighbourhood(frozenset({1}), tasks), 60)
    assert status == "optimal"
    assert routes[0] == plan[0]  # held: not even extended
    assert {v.node for v in routes[1]} - set(instance.depot_nodes) <= tasks
    assert cost(routes) == pytest.approx(brute, rel=1e-9, abs=1e-12)


def test_the_aavs_freed_with_one_are_those_that_share_its_tasks_then_the_nearest():
    instance, _, optimum = proved("reg-static-4-10-s24")
    visited = [{v.node for v in route if v.node < instance.n_tasks} for route in optimum]
    around = max(range(instance.n_aavs), key=lambda n: max(
        len(visited[n] & visited[k]) for k in range(instance.n_aavs) if k != n))
    shared = {k: len(visited[around] & visited[k]) for k in range(instance.n_aavs)
              if k != around}
    assert max(shared.values()) > 0  # the optimum has a coalition
    area = neighbourhood(instance, optimum, around, 2, 3)
    (partner,) = area.free - {around}
    assert shared[partner] == max(shared.values())
    own = visited[around] | visited[partner]
    added = area.tasks - own
    assert own <= area.tasks and len(added) == 3
    dist = instance.dist
    reach = {m: min(dist[m][j] for j in own) for m in range(instance.n_tasks) if m not in own}
    assert max(reach[m] for m in added) <= min(reach[m] for m in reach if m not in added)


@pytest.mark.parametrize("seed", range(3))
def test_the_excess_order_starts_with_the_visitors_of_the_task_most_above_its_bound(
        seed: int) -> None:
    # Bounds made up so that every task costs exactly its bound but T2, 5 above it: its
    # visitors lead; every other AAV's excess is 0, so they keep the shuffled order.
    instance, _, optimum = proved("reg-static-4-10-s24")
    evaluator = CostEvaluator(instance)
    least = [task.cost.total for task in evaluator.evaluate(optimum).per_task]
    least[2] -= 5.0
    visitors = {n for n, route in enumerate(optimum) if any(v.node == 2 for v in route)}
    shuffled = centre_order(evaluator, optimum, random.Random(seed))
    assert sorted(shuffled) == list(range(instance.n_aavs))
    order = centre_order(evaluator, optimum, random.Random(seed), least)
    assert 0 < len(visitors) < instance.n_aavs
    assert set(order[:len(visitors)]) == visitors
    assert order[len(visitors):] == [n for n in shuffled if n not in visitors]


def test_an_unknown_order_is_refused_by_name() -> None:
    with pytest.raises(ValueError, match="order: 'cheapest' is not one of shuffled, excess"):
        NeighbourhoodSettings(order="cheapest")


@pytest.mark.parametrize(("aavs", "extra", "order"),
                         [(3, 6, "shuffled"), (2, 1, "shuffled"), (2, 1, "excess")])
def test_a_search_from_a_random_plan_ends_at_the_optimum(aavs: int, extra: int,
                                                         order: str) -> None:
    # reg-static-3-6-s2 (J* 5.069236). Every AAV and task free: one repair is exact-bp
    # itself. Two AAVs and one more task: those neighbourhoods end proved at 6.344003
    # (measured), then the search grows them to the whole fleet and reaches J*.
    instance, J_star, _ = proved("reg-static-3-6-s2")
    start = random_plan(instance, 0)
    cost = CostEvaluator(instance).cost
    plan, report = search(instance, start, 600,
                          NeighbourhoodSettings(aavs, extra, 60, order))
    assert cost(start) > 150
    assert cost(plan) == pytest.approx(J_star, rel=1e-9)
    assert report.largest == 3 and report.proved >= 1 and report.improved >= 1
