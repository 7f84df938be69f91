"""TSAC-OCF: the policy's state, the masked transformer policy, the training (its losses,
its recipe) and the shipped policy."""

from __future__ import annotations

import json
import math
import socket

import numpy as np
import pytest

torch = pytest.importorskip("torch")

from tsac_bench.model.evaluator import CostEvaluator  # noqa: E402
from tsac_bench.model.generator import generate  # noqa: E402
from tsac_bench.planning import PlanningState, make_allocator  # noqa: E402
from tsac_bench.planning.solve import solve  # noqa: E402
from tsac_bench.solvers.ocf.engine import (  # noqa: E402
    C_MAX,
    K_MAX,
    CoalitionGame,
    DecisionView,
    sample_rng,
)
from tsac_bench.solvers.ocf.hocf import HeuristicSelection  # noqa: E402
from tsac_bench.solvers.tsac.features import (  # noqa: E402
    AGENT_DIM,
    COMPETITION_FEATURES,
    COMPETITION_SCALE,
    DEPOT_DIM,
    EXTRA_TASK_FEATURES,
    FEATURES,
    TASK_DIM,
    TASK_FEATURES,
    Observation,
    action_choice,
    action_of,
    competition_columns,
    observe,
    teacher_action,
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
    PolicyFileError,
    PolicySelection,
    TSACOCFAllocator,
    load_policy,
    margin_choice,
    policy_meta,
    read_policy,
    save_policy,
)
from tsac_bench.solvers.tsac.sac import (  # noqa: E402
    DiscreteSAC,
    Labelled,
    LabelledBatch,
    ReplayBuffer,
    RolloutWorkers,
    SACConfig,
    label_candidates,
    rollout_values,
    teacher_prior_of,
)
from tsac_bench.solvers.tsac.training import TrainConfig, replan_moments, train  # noqa: E402
from tsac_bench.solvers.tsac.verify import VerifierConfig  # noqa: E402

SMALL = NetConfig(AGENT_DIM, TASK_DIM, DEPOT_DIM, d_model=16, heads=2, layers=2,
                  feedforward=32, features=FEATURES, pass_action=True)
#: Where the competition columns sit in a task row: after the engine-derived ones.
COMPETITION = slice(len(TASK_FEATURES) + len(EXTRA_TASK_FEATURES),
                    len(TASK_FEATURES) + len(EXTRA_TASK_FEATURES) + len(COMPETITION_FEATURES))


def random_state(rng: np.random.Generator, n_tasks: int, n_depots: int,
                 valid: list[int] | None = None) -> Observation:
    """A state of random numbers; ``valid``: its valid actions (0 the pass, i task i - 1)."""
    mask = np.zeros(1 + n_tasks, dtype=bool)
    mask[valid if valid is not None else 1 + rng.choice(n_tasks, size=max(1, n_tasks // 2),
                                                        replace=False)] = True
    return Observation(rng.normal(size=AGENT_DIM).astype(np.float32),
                       rng.normal(size=(n_tasks, TASK_DIM)).astype(np.float32),
                       rng.normal(size=(n_depots, DEPOT_DIM)).astype(np.float32), mask,
                       rng.normal(size=DEPOT_DIM).astype(np.float32))


pytestmark = pytest.mark.usefixtures("one_torch_thread")


@pytest.fixture
def actor() -> PolicyNet:
    torch.manual_seed(0)
    return PolicyNet(SMALL).eval()


# --- the recipe of the shipped policy ------------------------------------------------------
#: Fields of the shipped run's configuration that this version no longer has, with the value
#: that made each a no-op there (the code paths of unshipped recipes, docs/tsac.md,
#: "History"): the td signal, feature sets 1-2, annealed cloning, look-ahead distillation.
RETIRED = {"signal": "rollout", "features": 3, "clone_weight": 0.0, "distill_weight": 0.0}
#: Fields that only a retired path read: td's update rate, discount and target networks,
#: the entropy bonus's temperature (replaced by the fixed teacher prior), the cloning
#: schedule (its weight was 0) and the distillation's margin (its weight was 0).
UNREAD = {"update_every", "clone_until", "clone_floor", "distill_margin", "sac.gamma",
          "sac.tau", "sac.target_entropy_ratio", "sac.initial_alpha", "sac.alpha_lr"}


def flat(config: dict, prefix: str = "") -> dict:
    out = {}
    for key, value in config.items():
        if isinstance(value, dict):
            out.update(flat(value, f"{prefix}{key}."))
        else:
            out[prefix + key] = value
    return out


def test_the_training_defaults_are_the_shipped_policys_recipe():
    meta = policy_meta()
    shipped = flat(meta["config"])
    defaults = flat(json.loads(json.dumps(TrainConfig().to_dict())))
    for key, value in RETIRED.items():
        assert shipped.pop(key) == value, key
    for key in UNREAD:
        shipped.pop(key)
    assert defaults == shipped
    # The numbers the docs state, read from the file rather than taken on trust.
    assert (defaults["steps"], defaults["seed"], defaults["teacher_prior"],
            defaults["rollouts"], defaults["label_candidates"]) == (27_128, 0, 0.3, 16, 16)
    assert meta["seed"] == 0 and meta["steps"] == 27_128
    # Its verifier: VerifierConfig's defaults.
    assert json.loads(json.dumps(VerifierConfig().to_dict())) == meta["verifier"]["config"]


def test_methods_names_the_shipped_policy_as_the_default():
    from typer.testing import CliRunner

    from tsac_bench.cli import app

    result = CliRunner().invoke(app, ["methods", "tsac-ocf"], env={"COLUMNS": "200"})
    assert result.exit_code == 0
    policy_row = next(line for line in result.stdout.splitlines() if "policy " in line)
    assert "the shipped policy 3 (solvers/tsac/policies/tsac-default.pt)" in policy_row


# --- the networks --------------------------------------------------------------------------
def test_masked_actions_get_exactly_zero_probability(actor):
    state = random_state(np.random.default_rng(1), 7, 2, valid=[1, 4, 5])
    with torch.no_grad():
        probs, log_probs = actor.distribution(collate([state]))
    probs = probs[0].numpy()
    assert (probs[[0, 2, 3, 6, 7]] == 0.0).all()
    assert (probs[[1, 4, 5]] > 0).all()
    assert math.isclose(probs.sum(), 1.0, rel_tol=1e-6)
    assert torch.isneginf(log_probs[0, [0, 2, 3, 6, 7]]).all()


def test_padding_never_changes_the_real_tokens(actor):
    rng = np.random.default_rng(2)
    state = random_state(rng, 5, 2)
    alone = actor(collate([state]))[0]
    # The same state padded to 12 tasks and 4 depots by longer neighbours in the batch.
    padded = actor(collate([random_state(rng, 12, 1), state, random_state(rng, 3, 4)]))[1]
    assert padded.shape == (13,)
    torch.testing.assert_close(padded[:6], alone)
    assert torch.isneginf(padded[6:]).all()


def test_the_losses_over_a_padded_batch_are_those_of_its_states():
    torch.manual_seed(3)
    sac = DiscreteSAC(SMALL, SACConfig(), "cpu", teacher_prior=0.3)
    rng = np.random.default_rng(3)
    items = []
    for m, k in [(3, 2), (9, 3), (5, 2), (1, 1)]:
        state = random_state(rng, m, k)
        actions = tuple(np.flatnonzero(state.action_mask).tolist())
        items.append(Labelled(state, actions, tuple(rng.normal(size=len(actions)).tolist())))
    with torch.no_grad():
        batch = LabelledBatch.of(items, "cpu")
        singles = [LabelledBatch.of([item], "cpu") for item in items]
        actor_loss, entropy = sac.actor_loss(batch.states)
        actor_each = [sac.actor_loss(b.states) for b in singles]
        # The label loss is the mean over every label of the batch.
        counts = torch.tensor([len(item.actions) for item in items], dtype=torch.float32)
        label_each = torch.stack([sac.label_loss(b) for b in singles])
        label = sac.label_loss(batch)
    torch.testing.assert_close(actor_loss, torch.stack([a for a, _ in actor_each]).mean())
    torch.testing.assert_close(entropy, torch.cat([e for _, e in actor_each]))
    torch.testing.assert_close(label, (label_each * counts).sum() / counts.sum())
    assert torch.isfinite(label) and torch.isfinite(actor_loss)


def test_a_few_hundred_updates_fit_the_labels():
    torch.manual_seed(6)
    rng = np.random.default_rng(6)
    items = []
    for _ in range(128):
        state = random_state(rng, int(rng.integers(2, 8)), 2)
        actions = np.flatnonzero(state.action_mask)
        # A label the state determines: the first column of each labelled task row.
        items.append(Labelled(state, tuple(actions.tolist()),
                              tuple(state.tasks[actions - 1, 0].tolist())))
    sac = DiscreteSAC(SMALL, SACConfig(lr=1e-3), "cpu", teacher_prior=0.3)
    probe = LabelledBatch.of(items, "cpu")
    with torch.no_grad():
        before = sac.label_loss(probe).item()
    for _ in range(150):
        sac.update_from_labels(LabelledBatch.of([items[i] for i in rng.integers(128, size=32)],
                                                "cpu"))
    with torch.no_grad():
        after = sac.label_loss(probe).item()
    assert after < 0.5 * before


def test_the_replay_buffer_is_a_ring():
    buffer: ReplayBuffer[int] = ReplayBuffer(3)
    for item in range(5):
        buffer.add(item)
    assert buffer.items == [3, 4, 2] and len(buffer) == 3
    assert set(buffer.sample(20, np.random.default_rng(0))) == {2, 3, 4}


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
    actor = load_policy()
    sampled = PolicySelection(actor, temperature=1.0).probabilities(view)
    greedy = PolicySelection(actor, temperature=0.0).probabilities(view)
    assert greedy.sum() == 1.0 and greedy[int(np.argmax(sampled))] == 1.0
    assert set(np.flatnonzero(sampled)) <= {0} | {action_of(view, m) for m in view.candidates}


def test_every_ocf_method_starts_alike_by_default():
    shared = ("init", "samples", "k_max", "c_max")
    settings = [make_allocator(m).settings() for m in ("hocf", "rocf", "tsac-ocf")]
    assert {tuple(s[k] for k in shared) for s in settings} == {("empty", 1, 200_000, 5_000)}


def mid_game(scale="8/20", seed=3, decisions=15):
    """A game a few HOCF decisions in, and the view of the next AAV with candidates."""
    state = PlanningState.static(generate(scale, seed))
    game = CoalitionGame(state)
    game.run(HeuristicSelection(state.instance, 1.0, 2.0, 1.0), np.random.default_rng(0),
             k_max=decisions, c_max=C_MAX)
    n = next(n for n in range(game.n_aavs) if len(game.candidates(n)) > 2)
    return game, DecisionView(game, n, game.candidates(n))


def test_the_competition_columns_are_scaled_and_the_pass_leads():
    game, view = mid_game()
    state = observe(view)
    assert state.tasks.shape == (len(game.visible), TASK_DIM) == (len(game.visible), 27)
    raw = competition_columns(view)
    divisor = np.array([COMPETITION_SCALE[c] for c in COMPETITION_FEATURES])
    np.testing.assert_allclose(state.tasks[:, COMPETITION], raw / divisor, rtol=1e-6)
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
    # The actions: the pass first, then the candidate tasks; the pass token is the depot
    # row nearest to the anchor.
    assert state.action_mask[0]
    assert set(np.flatnonzero(state.action_mask[1:]) + 1) == {
        action_of(view, m) for m in view.candidates}
    assert all(action_choice(view, action_of(view, m)) == m for m in view.candidates)
    nearest_depot = np.argmin(state.depots[:, 2])
    np.testing.assert_array_equal(state.pass_token, state.depots[nearest_depot])
    game.pass_turn(view.aav)
    assert not observe(view).action_mask[0]  # a second pass under this structure
    # The per-structure cache: after more accepted moves the columns are those of a game
    # built afresh on the same routes.
    game.run(HeuristicSelection(game.instance, 1.0, 2.0, 1.0), np.random.default_rng(1),
             k_max=len(game.decisions) + 20, c_max=C_MAX)
    assert len(game.trajectory) > 1
    n = next(n for n in range(game.n_aavs) if game.candidates(n))
    fresh = CoalitionGame(game.state, game.plan.routes)
    np.testing.assert_array_equal(observe(DecisionView(game, n, game.candidates(n))).tasks,
                                  observe(DecisionView(fresh, n, game.candidates(n))).tasks)


def test_the_teacher_columns_are_hocfs_priority_and_choice():
    game, view = mid_game()
    state = observe(view)
    hocf = HeuristicSelection(game.instance, 1.0, 2.0, 1.0)
    choice = hocf.select(view, np.random.default_rng(7))
    priority, chosen = state.tasks[:, -2], state.tasks[:, -1]
    assert chosen.sum() == 1.0 and game.visible[int(np.argmax(chosen))] == choice
    assert teacher_action(state) == action_of(view, choice)
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


def test_padding_never_changes_the_real_tokens_of_game_states():
    torch.manual_seed(0)
    actor = PolicyNet(SMALL).eval()
    state = observe(mid_game()[1])
    longer = observe(mid_game("16/40", seed=5)[1])
    assert len(longer.tasks) > len(state.tasks)
    alone = actor(collate([state]))[0]
    batch = collate([longer, state])
    assert not batch["tasks"][1, len(state.tasks):].any()  # zero-padded rows
    padded = actor(batch)[1]
    width = 1 + len(state.tasks)
    torch.testing.assert_close(padded[:width], alone)
    assert torch.isneginf(padded[width:]).all()


def test_stacked_heads_give_each_heads_values_of_the_real_actions():
    torch.manual_seed(4)
    heads = [QNet(SMALL).eval() for _ in range(3)]
    stacked = StackedHeads(heads)
    states = [observe(mid_game(scale, seed)[1])
              for scale, seed in (("8/20", 3), ("16/40", 5), ("4/10", 2))]
    for batch in ([states[0]], states):  # alone, and padded by longer and shorter states
        obs = collate(batch)
        with torch.inference_mode():
            values = stacked(obs)
            assert values.shape == (3, *obs["action_mask"].shape)
            for i, state in enumerate(batch):
                width = 1 + len(state.tasks)
                for head, stacked_values in zip(heads, values, strict=True):
                    torch.testing.assert_close(stacked_values[i, :width],
                                               head(obs)[i, :width], rtol=1e-5, atol=1e-5)
    wider = NetConfig(AGENT_DIM, TASK_DIM, DEPOT_DIM, d_model=32, heads=2, layers=2,
                      feedforward=32, features=FEATURES, pass_action=True)
    with pytest.raises(ValueError, match="one config"):
        StackedHeads([QNet(SMALL), QNet(wider)])


def test_a_rollout_label_is_the_J_of_replaying_the_action_and_its_completion():
    game, view = mid_game()
    completion = HeuristicSelection(game.instance, 1.0, 2.0, 1.0)
    actions = [0, *np.flatnonzero(observe(view).action_mask[1:])[:3] + 1]
    before = (game.plan.routes, len(game.decisions), set(game.tabu))
    values = rollout_values(game, view, actions, completion, rollouts=2, seed=7)
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
    actions = [0, *np.flatnonzero(observe(view).action_mask[1:])[:4] + 1]
    alone = rollout_values(game, view, actions, completion, rollouts=3, seed=11)
    assert alone.shape == (5, 3) and np.ptp(alone) > 0  # rollouts that differ, in order
    with RolloutWorkers(2) as workers:
        shared = rollout_values(game, view, actions, completion, rollouts=3, seed=11,
                                workers=workers)
    np.testing.assert_array_equal(shared, alone)
    with pytest.raises(ValueError, match="at least 2"):
        RolloutWorkers(1)


@pytest.mark.parametrize("seed", range(5))
def test_label_candidates_are_every_valid_action_or_that_many_drawn(seed):
    rng = np.random.default_rng(seed)
    valid = np.sort(rng.choice(40, size=int(rng.integers(2, 30)), replace=False))
    actions = label_candidates(valid, 8, rng)
    assert len(actions) == min(8, len(valid)) and len(set(actions.tolist())) == len(actions)
    assert set(actions) <= set(valid) and list(actions) == sorted(actions)
    if len(valid) <= 8:
        assert list(actions) == list(valid)


def test_policy_files_of_another_state_or_format_are_refused(tmp_path):
    assert load_policy().config.features == FEATURES == 3
    torch.manual_seed(1)
    save_policy(PolicyNet(SMALL), tmp_path / "p.pt", {})
    payload = torch.load(tmp_path / "p.pt", weights_only=True)
    payload["config"]["features"] = 2
    torch.save(payload, tmp_path / "v2.pt")
    with pytest.raises(PolicyFileError, match="feature set 2, this version builds 3"):
        load_policy(tmp_path / "v2.pt")
    payload["config"].update(features=3, task_dim=20)
    torch.save(payload, tmp_path / "narrow.pt")
    with pytest.raises(PolicyFileError, match=r"task 20.*do not fit"):
        load_policy(tmp_path / "narrow.pt")
    payload["format"] = "tsac-bench/policy@1"
    torch.save(payload, tmp_path / "old.pt")
    with pytest.raises(PolicyFileError, match="format: expected 'tsac-bench/policy@3'"):
        load_policy(tmp_path / "old.pt")
    # Same seed, same plan, with the pass in play and best of 2 games.
    instance = generate("8/20", 4)
    settings = {"policy": str(tmp_path / "p.pt"), "decode": "sample", "samples": 2}
    runs = [solve(instance, "tsac-ocf", seed=9, mode="dynamic", settings=settings)
            for _ in range(2)]
    assert runs[0].solution.routes == runs[1].solution.routes
    assert runs[0].evaluation.feasible and runs[0].claim_matches


def small_run(**settings) -> TrainConfig:
    return TrainConfig(**{"warmup": 20, "pretrain_updates": 3, "eval_every": 1000,
                          "eval_scale": "4/10", "eval_instances": 1, "checkpoint_every": 1000,
                          "curriculum": ((0.0, ("8/20",)),), "net": SMALL,
                          "label_share": 0.5, "label_candidates": 3, "rollouts": 1,
                          "replan_share": 0.0, **settings})


def test_training_writes_a_policy_and_resumes(tmp_path):
    config = small_run(steps=50, eval_every=50, checkpoint_every=25, label_share=0.3,
                       replan_share=0.5, curriculum=((0.0, ("4/10",)),))
    first = train(tmp_path, config, device="cpu")
    assert first["steps"] == 50 and first["labels"] and first["updates"]
    assert len(first["evals"]) == 1 and first["pretrain"]
    policy = read_policy(tmp_path / "policy.pt")
    assert policy.actor.config == SMALL and len(policy.critics) == 2
    # A call that runs out of its time stops at an episode's end with a checkpoint.
    paused = train(tmp_path, TrainConfig(steps=70), device="cpu",
                   resume=tmp_path / "checkpoint.pt", stop_after=1e-9)
    assert paused["steps"] == 50
    more = train(tmp_path, TrainConfig(steps=70), device="cpu",
                 resume=tmp_path / "checkpoint.pt")
    # The resumed run keeps its configuration (SMALL network, its curriculum), not the
    # defaults passed along with the new length.
    assert more["steps"] == 70 and more["config"]["net"]["d_model"] == SMALL.d_model
    assert [e["step"] for e in more["evals"]] == [50, 70]


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


def test_the_teacher_prior_puts_95_percent_on_hocfs_choice_and_the_rest_uniformly():
    tasks = torch.zeros((1, 3, 4))
    tasks[0, 1, -1] = 1.0  # task row 1 is the teacher's choice: action 2 after the pass
    states = {"tasks": tasks, "pass_token": torch.zeros((1, 3)),
              "action_mask": torch.tensor([[True, True, True, False]])}
    prior = teacher_prior_of(states)[0].exp()
    torch.testing.assert_close(prior, torch.tensor([0.05 / 3, 0.05 / 3, 0.95 + 0.05 / 3, 0.0]))


def test_with_a_teacher_prior_the_actor_loss_is_the_kl_regularised_one():
    torch.manual_seed(0)
    sac = DiscreteSAC(SMALL, SACConfig(), "cpu", teacher_prior=0.5)
    _, view = mid_game()
    states = collate([observe(view)])
    with torch.no_grad():
        loss, _ = sac.actor_loss(states)
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


def test_training_is_the_same_for_the_same_seed(tmp_path):
    first = train(tmp_path / "a", small_run(steps=40), device="cpu")
    second = train(tmp_path / "b", small_run(steps=40), device="cpu")
    assert first["updates"] and first["updates"] == second["updates"]
    assert first["episodes"] == second["episodes"]
    a, b = load_policy(tmp_path / "a" / "policy.pt"), load_policy(tmp_path / "b" / "policy.pt")
    assert all(torch.equal(x, y) for x, y in zip(a.state_dict().values(),
                                                 b.state_dict().values(), strict=True))
    other = train(tmp_path / "c", small_run(steps=40, seed=1), device="cpu")
    assert other["updates"] != first["updates"]


def test_training_with_label_workers_is_the_same_run(tmp_path):
    alone = train(tmp_path / "a", small_run(steps=40), device="cpu")
    shared = train(tmp_path / "b", small_run(steps=40), device="cpu", label_workers=2)
    assert alone["labels"] and shared["labels"] == alone["labels"]
    assert shared["updates"] == alone["updates"] and shared["episodes"] == alone["episodes"]


def margin_policy(path, critics: int = 2, unit: float = 1.0):
    torch.manual_seed(3)
    save_policy(PolicyNet(SMALL), path, {},
                critics=[QNet(SMALL) for _ in range(critics)], critic_unit=unit)
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
    obs = collate([observe(DecisionView(game, n, game.candidates(n)))])
    first, second = (q(obs) for q in policy.critics)
    # The critics run in one stacked pass (StackedHeads): their values to float rounding.
    torch.testing.assert_close(policy.values(obs), 2.5 * torch.minimum(first, second))
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
