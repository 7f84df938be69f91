import pytest

from tsac_bench.model import Solution, Visit
from tsac_bench.model.evaluator import CostEvaluator
from tsac_bench.model.generator import generate
from tsac_bench.planning import PlanningState
from tsac_bench.planning.solve import solve
from tsac_bench.solvers.greedy import GreedyAllocator


def test_greedy_on_the_hand_instance(hand):
    outcome = solve(hand, "greedy")
    # T1 needs 20 kg of deliveries, more than A1's 10 kg: greedy gives it to A0 (30 kg),
    # and every other task is fully served on time.
    assert all(b.cost.load == 0 for b in outcome.evaluation.per_task if b.task != "T2")
    assert outcome.cost < CostEvaluator(hand).cost(Solution.empty(hand))
    assert outcome.cost == pytest.approx(outcome.solution.cost, rel=0)


def test_greedy_splits_a_demand_no_single_aav_can_carry(paper_x20):
    # T7 is a 60 kg pickup; the largest AAV carries 30 kg.
    outcome = solve(paper_x20, "greedy")
    t7 = next(b for b in outcome.evaluation.per_task if b.task == "T7")
    assert len(t7.coalition) >= 2
    assert sum(t7.amounts.values()) == 60 and t7.cost.load == 0


@pytest.mark.parametrize("scale", ["4/10", "16/40"])
def test_greedy_beats_doing_nothing_and_is_deterministic(scale):
    instance = generate(scale, seed=11)
    first = solve(instance, "greedy", seed=1)
    second = solve(instance, "greedy", seed=2)
    assert first.solution.routes == second.solution.routes
    assert first.cost < instance.unserved_task_cost * instance.n_tasks


def test_greedy_keeps_committed_prefixes_and_visible_tasks(paper_x20):
    instance = paper_x20
    committed = ((Visit(instance.node_index["D0"]), Visit(instance.node_index["T4"], 30)),
                 (), (), ())
    state = PlanningState(instance, time=500.0, visible=frozenset(range(7)),
                          committed=committed)
    result = GreedyAllocator().plan(state)
    assert state.violations(result.routes) == []
    assert CostEvaluator(instance).evaluate(result.routes).feasible


def test_greedy_stops_at_its_time_limit():
    result = GreedyAllocator().plan(PlanningState.static(generate("16/40", 0)), time_limit=0.0)
    assert result.stats["stop"] == "time-limit"
