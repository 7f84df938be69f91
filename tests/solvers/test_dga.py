import itertools

import pytest
from replan import replan_state

from tsac_bench.errors import InvalidSetting
from tsac_bench.model import Visit
from tsac_bench.model.evaluator import CostEvaluator
from tsac_bench.model.generator import generate
from tsac_bench.model.io import instance_from_dict
from tsac_bench.planning import PlanningState, make_allocator
from tsac_bench.planning.solve import solve
from tsac_bench.solvers.dga import DGAAllocator

SMALL = {"islands": 2, "population": 4, "generations": 6, "migration_interval": 3}


def untimed(stats: dict) -> dict:
    """A plan call's stats without its clock readings (the trace's J values kept)."""
    return {**{k: v for k, v in stats.items() if k != "seconds"},
            "trace": [cost for _, cost in stats["trace"]]}


def test_best_J_never_rises_and_ends_at_the_returned_plan():
    # Every child mutated: without elitism this run's best rises (checked by hand).
    instance = generate("8/20", seed=3)
    dga = DGAAllocator(islands=2, population=4, generations=12, migration_interval=4,
                       mutation_rate=1.0)
    result = dga.plan(PlanningState.static(instance), seed=0)
    history = result.stats["best_J_per_generation"]
    assert result.stats["generations"] == 12 and len(history) == 13
    assert all(later <= earlier for earlier, later in itertools.pairwise(history))
    assert history[-1] < history[0]  # the search does improve on its initial population
    assert CostEvaluator(instance).cost(result.routes) == pytest.approx(history[-1], abs=1e-9)


def test_deterministic_per_seed():
    state = PlanningState.static(generate("8/20", seed=4))
    runs = [DGAAllocator(**SMALL).plan(state, seed=seed) for seed in (7, 7, 8)]
    assert runs[0].routes == runs[1].routes
    assert untimed(runs[0].stats) == untimed(runs[1].stats)
    assert untimed(runs[0].stats) != untimed(runs[2].stats)


def test_islands_in_worker_processes_give_the_same_plan():
    state = PlanningState.static(generate("4/10", seed=2))
    here = DGAAllocator(**SMALL).plan(state, seed=3)
    apart = DGAAllocator(**SMALL, workers=2).plan(state, seed=3)
    assert apart.routes == here.routes
    assert untimed(apart.stats) == untimed(here.stats)


def test_finds_the_optimum_of_a_two_task_instance():
    # Each AAV waits at its depot 1 km from one task; anything else flies further or leaves
    # a task unserved (110). Type-2 AAVs: 20 m/s, alpha 10, E_base 800.
    light = {"type": 2, "speed": 20, "capacity": 10, "max_range": 30000, "alpha": 10,
             "lam": 500}
    hand = instance_from_dict({
        "format": "tsac-bench/instance@1", "name": "dga-hand", "horizon": 3600,
        "weights": [100, 10, 1],
        "aavs": [{"id": "A0", "x": 0, "y": 0, **light}, {"id": "A1", "x": 6000, "y": 0, **light}],
        "depots": [{"id": "D0", "x": 0, "y": 0}, {"id": "D1", "x": 6000, "y": 0}],
        "tasks": [{"id": "T0", "x": 0, "y": 1000, "kind": "D", "demand": 5, "t_start": 0,
                   "t_end": 3600, "release": 0},
                  {"id": "T1", "x": 6000, "y": 1000, "kind": "P", "demand": 5, "t_start": 0,
                   "t_end": 3600, "release": 0}],
    })
    outcome = solve(hand, "dga", seed=0, settings=SMALL)
    assert outcome.solution.routes == ((Visit(2), Visit(0, 5), Visit(2)),
                                       (Visit(1, 5), Visit(3)))
    assert outcome.cost == pytest.approx(2 * (10 * 50 / 3600 + 10 * 1 / 800), abs=1e-12)


@pytest.mark.parametrize("t", [500.0, 1800.0])
def test_a_replan_keeps_prefixes_and_starts_from_the_incumbent(paper_x20, t):
    routes = solve(paper_x20, "greedy").solution.routes
    state = replan_state(paper_x20, routes, t)
    assert any(state.committed)
    result = DGAAllocator(**SMALL).plan(state, seed=1)
    assert state.violations(result.routes) == []
    evaluator = CostEvaluator(paper_x20)
    assert evaluator.evaluate(result.routes).feasible
    # The initial population holds the incumbent, repaired: it can only be better.
    history = result.stats["best_J_per_generation"]
    assert history[0] <= evaluator.cost(state.warm_routes()) + 1e-9


def test_static_plans_are_feasible(paper_x20):
    outcome = solve(paper_x20, "dga", seed=0, settings=SMALL)
    t7 = next(b for b in outcome.evaluation.per_task if b.task == "T7")
    assert sum(t7.amounts.values()) >= 30  # a 60 kg pickup needs a coalition anyway
    assert outcome.cost < paper_x20.unserved_task_cost * paper_x20.n_tasks


def test_a_spent_time_budget_returns_the_initial_population_best():
    state = PlanningState.static(generate("8/20", seed=1))
    result = DGAAllocator(**SMALL).plan(state, seed=0, time_limit=0.0)
    assert result.stats["stop"] == "time-limit" and result.stats["generations"] == 0
    assert state.violations(result.routes) == []
    assert CostEvaluator(state.instance).evaluate(result.routes).feasible


def test_a_budget_evolves_past_the_generation_cap_and_counts_individuals():
    """Without a generation cap the first 25 generations are the plain call's (the same
    epochs, the same streams), so the budgeted plan is never worse; 2 islands of 8 build 16
    individuals first and 14 per generation (the elite survives), so 25 generations are
    16 + 25 * 14 = 366 individuals."""
    state = PlanningState.static(generate("4/10", seed=2))
    plain = make_allocator("dga").plan(state, seed=3)
    assert plain.stats["work"] == 16 + 25 * 14
    budgeted = make_allocator("dga:generations=none").plan(state, seed=3, time_limit=1.5)
    assert budgeted.stats["generations"] > 25
    assert budgeted.stats["best_J_per_generation"][:26] == plain.stats["best_J_per_generation"]
    assert budgeted.stats["trace"][-1][1] == min(budgeted.stats["best_J_per_generation"])
    # An individual cap stops it mid-generation, exactly there.
    capped = make_allocator("dga:generations=none:evaluations=50").plan(state, seed=3)
    assert capped.stats["work"] == 50 and capped.stats["stop"] == "work"


@pytest.mark.parametrize(("settings", "message"), [
    ({"islands": 0}, "setting 'islands': got 0; allowed: an integer >= 1"),
    ({"population": 2, "elite": 2}, "setting 'elite': got 2; allowed: an integer in "
                                    "[0, population=2)"),
    # The default elite (1) no longer fits a population of one.
    ({"population": 1}, "setting 'migrants': got 1 (its default); allowed: an integer in "
                        "[0, population=1)"),
    ({"mutation_rate": 1.5}, "setting 'mutation_rate': got 1.5; allowed: a number in [0, 1]"),
    ({"candidates": 2.5}, "setting 'candidates': got 2.5; allowed: an integer >= 1"),
])
def test_bad_settings_are_clear_errors(settings, message):
    with pytest.raises(InvalidSetting, match="method 'dga' ") as caught:
        make_allocator("dga", **settings)
    assert message in str(caught.value)
