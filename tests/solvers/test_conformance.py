"""Every registered method obeys the allocator contract (docs/plugins.md).

Parametrized over ``available_methods()``, so a method registered later (built-in or
plug-in) is checked without touching this file. Instances are small and every plan call
gets ``TIME_LIMIT`` seconds, so that the exact solvers take part too.
"""

import pytest
from solver_cases import edge_cases, paper_x20, quick

from tsac_bench.errors import TsacBenchError
from tsac_bench.model.evaluator import CostEvaluator
from tsac_bench.model.io import read_solution, write_solution
from tsac_bench.planning import (
    MethodUnavailable,
    allocator_class,
    available_methods,
    supported_modes,
)
from tsac_bench.planning.solve import SolveOutcome, solve

TIME_LIMIT = 2.0
METHODS = available_methods()
EDGE = edge_cases()


@pytest.fixture(params=METHODS)
def method(request) -> str:
    try:
        allocator_class(request.param)
    except MethodUnavailable as exc:
        pytest.skip(str(exc))
    return request.param


def run(instance, method, mode, seed=0, time_limit=TIME_LIMIT) -> SolveOutcome:
    if mode not in supported_modes(allocator_class(method)):
        pytest.skip(f"{method} declares modes {supported_modes(allocator_class(method))}")
    outcome = solve(instance, method, seed=seed, time_limit=time_limit, mode=mode)
    # solve() already rejects forbidden and infeasible plans; the verdict is re-derived here
    # from the routes alone, as any reader of the solution file would.
    fresh = CostEvaluator(instance).evaluate(outcome.solution.routes)
    assert fresh.feasible, fresh.errors
    assert outcome.cost == fresh.J == outcome.solution.cost
    assert outcome.claim_matches, (outcome.claimed_cost, outcome.cost)
    return outcome


def test_an_undeclared_mode_is_refused_with_one_clear_line(method):
    unsupported = [m for m in ("static", "dynamic")
                   if m not in supported_modes(allocator_class(method))]
    if not unsupported:
        pytest.skip(f"{method} plans every mode")
    with pytest.raises(TsacBenchError, match=f"plans .* states only, not '{unsupported[0]}'"):
        solve(quick("quick-3-6-s3"), method, mode=unsupported[0])


def served(outcome, task_id) -> float:
    return next(b.cost.load for b in outcome.evaluation.per_task if b.task == task_id)


@pytest.mark.parametrize("mode", ["static", "dynamic"])
@pytest.mark.parametrize("name", ["quick-3-6-s3", "paper-small-x20"])
def test_feasible_and_scored_by_the_evaluator(method, mode, name, tmp_path):
    instance = paper_x20() if name == "paper-small-x20" else quick(name)
    outcome = run(instance, method, mode)
    assert outcome.solution.meta["method"] == method
    assert outcome.solution.meta["mode"] == mode
    # The solution file carries the same J back.
    path = tmp_path / "solution.json"
    write_solution(outcome.solution, instance, path)
    again = read_solution(path, instance)
    assert CostEvaluator(instance).cost(again) == outcome.cost == again.cost


def test_dynamic_run_records_every_planning_moment(method):
    instance = quick("quick-3-6-s3")
    outcome = run(instance, method, "dynamic")
    replans = outcome.stats["replans"]
    events = sorted({t.release for t in instance.tasks if t.release > 0})
    assert [r["time"] for r in replans] == [0.0, *events]
    assert replans[-1]["J"] == pytest.approx(outcome.cost, rel=1e-12)


def test_respects_its_time_budget(method):
    outcome = run(quick("quick-4-10-s5"), method, "static", time_limit=1.0)
    assert outcome.wall_time <= 2 * 1.0 + 3.0


def test_same_seed_same_result(method):
    instance = quick("quick-2-5-s2")
    for mode in ("static", "dynamic"):
        first, second = run(instance, method, mode, seed=7), run(instance, method, mode, seed=7)
        assert first.solution.routes == second.solution.routes
        assert first.cost == second.cost


@pytest.mark.parametrize("mode", ["static", "dynamic"])
def test_no_tasks(method, mode):
    outcome = run(EDGE["no-tasks"], method, mode)
    assert outcome.cost == 0.0
    assert all(route == () for route in outcome.solution.routes)


@pytest.mark.parametrize("mode", ["static", "dynamic"])
def test_one_aav(method, mode):
    instance = EDGE["one-aav"]
    outcome = run(instance, method, mode)
    # A 30 kg AAV with 35 kg of reachable, unhurried work serves some of it.
    assert outcome.cost < instance.unserved_task_cost * instance.n_tasks


@pytest.mark.parametrize("mode", ["static", "dynamic"])
def test_a_task_nobody_can_reach_in_time(method, mode):
    outcome = run(EDGE["unreachable"], method, mode)
    breakdown = {b.task: b for b in outcome.evaluation.per_task}
    assert breakdown["T1"].cost.load == 1.0
    assert breakdown["T1"].cost.total >= EDGE["unreachable"].unserved_task_cost
    assert breakdown["T0"].cost.load < 1.0  # the reachable task is still served


@pytest.mark.parametrize("mode", ["static", "dynamic"])
def test_a_demand_beyond_the_whole_fleet(method, mode):
    instance = EDGE["over-demand"]
    outcome = run(instance, method, mode)
    load = served(outcome, "T0")
    capacity = sum(a.capacity for a in instance.aavs)
    # Each AAV visits T0 at most once, so at most 40 of the 500 kg are ever covered; a
    # method still sends what it can.
    assert 1 - capacity / 500 - 1e-12 <= load < 1.0


def test_all_tasks_released_late(method):
    instance = EDGE["all-late"]
    outcome = run(instance, method, "dynamic")
    first = outcome.stats["replans"][0]
    assert first["time"] == 0.0 and first["visible"] == 0
    assert first["J"] == instance.unserved_task_cost * instance.n_tasks
    assert [r["time"] for r in outcome.stats["replans"]] == [0.0, 200.0, 400.0]
    assert outcome.cost < instance.unserved_task_cost * instance.n_tasks
