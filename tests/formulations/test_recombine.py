"""Plans put together from other plans' routes (formulations/branch_price/recombine.py)."""

import itertools
import json
from pathlib import Path

import pytest

from tsac_bench.formulations.branch_price.recombine import recombined_plan
from tsac_bench.formulations.network import canonical_routes, identical_groups
from tsac_bench.formulations.pricing import schedule_route
from tsac_bench.model.io import read_instance, read_solution
from tsac_bench.planning import PlanningState
from tsac_bench.planning.solve import solve

INSTANCES = Path(__file__).resolve().parents[2] / "instances"


def proved(folder: str, name: str):
    directory = INSTANCES / folder
    entry = json.loads((directory / "manifest.json").read_text())["instances"][name]
    instance = read_instance(directory / entry["file"])
    return instance, entry, read_solution(directory / entry["best_plan"], instance).routes


@pytest.mark.parametrize(("folder", "name"), [
    ("regression", "reg-static-3-6-s2"), ("regression", "reg-static-4-10-s24"),
    ("paper-mc/4-10", "gen-4-10-s5")])
def test_an_optimum_split_over_two_worse_plans_is_put_together_again(folder, name):
    # Half the AAVs fly the optimum's routes in one plan and greedy's in the other: neither
    # plan is optimal, their routes hold the optimum, so an exact recombination finds J*.
    instance, entry, optimum = proved(folder, name)
    other = solve(instance, "greedy").solution.routes
    half = instance.n_aavs // 2
    plans = [optimum[:half] + other[half:], other[:half] + optimum[half:]]
    cost = PlanningState.static(instance).evaluator().cost
    assert min(map(cost, plans)) > entry["J_star"] * (1 + 1e-6)
    assert cost(recombined_plan(instance, plans, time_limit=60)) == pytest.approx(
        entry["J_star"], rel=1e-9)


def test_a_recombined_plan_is_never_worse_than_the_best_it_was_given():
    instance, _, _ = proved("paper-mc/4-10", "gen-4-10-s7")
    plans = [solve(instance, "dga", seed=seed, settings={"generations": 5}).solution.routes
             for seed in range(3)]
    cost = PlanningState.static(instance).evaluator().cost
    # A MIP stopped at once still has the best given plan as its start.
    assert cost(recombined_plan(instance, plans, time_limit=0.01)) <= min(map(cost, plans))


def test_a_recombined_plan_is_the_best_of_every_choice_of_routes_by_brute_force():
    # Every AAV may take any route of the plans (closed at its nearest depot, as a column
    # is), one of an identical AAV's, or none: the least J over all those choices, by the
    # evaluator, is what the MIP must find (canonical plans: no late visit for the master
    # to miss). Coalitions and arrival times both count here, so a MIP that prices the
    # time term wrongly picks another choice.
    instance, _, _ = proved("paper-mc/4-10", "gen-4-10-s4")
    plans = [canonical_routes(instance, solve(instance, "dga", seed=seed,
                                              settings={"generations": 5}).solution.routes)
             for seed in range(3)]
    plans.append(canonical_routes(instance, solve(instance, "greedy").solution.routes))
    twins = {n: [n] for n in range(instance.n_aavs)}
    for group in identical_groups(instance, ()):
        for n in group:
            twins[n] = group
    choices = [{()} for _ in range(instance.n_aavs)]
    for plan in plans:
        for n, route in enumerate(plan):
            tail = list(route[:-1]) if route else []
            for k in twins[n]:
                choices[k].add(schedule_route(instance, (), tail) if tail else ())
    cost = PlanningState.static(instance).evaluator().cost
    brute = min(cost(routes) for routes in itertools.product(*choices))
    assert brute < min(map(cost, plans)) - 1e-6  # the choices hold a better plan
    assert cost(recombined_plan(instance, plans, time_limit=60)) <= brute + 1e-9
