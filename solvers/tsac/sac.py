"""Discrete soft actor-critic for the task-selection policy (paper Sec. III-B-2, Eqs. 14-17,
with the deviations docs/tsac.md, "Training", gives the reasons for): the algorithm, apart
from the training run that feeds it (``training``).

* Labels: at a share of the decisions, some valid actions of the state are each finished by
  HOCF (``rollout_values``, common random AAV orders), and their label is minus the mean
  final J, centred per state.
* Twin critics Q_theta1, Q_theta2 regress the labels (policy evaluation by rollouts, no
  bootstrapping); the actor minimises Eq. 16 against min(Q1, Q2) with the entropy bonus
  replaced by a fixed-weight KL divergence from a prior on HOCF's choice
  (``teacher_prior_of``): soft policy iteration that deviates from HOCF only where the
  critics put another action well ahead.
* Batches keep states unpadded until sampled; a batch is padded to its own longest state
  (L_max of Eq. 17) and every sum over actions runs under the padding and validity masks.
"""


from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any, Generic, TypeVar

import numpy as np
import torch
from torch import Tensor

from tsac_bench.solvers.ocf.engine import (
    C_MAX,
    K_MAX,
    PASS,
    CoalitionGame,
    DecisionView,
    SelectionRule,
    sample_rng,
)
from tsac_bench.solvers.tsac.features import (
    TEACHER_CHOICE_COLUMN,
    Observation,
    action_choice,
)
from tsac_bench.solvers.tsac.net import NetConfig, PolicyNet, QNet, collate, expectation


@dataclass(frozen=True)
class SACConfig:
    lr: float = 3e-4
    batch_size: int = 64
    buffer_size: int = 20_000


Item = TypeVar("Item")


class ReplayBuffer(Generic[Item]):
    """A ring of variable-length items (labelled states, demonstrations)."""

    def __init__(self, capacity: int) -> None:
        self.capacity = capacity
        self.items: list[Item] = []
        self.position = 0

    def __len__(self) -> int:
        return len(self.items)

    def add(self, item: Item) -> None:
        if len(self.items) < self.capacity:
            self.items.append(item)
        else:
            self.items[self.position] = item
        self.position = (self.position + 1) % self.capacity

    def sample(self, size: int, rng: np.random.Generator) -> list[Item]:
        return [self.items[i] for i in rng.integers(len(self.items), size=size)]


@dataclass(frozen=True)
class Demonstration:
    """A state and the demonstrator's action in it."""

    state: Observation
    action: int


def finish_games(game: CoalitionGame, aav: int, jobs: Sequence[tuple[int, int]],
                 completion: SelectionRule, seed: int) -> list[float]:
    """The final J of each job (choice, r): on a fork of the game, AAV ``aav`` takes the
    choice (``PASS`` or a task), then ``completion`` finishes the game with the generator
    ``sample_rng(seed, r)``. A module-level function of picklable arguments, so that
    ``RolloutWorkers`` can run it in another process."""
    finals = []
    for choice, r in jobs:
        fork = game.fork()
        if choice == PASS:
            fork.pass_turn(aav)
        else:
            fork.decide(aav, choice)
        fork.run(completion, sample_rng(seed, r), k_max=K_MAX, c_max=C_MAX)
        finals.append(fork.cost)
    return finals


class RolloutWorkers:
    """Worker processes that share the rollouts of a labelled state: each takes a
    contiguous share of its (action, rollout) jobs with its own copy of the game. Every
    job's result depends on the game, the action and its seed only, so the labels are the
    same to the last digit with any number of workers; only the wall time changes."""

    def __init__(self, workers: int) -> None:
        import multiprocessing
        from concurrent.futures import ProcessPoolExecutor

        if workers < 2:
            raise ValueError(f"workers: at least 2 (1 runs the rollouts in-process), got "
                             f"{workers}")
        self.workers = workers
        # forkserver, not fork: the parent holds torch's thread pools, which a forked
        # child must not inherit.
        self._pool = ProcessPoolExecutor(workers,
                                         mp_context=multiprocessing.get_context("forkserver"))

    def finish_games(self, game: CoalitionGame, aav: int, jobs: Sequence[tuple[int, int]],
                     completion: SelectionRule, seed: int) -> list[float]:
        """``finish_games`` over the workers; the results in the order of ``jobs``."""
        # Two shares per worker: rollout lengths differ by action, so the shares even out.
        shares = [part.tolist() for part in np.array_split(np.arange(len(jobs)),
                                                           2 * self.workers) if len(part)]
        futures = [self._pool.submit(finish_games, game, aav, [jobs[j] for j in share],
                                     completion, seed) for share in shares]
        return [final for future in futures for final in future.result()]

    def close(self) -> None:
        self._pool.shutdown()

    def __enter__(self) -> RolloutWorkers:
        return self

    def __exit__(self, *_: object) -> None:
        self.close()


def rollout_values(game: CoalitionGame, view: DecisionView, actions: Sequence[int],
                   completion: SelectionRule, *, rollouts: int, seed: int,
                   workers: RolloutWorkers | None = None) -> np.ndarray:
    """The final J of each action's rollouts, shape (len(actions), rollouts): on a fork of
    the game, the deciding AAV takes the action (a pass, or the ADD/REMOVE of a task, which
    the engine accepts or rejects), then ``completion`` finishes the game (new rounds, the
    engine's stop rules) with the generator ``sample_rng(seed, r)`` for rollout r: the same
    AAV orders for every action of the state (common random numbers), so their labels
    differ by the actions, not by the draws. ``workers``: run them in those processes (the
    same numbers)."""
    jobs = [(action_choice(view, action), r) for action in actions for r in range(rollouts)]
    finish = workers.finish_games if workers is not None else finish_games
    return np.array(finish(game, view.aav, jobs, completion, seed)).reshape(len(actions),
                                                                           rollouts)


def label_candidates(valid: np.ndarray, most: int, rng: np.random.Generator) -> np.ndarray:
    """The actions of a state to label, ascending: every valid one if there are at most
    ``most``, otherwise ``most`` drawn uniformly."""
    if len(valid) <= most:
        return valid
    return np.sort(rng.choice(valid, most, replace=False))


@dataclass(frozen=True)
class Labelled:
    """A state with the rollout value of some of its valid actions: ``q`` is minus the mean
    final J of each action's rollouts, centred on the mean over the labelled actions and
    divided by the label scale (the actor's loss is blind to a per-state constant)."""

    state: Observation
    actions: tuple[int, ...]
    q: tuple[float, ...]


@dataclass
class LabelledBatch:
    states: dict[str, Tensor]
    label_mask: Tensor  # (B, actions) True where a label exists
    labels: Tensor  # (B, actions), 0 where none

    @classmethod
    def of(cls, items: Sequence[Labelled], device: torch.device | str) -> LabelledBatch:
        states = collate([item.state for item in items], device)
        shape = states["action_mask"].shape
        mask = torch.zeros(shape, dtype=torch.bool)
        labels = torch.zeros(shape)
        for i, item in enumerate(items):
            index = torch.tensor(item.actions)
            mask[i, index] = True
            labels[i, index] = torch.tensor(item.q, dtype=torch.float32)
        return cls(states, mask.to(device), labels.to(device))


#: The teacher prior's share spread uniformly over the valid actions (the rest is on the
#: teacher's choice): the KL stays finite, and deviating from the teacher costs
#: log((1 - e) |valid| / e), about 5.3 units of ``teacher_prior`` with 10 valid actions.
TEACHER_PRIOR_SPREAD = 0.05


def teacher_choice(states: dict[str, Tensor]) -> Tensor:
    """HOCF's choice in each state, one-hot over the actions: the task row whose
    teacher-choice column is set; all zero where HOCF passes (action 0, so that argmax gives
    the action index as ``features.teacher_action`` does for one state)."""
    choice = states["tasks"][..., TEACHER_CHOICE_COLUMN]
    return torch.cat([torch.zeros_like(choice[:, :1]), choice], dim=1)


def teacher_prior_of(states: dict[str, Tensor]) -> Tensor:
    """Log-probabilities of the teacher prior over each state's actions (-inf outside the
    validity mask): ``1 - TEACHER_PRIOR_SPREAD`` on HOCF's choice (``teacher_choice``), the
    rest uniform over the valid actions."""
    mask = states["action_mask"]
    choice = teacher_choice(states)
    valid = mask.float()
    uniform = valid / valid.sum(dim=-1, keepdim=True).clamp(min=1)
    prior = TEACHER_PRIOR_SPREAD * uniform + (1 - TEACHER_PRIOR_SPREAD) * choice * valid
    prior = prior / prior.sum(dim=-1, keepdim=True).clamp(min=1e-12)
    return torch.where(mask, prior.clamp(min=1e-30).log(), torch.full_like(prior, -torch.inf))


def descend(optimizer: torch.optim.Optimizer, loss: Tensor) -> None:
    optimizer.zero_grad()
    loss.backward()
    optimizer.step()


class DiscreteSAC:
    """The actor, the twin critics and their optimisers. The actor's regulariser is
    ``teacher_prior`` (J units, fixed) times its KL divergence from ``teacher_prior_of``."""

    def __init__(self, net: NetConfig, config: SACConfig, device: torch.device | str,
                 teacher_prior: float):
        self.config = config
        self.teacher_prior = teacher_prior
        self.device = torch.device(device)
        self.actor = PolicyNet(net).to(self.device)
        self.critics = [QNet(net).to(self.device) for _ in range(2)]
        self.actor_optimizer = torch.optim.Adam(self.actor.parameters(), lr=config.lr)
        self.critic_optimizer = torch.optim.Adam(
            [p for q in self.critics for p in q.parameters()], lr=config.lr)

    def actor_loss(self, states: dict[str, Tensor]) -> tuple[Tensor, Tensor]:
        """Eq. 16 with the KL to the teacher prior in place of alpha log pi, and the
        entropy of each state's policy (logged)."""
        probs, log_probs = self.actor.distribution(states)
        with torch.no_grad():
            q = torch.minimum(*(c(states) for c in self.critics))
        mask = states["action_mask"]
        regulariser = self.teacher_prior * (log_probs - teacher_prior_of(states))
        loss = expectation(probs, regulariser - q, mask).mean()
        entropy = -expectation(probs, log_probs, mask)
        return loss, entropy.detach()

    def label_loss(self, batch: LabelledBatch) -> Tensor:
        """The critics regressed on rollout labels (Huber, over the labelled actions only),
        summed over the two critics: policy evaluation by Monte Carlo rollouts."""
        count = batch.label_mask.sum().clamp(min=1)
        zero = torch.zeros((), device=batch.labels.device)
        loss = zero
        for q in self.critics:
            error = torch.nn.functional.smooth_l1_loss(q(batch.states), batch.labels,
                                                       reduction="none")
            loss = loss + torch.where(batch.label_mask, error, zero).sum() / count
        return loss

    def update_from_labels(self, batch: LabelledBatch) -> dict[str, float]:
        """One step of soft policy iteration: the critics fit the rollout labels, the actor
        minimises its loss against them."""
        critic_loss = self.label_loss(batch)
        descend(self.critic_optimizer, critic_loss)
        actor_loss, entropy = self.actor_loss(batch.states)
        descend(self.actor_optimizer, actor_loss)
        return {"critic_loss": critic_loss.item(), "actor_loss": actor_loss.item(),
                "entropy": entropy.mean().item()}

    def clone_loss(self, demonstrations: Sequence[Demonstration]) -> Tensor:
        """Cross-entropy of the actor against the demonstrator's actions."""
        _, log_probs = self.actor.distribution(
            collate([d.state for d in demonstrations], self.device))
        actions = torch.tensor([d.action for d in demonstrations], device=self.device)
        return -log_probs.gather(1, actions.unsqueeze(1)).mean()

    # --- checkpoints -----------------------------------------------------------------
    def state_dict(self) -> dict[str, Any]:
        return {"actor": self.actor.state_dict(),
                "critics": [q.state_dict() for q in self.critics],
                "actor_optimizer": self.actor_optimizer.state_dict(),
                "critic_optimizer": self.critic_optimizer.state_dict()}

    def load_state_dict(self, state: dict[str, Any]) -> None:
        self.actor.load_state_dict(state["actor"])
        for q, s in zip(self.critics, state["critics"], strict=True):
            q.load_state_dict(s)
        self.actor_optimizer.load_state_dict(state["actor_optimizer"])
        self.critic_optimizer.load_state_dict(state["critic_optimizer"])
