"""Hand-computed costs on tests/data/hand.json (E_base = 20 * 60 + 2000 = 3200).

Distances are 3-4-5 triangles and axis legs, so every number below can be checked on paper;
docs/model.md walks through the multi-trip case.
"""

import pytest
from builders import plan

from tsac_bench.model import Solution
from tsac_bench.model.evaluator import CostEvaluator, InfeasibleSolution
from tsac_bench.model.generator import generate
from tsac_bench.planning.solve import solve

UNSERVED = 110.0


def J(instance, **routes):
    return CostEvaluator(instance).cost(plan(instance, **routes))


def test_empty_solution_costs_w1_plus_w2_per_task(hand):
    assert CostEvaluator(hand).cost(Solution.empty(hand)) == pytest.approx(4 * UNSERVED, abs=0)


def test_single_visit_each_term(hand):
    # A0 flies 5 km at 10 m/s: arrives at 500 s; q = 20 * 5 / 3200.
    result = CostEvaluator(hand).evaluate(plan(hand, A0=[("T0", 10), "D0"]))
    t0 = result.per_task[0].cost
    assert (t0.load, t0.op) == (0.0, 0.03125)
    assert t0.time == pytest.approx(500 / 3600, rel=1e-15)
    assert t0.total == pytest.approx(10 * 500 / 3600 + 0.03125, rel=1e-15)
    assert pytest.approx(3 * UNSERVED + 10 * 500 / 3600 + 0.03125, rel=1e-15) == result.J
    assert result.terms == pytest.approx({"load": 300.0, "time": 30 + 10 * 500 / 3600,
                                          "op": 0.03125})


def test_late_visit_earns_nothing_and_costs_its_leg(hand):
    # 10 km at 10 m/s arrives at 1000 s > t_end 900: C_load = 1, C_time = 1, q = 20*10/3200.
    assert J(hand, A0=[("T2", 15), "D1"]) == pytest.approx(3 * UNSERVED + 110.0625, rel=1e-15)
    assert J(hand) == 4 * UNSERVED  # dropping the late visit lowers J


def test_waiting_for_the_window_start(hand):
    # A1 reaches T2 after 500 s but the window opens at 600 s: it waits, C_time = 0.
    trace = CostEvaluator(hand).trace(1, plan(hand, A1=[("T2", 10), "D1"]).routes[1])
    assert trace.arrivals == (600.0, 1000.0)


def test_split_coalition_takes_the_last_arrival(hand):
    # A0 brings 5 kg at 500 s, A1 5 kg at 250 s: full demand, C_time from the later one.
    value = J(hand, A0=[("T0", 5), "D0"], A1=[("T0", 5), "D0"])
    assert value == pytest.approx(3 * UNSERVED + 10 * 500 / 3600 + 0.03125 + 0.015625,
                                  rel=1e-15)
    # A1 alone with 5 of 10 kg: half the load penalty.
    assert J(hand, A1=[("T0", 5), "D0"]) == pytest.approx(
        3 * UNSERVED + 50 + 10 * 250 / 3600 + 0.015625, rel=1e-15)


def test_range_exceedance_charges_the_full_range_cost(hand):
    # A1 (range 12 km): T2 at Dcum 10 km (q = 10*10/3200), D1 at 18 km, T0 at 23 km > 12 km
    # so q = (10 * 12 + 500) / 3200; T0 reached at 1250 s with 5 of 10 kg.
    result = CostEvaluator(hand).evaluate(plan(hand, A1=[("T2", 10), "D1", ("T0", 5), "D0"]))
    t0, _, t2, _ = (b.cost for b in result.per_task)
    assert t2 == pytest.approx((1 / 3, 0.0, 0.03125, 100 / 3 + 0.03125), rel=1e-15)
    assert t0 == pytest.approx((0.5, 1250 / 3600, 0.19375, 50 + 12500 / 3600 + 0.19375),
                               rel=1e-15)
    assert pytest.approx(307.0305555555556, rel=1e-15) == result.J
    assert result.traces[1].distance_at_arrival == (10000.0, 18000.0, 23000.0, 28000.0)


def test_multi_trip_reload(hand, data_dir):
    from tsac_bench.model.io import read_solution

    solution = read_solution(data_dir / "hand-solution.json", hand)
    result = CostEvaluator(hand).evaluate(solution)
    # docs/model.md: 51.4201388... + 50.00625 + 110 + 1.3951388... = 212.8215277...
    assert pytest.approx(212.82152777777778, rel=1e-15) == result.J
    assert result.terms == pytest.approx({"load": 200.0, "time": 10 + 2 * 5000 / 3600,
                                          "op": 0.04375})
    trace = result.traces[1]
    assert trace.delivery_load == (10, 0, 10, 0, 0)  # each depot loads the next delivery
    assert trace.arrivals == (0.0, 300.0, 400.0, 500.0, 600.0)


@pytest.mark.parametrize(
    ("routes", "code", "position"),
    [
        ({"A1": ["D0", ("T1", 10), ("T3", 10), "D0"]}, "over-capacity", 0),
        ({"A1": [("T3", 10), "D0"]}, "no-goods", 0),
        ({"A1": [("T0", 5)]}, "no-final-depot", 0),
        ({"A0": [("T0", 5), "D0", ("T0", 5), "D0"]}, "repeated-task", 2),
        ({"A0": [("T0", 0), "D0"]}, "bad-amount", 0),
        ({"A0": [("T0", 2.0), "D0"]}, "bad-amount", 0),
        ({"A0": [("T0", True), "D0"]}, "bad-amount", 0),
        ({"A0": [("T0", 5), ("D0", 3)]}, "depot-amount", 1),
        ({"A1": [("T0", 11), "D0"]}, "over-capacity", 0),
    ],
)
def test_infeasible_routes_are_named(hand, routes, code, position):
    result = CostEvaluator(hand).evaluate(plan(hand, **routes))
    assert not result.feasible and result.J is None
    assert [(e.code, e.position) for e in result.errors][:1] == [(code, position)]
    with pytest.raises(InfeasibleSolution, match=code):
        CostEvaluator(hand).cost(plan(hand, **routes))


def test_pickup_goods_do_not_feed_a_delivery(hand):
    # Eq. 10 as docs/model.md reads it: d and p are separate, so 10 kg picked up at T0 cannot be
    # delivered at T3 without a depot visit in between.
    result = CostEvaluator(hand).evaluate(plan(hand, A0=[("T0", 10), ("T3", 5), "D0"]))
    assert [(e.code, e.position) for e in result.errors] == [("no-goods", 1)]
    # After a depot visit both kinds ride together: D0 loads T3's and T1's goods (10 kg).
    mixed = CostEvaluator(hand).evaluate(plan(hand, A0=["D0", ("T3", 5), ("T0", 5), ("T1", 5),
                                                        "D0"]))
    assert mixed.feasible
    assert mixed.traces[0].delivery_load == (10, 5, 5, 0, 0)
    assert mixed.traces[0].pickup_load == (0, 0, 5, 5, 0)


def test_plan_state_tracks_cost_and_coverage(hand):
    evaluator = CostEvaluator(hand)
    state = evaluator.state(Solution.empty(hand).routes)
    assert state.cost == 4 * UNSERVED
    delta = state.set_route(1, plan(hand, A1=[("T0", 5), "D0"]).routes[1])
    assert delta == pytest.approx(50 + 10 * 250 / 3600 + 0.015625 - UNSERVED, rel=1e-15)
    assert state.covered(0) == 5 and state.covered(0, exclude=1) == 0
    assert state.propose(0, plan(hand, A0=[("T3", 5), "D0"]).routes[0]) is None


def test_plan_state_coverage_kept_across_route_changes_equals_a_fresh_states():
    instance = generate("8/20", seed=3)
    evaluator = CostEvaluator(instance)
    routes = solve(instance, "greedy", seed=0).solution.routes
    state = evaluator.state(Solution.empty(instance).routes)
    # Every AAV's route set, then every other one emptied again: covered() is kept by the
    # changes, never recomputed from scratch.
    changes = [*enumerate(routes), *((n, ()) for n in range(0, instance.n_aavs, 2))]
    for n, route in changes:
        state.set_route(n, route)
        fresh = evaluator.state(state.routes)
        for m in range(instance.n_tasks):
            t_end = instance.tasks[m].latest_on_time
            assert state.covered(m) == fresh.covered(m) == sum(
                c.amount for c in fresh.members[m].values() if c.arrival <= t_end)
            assert [state.covered(m, exclude=k) for k in range(instance.n_aavs)] == [
                fresh.covered(m, exclude=k) for k in range(instance.n_aavs)]
    assert 0 < sum(state.covered(m) for m in range(instance.n_tasks)) < sum(
        evaluator.state(routes).covered(m) for m in range(instance.n_tasks))


def stamped(instance, aav, visits):
    """Routes with stamps: ``visits`` are Visit keyword dicts by id (node, amount,
    planned_at, load); other AAVs idle."""
    from tsac_bench.model import Visit

    route = tuple(Visit(instance.node_index[v["node"]], v.get("amount", 0),
                        v.get("planned_at"), v.get("load")) for v in visits)
    return tuple(route if a.id == aav else () for a in instance.aavs)


def test_planned_at_delays_the_departure_not_the_arrival_of_an_earlier_plan(hand):
    # A1 (20 m/s) to T3 (2 km south, window [0, 3600]) and home. Planned at 400 s, it leaves
    # the start at 400 and reaches T3 at 500, D0 at 600; a stamp earlier than the arrival
    # changes nothing (D0 planned at 450 s, reached at 600).
    routes = stamped(hand, "A1", [{"node": "D0"}, {"node": "T3", "amount": 10,
                                                   "planned_at": 400.0},
                                  {"node": "D0", "planned_at": 450}])
    result = CostEvaluator(hand).evaluate(routes)
    trace = result.traces[1]
    assert trace.departures == (0.0, 400.0, 500.0)
    assert trace.arrivals == (0.0, 500.0, 600.0)
    # T3: full, C_time = 500 / 3600, q = 10 * 2 / 3200.
    assert pytest.approx(10 * 500 / 3600 + 0.00625 + 3 * UNSERVED, rel=1e-15) == result.J


def test_a_recorded_load_bounds_the_deliveries_of_its_trip(hand):
    # D0 loaded 10 kg: T1 (10 kg) fits, T1 and T3 (20 kg) do not; any delivery may use them.
    fits = stamped(hand, "A0", [{"node": "D0", "load": 10}, {"node": "T3", "amount": 10},
                                {"node": "D0"}])
    assert CostEvaluator(hand).evaluate(fits).feasible
    beyond = stamped(hand, "A0", [{"node": "D0", "load": 10}, {"node": "T1", "amount": 10},
                                  {"node": "T3", "amount": 10}, {"node": "D0"}])
    result = CostEvaluator(hand).evaluate(beyond)
    assert [(e.code, e.position) for e in result.errors] == [("load-exceeded", 0)]
    assert "need 20 kg but it loaded 10 kg" in str(result.errors[0])


@pytest.mark.parametrize(("visits", "code", "position"), [
    ([{"node": "T0", "amount": 5, "planned_at": -1.0}, {"node": "D0"}], "bad-planned-at", 0),
    ([{"node": "T0", "amount": 5, "planned_at": float("nan")}, {"node": "D0"}],
     "bad-planned-at", 0),
    ([{"node": "T0", "amount": 5, "planned_at": "10"}, {"node": "D0"}], "bad-planned-at", 0),
    ([{"node": "T0", "amount": 5, "planned_at": True}, {"node": "D0"}], "bad-planned-at", 0),
    ([{"node": "T0", "amount": 5, "load": 5}, {"node": "D0"}], "bad-load", 0),
    ([{"node": "D0", "load": 2.0}, {"node": "T3", "amount": 1}, {"node": "D0"}], "bad-load", 0),
    ([{"node": "D0", "load": -1}, {"node": "D0"}], "bad-load", 0),
])
def test_malformed_stamps_are_named(hand, visits, code, position):
    result = CostEvaluator(hand).evaluate(stamped(hand, "A0", visits))
    assert [(e.code, e.position) for e in result.errors][:1] == [(code, position)]


def test_a_planning_moment_prices_free_visits_as_planned_then(hand):
    # The evaluator of a re-plan at 400 s with A1's first visit committed times the rest as
    # the simulator will stamp it: the same route, stamped, costs the same offline.
    from tsac_bench.model import Visit
    from tsac_bench.planning import PlanningState

    d0, t3 = hand.node_index["D0"], hand.node_index["T3"]
    state = PlanningState(hand, 400.0, frozenset(range(hand.n_tasks)),
                          ((), (Visit(d0),)))
    route = (Visit(d0), Visit(t3, 10), Visit(d0))
    planned = state.evaluator().evaluate(((), route))
    assert planned.traces[1].arrivals == (0.0, 500.0, 600.0)
    stamped_route = (Visit(d0), Visit(t3, 10, 400.0), Visit(d0, 0, 400.0))
    assert CostEvaluator(hand).cost(((), stamped_route)) == planned.J
    assert state.anchor(1) == (d0, 400.0, 0.0, None)
    assert state.anchor(0) == (hand.start_node(0), 400.0, 0.0, 0)
