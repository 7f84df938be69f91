"""The shared route edits, on tests/data/hand.json (see test_evaluator.py for the numbers)."""

import pytest
from builders import plan

from tsac_bench.model import Visit
from tsac_bench.model.evaluator import CostEvaluator
from tsac_bench.planning.insertion import best_insertion, max_amount, removal_route, top_up


def test_max_amount_is_the_capacity_slack_where_the_goods_ride(hand):
    evaluator = CostEvaluator(hand)
    # A1 (10 kg): D0 loads T1's 4 kg and T3's 3 kg; T1's goods ride D0 -> T1 at 7 kg.
    route = plan(hand, A1=["D0", ("T1", 4), ("T3", 3), "D0"]).routes[1]
    trace = evaluator.trace(1, route)
    assert max_amount(hand, trace, 1) == 4 + 10 - 7
    # A pickup rides from its task to the next depot: T0's 5 kg with T2's 2 kg after it.
    route = plan(hand, A1=[("T0", 5), ("T2", 2), "D1"]).routes[1]
    assert max_amount(hand, evaluator.trace(1, route), 0) == 5 + 10 - 7


def test_top_up_raises_on_time_amounts_and_lowers_J(hand):
    state = CostEvaluator(hand).state(plan(hand, A0=[("T0", 5), "D0"]).routes)
    before = state.cost
    assert top_up(state, [0, 0]) == 1
    assert state.routes[0] == (Visit(0, 10), Visit(hand.node_index["D0"]))
    assert state.cost == pytest.approx(before - 50, rel=1e-12)  # w1 * 5 / 10
    assert top_up(state, [0, 0]) == 0


def test_top_up_leaves_late_and_committed_visits_alone(hand):
    # A0 reaches T2 late (1000 s > 900 s): more goods would still earn nothing.
    state = CostEvaluator(hand).state(plan(hand, A0=[("T2", 5), "D1"]).routes)
    assert top_up(state, [0, 0]) == 0
    state = CostEvaluator(hand).state(plan(hand, A0=[("T0", 5), "D0"]).routes)
    assert top_up(state, [1, 0]) == 0


def test_best_insertion_splits_by_capacity_and_removal_cleans_depots(hand):
    state = CostEvaluator(hand).state(plan(hand).routes)
    proposal = best_insertion(state, 1, hand.node_index["T1"])  # a 20 kg delivery, 10 kg AAV
    assert proposal is not None and proposal.delta < 0
    assert [v.amount for v in proposal.trace.route if v.node == 1] == [10]
    state.apply(proposal)
    route = removal_route(hand, state.routes[1], hand.node_index["T1"])
    assert route == ()
