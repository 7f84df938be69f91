"""The OCF game engine (solvers/ocf/engine.py) and its two selection rules, rocf and hocf."""

import itertools

import numpy as np
import pytest
from solver_cases import DEPOTS, aav, edge_cases, paper_x20, quick, task

from tsac_bench.errors import InvalidSetting
from tsac_bench.model import Instance, Visit
from tsac_bench.model.evaluator import CostEvaluator
from tsac_bench.model.generator import generate
from tsac_bench.planning import PlanningState, make_allocator
from tsac_bench.planning.budget import WorkStop
from tsac_bench.planning.insertion import best_insertion, removal_route
from tsac_bench.planning.simulator import simulate
from tsac_bench.planning.solve import solve
from tsac_bench.solvers.ocf.engine import (
    C_MAX,
    INIT,
    K_MAX,
    PASS,
    STRICT_DECREASE,
    CoalitionGame,
    DecisionView,
    Move,
    sample_rng,
)
from tsac_bench.solvers.ocf.hocf import HeuristicSelection
from tsac_bench.solvers.ocf.rocf import UniformSelection
from tsac_bench.solvers.tsac.features import (
    AGENT_FEATURES,
    DEPOT_FEATURES,
    TASK_FEATURES,
    agent_columns,
    depot_columns,
    task_columns,
)


def rule_for(name, instance):
    if name == "rocf":
        return UniformSelection()
    return HeuristicSelection(instance, 1.0, 2.0, 1.0)


def small_instances():
    yield from (quick(n) for n in ("quick-2-4-s1", "quick-3-6-s3", "quick-4-10-s5"))
    yield paper_x20()
    yield edge_cases()["one-aav"]
    yield from (generate("3/6", seed) for seed in range(4))


def play(state, rule_name, seed=0, **limits):
    game = CoalitionGame(state)
    stop = game.run(rule_for(rule_name, state.instance), np.random.default_rng(seed),
                    k_max=limits.get("k_max", 10**6), c_max=limits.get("c_max", 10**6))
    return game, stop


def improving_moves(game):
    """Every single-AAV ADD or REMOVE that lowers J and is not tabu, found without the
    engine's candidate lists (only tasks beyond the AAV's range are skipped: the mask)."""
    found = []
    plan, instance = game.plan, game.instance
    for n in range(instance.n_aavs):
        ff = game.first_free[n]
        route = game.route(n)
        anchor = game.anchor(n)
        for m in sorted(game.state.visible):
            if any(v.node == m for v in route[:ff]):
                continue
            if any(v.node == m for v in route):
                proposal, op = plan.propose(n, removal_route(instance, route, m, ff)), "remove"
            else:
                if anchor.flown + instance.dist[anchor.node, m] > instance.aavs[n].max_range:
                    continue
                proposal, op = best_insertion(plan, n, m, ff), "add"
            if proposal is None or proposal.delta >= -STRICT_DECREASE:
                continue
            if game.key_after(Move(op, n, m, proposal)) in game.tabu:
                continue
            found.append((n, m, op, proposal.delta))
    return found


@pytest.mark.parametrize("rule", ["rocf", "hocf"])
def test_every_accepted_move_strictly_lowers_J_and_the_trajectory_shows_it(rule):
    for instance in small_instances():
        game, _ = play(PlanningState.static(instance), rule, seed=1)
        trajectory = game.trajectory
        assert trajectory[0] == instance.unserved_task_cost * instance.n_tasks
        assert all(b - a < -STRICT_DECREASE for a, b in itertools.pairwise(trajectory))
        accepted = [d.J for d in game.decisions if d.accepted]
        assert accepted == trajectory[1:]
        # The incremental J agrees with a from-scratch evaluation of the final routes.
        assert trajectory[-1] == pytest.approx(CostEvaluator(instance).cost(game.plan.routes),
                                               rel=1e-12, abs=1e-9)


@pytest.mark.parametrize("rule", ["rocf", "hocf"])
def test_the_final_structure_is_nash_stable(rule):
    for instance in small_instances():
        for seed in range(2):
            game, stop = play(PlanningState.static(instance), rule, seed=seed)
            assert stop == "stable"
            assert improving_moves(game) == [], instance.name


@pytest.mark.parametrize("rule", ["rocf", "hocf"])
def test_a_replan_game_keeps_the_prefixes_and_ends_stable(rule):
    instance = generate("6/15", seed=8)
    states = []

    class Capture:
        name = "capture"

        def plan(self, state, *, seed=0, time_limit=None):
            states.append(state)
            return make_allocator(rule).plan(state, seed=seed)

    simulate(instance, Capture())
    late = states[-1]
    assert any(late.committed)
    game, stop = play(late, rule, seed=3)
    assert stop == "stable"
    assert late.violations(game.plan.routes) == []
    assert improving_moves(game) == []


def test_a_move_that_revisits_a_tabu_structure_is_rejected():
    instance = quick("quick-2-4-s1")
    game = CoalitionGame(PlanningState.static(instance))
    n, m = 0, next(m for m in game.valid_tasks(0))
    move = game.move(n, m)
    assert move.op == "add" and game.acceptable(move)
    game.tabu.add(game.key_after(move))
    assert not game.acceptable(move)
    assert game.tabu_hits == 1
    assert not game.decide(n, m) and game.decisions[-1].accepted is False
    assert m in game.rejected[n]


def test_structure_key_ignores_order_and_depots_but_not_amounts():
    instance = quick("quick-3-6-s3")
    game = CoalitionGame(PlanningState.static(instance))
    depot = instance.depot_nodes[0]
    a = game.plan.propose(0, (Visit(depot), Visit(1, 5), Visit(4, 5), Visit(depot)))
    b = game.plan.propose(0, (Visit(4, 5), Visit(depot), Visit(1, 5), Visit(depot)))
    c = game.plan.propose(0, (Visit(depot), Visit(1, 4), Visit(4, 5), Visit(depot)))
    keys = [game.key_after(Move("add", 0, 1, p)) for p in (a, b, c)]
    assert keys[0] == keys[1] != keys[2]


def residual_case() -> Instance:
    """T0 (20 kg, window [0, 390]): A0 brings 10 kg on time, A1 5 kg late; A2 is free."""
    return Instance("residual", (aav("A0", 1), aav("A1", 2), aav("A2", 2)), DEPOTS, (
        task("T0", 2000, 0, 20, window=(0, 390)), task("T1", -1000, 0, 5)))


def test_residual_demand_is_eq_19_as_each_aav_sees_it():
    instance = residual_case()
    d0, d1 = instance.depot_nodes
    routes = ((Visit(d0), Visit(0, 10), Visit(d0)),  # arrives at 200 s: on time
              ((Visit(d1), Visit(1, 5), Visit(d1), Visit(0, 5), Visit(d1))),  # 600 s: late
              ())
    game = CoalitionGame(PlanningState.static(instance), routes)
    assert [game.residual(n, 0) for n in range(3)] == [20, 10, 10]
    view = DecisionView(game, 2, tuple(game.valid_tasks(2)))
    features = task_columns(view)
    assert features.shape == (2, len(TASK_FEATURES))
    column = dict(zip(TASK_FEATURES, features[0], strict=True))
    assert column["residual"] == 10 and column["coalition_size"] == 2
    assert column["covered"] == 10 and column["member"] == 0
    assert agent_columns(view).shape == (len(AGENT_FEATURES),)
    assert depot_columns(view).shape == (2, len(DEPOT_FEATURES))
    # HOCF's ineffective-resource exit: A1's late visit does nothing, it leaves first.
    hocf = HeuristicSelection(instance, 1.0, 2.0, 1.0)
    a1 = DecisionView(game, 1, tuple(game.valid_tasks(1)))
    assert 0 in a1.candidates and hocf.select(a1, np.random.default_rng(0)) == 0


def test_the_validity_mask():
    instance = residual_case()
    d0 = instance.depot_nodes[0]
    game = CoalitionGame(PlanningState.static(instance),
                         ((Visit(d0), Visit(0, 20), Visit(d0)), (), ()))
    # T0 is fully covered by A0: nothing left for A1 or A2 to join. A0 may leave it.
    assert game.valid_tasks(0) == [0, 1]
    assert game.valid_tasks(1) == [1] == game.valid_tasks(2)
    # From a committed visit to T1 ending at 100 s, T0 (3 km away, closes at 390 s) is out
    # of reach for A0 (10 m/s) and the committed T1 cannot be removed.
    late = PlanningState(instance, 50.0, frozenset({0, 1}),
                         committed=((Visit(d0), Visit(1, 5)), (), ()))
    game = CoalitionGame(late)
    assert game.anchor(0).time == 100.0 and game.valid_tasks(0) == []
    assert game.valid_tasks(1) == [0]


def test_uniform_selection_is_uniform_over_the_candidates():
    game = CoalitionGame(PlanningState.static(quick("quick-3-6-s3")))
    view = DecisionView(game, 0, (1, 3, 4))
    rng = np.random.default_rng(0)
    counts = np.bincount([UniformSelection().select(view, rng) for _ in range(3000)],
                         minlength=5)
    assert counts[[0, 2]].sum() == 0
    assert all(900 <= c <= 1100 for c in counts[[1, 3, 4]])


def test_hocf_prefers_the_nearer_of_two_otherwise_equal_tasks():
    instance = Instance("near-far", (aav("A0", 1),), DEPOTS, (
        task("T0", 0, 4000, 10), task("T1", 0, 1000, 10)))
    game = CoalitionGame(PlanningState.static(instance))
    view = DecisionView(game, 0, tuple(game.valid_tasks(0)))
    hocf = HeuristicSelection(instance, 1.0, 2.0, 1.0)
    scores = hocf.priorities(view, (0, 1))
    near, far = scores[1], scores[0]
    # Scored together or one at a time, the same numbers.
    assert (hocf.priorities(view, (1,))[1], hocf.priorities(view, (0,))[0]) == (near, far)
    d_max = float(instance.dist.max())
    # Same window and share. Proximity differs by 3 km; urgency by the 300 s more slack
    # the near task leaves (it is reached earlier), against it.
    assert near - far == pytest.approx(2.0 * 3000 / d_max - 300 / 3600, rel=1e-12)
    assert hocf.select(view, np.random.default_rng(0)) == 1


def test_what_a_game_keeps_across_moves_equals_what_a_fresh_game_computes():
    """Route proximity (rows of AAVs whose routes a move left alone are kept), the residuals
    (kept per AAV and structure, on the plan's on-time sums kept by its moves) and the task
    features built on them must be what a fresh game on the same structure computes."""
    state = PlanningState.static(generate("8/20", seed=4))
    game = CoalitionGame(state)
    hocf = HeuristicSelection(state.instance, 1.0, 2.0, 1.0)
    checked = []

    class Checking:
        def select(self, view, rng):
            fresh = CoalitionGame(state, game.plan.routes)
            # What the engine left for this decision first, then every AAV's.
            np.testing.assert_array_equal(
                task_columns(view),
                task_columns(DecisionView(fresh, view.aav, view.candidates)))
            assert game.valid_tasks(view.aav) == fresh.valid_tasks(view.aav)
            kept, afresh = game.route_proximity(), fresh.route_proximity()
            np.testing.assert_array_equal(kept[0], afresh[0])
            np.testing.assert_array_equal(kept[1], afresh[1])
            for n in range(game.n_aavs):
                assert game.residuals(n).tolist() == [
                    max(0, task.demand - fresh.plan.covered(m, exclude=n))
                    for m, task in ((m, state.instance.tasks[m]) for m in game.visible)]
            checked.append(len(game.trajectory))
            return hocf.select(view, rng)

    game.run(Checking(), np.random.default_rng(0), k_max=60, c_max=C_MAX)
    assert len(set(checked)) > 5  # checked after several accepted moves


def test_stop_conditions():
    state = PlanningState.static(generate("4/10", seed=2))
    game = CoalitionGame(state)
    assert game.run(UniformSelection(), np.random.default_rng(0), k_max=0, c_max=5) == "k_max"
    assert game.decisions == [] and game.plan.routes == state.base_routes()
    game = CoalitionGame(state)
    stop = game.run(UniformSelection(), np.random.default_rng(0), k_max=10**6, c_max=1)
    assert stop == "c_max" and game.decisions[-1].accepted is False
    game = CoalitionGame(state)
    assert game.run(UniformSelection(), np.random.default_rng(0), k_max=10**6, c_max=10,
                    stop=WorkStop(0.0, None)) == "time-limit"
    result = make_allocator("rocf").plan(state, time_limit=0.0)
    assert result.stats["stop"] == "time-limit" and result.stats["decisions"] == 0
    # A plan call's decisions, over all its games, stop it at exactly that count.
    result = make_allocator("rocf:samples=none:decisions=25").plan(state)
    assert result.stats["stop"] == "work" and result.stats["work"] == 25
    assert sum(1 for _ in result.stats["sample_J"]) == result.stats["games"]


@pytest.mark.parametrize("method", ["hocf", "rocf", "tsac-ocf"])
def test_a_budget_plays_games_after_the_first_and_keeps_the_best(method):
    """Game 0 of a budgeted call is the plain call's game (same seed, same stream), so the
    budgeted plan is never worse; the call records the games played and its trace ends at
    its J."""
    state = PlanningState.static(generate("8/20", seed=4))
    plain = make_allocator(method).plan(state, seed=5)
    budgeted = make_allocator(f"{method}:samples=none").plan(state, seed=5, time_limit=0.6)
    assert budgeted.stats["sample_J"][0] == plain.cost
    assert budgeted.stats["games"] >= 2
    assert budgeted.cost == min(budgeted.stats["sample_J"]) <= plain.cost
    assert budgeted.stats["trace"][-1][1] == budgeted.cost
    assert budgeted.stats["trace"][0][1] == plain.stats["J_initial"]


def test_an_open_ended_call_is_refused():
    state = PlanningState.static(generate("4/10", seed=2))
    with pytest.raises(InvalidSetting, match="'samples': none needs a budget"):
        make_allocator("hocf:samples=none").plan(state)


def test_a_rule_must_pick_a_candidate():
    class Wrong:
        def select(self, view, rng):
            return -1

    game = CoalitionGame(PlanningState.static(quick("quick-2-4-s1")))
    with pytest.raises(ValueError, match="not a candidate"):
        game.run(Wrong(), np.random.default_rng(0), k_max=10, c_max=10)


@pytest.mark.parametrize("method", ["rocf", "hocf"])
def test_allocator_result_and_settings(method):
    instance = generate("8/20", seed=6)
    outcome = solve(instance, method, seed=5)
    stats = outcome.stats
    assert stats["stop"] == "stable"
    assert stats["accepted"] + stats["rejected"] == stats["decisions"]
    assert stats["trajectory"][-1] == pytest.approx(outcome.cost, rel=1e-12)
    assert outcome.claimed_cost == pytest.approx(outcome.cost, rel=1e-12)
    assert outcome.solution.meta["settings"]["init"] == "empty"
    again = solve(instance, method, seed=5)
    assert again.solution.routes == outcome.solution.routes
    with pytest.raises(InvalidSetting, match=f"method '{method}' setting 'init': got 'random'; "
                                             "allowed: one of 'empty', 'incumbent', 'greedy'"):
        make_allocator(method, init="random")


@pytest.mark.parametrize("method", ["rocf", "hocf"])
def test_greedy_start_never_ends_above_greedy(method):
    for seed in range(3):
        instance = generate("6/15", seed=seed)
        greedy = solve(instance, "greedy").cost
        assert solve(instance, method, settings={"init": "greedy"}).cost <= greedy


def test_incumbent_start_is_the_warm_plan():
    instance = generate("6/15", seed=9)
    states = []

    class Capture:
        name = "capture"

        def plan(self, state, *, seed=0, time_limit=None):
            states.append(state)
            return make_allocator("hocf").plan(state, seed=seed)

    simulate(instance, Capture())
    state = states[-1]
    warm = state.warm_routes()
    assert state.violations(warm) == []
    result = make_allocator("hocf", init="incumbent").plan(state)
    assert result.stats["J_initial"] == pytest.approx(CostEvaluator(instance).cost(warm))
    assert result.cost <= result.stats["J_initial"]


def test_an_accepted_move_forgets_exactly_the_rejections_it_may_have_changed():
    instance = generate("4/10", seed=1)
    game = CoalitionGame(PlanningState.static(instance))
    game.run(UniformSelection(), np.random.default_rng(0), k_max=12, c_max=10**6)
    everything = set(range(instance.n_tasks))
    for n in range(instance.n_aavs):
        game.rejected[n] = set(everything)
    n = 1
    move = next(mv for m in game.valid_tasks(n) if (mv := game.move(n, m)) is not None
                and game.acceptable(mv))
    old = dict(game.plan.traces[n].contributions)
    new = dict(move.proposal.trace.contributions)
    changed = {m for m in old.keys() | new.keys() if old.get(m) != new.get(m)}
    game._apply(move)
    stale = {k for m in changed for k in game.plan.members[m]} | {n}
    for k in range(instance.n_aavs):
        assert game.rejected[k] == (set() if k in stale else everything - changed)
    assert changed and any(k not in stale for k in range(instance.n_aavs))


@pytest.mark.parametrize("method", ["rocf", "hocf"])
def test_samples_return_the_best_of_k_games_each_with_its_own_stream(method):
    state = PlanningState.static(generate("8/20", seed=4))
    allocator = make_allocator(method)
    assert (allocator.init, allocator.samples) == (INIT, 1) == ("empty", 1)
    singles = []
    for k in range(3):
        game = CoalitionGame(state, state.base_routes())
        game.run(allocator.rule(state), sample_rng(11, k), k_max=K_MAX, c_max=C_MAX)
        singles.append(game)
    best = make_allocator(method, samples=3).plan(state, seed=11)
    assert best.stats["sample_J"] == [g.cost for g in singles]
    winner = singles[best.stats["sample"]]
    assert best.cost == min(g.cost for g in singles) and best.routes == winner.plan.routes
    # One sample is the plain game seeded with the call's seed; repeats give the same plan.
    assert allocator.plan(state, seed=11).routes == singles[0].plan.routes
    assert make_allocator(method, samples=3).plan(state, seed=11).routes == best.routes
    if method == "rocf":  # random selection: the streams differ, so do the games
        assert len(set(best.stats["sample_J"])) > 1
    with pytest.raises(ValueError, match="samples"):
        make_allocator(method, samples=0)


def test_a_pass_changes_nothing_and_is_allowed_once_per_structure():
    state = PlanningState.static(generate("4/10", seed=3))
    game = CoalitionGame(state)
    game.run(UniformSelection(), np.random.default_rng(0), k_max=5, c_max=10**6)
    game.rejected[0].add(game.valid_tasks(0)[0])
    before = (game.plan.routes, game.cost, game.key, set(game.tabu),
              [set(r) for r in game.rejected], len(game.trajectory))
    assert game.can_pass(0)
    game.pass_turn(0)
    assert (game.plan.routes, game.cost, game.key, set(game.tabu),
            [set(r) for r in game.rejected], len(game.trajectory)) == before
    assert game.decisions[-1][1:5] == (0, PASS, "pass", False)
    assert not game.can_pass(0) and game.can_pass(1)
    with pytest.raises(ValueError, match="already passed"):
        game.pass_turn(0)
    # Any accepted move changes the structure: AAV 0 may pass again.
    move = next(mv for n in range(game.n_aavs) for m in game.candidates(n)
                if (mv := game.move(n, m)) is not None and game.acceptable(mv))
    game._apply(move)
    assert game.can_pass(0)


def test_a_rule_that_passes_whenever_it_may_still_ends_nash_stable():
    class Shy:
        def select(self, view, rng):
            return PASS if view.can_pass else UniformSelection().select(view, rng)

    for instance in small_instances():
        game = CoalitionGame(PlanningState.static(instance))
        stop = game.run(Shy(), np.random.default_rng(2), k_max=10**6, c_max=10**6)
        assert stop == "stable" and improving_moves(game) == [], instance.name
        assert any(d.op == "pass" for d in game.decisions)


def test_a_rule_that_draws_meets_the_same_aav_orders_as_one_that_does_not():
    """Methods compared on a seed differ by their choices, not by their AAV orders: HOCF,
    and HOCF that also draws a number per decision (as a sampling policy does), play the
    very same game."""
    state = PlanningState.static(generate("8/20", 5))
    hocf = HeuristicSelection(state.instance, 1.0, 2.0, 1.0)

    class Drawing:
        def __init__(self) -> None:
            self.draws = 0

        def select(self, view, rng):
            rng.random()
            self.draws += 1
            return hocf.select(view, rng)

    drawing = Drawing()
    games = [CoalitionGame(state), CoalitionGame(state)]
    games[0].run(hocf, sample_rng(3, 0), k_max=K_MAX, c_max=C_MAX)
    games[1].run(drawing, sample_rng(3, 0), k_max=K_MAX, c_max=C_MAX)
    assert drawing.draws > 50
    assert [(d.aav, d.task, d.accepted) for d in games[1].decisions] == [
        (d.aav, d.task, d.accepted) for d in games[0].decisions]
    assert games[1].cost == games[0].cost


def test_residuals_follow_accepted_moves():
    instance = residual_case()
    d0, d1 = instance.depot_nodes
    routes = ((Visit(d0), Visit(0, 10), Visit(d0)),
              ((Visit(d1), Visit(1, 5), Visit(d1), Visit(0, 5), Visit(d1))), ())
    game = CoalitionGame(PlanningState.static(instance), routes)
    # Each AAV's own visit does not count for itself; A1's visit to T0 is late.
    assert [game.residuals(n).tolist() for n in range(3)] == [[20, 0], [10, 5], [10, 0]]
    assert game.decide(2, 0)  # A2 joins T0 with the 10 kg left for it, on time
    assert game.plan.members[0][2].amount == 10
    assert [game.residuals(n).tolist() for n in range(3)] == [[10, 0], [0, 5], [10, 0]]
    # T0 covered twice over on time: A2 leaving it is accepted, and A0, asked last before
    # that move, sees the 10 kg A2 brought missing again.
    over = CoalitionGame(PlanningState.static(instance),
                         ((Visit(d0), Visit(0, 20), Visit(d0)), (),
                          (Visit(d0), Visit(0, 10), Visit(d0))))
    assert over.residuals(0).tolist() == [10, 5]
    assert over.decide(2, 0) and 2 not in over.plan.members[0]
    assert over.residuals(0).tolist() == [20, 5]
