import math

import pytest
from replan import replan_state

from tsac_bench.errors import InvalidSetting
from tsac_bench.model import Instance, Visit
from tsac_bench.model.evaluator import CostEvaluator
from tsac_bench.model.generator import generate
from tsac_bench.model.io import instance_from_dict
from tsac_bench.planning import PlanningState, make_allocator
from tsac_bench.planning.solve import solve
from tsac_bench.solvers.cnp import ContractNetAllocator, ContractNetManager

# Type-2 AAVs of TABLE 1: 20 m/s, 10 kg, 30 km, alpha 10; E_base = 10 * 30 + 500 = 800.
LIGHT = {"type": 2, "speed": 20, "capacity": 10, "max_range": 30000, "alpha": 10, "lam": 500}


def instance(aavs, depots, tasks) -> Instance:
    return instance_from_dict({
        "format": "tsac-bench/instance@1", "name": "cnp-hand", "horizon": 3600,
        "weights": [100, 10, 1],
        "aavs": [{"id": f"A{i}", "x": x, "y": y, **LIGHT} for i, (x, y) in enumerate(aavs)],
        "depots": [{"id": f"D{i}", "x": x, "y": y} for i, (x, y) in enumerate(depots)],
        "tasks": [{"id": f"T{i}", "x": x, "y": y, "kind": kind, "demand": demand,
                   "t_start": 0, "t_end": t_end, "release": 0}
                  for i, (x, y, kind, demand, t_end) in enumerate(tasks)],
    })


def task_cost(arrival: float, legs_km: list[float]) -> float:
    """C_m of a fully served task: w2 * (latest arrival - t_start) / T_hor + w3 * sum q."""
    return 10 * arrival / 3600 + sum(10 * km / 800 for km in legs_km)


def test_the_clearly_cheapest_aav_wins_the_contract():
    # A0 waits 1 km from the task at its depot, A1 is 8 km away.
    hand = instance(aavs=[(0, 0), (8000, 0)], depots=[(0, 0), (8000, 0)],
                    tasks=[(0, 1000, "D", 5, 3600)])
    manager = ContractNetManager(PlanningState.static(hand))
    bids = [c.bid(0) for c in manager.contractors]
    # A0: D0 -> T0 (1 km, 50 s); A1: D1 -> T0 (8.062 km, 403.1 s). An unserved task costs 110.
    far = math.hypot(8000, 1000)
    assert bids[0].price == pytest.approx(task_cost(50, [1.0]) - 110, abs=1e-9)
    assert bids[1].price == pytest.approx(task_cost(far / 20, [far / 1000]) - 110, abs=1e-9)
    assert (bids[0].amount, bids[1].amount) == (5, 5)
    assert manager.run() == "done"
    assert [(a.task, a.aav, a.amount) for a in manager.awards] == [(0, 0, 5)]
    assert manager.plan.routes == ((Visit(1), Visit(0, 5), Visit(1)), ())
    assert manager.plan.cost == pytest.approx(task_cost(50, [1.0]), abs=1e-12)


def test_the_residual_demand_is_announced_again():
    # 15 kg for 10 kg AAVs: the nearer one takes 10 kg, the residual 5 kg goes to the other.
    hand = instance(aavs=[(0, 0), (2000, 0)], depots=[(0, 0), (2000, 0)],
                    tasks=[(0, 1000, "D", 15, 3600)])
    result = ContractNetAllocator().plan(PlanningState.static(hand))
    assert result.stats["announcements"] == 2 and result.stats["awards"] == 2
    assert result.routes == ((Visit(1), Visit(0, 10), Visit(1)),
                             (Visit(2), Visit(0, 5), Visit(1)))
    far = math.hypot(2000, 1000)
    assert CostEvaluator(hand).cost(result.routes) == pytest.approx(
        task_cost(far / 20, [1.0, far / 1000]), abs=1e-12)


def test_an_awarded_arrival_is_a_promise():
    # T0 (deadline 3000) is contracted first. T1 lies just off the way to it: flying T1 first
    # would lower J but delay T0 by 2 s, which the contract forbids; greedy does it.
    hand = instance(aavs=[(0, 0)], depots=[(0, 0)],
                    tasks=[(2000, 0, "D", 5, 3000), (1000, 200, "D", 5, 3600)])
    evaluator = CostEvaluator(hand)
    bound = ContractNetAllocator().plan(PlanningState.static(hand)).routes
    loose = ContractNetAllocator(commitment="deadline").plan(PlanningState.static(hand)).routes
    greedy = solve(hand, "greedy").solution.routes
    assert [v.node for v in bound[0]] == [2, 0, 1, 2]
    assert [v.node for v in loose[0]] == [v.node for v in greedy[0]] == [2, 1, 0, 2]
    side = math.hypot(1000, 200)
    assert evaluator.cost(bound) == pytest.approx(
        task_cost(100, [2.0]) + task_cost(100 + side / 20, [side / 1000]), abs=1e-12)
    assert evaluator.cost(loose) < evaluator.cost(bound)


@pytest.mark.parametrize("commitment", ["arrival", "deadline"])
@pytest.mark.parametrize(("scale", "seed"), [("4/10", 0), ("4/10", 1), ("8/20", 2), ("8/20", 3)])
def test_every_award_leaves_a_feasible_route_and_keeps_earlier_promises(scale, seed,
                                                                        commitment):
    # Heavy demands and short windows: capacity and promises both bind.
    generated = generate(scale, seed, demand_levels=(10, 20, 30, 60),
                         demand_weights=(1, 1, 1, 1), window_min=300, window_max=900)
    manager = ContractNetManager(PlanningState.static(generated), commitment)
    manager.run()
    evaluator = CostEvaluator(generated)
    deadline = [t.t_end + 1e-6 for t in generated.tasks]
    held: dict[int, dict[int, float]] = {}  # AAV -> task -> arrival before the award
    for award in manager.awards:
        trace = evaluator.trace(award.aav, award.route)
        assert trace.feasible, trace.errors
        assert award.price < 0
        arrival = {m: c.arrival for m, c in trace.contributions}
        for m, before in held.get(award.aav, {}).items():
            promise = before if commitment == "arrival" else max(before, deadline[m])
            assert arrival[m] <= promise + 1e-6
        held[award.aav] = arrival
    assert evaluator.evaluate(manager.plan.routes).feasible
    assert manager.plan.cost == pytest.approx(evaluator.cost(manager.plan.routes), abs=1e-9)


def test_deterministic_and_feasible_on_the_paper_instance(paper_x20):
    first = solve(paper_x20, "cnp", seed=1)
    second = solve(paper_x20, "cnp", seed=2)
    assert first.solution.routes == second.solution.routes
    assert first.cost < paper_x20.unserved_task_cost * paper_x20.n_tasks


def test_a_replan_keeps_prefixes_and_contracts_and_announces_only_new_or_short_tasks(paper_x20):
    early = PlanningState(paper_x20, 0.0, paper_x20.released_by(0.0))
    routes = ContractNetAllocator().plan(early).routes
    state = replan_state(paper_x20, routes, 500.0)
    assert any(state.committed) and state.visible > early.visible
    manager = ContractNetManager(state)
    in_force = manager.plan.routes
    assert in_force == state.warm_routes()
    announced = set(manager.agenda())
    evaluator = CostEvaluator(paper_x20)
    short = {m for m in early.visible if manager.residual(m) > 0}
    assert announced == (state.visible - early.visible) | short
    manager.run()
    replanned = manager.plan.routes
    assert state.violations(replanned) == []
    assert evaluator.evaluate(replanned).feasible
    for n, route in enumerate(in_force):
        # Contracts persist: every task visit in force stays, with its amount, in order.
        held = [v for v in route if v.amount]
        assert [v for v in replanned[n] if v in held] == held


def test_warm_routes_drop_tasks_no_longer_visible(paper_x20):
    routes = solve(paper_x20, "cnp").solution.routes
    n = next(n for n, r in enumerate(routes) if sum(v.amount > 0 for v in r) >= 2)
    dropped = next(v.node for v in routes[n] if v.amount)
    state = PlanningState(paper_x20, 0.0, frozenset(range(10)) - {dropped},
                          incumbent=routes)
    cut = state.warm_routes()
    assert dropped not in {v.node for v in cut[n]}
    assert CostEvaluator(paper_x20).evaluate(cut).feasible
    assert all(cut[k] == routes[k] for k in range(4) if k != n)


def test_unknown_commitment_is_a_clear_error():
    with pytest.raises(InvalidSetting, match="method 'cnp' setting 'commitment': got 'never'; "
                                             "allowed: one of 'arrival', 'deadline'"):
        make_allocator("cnp", commitment="never")
