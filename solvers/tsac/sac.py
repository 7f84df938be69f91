"""Discrete soft actor-critic for the task-selection policy (paper Sec. III-B-2, Eqs. 14-17)
and the training run behind ``tsac-bench train``.

* Twin critics Q_theta1, Q_theta2 with Polyak-averaged target copies; the critic target is
  the exact expectation over the next state's valid actions (Eq. 15), not a sample.
* The actor minimises Eq. 16, the expectation over the valid actions of
  alpha log pi - min_j Q_j.
* The temperature alpha is learned (automatic entropy tuning): the target entropy of a state
  is ``target_entropy_ratio * log(number of valid actions)``, so states with one valid task
  ask for none.
* The replay buffer keeps states unpadded; a sampled batch is padded to its own longest
  state (L_max of Eq. 17) and every sum over actions runs under the padding and validity
  masks, so padded entries contribute neither value nor gradient.
* Curriculum: the scales an episode is drawn from change with the share of steps done.

Files written to the output folder: ``checkpoint.pt`` (everything needed to resume),
``policy.pt`` (the actor alone, the form ``tsac-ocf`` loads), ``curve.json`` and
``curve.png`` (the training curve).
"""

from __future__ import annotations

import copy
import json
import math
import time
from collections.abc import Callable, Sequence
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import torch
from torch import Tensor
from torch.nn import functional as F

from tsac_bench.model.evaluator import CostEvaluator
from tsac_bench.model.generator import generate
from tsac_bench.planning import PlanningState, make_allocator
from tsac_bench.solvers.ocf.engine import CoalitionGame
from tsac_bench.solvers.tsac.env import (
    AGENT_DIM,
    DEPOT_DIM,
    TASK_DIM,
    Observation,
    TaskSelectionEnv,
    unpad,
)
from tsac_bench.solvers.tsac.net import NetConfig, PolicyNet, QNet, collate, expectation
from tsac_bench.solvers.tsac.policy import PolicySelection, save_policy


@dataclass(frozen=True)
class SACConfig:
    gamma: float = 0.97
    lr: float = 3e-4
    tau: float = 0.01  # Polyak step of the target critics
    batch_size: int = 64
    buffer_size: int = 20_000
    target_entropy_ratio: float = 0.3
    initial_alpha: float = 0.05


@dataclass(frozen=True)
class Transition:
    state: Observation
    action: int  # index into the state's task rows
    reward: float
    next_state: Observation
    done: bool  # terminated (a stable structure); a truncated episode bootstraps


class ReplayBuffer:
    """A ring of variable-length transitions."""

    def __init__(self, capacity: int) -> None:
        self.capacity = capacity
        self.items: list[Transition] = []
        self.position = 0

    def __len__(self) -> int:
        return len(self.items)

    def add(self, transition: Transition) -> None:
        if len(self.items) < self.capacity:
            self.items.append(transition)
        else:
            self.items[self.position] = transition
        self.position = (self.position + 1) % self.capacity

    def sample(self, size: int, rng: np.random.Generator) -> list[Transition]:
        return [self.items[i] for i in rng.integers(len(self.items), size=size)]


@dataclass
class Batch:
    states: dict[str, Tensor]
    actions: Tensor
    rewards: Tensor
    next_states: dict[str, Tensor]
    dones: Tensor

    @classmethod
    def of(cls, transitions: Sequence[Transition], device: torch.device | str) -> Batch:
        return cls(collate([t.state for t in transitions], device),
                   torch.tensor([t.action for t in transitions], device=device),
                   torch.tensor([t.reward for t in transitions], dtype=torch.float32,
                                device=device),
                   collate([t.next_state for t in transitions], device),
                   torch.tensor([float(t.done) for t in transitions], device=device))


class DiscreteSAC:
    """The actor, the twin critics, their targets, alpha and the optimisers."""

    def __init__(self, net: NetConfig, config: SACConfig, device: torch.device | str = "cpu"):
        self.config = config
        self.device = torch.device(device)
        self.actor = PolicyNet(net).to(self.device)
        self.critics = [QNet(net).to(self.device) for _ in range(2)]
        self.targets = [copy.deepcopy(q).requires_grad_(False) for q in self.critics]
        self.log_alpha = torch.tensor(math.log(config.initial_alpha), device=self.device,
                                      requires_grad=True)
        self.actor_optimizer = torch.optim.Adam(self.actor.parameters(), lr=config.lr)
        self.critic_optimizer = torch.optim.Adam(
            [p for q in self.critics for p in q.parameters()], lr=config.lr)
        self.alpha_optimizer = torch.optim.Adam([self.log_alpha], lr=config.lr)

    @property
    def alpha(self) -> Tensor:
        return self.log_alpha.exp().detach()

    # --- the losses ------------------------------------------------------------------
    def critic_loss(self, batch: Batch) -> Tensor:
        """Eq. 14 with the target of Eq. 15, summed over the two critics."""
        with torch.no_grad():
            probs, log_probs = self.actor.distribution(batch.next_states)
            q_next = torch.minimum(*(t(batch.next_states) for t in self.targets))
            soft_value = expectation(probs, q_next - self.alpha * log_probs,
                                     batch.next_states["action_mask"])
            target = batch.rewards + self.config.gamma * (1.0 - batch.dones) * soft_value
        chosen = batch.actions.unsqueeze(1)
        return sum(F.mse_loss(q(batch.states).gather(1, chosen).squeeze(1), target)
                   for q in self.critics)

    def actor_loss(self, batch: Batch) -> tuple[Tensor, Tensor]:
        """Eq. 16 and the entropy of each state's policy (for the temperature)."""
        probs, log_probs = self.actor.distribution(batch.states)
        with torch.no_grad():
            q = torch.minimum(*(c(batch.states) for c in self.critics))
        mask = batch.states["action_mask"]
        loss = expectation(probs, self.alpha * log_probs - q, mask).mean()
        entropy = -expectation(probs, log_probs, mask)
        return loss, entropy.detach()

    def alpha_loss(self, entropy: Tensor, action_mask: Tensor) -> Tensor:
        target = self.config.target_entropy_ratio * torch.log(
            action_mask.sum(dim=-1).clamp(min=1).float())
        return (self.log_alpha * (entropy - target)).mean()

    def imitate(self, batch: Batch) -> dict[str, float]:
        """One pre-training step: the actor by cross-entropy on the batch's actions (a
        demonstrator's), the critics by Eqs. 14-15 under the actor being cloned."""
        critic_loss = self.critic_loss(batch)
        self.critic_optimizer.zero_grad()
        critic_loss.backward()
        self.critic_optimizer.step()
        clone_loss = self.clone_loss(batch)
        self.actor_optimizer.zero_grad()
        clone_loss.backward()
        self.actor_optimizer.step()
        self._track_targets()
        return {"critic_loss": critic_loss.item(), "clone_loss": clone_loss.item()}

    def _track_targets(self) -> None:
        with torch.no_grad():
            for q, target in zip(self.critics, self.targets, strict=True):
                for p, p_target in zip(q.parameters(), target.parameters(), strict=True):
                    p_target.lerp_(p, self.config.tau)

    def clone_loss(self, batch: Batch) -> Tensor:
        """Cross-entropy of the actor against the batch's (a demonstrator's) actions."""
        _, log_probs = self.actor.distribution(batch.states)
        return -log_probs.gather(1, batch.actions.unsqueeze(1)).mean()

    def update(self, batch: Batch, demonstrations: Batch | None = None,
               clone_weight: float = 0.0) -> dict[str, float]:
        """One SAC step; with ``demonstrations``, the actor loss also carries
        ``clone_weight`` times the cross-entropy on them (SAC + behaviour cloning)."""
        critic_loss = self.critic_loss(batch)
        self.critic_optimizer.zero_grad()
        critic_loss.backward()
        self.critic_optimizer.step()
        actor_loss, entropy = self.actor_loss(batch)
        if demonstrations is not None and clone_weight > 0:
            actor_loss = actor_loss + clone_weight * self.clone_loss(demonstrations)
        self.actor_optimizer.zero_grad()
        actor_loss.backward()
        self.actor_optimizer.step()
        alpha_loss = self.alpha_loss(entropy, batch.states["action_mask"])
        self.alpha_optimizer.zero_grad()
        alpha_loss.backward()
        self.alpha_optimizer.step()
        self._track_targets()
        return {"critic_loss": critic_loss.item(), "actor_loss": actor_loss.item(),
                "entropy": entropy.mean().item(), "alpha": self.alpha.item()}

    # --- checkpoints -----------------------------------------------------------------
    def state_dict(self) -> dict[str, Any]:
        return {"actor": self.actor.state_dict(),
                "critics": [q.state_dict() for q in self.critics],
                "targets": [t.state_dict() for t in self.targets],
                "log_alpha": self.log_alpha.detach().clone(),
                "actor_optimizer": self.actor_optimizer.state_dict(),
                "critic_optimizer": self.critic_optimizer.state_dict(),
                "alpha_optimizer": self.alpha_optimizer.state_dict()}

    def load_state_dict(self, state: dict[str, Any]) -> None:
        self.actor.load_state_dict(state["actor"])
        for q, s in zip(self.critics, state["critics"], strict=True):
            q.load_state_dict(s)
        for t, s in zip(self.targets, state["targets"], strict=True):
            t.load_state_dict(s)
        with torch.no_grad():
            self.log_alpha.copy_(state["log_alpha"])
        self.actor_optimizer.load_state_dict(state["actor_optimizer"])
        self.critic_optimizer.load_state_dict(state["critic_optimizer"])
        self.alpha_optimizer.load_state_dict(state["alpha_optimizer"])


# --- the training run --------------------------------------------------------------------
#: (share of the steps from which the stage applies, the scales episodes are drawn from)
DEFAULT_CURRICULUM: tuple[tuple[float, tuple[str, ...]], ...] = (
    (0.0, ("4/10", "8/20")),
    (0.3, ("8/20", "16/40")),
    (0.7, ("16/40",)),
)


@dataclass(frozen=True)
class TrainConfig:
    steps: int = 16_000
    seed: int = 0
    warmup: int = 4_000  # decisions collected before the first update
    #: Who takes the warm-up decisions: a registered OCF method's selection rule (its
    #: decisions then also pre-train the actor by imitation and stay as demonstrations)
    #: or None (uniformly random).
    demonstrator: str | None = "hocf"
    pretrain_updates: int = 1_000  # imitation + critic steps after the warm-up
    clone_weight: float = 2.0  # weight of the demonstrations' cross-entropy in SAC's actor loss
    update_every: int = 2  # env steps per gradient update
    curriculum: tuple[tuple[float, tuple[str, ...]], ...] = DEFAULT_CURRICULUM
    episode_steps: int = 400  # truncation of one episode (one OCF game)
    eval_every: int = 2_000
    eval_scale: str = "16/40"
    eval_instances: int = 3
    checkpoint_every: int = 1_000
    net: NetConfig = field(default_factory=lambda: NetConfig(
        AGENT_DIM, TASK_DIM, DEPOT_DIM, d_model=32, heads=4, layers=2, feedforward=64))
    sac: SACConfig = field(default_factory=SACConfig)

    def scales_at(self, step: int) -> tuple[str, ...]:
        share = step / max(1, self.steps)
        return next(scales for start, scales in reversed(self.curriculum) if share >= start)

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> TrainConfig:
        data = dict(data)
        data["curriculum"] = tuple((s, tuple(scales)) for s, scales in data["curriculum"])
        data["net"] = NetConfig(**data["net"])
        data["sac"] = SACConfig(**data["sac"])
        return cls(**data)


def resolve_device(device: str) -> torch.device:
    if device == "auto":
        return torch.device("cuda" if torch.cuda.is_available() else "cpu")
    if device == "cuda" and not torch.cuda.is_available():
        raise ValueError("--device cuda: no CUDA device is available")
    return torch.device(device)


class Evaluation:
    """Final J of the policy-driven game on fixed static moments, against HOCF's."""

    def __init__(self, config: TrainConfig) -> None:
        self.states = [PlanningState.static(generate(config.eval_scale, 1_000_000 + i))
                       for i in range(config.eval_instances)]
        hocf = make_allocator("hocf")
        self.reference = [CostEvaluator(s.instance).cost(hocf.plan(s, seed=0).routes)
                          for s in self.states]

    def __call__(self, actor: PolicyNet) -> dict[str, float]:
        costs = []
        actor.eval()
        for i, state in enumerate(self.states):
            game = CoalitionGame(state, state.base_routes())
            game.run(PolicySelection(actor), np.random.default_rng(i), k_max=200_000,
                     c_max=5_000)
            costs.append(game.cost)
        actor.train()
        return {"eval_J": float(np.mean(costs)),
                "eval_ratio_hocf": float(np.mean(costs) / np.mean(self.reference))}


def train(out: Path, config: TrainConfig, *, device: str = "auto", resume: Path | None = None,
          on_step: Callable[[int, dict[str, float]], None] | None = None) -> dict[str, Any]:
    """Train from scratch (or from ``resume``'s checkpoint) up to ``config.steps`` env
    steps; returns the summary written to ``curve.json``."""
    out.mkdir(parents=True, exist_ok=True)
    torch_device = resolve_device(device)
    checkpoint = None
    if resume is not None:
        checkpoint = torch.load(resume, map_location=torch_device, weights_only=False)
        # The run goes on as it was configured; only its length may change.
        config = TrainConfig.from_dict({**checkpoint["config"], "steps": config.steps})
    torch.manual_seed(config.seed)
    sac = DiscreteSAC(config.net, config.sac, torch_device)
    buffer = ReplayBuffer(config.sac.buffer_size)
    demos = ReplayBuffer(config.warmup)  # the demonstrator's decisions, never overwritten
    rng = np.random.default_rng(config.seed)
    sampler = torch.Generator().manual_seed(config.seed)
    log: dict[str, list] = {"updates": [], "episodes": [], "evals": []}
    step, episode, seconds = 0, 0, 0.0
    if checkpoint is not None:
        sac.load_state_dict(checkpoint["sac"])
        buffer.items, buffer.position = checkpoint["buffer"], checkpoint["buffer_position"]
        demos.items = checkpoint["demonstrations"]
        rng.bit_generator.state = checkpoint["rng"]
        sampler.set_state(checkpoint["sampler"])
        log, step, episode = checkpoint["log"], checkpoint["step"], checkpoint["episode"]
        seconds = checkpoint["seconds"]
    evaluate = Evaluation(config)
    env = TaskSelectionEnv(config.scales_at(step), max_steps=config.episode_steps)
    began = time.perf_counter() - seconds

    def save_checkpoint() -> None:
        torch.save({"config": config.to_dict(), "sac": sac.state_dict(), "buffer": buffer.items,
                    "demonstrations": demos.items,
                    "buffer_position": buffer.position, "rng": rng.bit_generator.state,
                    "sampler": sampler.get_state(), "log": log, "step": step,
                    "episode": episode, "seconds": time.perf_counter() - began},
                   out / "checkpoint.pt")

    demonstrator = (make_allocator(config.demonstrator) if config.demonstrator is not None
                     else None)
    expert_run = demonstrator is not None

    def reset(**kwargs: Any) -> tuple[Observation, float, Any]:
        padded, info = env.reset(**kwargs)
        rule = demonstrator.rule(env.game.state) if demonstrator is not None else None
        return unpad(padded), info["J"], rule

    state, start_J, expert = reset(seed=int(rng.integers(2**31)))
    returns = 0.0
    stats: dict[str, float] = {}
    while step < config.steps:
        if step < config.warmup and expert is not None:
            action = env.game.visible.index(expert.select(env.view, rng))
        elif step < config.warmup:
            action = int(rng.choice(np.flatnonzero(state.action_mask)))
        else:
            with torch.no_grad():
                probs, _ = sac.actor.distribution(collate([state], torch_device))
            action = int(torch.multinomial(probs[0].cpu(), 1, generator=sampler))
        padded, reward, terminated, truncated, info = env.step(action)
        next_state = unpad(padded)
        transition = Transition(state, action, reward, next_state, terminated)
        buffer.add(transition)
        if step < config.warmup and expert is not None:
            demos.add(transition)
        state, returns, step = next_state, returns + reward, step + 1
        if step > config.warmup and step % config.update_every == 0:
            demonstrations = (Batch.of(demos.sample(config.sac.batch_size, rng), torch_device)
                              if expert_run and len(demos) else None)
            stats = sac.update(Batch.of(buffer.sample(config.sac.batch_size, rng),
                                        torch_device), demonstrations, config.clone_weight)
            if step % 50 < config.update_every:
                log["updates"].append({"step": step, **stats})
        if terminated or truncated:
            log["episodes"].append({"step": step, "return": returns, "J_start": start_J,
                                    "J_end": info["J"], "scales": list(env.scales)})
            episode += 1
            env.set_scales(config.scales_at(step))
            state, start_J, expert = reset()
            returns = 0.0
        if step == config.warmup and expert is not None:
            for i in range(config.pretrain_updates):
                stats = sac.imitate(Batch.of(buffer.sample(config.sac.batch_size, rng),
                                             torch_device))
                if i % 50 == 0:
                    log.setdefault("pretrain", []).append({"update": i, **stats})
        if step % config.eval_every == 0 or step == config.steps:
            log["evals"].append({"step": step, **evaluate(sac.actor)})
            stats = {**stats, **log["evals"][-1]}
        if step % config.checkpoint_every == 0 or step == config.steps:
            save_checkpoint()
        if on_step is not None:
            on_step(step, stats)
    seconds = time.perf_counter() - began
    meta = {"steps": step, "episode_count": episode, "seed": config.seed, "seconds": seconds,
            "device": str(torch_device), "torch": torch.__version__,
            "threads": torch.get_num_threads(), "config": config.to_dict()}
    save_policy(sac.actor, out / "policy.pt", meta)
    summary = {**meta, **log}
    (out / "curve.json").write_text(json.dumps(summary, indent=1))
    plot_curve(summary, out / "curve.png")
    return summary


def plot_curve(summary: dict[str, Any], path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 3, figsize=(13, 3.6))
    episodes = summary["episodes"]
    if episodes:
        steps = np.array([e["step"] for e in episodes])
        gain = np.array([1 - e["J_end"] / e["J_start"] for e in episodes])
        window = max(1, len(gain) // 30)
        smooth = np.convolve(gain, np.ones(window) / window, mode="valid")
        axes[0].plot(steps, gain, ".", alpha=0.2, ms=3)
        axes[0].plot(steps[window - 1:], smooth)
    axes[0].set(title="episode: 1 - J_end / J_start", xlabel="env step")
    updates = summary["updates"]
    if updates:
        steps = [u["step"] for u in updates]
        axes[1].semilogy(steps, [u["critic_loss"] for u in updates], label="critic loss")
        axes[1].semilogy(steps, [u["alpha"] for u in updates], label="alpha")
        axes[1].legend()
    axes[1].set(title="SAC", xlabel="env step")
    evals = summary["evals"]
    if evals:
        axes[2].plot([e["step"] for e in evals], [e["eval_ratio_hocf"] for e in evals], "o-")
        axes[2].axhline(1.0, color="grey", lw=0.8)
    axes[2].set(title="held-out static 16/40: J(policy) / J(HOCF)", xlabel="env step")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
