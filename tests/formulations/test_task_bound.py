"""The tasks-on-their-own lower bound (formulations/task_bound.py): hand-computed values,
never above an optimum (brute force, the regression set's J*, the MILP in dynamic states),
and reported by the exact methods when it beats their own bound."""

from __future__ import annotations

import json
import math
from pathlib import Path

import pytest
from brute_force import brute_force
from plans import random_plan
from tiny import tiny_instance

from tsac_bench.formulations.task_bound import task_lower_bound, task_lower_bounds
from tsac_bench.model import AAV, Depot, Instance, Task, TaskKind, Visit
from tsac_bench.model.evaluator import CostEvaluator
from tsac_bench.model.io import read_instance
from tsac_bench.planning import PlanningState

ROOT = Path(__file__).resolve().parents[2]
REGRESSION = ROOT / "instances" / "regression"

ROOMY = {"speed": 10.0, "capacity": 4, "max_range": 100_000.0, "alpha": 20.0, "lam": 200.0}


def pair_instance(kind: TaskKind, t_start: float) -> Instance:
    """Two AAVs on a depot, one 6 kg task 1 km away: only both together serve it all."""
    return Instance("pair", (AAV("A0", 1, 0, 0, **ROOMY), AAV("A1", 1, 0, 0, **ROOMY)),
                    (Depot("D0", 0, 0),),
                    (Task("T0", 1000, 0, kind, 6, t_start, t_start + 500),), horizon=1000.0)


def test_a_two_aav_coalition_by_hand() -> None:
    # Both arrive at 100 s (1 km at 10 m/s, by way of the depot, 0 m away): C_time 0.1;
    # each pays 20 per km * 1 km / E_base (20 * 100 + 200 = 2200). One AAV alone would
    # leave a third unserved (100 / 3 more), nobody costs 110.
    instance = pair_instance(TaskKind.DELIVERY, 0.0)
    expected = 10 * 0.1 + 2 * 20 / 2200
    assert task_lower_bound(PlanningState.static(instance)) == pytest.approx(expected, rel=1e-9)
    together = ((Visit(1), Visit(0, 3), Visit(1)), (Visit(1), Visit(0, 3), Visit(1)))
    assert CostEvaluator(instance).cost(together) == pytest.approx(expected, rel=1e-12)
    assert brute_force(instance)[0] == pytest.approx(expected, rel=1e-9)


def test_waiting_for_the_window_costs_no_time() -> None:
    # A pickup whose window opens after both can be there: only the legs are paid.
    instance = pair_instance(TaskKind.PICKUP, 300.0)
    assert task_lower_bound(PlanningState.static(instance)) == pytest.approx(2 * 20 / 2200,
                                                                              rel=1e-9)


def test_invisible_tasks_cost_110_and_committed_ones_0() -> None:
    instance = pair_instance(TaskKind.DELIVERY, 0.0)
    nothing_visible = PlanningState(instance, 10.0, frozenset(), ((), ()))
    assert task_lower_bound(nothing_visible) == 110.0
    assert task_lower_bounds(nothing_visible) == [110.0]
    committed = PlanningState(instance, 10.0, frozenset({0}), ((Visit(1), Visit(0, 3)), ()))
    assert task_lower_bound(committed) == 0.0
    assert task_lower_bounds(committed) == [0.0]


def test_a_late_plan_time_makes_the_coalition_later() -> None:
    # Planned at 50 s, the AAVs leave their starts then: at T0 at 150 s.
    instance = pair_instance(TaskKind.DELIVERY, 0.0)
    state = PlanningState(instance, 50.0, frozenset({0}), ((), ()))
    assert task_lower_bound(state) == pytest.approx(10 * 0.15 + 2 * 20 / 2200, rel=1e-9)


@pytest.mark.parametrize("seed", range(10))
def test_never_above_the_brute_force_optimum(seed: int) -> None:
    instance = tiny_instance(300 + seed, n_aavs=2, n_tasks=3, max_demand=5)
    optimum, _ = brute_force(instance)
    bound = task_lower_bound(PlanningState.static(instance))
    assert 0.0 < bound <= optimum + 1e-9


@pytest.mark.parametrize("seed", range(6))
def test_each_task_costs_at_least_its_own_bound_in_any_plan(seed: int) -> None:
    # Per task, not only in sum: the neighbourhood search's "excess" order reads a task's
    # cost above its own bound as what a repair could at best take off it.
    instance = tiny_instance(300 + seed, n_aavs=2, n_tasks=3, max_demand=5)
    state = PlanningState.static(instance)
    least = task_lower_bounds(state)
    assert math.fsum(least) == task_lower_bound(state)
    evaluator = CostEvaluator(instance)
    for routes in (brute_force(instance)[1], random_plan(instance, seed)):
        for m, task in enumerate(evaluator.evaluate(routes).per_task):
            assert least[m] <= task.cost.total + 1e-12, (m, task.cost)


def test_never_above_a_regression_optimum() -> None:
    manifest = json.loads((REGRESSION / "manifest.json").read_text())["instances"]
    for name, entry in manifest.items():
        instance = read_instance(REGRESSION / entry["file"])
        bound = task_lower_bound(PlanningState.static(instance))
        assert bound <= entry["J_star"] + 1e-9, name


def test_an_exact_method_without_a_bound_reports_this_one() -> None:
    from tsac_bench.solvers.exact import _checked

    instance = tiny_instance(301, n_aavs=2, n_tasks=3, max_demand=5)
    state = PlanningState.static(instance)
    _, routes = brute_force(instance)
    result = _checked(state, state.evaluator(), routes, {"status": "feasible"})
    stats = result.stats
    assert stats["solver_lower_bound"] is None
    assert result.lower_bound == stats["task_bound"] == task_lower_bound(state)
    assert stats["mip_gap"] == pytest.approx((stats["J"] - result.lower_bound) / stats["J"])
