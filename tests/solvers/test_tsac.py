"""TSAC-OCF: the environment, the masked transformer policy, the SAC losses and training,
and the shipped policy."""

from __future__ import annotations

import math
import socket

import numpy as np
import pytest

torch = pytest.importorskip("torch")
pytest.importorskip("gymnasium")

from tsac_bench.model.evaluator import CostEvaluator  # noqa: E402
from tsac_bench.model.generator import generate  # noqa: E402
from tsac_bench.planning import PlanningState, make_allocator  # noqa: E402
from tsac_bench.planning.solve import solve  # noqa: E402
from tsac_bench.solvers.ocf.engine import (  # noqa: E402
    C_MAX,
    COMPETITION_FEATURES,
    K_MAX,
    CoalitionGame,
    DecisionView,
    sample_rng,
)
from tsac_bench.solvers.ocf.hocf import HeuristicSelection  # noqa: E402
from tsac_bench.solvers.tsac.env import (  # noqa: E402
    AGENT_DIM,
    COMPETITION_SCALE,
    DEPOT_DIM,
    FEATURE_SETS,
    TASK_DIM,
    Observation,
    TaskSelectionEnv,
    action_choice,
    observe,
    pad,
    replan_moments,
    unpad,
)
from tsac_bench.solvers.tsac.net import (  # noqa: E402
    NetConfig,
    PolicyNet,
    QNet,
    StackedHeads,
    collate,
)
from tsac_bench.solvers.tsac.policy import (  # noqa: E402
    DEFAULT_POLICY,
    MARGIN_FEATURES,
    PolicyFileError,
    PolicySelection,
    TSACOCFAllocator,
    load_policy,
    margin_choice,
    read_policy,
    save_policy,
)
from tsac_bench.solvers.tsac.sac import (  # noqa: E402
    Batch,
    DiscreteSAC,
    Labelled,
    LabelledBatch,
    LookAheadSelection,
    RolloutWorkers,
    SACConfig,
    TrainConfig,
    Transition,
    best_label,
    label_candidates,
    rollout_values,
    teacher_prior_of,
    train,
)

SMALL = NetConfig(AGENT_DIM, TASK_DIM, DEPOT_DIM, d_model=16, heads=2, layers=2,
                  feedforward=32)
#: The policy shipped before the present one (feature set 1, the actor alone).
POLICY_1 = DEFAULT_POLICY.parent / "tsac-policy-1.pt"


def random_state(rng: np.random.Generator, n_tasks: int, n_depots: int,
                 valid: list[int] | None = None) -> Observation:
    mask = np.zeros(n_tasks, dtype=bool)
    mask[valid if valid is not None else rng.choice(n_tasks, size=max(1, n_tasks // 2),
                                                    replace=False)] = True
    return Observation(rng.normal(size=AGENT_DIM).astype(np.float32),
                       rng.normal(size=(n_tasks, TASK_DIM)).astype(np.float32),
                       rng.normal(size=(n_depots, DEPOT_DIM)).astype(np.float32), mask)


pytestmark = pytest.mark.usefixtures("one_torch_thread")


@pytest.fixture
def actor() -> PolicyNet:
    torch.manual_seed(0)
    return PolicyNet(SMALL).eval()


def test_masked_actions_get_exactly_zero_probability(actor):
    state = random_state(np.random.default_rng(1), 7, 2, valid=[1, 4, 5])
    with torch.no_grad():
        probs, log_probs = actor.distribution(collate([state]))
    probs = probs[0].numpy()
    assert (probs[[0, 2, 3, 6]] == 0.0).all()
    assert (probs[[1, 4, 5]] > 0).all()
    assert math.isclose(probs.sum(), 1.0, rel_tol=1e-6)
    assert torch.isneginf(log_probs[0, [0, 2, 3, 6]]).all()


def test_padding_never_changes_the_real_tokens(actor):
    rng = np.random.default_rng(2)
    state = random_state(rng, 5, 2)
    alone = actor(collate([state]))[0]
    # The same state padded to 12 tasks and 4 depots by longer neighbours in the batch.
    padded = actor(collate([random_state(rng, 12, 1), state, random_state(rng, 3, 4)]))[1]
    assert padded.shape == (12,)
    torch.testing.assert_close(padded[:5], alone)
    assert torch.isneginf(padded[5:]).all()


def test_replay_loss_over_a_padded_batch_equals_the_loss_over_valid_entries():
    torch.manual_seed(3)
    sac = DiscreteSAC(SMALL, SACConfig())
    rng = np.random.default_rng(3)
    transitions = []
    for i, (m, k) in enumerate([(3, 2), (9, 3), (5, 2), (1, 1)]):
        state = random_state(rng, m, k)
        transitions.append(Transition(state, int(np.flatnonzero(state.action_mask)[0]),
                                      float(rng.random()), random_state(rng, m + 1, k),
                                      done=i == 2))
    with torch.no_grad():
        batch = Batch.of(transitions, "cpu")
        singles = [Batch.of([t], "cpu") for t in transitions]
        critic = sac.critic_loss(batch)
        actor_loss, entropy = sac.actor_loss(batch)
        critic_each = torch.stack([sac.critic_loss(b) for b in singles])
        actor_each = [sac.actor_loss(b) for b in singles]
    torch.testing.assert_close(critic, critic_each.mean())
    torch.testing.assert_close(actor_loss, torch.stack([a for a, _ in actor_each]).mean())
    torch.testing.assert_close(entropy, torch.cat([e for _, e in actor_each]))
    assert torch.isfinite(critic) and torch.isfinite(actor_loss)


def test_a_terminal_next_state_without_valid_actions_adds_no_value():
    torch.manual_seed(4)
    sac = DiscreteSAC(SMALL, SACConfig())
    rng = np.random.default_rng(4)
    state = random_state(rng, 4, 2)
    terminal = Observation(state.agent, state.tasks, state.depots, np.zeros(4, dtype=bool))
    batch = Batch.of([Transition(state, int(np.flatnonzero(state.action_mask)[0]), 0.5,
                                 terminal, True)], "cpu")
    with torch.no_grad():
        q = torch.stack([c(batch.states)[0, batch.actions[0]] for c in sac.critics])
        assert torch.isclose(sac.critic_loss(batch), ((q - 0.5) ** 2).sum())


def test_environment_reward_is_minus_the_change_of_J():
    env = TaskSelectionEnv(("4/10",), max_tasks=10, max_depots=2)
    obs, info = env.reset(seed=5)
    assert env.observation_space.contains(obs)
    again, _ = TaskSelectionEnv(("4/10",), max_tasks=10, max_depots=2).reset(seed=5)
    assert all(np.array_equal(obs[k], again[k]) for k in obs)
    rng = np.random.default_rng(5)
    start, total, done = info["J"], 0.0, False
    while not done:
        action = int(rng.choice(np.flatnonzero(obs["action_mask"])))
        obs, reward, terminated, truncated, info = env.step(action)
        assert reward >= 0.0  # Eq. 22: only strict decreases of J are accepted
        total += reward
        done = terminated or truncated
    assert terminated and not obs["action_mask"].any()
    assert math.isclose(total * 110.0, start - info["J"], rel_tol=1e-9, abs_tol=1e-9)
    with pytest.raises(ValueError, match="not a valid task"):
        env.reset(seed=5)
        env.step(len(env.game.visible))  # a padding slot or beyond


def test_a_few_hundred_updates_lower_the_critic_loss():
    torch.manual_seed(6)
    env = TaskSelectionEnv(("4/10",), max_tasks=10, max_depots=2)
    rng = np.random.default_rng(6)
    obs, _ = env.reset(seed=6)
    transitions = []
    while len(transitions) < 256:
        state = unpad(obs)
        action = int(rng.choice(np.flatnonzero(state.action_mask)))
        obs, reward, terminated, truncated, _ = env.step(action)
        transitions.append(Transition(state, action, reward, unpad(obs), terminated))
        if terminated or truncated:
            obs, _ = env.reset()
    sac = DiscreteSAC(SMALL, SACConfig(batch_size=32, lr=1e-3))
    probe = Batch.of(transitions[:128], "cpu")
    with torch.no_grad():
        before = sac.critic_loss(probe).item()
    for _ in range(150):
        sac.update(Batch.of([transitions[i] for i in rng.integers(256, size=32)], "cpu"))
    with torch.no_grad():
        after = sac.critic_loss(probe).item()
    assert after < 0.5 * before


def test_training_writes_a_policy_and_resumes_from_its_checkpoint(tmp_path):
    config = TrainConfig(steps=40, warmup=20, pretrain_updates=5, eval_every=40,
                         eval_scale="4/10", eval_instances=1, checkpoint_every=20,
                         curriculum=((0.0, ("4/10",)),), net=SMALL, signal="td", features=1)
    first = train(tmp_path, config, device="cpu")
    assert first["steps"] == 40 and len(first["evals"]) == 1
    assert isinstance(load_policy(tmp_path / "policy.pt"), PolicyNet)
    more = train(tmp_path, TrainConfig(steps=60), device="cpu",
                 resume=tmp_path / "checkpoint.pt")
    # The resumed run keeps its configuration (SMALL network, its curriculum), not the
    # defaults passed along with the new length.
    assert more["steps"] == 60 and more["config"]["net"]["d_model"] == SMALL.d_model
    assert [e["step"] for e in more["evals"]] == [40, 60]


def test_the_shipped_policy_loads_without_gpu_or_network(monkeypatch):
    def no_network(*args, **kwargs):
        raise OSError("network access in a test")

    monkeypatch.setattr(socket, "socket", no_network)
    monkeypatch.setattr(torch.cuda, "is_available", lambda: False)
    assert DEFAULT_POLICY.stat().st_size < 5_000_000
    actor = load_policy()
    assert all(p.device.type == "cpu" and not p.requires_grad for p in actor.parameters())
    outcome = solve(generate("4/10", 7), "tsac-ocf", seed=3, mode="dynamic")
    assert outcome.evaluation.feasible and outcome.claim_matches


def test_a_file_that_is_not_a_policy_is_a_clear_error(tmp_path):
    bad = tmp_path / "bad.pt"
    torch.save({"format": "something else"}, bad)
    with pytest.raises(PolicyFileError, match="format"):
        load_policy(bad)
    with pytest.raises(PolicyFileError, match="cannot read"):
        load_policy(tmp_path / "missing.pt")


def test_zero_temperature_takes_the_most_probable_task():
    state = PlanningState.static(generate("4/10", 8))
    game = CoalitionGame(state, state.base_routes())
    n = next(n for n in range(game.n_aavs) if game.candidates(n))
    view = DecisionView(game, n, game.candidates(n))
    for actor in (load_policy(), load_policy(POLICY_1)):
        features = FEATURE_SETS[actor.config.features]
        sampled = PolicySelection(actor, temperature=1.0).probabilities(view)
        greedy = PolicySelection(actor, temperature=0.0).probabilities(view)
        assert greedy.sum() == 1.0 and greedy[int(np.argmax(sampled))] == 1.0
        tasks = {features.offset + game.visible.index(m) for m in view.candidates}
        assert set(np.flatnonzero(sampled)) <= tasks | ({0} if features.pass_action else set())


def test_every_ocf_method_starts_alike_by_default():
    shared = ("init", "samples", "k_max", "c_max")
    settings = [make_allocator(m).settings() for m in ("hocf", "rocf", "tsac-ocf")]
    assert {tuple(s[k] for k in shared) for s in settings} == {("empty", 1, 200_000, 5_000)}


V2 = FEATURE_SETS[2]
SMALL_V2 = NetConfig(AGENT_DIM, V2.task_dim, DEPOT_DIM, d_model=16, heads=2, layers=2,
                     feedforward=32, features=2, pass_action=True)


def mid_game(scale="8/20", seed=3, decisions=15):
    """A game a few HOCF decisions in, and the view of the next AAV with candidates."""
    state = PlanningState.static(generate(scale, seed))
    game = CoalitionGame(state)
    game.run(HeuristicSelection(state.instance, 1.0, 2.0, 1.0), np.random.default_rng(0),
             k_max=decisions, c_max=C_MAX)
    n = next(n for n in range(game.n_aavs) if len(game.candidates(n)) > 2)
    return game, DecisionView(game, n, game.candidates(n))


def test_feature_set_2_adds_scaled_competition_columns_and_leads_with_the_pass():
    game, view = mid_game()
    old, new = observe(view, FEATURE_SETS[1]), observe(view, V2)
    assert new.tasks.shape == (len(game.visible), V2.task_dim) == (len(game.visible), 25)
    np.testing.assert_array_equal(new.tasks[:, :TASK_DIM], old.tasks)
    raw = view.competition_features()
    divisor = np.array([COMPETITION_SCALE[c] for c in COMPETITION_FEATURES])
    np.testing.assert_allclose(new.tasks[:, TASK_DIM:], raw / divisor, rtol=1e-6)
    # By hand for one task: the nearest other AAV, the others' reach, the detour costs.
    i = 0
    m = game.visible[i]
    others = [k for k in range(game.n_aavs) if k != view.aav]
    nearest = {k: min(game.instance.dist[v, m] for v in
                      [game.anchor(k).node, *(x.node for x in game.route(k)[game.first_free[k]:])])
               for k in range(game.n_aavs)}
    assert raw[i, 0] == pytest.approx(min(nearest[k] for k in others) / 1000)
    rate = [game.instance.weights[2] * a.alpha / 1000 / game.instance.e_base
            for a in game.instance.aavs]
    assert raw[i, 3] == pytest.approx(min(2 * nearest[k] * rate[k] for k in others))
    assert raw[i, 4] == pytest.approx(2 * nearest[view.aav] * rate[view.aav])
    assert 0.0 <= raw[i, 2] <= 1.0
    # The action rows: pass first, then the candidate tasks; the pass token is the depot
    # row nearest to the anchor.
    assert new.action_mask[0] and (new.action_mask[1:] == old.action_mask).all()
    nearest_depot = np.argmin(new.depots[:, 2])
    np.testing.assert_array_equal(new.pass_token, new.depots[nearest_depot])
    game.pass_turn(view.aav)
    assert not observe(view, V2).action_mask[0]  # a second pass under this structure
    # The per-structure cache: after more accepted moves the columns are those of a game
    # built afresh on the same routes.
    game.run(HeuristicSelection(game.instance, 1.0, 2.0, 1.0), np.random.default_rng(1),
             k_max=len(game.decisions) + 20, c_max=C_MAX)
    assert len(game.trajectory) > 1
    n = next(n for n in range(game.n_aavs) if game.candidates(n))
    fresh = CoalitionGame(game.state, game.plan.routes)
    np.testing.assert_array_equal(
        DecisionView(game, n, game.candidates(n)).competition_features(),
        DecisionView(fresh, n, game.candidates(n)).competition_features())


def test_feature_set_3_adds_hocf_priority_and_choice_as_teacher_columns():
    game, view = mid_game()
    v3 = FEATURE_SETS[3]
    two, three = observe(view, V2), observe(view, v3)
    assert three.tasks.shape == (len(game.visible), v3.task_dim) == (len(game.visible), 27)
    np.testing.assert_array_equal(three.tasks[:, :V2.task_dim], two.tasks)
    np.testing.assert_array_equal(three.action_mask, two.action_mask)
    hocf = HeuristicSelection(game.instance, 1.0, 2.0, 1.0)
    choice = hocf.select(view, np.random.default_rng(7))
    priority, chosen = three.tasks[:, -2], three.tasks[:, -1]
    assert chosen.sum() == 1.0 and game.visible[int(np.argmax(chosen))] == choice
    # By hand for one task (module docstring of hocf.py): the weights 1, 2, 1 sum to 4.
    m, n, instance = game.visible[3], view.aav, game.instance
    task, anchor = instance.tasks[m], view.anchor
    slack = task.t_end - (anchor.time + instance.dist[anchor.node, m] / instance.aavs[n].speed)
    urgency = 1.0 - min(1.0, max(0.0, slack / instance.horizon))
    free_route = [anchor.node, *(v.node for v in game.route(n)[game.first_free[n]:])]
    proximity = 1.0 - min(instance.dist[k, m] for k in free_route) / instance.dist.max()
    share = min(view.residual(m), instance.aavs[n].capacity) / task.demand
    assert priority[3] == pytest.approx((urgency + 2 * proximity + share) / 4, rel=1e-6)
    assert ((priority >= 0) & (priority <= 1)).all()
    # Zero-padded like every other column.
    gym_form = pad(three, 80, 8)
    assert gym_form["tasks"].shape == (80, 27) and not gym_form["tasks"][len(game.visible):].any()


def test_padding_never_changes_the_real_tokens_with_competition_and_pass():
    torch.manual_seed(0)
    actor = PolicyNet(SMALL_V2).eval()
    _, view = mid_game()
    state = observe(view, V2)
    _, other_view = mid_game("16/40", seed=5)
    longer = observe(other_view, V2)
    assert len(longer.tasks) > len(state.tasks)
    alone = actor(collate([state]))[0]
    batch = collate([longer, state])
    assert batch["tasks"].shape[-1] == V2.task_dim
    assert not batch["tasks"][1, len(state.tasks):].any()  # zero-padded rows
    padded = actor(batch)[1]
    width = 1 + len(state.tasks)
    torch.testing.assert_close(padded[:width], alone)
    assert torch.isneginf(padded[width:]).all()
    # The Gymnasium form pads the same way and round-trips.
    gym_form = pad(state, 80, 8)
    assert gym_form["tasks"].shape == (80, V2.task_dim) and not gym_form["tasks"][
        len(state.tasks):].any()
    back = unpad(gym_form)
    np.testing.assert_array_equal(back.action_mask, state.action_mask)
    np.testing.assert_array_equal(back.pass_token, state.pass_token)


@pytest.mark.parametrize("config", [SMALL, SMALL_V2], ids=["tasks only", "pass token"])
def test_stacked_heads_give_each_heads_values_of_the_real_actions(config):
    torch.manual_seed(4)
    heads = [QNet(config).eval() for _ in range(3)]
    stacked = StackedHeads(heads)
    features = FEATURE_SETS[config.features]
    states = [observe(mid_game(scale, seed)[1], features)
              for scale, seed in (("8/20", 3), ("16/40", 5), ("4/10", 2))]
    for batch in ([states[0]], states):  # alone, and padded by longer and shorter states
        obs = collate(batch)
        with torch.inference_mode():
            values = stacked(obs)
            assert values.shape == (3, *obs["action_mask"].shape)
            for i, state in enumerate(batch):
                width = features.offset + len(state.tasks)
                for head, stacked_values in zip(heads, values, strict=True):
                    torch.testing.assert_close(stacked_values[i, :width],
                                               head(obs)[i, :width], rtol=1e-5, atol=1e-5)
    with pytest.raises(ValueError, match="one config"):
        StackedHeads([QNet(SMALL), QNet(SMALL_V2)])


def test_the_environment_with_feature_set_2_passes_and_ends_stable():
    env = TaskSelectionEnv(("4/10",), max_tasks=10, max_depots=2, features=2)
    obs, _ = env.reset(seed=5)
    assert env.observation_space.contains(obs) and obs["action_mask"][0] == 1
    before = env.game.plan.routes
    obs, reward, terminated, _, _ = env.step(0)
    assert reward == 0.0 and env.game.plan.routes == before and not terminated
    assert env.game.decisions[-1].op == "pass"
    rng = np.random.default_rng(1)
    done = False
    while not done:
        obs, _, terminated, truncated, _ = env.step(
            int(rng.choice(np.flatnonzero(obs["action_mask"]))))
        done = terminated or truncated
    assert terminated and not obs["action_mask"].any()


def test_a_rollout_label_is_the_J_of_replaying_the_action_and_its_completion():
    game, view = mid_game()
    completion = HeuristicSelection(game.instance, 1.0, 2.0, 1.0)
    actions = [0, *np.flatnonzero(observe(view, V2).action_mask[1:])[:3] + 1]
    before = (game.plan.routes, len(game.decisions), set(game.tabu))
    values = rollout_values(game, view, actions, V2, completion, rollouts=2, seed=7)
    assert (game.plan.routes, len(game.decisions), set(game.tabu)) == before  # forks only
    for i, action in enumerate(actions):
        for r in range(2):
            replay = game.fork()
            if action == 0:
                replay.pass_turn(view.aav)
            else:
                replay.decide(view.aav, game.visible[action - 1])
            replay.run(completion, sample_rng(7, r), k_max=K_MAX, c_max=C_MAX)
            assert values[i, r] == replay.cost
            assert replay.cost == pytest.approx(
                CostEvaluator(game.instance).cost(replay.plan.routes), rel=1e-12)
    # The pass label is HOCF finishing the game from this very structure.
    plain = game.fork()
    plain.run(completion, sample_rng(7, 1), k_max=K_MAX, c_max=C_MAX)
    assert values[0, 1] == plain.cost


def test_rollout_workers_give_the_same_labels_to_the_last_digit():
    game, view = mid_game()
    completion = HeuristicSelection(game.instance, 1.0, 2.0, 1.0)
    actions = [0, *np.flatnonzero(observe(view, V2).action_mask[1:])[:4] + 1]
    alone = rollout_values(game, view, actions, V2, completion, rollouts=3, seed=11)
    assert alone.shape == (5, 3) and np.ptp(alone) > 0  # rollouts that differ, in order
    with RolloutWorkers(2) as workers:
        shared = rollout_values(game, view, actions, V2, completion, rollouts=3, seed=11,
                                workers=workers)
        look_ahead = LookAheadSelection(completion, V2, rollouts=2, workers=workers)
        assert (look_ahead.select(view, np.random.default_rng(4))
                == LookAheadSelection(completion, V2, rollouts=2).select(
                    view, np.random.default_rng(4)))
    np.testing.assert_array_equal(shared, alone)
    with pytest.raises(ValueError, match="at least 2"):
        RolloutWorkers(1)


def test_policy_files_name_their_feature_set(tmp_path):
    assert load_policy(POLICY_1).config.features == 1  # it predates feature set 2
    assert load_policy().config.features == 3
    torch.manual_seed(1)
    actor = PolicyNet(SMALL_V2)
    save_policy(actor, tmp_path / "v2.pt", {})
    loaded = load_policy(tmp_path / "v2.pt")
    assert loaded.config.features == 2 and loaded.config.pass_action
    # A file whose network does not fit its feature set is refused with the reason.
    payload = torch.load(tmp_path / "v2.pt", weights_only=True)
    payload["config"]["features"] = 1
    torch.save(payload, tmp_path / "mixed.pt")
    with pytest.raises(PolicyFileError, match="do not fit feature set 1"):
        load_policy(tmp_path / "mixed.pt")
    payload["config"]["features"] = 9
    torch.save(payload, tmp_path / "future.pt")
    with pytest.raises(PolicyFileError, match="feature set 9 is unknown"):
        load_policy(tmp_path / "future.pt")
    # Same seed, same plan, with the pass in play and best of 2 games.
    instance = generate("8/20", 4)
    settings = {"policy": str(tmp_path / "v2.pt"), "decode": "sample", "samples": 2}
    runs = [solve(instance, "tsac-ocf", seed=9, mode="dynamic", settings=settings)
            for _ in range(2)]
    assert runs[0].solution.routes == runs[1].solution.routes
    assert runs[0].evaluation.feasible and runs[0].claim_matches


@pytest.mark.parametrize(("settings", "weights"), [
    # From clone_weight 2 after the 1 000 warm-up decisions to the floor at clone_until.
    ({}, [2.0, 1.0, 0.0, 0.0]),
    ({"clone_floor": 0.5}, [2.0, 1.25, 0.5, 0.5]),
    ({"clone_floor": 1.0, "clone_until": 0.5}, [2.0, 1.0, 1.0, 1.0]),
    ({"clone_floor": 2.0}, [2.0, 2.0, 2.0, 2.0]),
    # The td signal keeps its weight constant; a schedule ending by the warm-up: the floor.
    ({"clone_floor": 0.5, "signal": "td"}, [2.0, 2.0, 2.0, 2.0]),
    ({"clone_floor": 0.5, "clone_until": 0.1}, [0.5, 0.5, 0.5, 0.5]),
])
def test_the_cloning_weight_falls_from_clone_weight_to_clone_floor(settings, weights):
    config = TrainConfig(steps=8000, warmup=1000, **settings)
    # The warm-up's end, half-way to clone_until=1, clone_until=1, after the last step.
    assert [config.clone_weight_at(s) for s in (1000, 4500, 8000, 9000)] == weights


def test_rollout_training_writes_a_feature_set_2_policy_and_resumes(tmp_path):
    config = TrainConfig(steps=50, warmup=20, pretrain_updates=3, eval_every=50,
                         eval_scale="4/10", eval_instances=1, checkpoint_every=25,
                         curriculum=((0.0, ("4/10",)),), net=SMALL_V2, label_share=0.3,
                         label_candidates=3, rollouts=1, replan_share=0.5)
    first = train(tmp_path, config, device="cpu")
    assert first["steps"] == 50 and first["labels"] and first["updates"]
    assert load_policy(tmp_path / "policy.pt").config.features == 2
    assert [config.clone_weight_at(s) for s in (20, 35, 50)] == [2.0, 1.0, 0.0]
    # A call that runs out of its time stops at an episode's end with a checkpoint.
    paused = train(tmp_path, TrainConfig(steps=70), device="cpu",
                   resume=tmp_path / "checkpoint.pt", stop_after=1e-9)
    assert paused["steps"] == 50
    more = train(tmp_path, TrainConfig(steps=70), device="cpu",
                 resume=tmp_path / "checkpoint.pt")
    assert more["steps"] == 70 and more["config"]["net"]["d_model"] == SMALL_V2.d_model


def test_replan_moments_are_the_states_of_simulated_dynamic_runs():
    sample = replan_moments(("6/15",))
    rng = np.random.default_rng(4)
    moments = [sample(rng) for _ in range(12)]
    later = [s for s in moments if s.time > 0]
    assert later and any(any(p) for s in later for p in s.committed)
    assert any(s.time == 0 for s in moments)
    for state in moments:
        assert state.visible <= state.instance.released_by(state.time)
        game = CoalitionGame(state, state.base_routes())
        game.run(PolicySelection(load_policy()), np.random.default_rng(0), k_max=K_MAX,
                 c_max=C_MAX)
        assert state.violations(game.plan.routes) == []
    again = replan_moments(("6/15",))(np.random.default_rng(4))
    assert (again.instance.name, again.time, again.visible) == (
        moments[0].instance.name, moments[0].time, moments[0].visible)


# --- look-ahead distillation ---------------------------------------------------------------
def test_the_distillation_target_is_the_labelled_action_of_least_mean_final_J():
    assert best_label([0, 3, 5], [10.0, 7.0, 9.0]) == 3
    # A tie goes to the completion's own choice if it ties, else to the lowest index.
    assert best_label([0, 3, 5], [10.0, 7.0, 7.0], reference=5) == 5
    assert best_label([0, 3, 5], [10.0, 7.0, 7.0], reference=0) == 3
    assert best_label([0, 3, 5], [10.0, 7.0, 7.0]) == 3
    # With a margin the completion's choice stays the target unless beaten by more.
    assert best_label([0, 3, 5], [10.0, 7.0, 7.5], reference=5, margin=0.5) == 5
    assert best_label([0, 3, 5], [10.0, 7.0, 7.6], reference=5, margin=0.5) == 3
    assert best_label([0, 3, 5], [10.0, 7.0, 7.6], reference=5) == 3


def test_the_distillation_loss_is_the_cross_entropy_toward_the_least_final_J():
    rng = np.random.default_rng(5)
    states = [random_state(rng, 4, 2, valid=[0, 1, 3]), random_state(rng, 3, 2, valid=[1, 2]),
              random_state(rng, 5, 2, valid=[0, 4])]
    # Finals (10, 7, 9), (4, 4.5), (3, 3): targets 1, 1 and, on the tie, the lowest index 0.
    items = [Labelled(states[0], (0, 1, 3), (-1.33, 1.67, -0.33), best_label([0, 1, 3],
                                                                          [10, 7, 9])),
             Labelled(states[1], (1, 2), (0.25, -0.25), best_label([1, 2], [4, 4.5])),
             Labelled(states[2], (0, 4), (0.0, 0.0), best_label([0, 4], [3, 3])),
             Labelled(states[0], (0, 1), (0.5, -0.5))]  # labelled before targets existed
    assert [item.target for item in items] == [1, 1, 0, None]
    sac = DiscreteSAC(SMALL, SACConfig())
    batch = LabelledBatch.of(items, "cpu")
    assert batch.targets.tolist() == [1, 1, 0, -1]
    with torch.no_grad():
        loss = sac.distill_loss(batch).item()
        expected = -np.mean([torch.log(sac.actor.distribution(collate([s]))[0][0, t]).item()
                             for s, t in zip(states, (1, 1, 0), strict=True)])
    assert loss == pytest.approx(expected, rel=1e-5)


def test_the_teacher_prior_puts_95_percent_on_hocfs_choice_and_the_rest_uniformly():
    tasks = torch.zeros((1, 3, 4))
    tasks[0, 1, -1] = 1.0  # task row 1 is the teacher's choice: action 2 after the pass
    states = {"tasks": tasks, "pass_token": torch.zeros((1, 3)),
              "action_mask": torch.tensor([[True, True, True, False]])}
    prior = teacher_prior_of(states)[0].exp()
    torch.testing.assert_close(prior, torch.tensor([0.05 / 3, 0.05 / 3, 0.95 + 0.05 / 3, 0.0]))


def test_with_a_teacher_prior_the_actor_loss_is_the_kl_regularised_one():
    torch.manual_seed(0)
    v3 = FEATURE_SETS[3]
    net = NetConfig(AGENT_DIM, v3.task_dim, DEPOT_DIM, d_model=16, heads=2, layers=2,
                    feedforward=32, features=3, pass_action=True)
    sac = DiscreteSAC(net, SACConfig(), teacher_prior=0.5)
    _, view = mid_game()
    states = collate([observe(view, v3)])
    batch = Batch(states, torch.zeros(0), torch.zeros(0), states, torch.zeros(0))
    with torch.no_grad():
        loss, _ = sac.actor_loss(batch)
        probs, log_probs = sac.actor.distribution(states)
        q = torch.minimum(*(c(states) for c in sac.critics))
    valid = states["action_mask"][0]
    prior = teacher_prior_of(states)[0]
    expected = sum(probs[0, a] * (0.5 * (log_probs[0, a] - prior[a]) - q[0, a])
                   for a in torch.nonzero(valid).flatten().tolist())
    assert loss.item() == pytest.approx(expected.item(), rel=1e-5)
    # HOCF's choice (its teacher column) carries 95 % of the prior plus its uniform share.
    choice = 1 + int(torch.argmax(states["tasks"][0, :, -1]))
    assert prior[choice].exp().item() == pytest.approx(0.95 + 0.05 / int(valid.sum()))


@pytest.mark.parametrize("seed", range(5))
def test_the_completions_choice_is_always_among_the_labelled_actions(seed):
    rng = np.random.default_rng(seed)
    valid = np.sort(rng.choice(40, size=int(rng.integers(2, 30)), replace=False))
    reference = int(rng.choice(valid))
    actions = label_candidates(valid, 8, rng, reference)
    assert reference in actions and len(actions) == min(8, len(valid))
    assert len(set(actions.tolist())) == len(actions) and set(actions) <= set(valid)
    assert list(actions) == sorted(actions)


def test_with_distillation_every_labelled_state_holds_hocfs_choice(tmp_path, monkeypatch):
    from tsac_bench.solvers.tsac import sac as sac_module

    real, seen = sac_module.rollout_values, []

    def spy(game, view, actions, features, completion, **keywords):
        hocf = HeuristicSelection(game.instance, 1.0, 2.0, 1.0).select(view, None)
        seen.append((hocf, [action_choice(view, a, features) for a in actions]))
        return real(game, view, actions, features, completion, **keywords)

    monkeypatch.setattr(sac_module, "rollout_values", spy)
    summary = train(tmp_path, distilling(steps=60), device="cpu")
    assert len(seen) >= 5 and all(hocf in choices for hocf, choices in seen)
    distilled = [u["distill_loss"] for u in summary["updates"] if "distill_loss" in u]
    assert distilled and all(math.isfinite(d) and d > 0 for d in distilled)


def distilling(**settings) -> TrainConfig:
    return TrainConfig(**{"warmup": 20, "pretrain_updates": 3, "eval_every": 1000,
                          "eval_scale": "4/10", "eval_instances": 1, "checkpoint_every": 1000,
                          "curriculum": ((0.0, ("8/20",)),), "net": SMALL_V2,
                          "label_share": 0.5, "label_candidates": 3, "rollouts": 1,
                          "replan_share": 0.0, "distill_weight": 1.0, **settings})


def test_distilled_training_is_the_same_for_the_same_seed(tmp_path):
    first = train(tmp_path / "a", distilling(steps=40), device="cpu")
    second = train(tmp_path / "b", distilling(steps=40), device="cpu")
    assert first["updates"] == second["updates"] and first["episodes"] == second["episodes"]
    a, b = load_policy(tmp_path / "a" / "policy.pt"), load_policy(tmp_path / "b" / "policy.pt")
    assert all(torch.equal(x, y) for x, y in zip(a.state_dict().values(),
                                                 b.state_dict().values(), strict=True))
    other = train(tmp_path / "c", distilling(steps=40, seed=1), device="cpu")
    assert other["updates"] != first["updates"]


def test_training_with_label_workers_is_the_same_run(tmp_path):
    alone = train(tmp_path / "a", distilling(steps=40), device="cpu")
    shared = train(tmp_path / "b", distilling(steps=40), device="cpu", label_workers=2)
    assert alone["labels"] and shared["labels"] == alone["labels"]
    assert shared["updates"] == alone["updates"] and shared["episodes"] == alone["episodes"]


def test_the_look_ahead_takes_the_action_of_least_rollout_J():
    game, view = mid_game()
    completion = HeuristicSelection(game.instance, 1.0, 2.0, 1.0)
    look_ahead = LookAheadSelection(completion, V2, rollouts=1)
    choice = look_ahead.select(view, np.random.default_rng(3))
    # Replayed: the same generator draws the same rollout seed after HOCF's choice.
    rng = np.random.default_rng(3)
    valid = np.flatnonzero(observe(view, V2).action_mask)
    finals = rollout_values(game, view, valid.tolist(), V2, completion, rollouts=1,
                            seed=int(rng.integers(2**31)))[:, 0]
    chosen = [action_choice(view, int(a), V2) for a in valid].index(choice)
    assert finals[chosen] == finals.min() and np.ptp(finals) > 0


SMALL_V3 = NetConfig(AGENT_DIM, MARGIN_FEATURES.task_dim, DEPOT_DIM, d_model=16, heads=2,
                     layers=2, feedforward=32, features=3, pass_action=True)


def margin_policy(path, critics: int = 2, unit: float = 1.0):
    torch.manual_seed(3)
    save_policy(PolicyNet(SMALL_V3), path, {},
                critics=[QNet(SMALL_V3) for _ in range(critics)], critic_unit=unit)
    return path


def test_margin_choice_deviates_only_beyond_the_margin_and_never_to_an_invalid_action():
    values = np.array([1.0, 0.25, 0.5, 5.0])
    valid = np.array([True, True, True, False])
    assert margin_choice(values, valid, teacher=1, margin=0.5) == 0  # 0.75 above the teacher
    assert margin_choice(values, valid, teacher=1, margin=1.0) == 1
    assert margin_choice(values, valid, teacher=0, margin=-1.0) == 0


def test_policy_files_carry_the_critics_in_j(tmp_path):
    policy = read_policy(margin_policy(tmp_path / "p.pt", unit=2.5))
    assert len(policy.critics) == 2 and policy.critic_unit == 2.5
    assert all(not p.requires_grad for q in policy.critics for p in q.parameters())
    state = PlanningState.static(generate("4/10", 8))
    game = CoalitionGame(state, state.base_routes())
    n = next(n for n in range(game.n_aavs) if game.candidates(n))
    obs = collate([observe(DecisionView(game, n, game.candidates(n)), MARGIN_FEATURES)])
    first, second = (q(obs) for q in policy.critics)
    # The critics run in one stacked pass (StackedHeads): their values to float rounding.
    torch.testing.assert_close(policy.values(obs), 2.5 * torch.minimum(first, second))
    # A version 1 file (the actor alone) still loads, without critics.
    assert read_policy(POLICY_1).critics == ()
    assert len(read_policy(DEFAULT_POLICY).critics) == 2


def test_margin_decoding_plays_hocfs_game_when_no_deviation_clears_the_margin(tmp_path):
    """With a margin no critic difference reaches, every decision is HOCF's: the same J;
    with margin 0 the critics (random here) play another game, the same one per seed."""
    path = str(margin_policy(tmp_path / "p.pt"))
    instance = generate("8/20", 5)
    hocf = solve(instance, "hocf", seed=2, mode="dynamic")
    kept = solve(instance, TSACOCFAllocator(path, decode="margin", margin=1e9, verify=None),
                 seed=2, mode="dynamic")
    assert kept.cost == hocf.cost and kept.solution.routes == hocf.solution.routes
    runs = [solve(instance, "tsac-ocf", seed=2, mode="dynamic",
                  settings={"policy": path, "decode": "margin", "margin": 0, "verify": "none"})
            for _ in range(2)]
    assert runs[0].solution.routes == runs[1].solution.routes
    assert runs[0].cost != hocf.cost
    assert runs[0].evaluation.feasible and runs[0].claim_matches


def test_a_policy_the_decoding_cannot_run_is_a_bad_setting(tmp_path, data_dir):
    from tsac_bench.cli import app
    from tsac_bench.errors import InvalidSetting

    without = margin_policy(tmp_path / "no-critics.pt", critics=0)
    with pytest.raises(InvalidSetting, match=r"setting 'decode'.*no twin critics"):
        make_allocator("tsac-ocf", policy=str(without), decode="margin")
    v2 = tmp_path / "v2.pt"
    save_policy(PolicyNet(SMALL_V2), v2, {}, critics=[QNet(SMALL_V2), QNet(SMALL_V2)])
    with pytest.raises(InvalidSetting, match="needs HOCF's choice in the state"):
        make_allocator("tsac-ocf", policy=str(v2), decode="margin")
    with pytest.raises(InvalidSetting, match=r"got 'margin' \(its default\).*decode=sample"):
        make_allocator("tsac-ocf", policy=str(without))
    assert make_allocator("tsac-ocf", policy=str(without), decode="sample").decode == "sample"
    with pytest.raises(PolicyFileError, match="decode=margin: its file carries no twin critics"):
        TSACOCFAllocator(str(without)).rule(PlanningState.static(generate("4/10", 1)))
    # Not a torch file at all (torch raised a KeyError from its unpickler): one line.
    junk = tmp_path / "junk.pt"
    junk.write_text("junk")
    with pytest.raises(InvalidSetting, match=rf"setting 'policy'.*{junk}: cannot read"):
        make_allocator("tsac-ocf", policy=str(junk))
    from typer.testing import CliRunner

    result = CliRunner().invoke(app, ["solve", str(data_dir / "hand.json"), "--method",
                                      f"tsac-ocf:policy={junk}"])
    assert result.exit_code == 2
    assert result.stderr.count("\n") == 1 and "cannot read the policy" in result.stderr
