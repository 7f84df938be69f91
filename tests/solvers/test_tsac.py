"""TSAC-OCF: the environment, the masked transformer policy, the SAC losses and training,
and the shipped policy."""

from __future__ import annotations

import math
import socket

import numpy as np
import pytest

torch = pytest.importorskip("torch")
pytest.importorskip("gymnasium")

from tsac_bench.model.generator import generate  # noqa: E402
from tsac_bench.planning import PlanningState, make_allocator  # noqa: E402
from tsac_bench.planning.solve import solve  # noqa: E402
from tsac_bench.solvers.ocf.engine import CoalitionGame, DecisionView  # noqa: E402
from tsac_bench.solvers.tsac.env import (  # noqa: E402
    AGENT_DIM,
    DEPOT_DIM,
    TASK_DIM,
    Observation,
    TaskSelectionEnv,
    unpad,
)
from tsac_bench.solvers.tsac.net import NetConfig, PolicyNet, collate  # noqa: E402
from tsac_bench.solvers.tsac.policy import (  # noqa: E402
    DEFAULT_POLICY,
    PolicyFileError,
    PolicySelection,
    load_policy,
)
from tsac_bench.solvers.tsac.sac import (  # noqa: E402
    Batch,
    DiscreteSAC,
    SACConfig,
    TrainConfig,
    Transition,
    train,
)

SMALL = NetConfig(AGENT_DIM, TASK_DIM, DEPOT_DIM, d_model=16, heads=2, layers=2,
                  feedforward=32)


def random_state(rng: np.random.Generator, n_tasks: int, n_depots: int,
                 valid: list[int] | None = None) -> Observation:
    mask = np.zeros(n_tasks, dtype=bool)
    mask[valid if valid is not None else rng.choice(n_tasks, size=max(1, n_tasks // 2),
                                                    replace=False)] = True
    return Observation(rng.normal(size=AGENT_DIM).astype(np.float32),
                       rng.normal(size=(n_tasks, TASK_DIM)).astype(np.float32),
                       rng.normal(size=(n_depots, DEPOT_DIM)).astype(np.float32), mask)


@pytest.fixture(autouse=True)
def one_thread():
    """Small networks run fastest on one thread, and a shared machine stays usable."""
    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(threads)


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
                         curriculum=((0.0, ("4/10",)),), net=SMALL)
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
    actor = load_policy()
    sampled = PolicySelection(actor, temperature=1.0).probabilities(view)
    greedy = PolicySelection(actor, temperature=0.0).probabilities(view)
    assert greedy.sum() == 1.0 and greedy[int(np.argmax(sampled))] == 1.0
    assert set(np.flatnonzero(sampled)) <= {game.visible.index(m) for m in view.candidates}


def test_every_ocf_method_starts_alike_by_default():
    shared = ("init", "samples", "k_max", "c_max")
    settings = [make_allocator(m).settings() for m in ("hocf", "rocf", "tsac-ocf")]
    assert {tuple(s[k] for k in shared) for s in settings} == {("empty", 1, 200_000, 5_000)}
