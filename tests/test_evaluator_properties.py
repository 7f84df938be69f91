"""Properties of J that docs/model.md promises, on random feasible plans of generated instances."""

import math

from hypothesis import given, settings
from hypothesis import strategies as st
from random_plans import random_plan, random_route

from tsac_bench.model import Solution
from tsac_bench.model.evaluator import TIME_TOLERANCE, CostEvaluator
from tsac_bench.model.generator import generate

scales = st.sampled_from(["2/4", "4/10", "8/20"])
seeds = st.integers(0, 10_000)


@settings(max_examples=60, deadline=None)
@given(scale=scales, instance_seed=st.integers(0, 50), plan_seed=seeds)
def test_cost_is_non_negative_and_bounded(scale, instance_seed, plan_seed):
    instance = generate(scale, instance_seed)
    result = CostEvaluator(instance).evaluate(random_plan(instance, plan_seed))
    assert result.feasible
    assert result.J >= 0
    # Every task costs at most w1 + w2 plus the op cost of its coalition.
    op = sum(b.cost.op for b in result.per_task)
    assert instance.unserved_task_cost * instance.n_tasks + op + 1e-9 >= result.J
    assert math.isclose(result.J, sum(result.terms.values()), rel_tol=1e-12)


@settings(max_examples=20, deadline=None)
@given(scale=scales, instance_seed=st.integers(0, 50))
def test_empty_solution_costs_w1_plus_w2_per_task(scale, instance_seed):
    instance = generate(scale, instance_seed)
    assert CostEvaluator(instance).cost(Solution.empty(instance)) == \
        instance.unserved_task_cost * instance.n_tasks


@settings(max_examples=80, deadline=None)
@given(scale=scales, instance_seed=st.integers(0, 50), plan_seed=seeds)
def test_dropping_a_late_visit_never_raises_J(scale, instance_seed, plan_seed):
    # Tight windows so that random plans are often late.
    instance = generate(scale, instance_seed, window_min=60.0, window_max=300.0,
                        reach_slack=0.0)
    evaluator = CostEvaluator(instance)
    routes = random_plan(instance, plan_seed)
    before = evaluator.evaluate(routes)
    for n, trace in enumerate(before.traces):
        for k, node in enumerate(v.node for v in trace.route):
            if node < instance.n_tasks and \
                    trace.arrivals[k] > instance.tasks[node].t_end + TIME_TOLERANCE:
                dropped = list(routes)
                dropped[n] = routes[n][:k] + routes[n][k + 1:]
                after = evaluator.evaluate(dropped)
                assert after.feasible
                assert after.J <= before.J + 1e-9


@settings(max_examples=80, deadline=None)
@given(scale=scales, instance_seed=st.integers(0, 50), plan_seed=seeds,
       change_seed=seeds, data=st.data())
def test_incremental_path_equals_full_evaluation(scale, instance_seed, plan_seed, change_seed,
                                                 data):
    import numpy as np

    instance = generate(scale, instance_seed)
    evaluator = CostEvaluator(instance)
    routes = list(random_plan(instance, plan_seed))
    state = evaluator.state(routes)
    assert math.isclose(state.cost, evaluator.cost(routes), rel_tol=1e-12)
    rng = np.random.default_rng(change_seed)
    for _ in range(3):
        n = data.draw(st.integers(0, instance.n_aavs - 1))
        new_route = random_route(instance, n, rng, evaluator)
        proposal = state.propose(n, new_route)
        routes[n] = new_route
        full = evaluator.cost(routes)
        assert math.isclose(state.cost + proposal.delta, full, rel_tol=1e-12, abs_tol=1e-9)
        state.apply(proposal)
        assert math.isclose(state.cost, full, rel_tol=1e-12, abs_tol=1e-9)
