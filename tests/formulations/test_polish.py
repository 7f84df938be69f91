"""Split polishing: optimal amounts for fixed sequences, never worse."""

from __future__ import annotations

import itertools

import pytest
from plans import random_plan
from tiny import tiny_instance

from tsac_bench.model import Solution, Visit
from tsac_bench.model.evaluator import CostEvaluator
from tsac_bench.planning.polish import polish, polish_routes

pytest.importorskip("cvxpy")


def best_amounts_by_enumeration(instance, routes):
    """Every amount vector (1..B per visit) for the fixed sequences; the lowest J."""
    evaluator = CostEvaluator(instance)
    slots = [(n, k) for n, r in enumerate(routes) for k, v in enumerate(r)
             if not instance.is_depot(v.node)]
    ranges = [range(1, instance.aavs[n].capacity + 1) for n, _ in slots]
    best = evaluator.cost(routes)
    for amounts in itertools.product(*ranges):
        candidate = [list(r) for r in routes]
        for (n, k), a in zip(slots, amounts, strict=True):
            candidate[n][k] = Visit(candidate[n][k].node, a)
        result = evaluator.evaluate([tuple(r) for r in candidate])
        if result.feasible and best > result.J:
            best = result.J
    return best


@pytest.mark.parametrize("seed", range(8))
def test_polish_finds_the_best_amounts_of_the_sequences(seed: int) -> None:
    instance = tiny_instance(seed, n_aavs=2, n_tasks=3, max_demand=6)
    routes = random_plan(instance, seed)
    polished = polish_routes(instance, routes)
    evaluator = CostEvaluator(instance)
    assert [[v.node for v in r] for r in polished] == [[v.node for v in r] for r in routes]
    assert evaluator.cost(polished) == pytest.approx(
        best_amounts_by_enumeration(instance, routes), rel=1e-9, abs=1e-9)


def test_polish_never_worsens_and_improves_random_plans() -> None:
    improved = 0
    for seed in range(12):
        instance = tiny_instance(seed, n_aavs=3, n_tasks=5, max_demand=6)
        routes = random_plan(instance, seed)
        solution = Solution(instance.name, routes)
        before = CostEvaluator(instance).cost(routes)
        after = polish(instance, solution)
        assert after.cost <= before + 1e-12
        assert after.cost == pytest.approx(CostEvaluator(instance).cost(after.routes))
        improved += after.cost < before - 1e-9
    assert improved >= 3


def test_polishing_a_dynamic_run_keeps_its_stamps_and_recorded_loads(hand):
    # A0 (30 kg) left D0 with 10 kg on record: T1 (20 kg) and T3 (10 kg) would take 30 kg
    # offline, but this trip can deliver only the 10 kg it loaded; the stamps stay.
    d0, t1, t3 = (hand.node_index[i] for i in ("D0", "T1", "T3"))
    route = (Visit(d0, load=10), Visit(t1, 5, planned_at=100.0), Visit(t3, 5, planned_at=100.0),
             Visit(d0, planned_at=100.0))
    polished = polish_routes(hand, (route, ()))
    assert CostEvaluator(hand).evaluate(polished).feasible
    assert [v.planned_at for v in polished[0]] == [None, 100.0, 100.0, 100.0]
    assert polished[0][1].amount + polished[0][2].amount <= 10
    unrecorded = tuple(v._replace(load=None) for v in route)
    assert sum(v.amount for v in polish_routes(hand, (unrecorded, ()))[0]) == 30
