"""Every method's dynamic runs are physical (docs/model.md, "The dynamic run"), checked on the
executed routes alone, over seeded random instances:

* no AAV leaves for a visit before its ``planned_at``, nor toward a task before its release;
* every depot visit the AAV left by the last re-plan records its load, and no trip delivers
  more than its depot's recorded load;
* with the stamps removed the routes are a feasible offline solution of no higher J.
"""

import pytest

from tsac_bench.model.evaluator import CostEvaluator
from tsac_bench.model.generator import generate
from tsac_bench.planning import (
    MethodUnavailable,
    allocator_class,
    available_methods,
    supported_modes,
)
from tsac_bench.planning.simulator import release_times
from tsac_bench.planning.solve import solve

#: (scale, seed) of the random instances; the exact MILP gets the smallest only.
CASES = [("3/6", 1), ("3/6", 2), ("4/10", 3)]
EXACT_CASES = CASES[:1]
TIME_LIMIT = 1.0


def dynamic_methods() -> list[str]:
    methods = []
    for name in available_methods():
        try:
            if "dynamic" in supported_modes(allocator_class(name)):
                methods.append(name)
        except MethodUnavailable:
            continue
    return methods


def physical_violations(instance, routes) -> list[str]:
    """What in the executed ``routes`` no AAV could have flown."""
    evaluator = CostEvaluator(instance)
    last_replan = max(release_times(instance), default=0.0)
    problems = []
    for n, route in enumerate(routes):
        trace = evaluator.trace(n, route)
        for k, v in enumerate(route):
            departure = trace.departures[k]
            if v.planned_at is not None and departure < v.planned_at:
                problems.append(f"{n}[{k}]: left at {departure} before planned {v.planned_at}")
            if v.node < instance.n_tasks and departure < instance.tasks[v.node].release:
                problems.append(f"{n}[{k}]: left at {departure} toward a task released at "
                                f"{instance.tasks[v.node].release}")
            if not instance.is_depot(v.node) or k + 1 == len(route):
                continue
            trip = route[k + 1:]
            end = next((i for i, w in enumerate(trip) if instance.is_depot(w.node)), len(trip))
            needed = sum(w.amount for w in trip[:end] if instance.tasks[w.node].is_delivery)
            if v.load is not None and needed > v.load:
                problems.append(f"{n}[{k}]: trip delivers {needed} kg, loaded {v.load} kg")
            # Left by the last re-plan under a plan made before it: the load is on record.
            planned = route[k + 1].planned_at or 0.0
            if v.load is None and planned < last_replan and \
                    trace.departures[k + 1] <= last_replan:
                problems.append(f"{n}[{k}]: depot left at {trace.departures[k + 1]} by the "
                                f"re-plan at {last_replan} records no load")
    return problems


@pytest.mark.parametrize("method", dynamic_methods())
def test_dynamic_runs_are_physical_and_no_better_than_offline(method):
    stamps = loads = 0
    for scale, seed in EXACT_CASES if method == "exact" else CASES:
        instance = generate(scale, seed)
        outcome = solve(instance, method, seed=seed, time_limit=TIME_LIMIT, mode="dynamic")
        routes = outcome.solution.routes
        assert physical_violations(instance, routes) == []
        stamps += sum(v.planned_at is not None for r in routes for v in r)
        loads += sum(v.load is not None for r in routes for v in r)
        offline = tuple(tuple(v._replace(planned_at=None, load=None) for v in r)
                        for r in routes)
        result = CostEvaluator(instance).evaluate(offline)
        assert result.feasible, result.errors
        assert outcome.cost + 1e-9 >= result.J
    # The runs did re-plan and leave depots before re-plans: the checks had work to do.
    assert stamps > 0 and loads > 0


def test_the_check_sees_an_unphysical_run():
    # A physical run with its stamps cleared is what the simulator produced before them: an
    # AAV heading for a task before its release, a depot left without a record of its load.
    instance = generate("4/10", 3)
    routes = solve(instance, "greedy", mode="dynamic").solution.routes
    assert physical_violations(instance, routes) == []
    cleared = tuple(tuple(v._replace(planned_at=None) for v in r) for r in routes)
    assert any("toward a task released" in p for p in physical_violations(instance, cleared))
    unloaded = tuple(tuple(v._replace(load=None) for v in r) for r in routes)
    assert any("records no load" in p for p in physical_violations(instance, unloaded))
