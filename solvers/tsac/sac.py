"""Discrete soft actor-critic for the task-selection policy (paper Sec. III-B-2, Eqs. 14-17)
and the training run behind ``tsac-bench train``.

* Twin critics Q_theta1, Q_theta2. Two learning signals (``TrainConfig.signal``):
  "rollout" (default): the critics regress rollout labels, Q(s, a) = minus the final J
  after action a and a completion of the game by HOCF with common random AAV orders
  (``rollout_values``), centred per state: soft policy iteration. "td": Polyak-averaged
  target copies and the per-decision reward -dJ, the target being the exact expectation
  over the next state's valid actions (Eq. 15), not a sample.
* The actor minimises Eq. 16, the expectation over the valid actions of
  alpha log pi - min_j Q_j.
* The temperature alpha is learned (automatic entropy tuning): the target entropy of a state
  is ``target_entropy_ratio * log(number of valid actions)``, so states with one valid task
  ask for none.
* The replay buffer keeps states unpadded; a sampled batch is padded to its own longest
  state (L_max of Eq. 17) and every sum over actions runs under the padding and validity
  masks, so padded entries contribute neither value nor gradient.
* Curriculum: the scales an episode is drawn from change with the share of steps done;
  with the rollout signal, half the episodes are moments of simulated dynamic runs
  (re-plans with committed prefixes) and the cloning weight is annealed to 0.
* Look-ahead distillation (rollout signal, ``TrainConfig.distill_weight``, off by default):
  the actor's loss also takes the cross-entropy toward each labelled state's action of
  least mean final J, the completion's own choice always among the labelled actions.

Files written to the output folder: ``checkpoint.pt`` (everything needed to resume),
``policy.pt`` (the form ``tsac-ocf`` loads: the actor, and with rollout labels the critics
that ``decode=margin`` uses; ``policy-STEP.pt`` at each gauge point), ``curve.json`` and
``curve.png`` (the training curve).
"""

from __future__ import annotations

import copy
import json
import math
import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any, ClassVar

import numpy as np
import torch
from torch import Tensor
from torch.nn import functional as F

from tsac_bench.errors import InvalidSetting
from tsac_bench.model.evaluator import CostEvaluator
from tsac_bench.model.generator import generate
from tsac_bench.planning import PlanningState, make_allocator
from tsac_bench.planning.settings import (
    Constraint,
    Interval,
    NoneOr,
    Options,
    declare,
)
from tsac_bench.solvers.ocf.engine import (
    C_MAX,
    K_MAX,
    PASS,
    STRICT_DECREASE,
    CoalitionGame,
    DecisionView,
    SelectionRule,
    sample_rng,
)
from tsac_bench.solvers.tsac.env import (
    AGENT_DIM,
    DEPOT_DIM,
    FEATURE_SETS,
    TEACHER_CHOICE_COLUMN,
    FeatureSet,
    MomentSampler,
    Observation,
    TaskSelectionEnv,
    action_choice,
    generated_moments,
    observe,
    replan_moments,
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
    #: The target entropy per state is this share of the uniform policy's. The first policy
    #: (td, 0.3) never reached 0.3 while cloned, so alpha climbed without end.
    target_entropy_ratio: float = 0.1
    initial_alpha: float = 0.05
    #: A faster step for log alpha than for the networks, so that alpha follows the entropy
    #: target within a few hundred updates instead of drifting for thousands.
    alpha_lr: float = 3e-3


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
                   features: FeatureSet, completion: SelectionRule, *, rollouts: int,
                   seed: int, workers: RolloutWorkers | None = None) -> np.ndarray:
    """The final J of each action's rollouts, shape (len(actions), rollouts): on a fork of
    the game, the deciding AAV takes the action (a pass, or the ADD/REMOVE of a task, which
    the engine accepts or rejects), then ``completion`` finishes the game (new rounds, the
    engine's stop rules) with the generator ``sample_rng(seed, r)`` for rollout r: the same
    AAV orders for every action of the state (common random numbers), so their labels
    differ by the actions, not by the draws. ``workers``: run them in those processes (the
    same numbers)."""
    jobs = [(action_choice(view, action, features), r)
            for action in actions for r in range(rollouts)]
    finish = workers.finish_games if workers is not None else finish_games
    return np.array(finish(game, view.aav, jobs, completion, seed)).reshape(len(actions),
                                                                           rollouts)


def label_candidates(valid: np.ndarray, most: int, rng: np.random.Generator,
                     reference: int | None = None) -> np.ndarray:
    """The actions of a state to label, ascending: every valid one if there are at most
    ``most``, otherwise ``most`` drawn uniformly; ``reference`` (an action index, the
    completion method's own choice) is then always one of them, so that the best label is
    never worse than following the completion from here (in the rollouts' estimate)."""
    if len(valid) <= most:
        return valid
    if reference is None:
        return np.sort(rng.choice(valid, most, replace=False))
    others = rng.choice(valid[valid != reference], most - 1, replace=False)
    return np.sort(np.append(others, reference))


def best_label(actions: Sequence[int], finals: Sequence[float],
               reference: int | None = None, margin: float = 0.0) -> int:
    """The labelled action of least mean final J (the look-ahead's choice, the distillation
    target), unless ``reference``'s mean final J is within ``margin`` of the least (then
    ``reference``); among tied least the lowest index."""
    least = min(finals)
    if (reference in actions
            and finals[list(actions).index(reference)] <= least + max(margin, STRICT_DECREASE)):
        return reference
    return min(a for a, f in zip(actions, finals, strict=True) if f <= least + STRICT_DECREASE)


def reference_action(view: DecisionView, rule: SelectionRule, features: FeatureSet,
                     rng: np.random.Generator) -> int:
    """``rule``'s choice in the state as an action index."""
    choice = rule.select(view, rng)
    return 0 if choice == PASS else features.offset + view.game.visible.index(choice)


class LookAheadSelection:
    """Selection rule: the one-step look-ahead that the rollout labels encode. In each
    state, the actions of ``label_candidates`` (``candidates`` of them, ``completion``'s own
    choice among them; None: every valid action) are labelled by ``rollout_values`` and the
    action of ``best_label`` is taken: the policy that distillation imitates. ``workers``:
    where the rollouts run (None: in this process)."""

    def __init__(self, completion: SelectionRule, features: FeatureSet = FEATURE_SETS[2], *,
                 candidates: int | None = None, rollouts: int = 1,
                 workers: RolloutWorkers | None = None) -> None:
        self.completion, self.features = completion, features
        self.candidates, self.rollouts, self.workers = candidates, rollouts, workers

    def select(self, view: DecisionView, rng: np.random.Generator) -> int:
        valid = np.flatnonzero(observe(view, self.features).action_mask)
        reference = reference_action(view, self.completion, self.features, rng)
        if len(valid) == 1:
            return action_choice(view, int(valid[0]), self.features)
        actions = label_candidates(valid, self.candidates or len(valid), rng, reference)
        finals = rollout_values(view.game, view, actions.tolist(), self.features,
                                self.completion, rollouts=self.rollouts,
                                seed=int(rng.integers(2**31)),
                                workers=self.workers).mean(axis=1)
        return action_choice(view, best_label(actions.tolist(), finals.tolist(), reference),
                             self.features)


@dataclass(frozen=True)
class Labelled:
    """A state with the rollout value of some of its valid actions: ``q`` is minus the mean
    final J of each action's rollouts, centred on the mean over the labelled actions and
    divided by the label scale (the actor's loss is blind to a per-state constant).
    ``target`` is the action of ``best_label`` (the distillation target; None in states
    labelled before it existed)."""

    state: Observation
    actions: tuple[int, ...]
    q: tuple[float, ...]
    target: int | None = None


@dataclass
class LabelledBatch:
    states: dict[str, Tensor]
    label_mask: Tensor  # (B, actions) True where a label exists
    labels: Tensor  # (B, actions), 0 where none
    targets: Tensor  # (B,) the distillation target's action, -1 where none

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
        targets = torch.tensor([-1 if item.target is None else item.target for item in items])
        return cls(states, mask.to(device), labels.to(device), targets.to(device))



#: The teacher prior's share spread uniformly over the valid actions (the rest is on the
#: teacher's choice): the KL stays finite, and deviating from the teacher costs
#: log((1 - e) |valid| / e), about 5.3 units of ``teacher_prior`` with 10 valid actions.
TEACHER_PRIOR_SPREAD = 0.05


def teacher_choice(states: dict[str, Tensor]) -> Tensor:
    """HOCF's choice in each feature-set-3 state, one-hot over the actions: the task row
    whose teacher-choice column is set; all zero where HOCF passes (action 0, so that argmax
    gives the action index as ``env.teacher_action`` does for one state)."""
    choice = states["tasks"][..., TEACHER_CHOICE_COLUMN]
    if "pass_token" in states:
        choice = torch.cat([torch.zeros_like(choice[:, :1]), choice], dim=1)
    return choice


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


def _descend(optimizer: torch.optim.Optimizer, loss: Tensor) -> None:
    optimizer.zero_grad()
    loss.backward()
    optimizer.step()

class DiscreteSAC:
    """The actor, the twin critics, their targets, alpha and the optimisers."""

    def __init__(self, net: NetConfig, config: SACConfig, device: torch.device | str = "cpu",
                 teacher_prior: float = 0.0):
        self.config = config
        #: > 0: the actor's regulariser is this weight (J units, fixed) times the KL
        #: divergence from ``teacher_prior_of`` (the states must carry the teacher columns)
        #: instead of alpha times the negative entropy.
        self.teacher_prior = teacher_prior
        self.device = torch.device(device)
        self.actor = PolicyNet(net).to(self.device)
        self.critics = [QNet(net).to(self.device) for _ in range(2)]
        self.targets = [copy.deepcopy(q).requires_grad_(False) for q in self.critics]
        self.log_alpha = torch.tensor(math.log(config.initial_alpha), device=self.device,
                                      requires_grad=True)
        self.actor_optimizer = torch.optim.Adam(self.actor.parameters(), lr=config.lr)
        self.critic_optimizer = torch.optim.Adam(
            [p for q in self.critics for p in q.parameters()], lr=config.lr)
        self.alpha_optimizer = torch.optim.Adam([self.log_alpha], lr=config.alpha_lr)

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

    def actor_loss(self, batch: Batch, distribution: tuple[Tensor, Tensor] | None = None
                   ) -> tuple[Tensor, Tensor]:
        """Eq. 16 and the entropy of each state's policy (for the temperature).
        ``distribution``: the actor's (probabilities, log-probabilities) on the batch's
        states where the caller has them already."""
        probs, log_probs = distribution or self.actor.distribution(batch.states)
        with torch.no_grad():
            q = torch.minimum(*(c(batch.states) for c in self.critics))
        mask = batch.states["action_mask"]
        if self.teacher_prior > 0:
            regulariser = self.teacher_prior * (log_probs - teacher_prior_of(batch.states))
        else:
            regulariser = self.alpha * log_probs
        loss = expectation(probs, regulariser - q, mask).mean()
        entropy = -expectation(probs, log_probs, mask)
        return loss, entropy.detach()

    def alpha_loss(self, entropy: Tensor, action_mask: Tensor) -> Tensor:
        target = self.config.target_entropy_ratio * torch.log(
            action_mask.sum(dim=-1).clamp(min=1).float())
        return (self.log_alpha * (entropy - target)).mean()

    def label_loss(self, batch: LabelledBatch) -> Tensor:
        """The critics regressed on rollout labels (Huber, over the labelled actions only),
        summed over the two critics: policy evaluation by Monte Carlo rollouts."""
        count = batch.label_mask.sum().clamp(min=1)
        zero = torch.zeros((), device=batch.labels.device)
        loss = zero
        for q in self.critics:
            error = F.smooth_l1_loss(q(batch.states), batch.labels, reduction="none")
            loss = loss + torch.where(batch.label_mask, error, zero).sum() / count
        return loss

    def distill_loss(self, batch: LabelledBatch, log_probs: Tensor | None = None) -> Tensor:
        """Cross-entropy of the actor against each state's distillation target (the
        labelled action of least mean final J), over the states that have one;
        ``log_probs``: the actor's on the batch's states where the caller has them."""
        if log_probs is None:
            _, log_probs = self.actor.distribution(batch.states)
        has = batch.targets >= 0
        if not bool(has.any()):
            return torch.zeros((), device=batch.labels.device)
        chosen = log_probs[has].gather(1, batch.targets[has].unsqueeze(1))
        return -chosen.mean()

    def update_from_labels(self, batch: LabelledBatch, demonstrations: Batch | None = None,
                           clone_weight: float = 0.0, distill_weight: float = 0.0
                           ) -> dict[str, float]:
        """One step of soft policy iteration: the critics fit the rollout labels, the actor
        minimises Eq. 16 against them (plus ``clone_weight`` times the cross-entropy on
        demonstrations and ``distill_weight`` times the cross-entropy on the batch's
        distillation targets), the temperature follows its entropy target."""
        critic_loss = self.label_loss(batch)
        _descend(self.critic_optimizer, critic_loss)
        states = Batch(batch.states, torch.zeros(0), torch.zeros(0), batch.states,
                       torch.zeros(0))
        distill: list[Tensor] = []  # the unweighted term, for the stats

        def weighted_distill(log_probs: Tensor) -> Tensor:
            distill.append(self.distill_loss(batch, log_probs))
            return distill_weight * distill[0]

        actor_loss, entropy = self._policy_step(
            states, demonstrations, clone_weight,
            weighted_distill if distill_weight > 0 else None)
        stats = {"critic_loss": critic_loss.item(), "actor_loss": actor_loss.item(),
                 "entropy": entropy.mean().item(), "alpha": self.alpha.item(),
                 "clone_weight": clone_weight}
        if distill:
            stats["distill_loss"] = distill[0].item()
        return stats

    def _policy_step(self, batch: Batch, demonstrations: Batch | None,
                     clone_weight: float, extra: Callable[[Tensor], Tensor] | None = None
                     ) -> tuple[Tensor, Tensor]:
        """The actor's step (Eq. 16, plus ``clone_weight`` times the cross-entropy on
        demonstrations, plus ``extra`` of the actor's log-probabilities on the batch's
        states, from the same forward pass) and the temperature's; returns the actor loss
        and the entropies."""
        distribution = self.actor.distribution(batch.states)
        actor_loss, entropy = self.actor_loss(batch, distribution)
        if demonstrations is not None and clone_weight > 0:
            actor_loss = actor_loss + clone_weight * self.clone_loss(demonstrations)
        if extra is not None:
            actor_loss = actor_loss + extra(distribution[1])
        _descend(self.actor_optimizer, actor_loss)
        if self.teacher_prior == 0:  # the KL to the teacher has a fixed weight
            _descend(self.alpha_optimizer, self.alpha_loss(entropy, batch.states["action_mask"]))
        return actor_loss, entropy

    def imitate(self, batch: Batch) -> dict[str, float]:
        """One pre-training step: the actor by cross-entropy on the batch's actions (a
        demonstrator's), the critics by Eqs. 14-15 under the actor being cloned."""
        critic_loss = self.critic_loss(batch)
        _descend(self.critic_optimizer, critic_loss)
        clone_loss = self.clone_loss(batch)
        _descend(self.actor_optimizer, clone_loss)
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
        _descend(self.critic_optimizer, critic_loss)
        actor_loss, entropy = self._policy_step(batch, demonstrations, clone_weight)
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
#: The small scales stay to the end: a short run that dropped 8/20 at 40 % of its steps
#: ended 22 % above HOCF there while level with it at 16/40 and 32/80.
DEFAULT_CURRICULUM: tuple[tuple[float, tuple[str, ...]], ...] = (
    (0.0, ("4/10", "8/20", "16/40")),
    (0.3, ("8/20", "16/40", "32/80")),
)
SIGNALS = ("rollout", "td")
#: The OCF methods whose selection rule can take the warm-up decisions or finish a rollout.
RULE_METHODS = ("hocf", "rocf")


@dataclass(frozen=True)
class TrainConfig:
    steps: int = 16_000
    seed: int = 0
    #: "rollout": critic targets from rollouts (soft policy iteration, docs/tsac.md);
    #: "td": the per-decision reward -dJ / (w1 + w2) with Eqs. 14-15 (the first policy's).
    signal: str = "rollout"
    features: int = 2  # the version of tsac_env.FEATURE_SETS
    warmup: int = 1_000  # decisions taken by the demonstrator before the first update
    #: Who takes the warm-up decisions: a registered OCF method's selection rule (its
    #: decisions then also pre-train the actor by imitation and stay as demonstrations)
    #: or None (uniformly random).
    demonstrator: str | None = "hocf"
    pretrain_updates: int = 500  # imitation (+ critic) steps after the warm-up
    clone_weight: float = 2.0  # weight of the demonstrations' cross-entropy in SAC's actor loss
    #: rollout signal: the cloning weight falls linearly from ``clone_weight`` after the
    #: warm-up to ``clone_floor`` at this share of the steps (td: constant). 1: in three short
    #: runs the gauge was best while the weight was fading (0.8 to 0.5 of 2) and got worse
    #: within 2 000 steps of reaching 0, so the critic is given the whole run to take over.
    clone_until: float = 1.0
    #: rollout signal: the weight the cloning falls to at ``clone_until`` and keeps afterwards
    #: (at most ``clone_weight``). With 0 the 8 000-step full ablation run ended with a mean J
    #: 66 % above HOCF's at 16/40 (104 % at 32/80); at step 4000 (weight 1.1) 7 % (5 % below).
    clone_floor: float = 0.0
    #: rollout signal: weight of look-ahead distillation in the actor's loss, the
    #: cross-entropy toward each labelled state's action of least mean final J (with a
    #: weight > 0 the completion's own choice is always among the labelled actions). 0:
    #: none, the behaviour before it existed.
    distill_weight: float = 0.0
    #: rollout signal, distillation: J by which the least mean final J must beat the
    #: completion's own choice's to be the target (else that choice is). In the first
    #: distillation run (margin 0) 53 % of the labelled states had several actions tied for
    #: the least J and 7 % a best action ahead of the second by 1 J or more.
    distill_margin: float = 0.0
    #: rollout signal: > 0 regularises the actor by this weight (J units, fixed) times its
    #: KL divergence from the teacher prior (HOCF's choice, ``teacher_prior_of``; needs a
    #: feature set with teacher columns) in place of the entropy bonus: the soft-greedy
    #: policy becomes prior x exp(Q / weight), HOCF's choice unless the critic puts another
    #: action ahead by about 5 weights. 0: the entropy bonus with its tuned alpha.
    teacher_prior: float = 0.0
    update_every: int = 2  # td: env steps per gradient update
    curriculum: tuple[tuple[float, tuple[str, ...]], ...] = DEFAULT_CURRICULUM
    #: rollout signal: share of the episodes played on a moment of a simulated dynamic run
    #: (t = 0 or a re-plan); the others are t = 0 moments (static or released-only). The td
    #: signal ignores it: its episodes are TaskSelectionEnv's default t = 0 moments.
    replan_share: float = 0.5
    label_share: float = 0.25  # rollout: share of the decisions whose actions are labelled
    label_candidates: int = 8  # rollout: most actions labelled per state (drawn uniformly)
    rollouts: int = 2  # rollout: completions per labelled action (common AAV orders)
    completion: str = "hocf"  # rollout: the OCF method that finishes the game
    #: rollout: J units per unit of Q. 1: label differences (0.1-5 J) stand well above
    #: alpha log pi; at 10 the soft-greedy policy was near-uniform (entropy 1.6-2.0 nats).
    label_scale: float = 1.0
    updates_per_label: int = 1  # rollout: gradient steps per labelled state
    episode_steps: int = 600  # truncation of one episode (one OCF game)
    eval_every: int = 2_000
    eval_scale: str = "16/40"
    eval_instances: int = 3
    checkpoint_every: int = 1_000
    net: NetConfig | None = None  # default: d_model 32, 4 heads, 2 layers, ff 64
    sac: SACConfig = field(default_factory=SACConfig)

    #: The fields ``tsac-bench train --set`` may change: the scalar ones, less steps and seed
    #: (options of their own) and eval_scale (a scale has no constraint to check it by).
    setting_constraints: ClassVar[Mapping[str, Constraint]] = declare(
        signal=Options(*SIGNALS),
        features=Interval(int, min(FEATURE_SETS), max(FEATURE_SETS)),
        warmup=Interval(int, 0, None),
        demonstrator=NoneOr(Options(*RULE_METHODS)),
        pretrain_updates=Interval(int, 0, None),
        clone_weight=Interval(float, 0, None),
        clone_until=Interval(float, 0, 1),
        clone_floor=Interval(float, 0, "clone_weight"),
        distill_weight=Interval(float, 0, None),
        distill_margin=Interval(float, 0, None),
        teacher_prior=Interval(float, 0, None),
        update_every=Interval(int, 1, None),
        replan_share=Interval(float, 0, 1),
        label_share=Interval(float, 0, 1),
        label_candidates=Interval(int, 2, None),
        rollouts=Interval(int, 1, None),
        completion=Options(*RULE_METHODS),
        label_scale=Interval(float, 0, None, closed="neither"),
        updates_per_label=Interval(int, 1, None),
        episode_steps=Interval(int, 1, None),
        eval_every=Interval(int, 1, None),
        eval_instances=Interval(int, 1, None),
        checkpoint_every=Interval(int, 1, None),
    )

    def __post_init__(self) -> None:
        if self.signal not in SIGNALS:
            raise ValueError(f"signal must be one of {', '.join(SIGNALS)}, got {self.signal!r}")
        if self.features not in FEATURE_SETS:
            raise ValueError(f"features must be one of {sorted(FEATURE_SETS)}")
        fs = FEATURE_SETS[self.features]
        if self.teacher_prior > 0 and not fs.teacher:
            raise InvalidSetting(f"teacher_prior: needs a feature set with teacher columns "
                                 f"(3), not {self.features}")
        if self.net is None:
            object.__setattr__(self, "net", NetConfig(
                AGENT_DIM, fs.task_dim, DEPOT_DIM, d_model=32, heads=4, layers=2,
                feedforward=64, features=fs.version, pass_action=fs.pass_action))
        elif (self.net.features, self.net.task_dim, self.net.pass_action) != (
                fs.version, fs.task_dim, fs.pass_action):
            raise ValueError(f"net: built for feature set {self.net.features}, not "
                             f"{self.features}")

    def scales_at(self, step: int) -> tuple[str, ...]:
        share = step / max(1, self.steps)
        return next(scales for start, scales in reversed(self.curriculum) if share >= start)

    def clone_weight_at(self, step: int) -> float:
        if self.signal == "td":
            return self.clone_weight
        end = self.clone_until * self.steps
        if end <= self.warmup:
            return self.clone_floor
        share_left = max(0.0, 1.0 - (step - self.warmup) / (end - self.warmup))
        return self.clone_floor + (self.clone_weight - self.clone_floor) * share_left

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
            game.run(PolicySelection(actor), np.random.default_rng(i), k_max=K_MAX,
                     c_max=C_MAX)
            costs.append(game.cost)
        actor.train()
        return {"eval_J": float(np.mean(costs)),
                "eval_ratio_hocf": float(np.mean(costs) / np.mean(self.reference))}


class _Run:
    """What a training run carries between steps and across a resume."""

    def __init__(self, out: Path, config: TrainConfig, device: torch.device,
                 checkpoint: dict[str, Any] | None, workers: RolloutWorkers | None) -> None:
        self.out, self.config, self.device, self.workers = out, config, device, workers
        torch.manual_seed(config.seed)
        self.sac = DiscreteSAC(config.net, config.sac, device, config.teacher_prior)
        self.buffer = ReplayBuffer(config.sac.buffer_size)
        self.demos = ReplayBuffer(config.warmup)  # the demonstrator's decisions
        self.rng = np.random.default_rng(config.seed)
        self.sampler = torch.Generator().manual_seed(config.seed)
        self.log: dict[str, list] = {"updates": [], "episodes": [], "evals": []}
        self.step, self.episode, seconds = 0, 0, 0.0
        if checkpoint is not None:
            self.sac.load_state_dict(checkpoint["sac"])
            self.buffer.items = checkpoint["buffer"]
            self.buffer.position = checkpoint["buffer_position"]
            self.demos.items = checkpoint["demonstrations"]
            self.rng.bit_generator.state = checkpoint["rng"]
            self.sampler.set_state(checkpoint["sampler"])
            self.log, self.step = checkpoint["log"], checkpoint["step"]
            self.episode, seconds = checkpoint["episode"], checkpoint["seconds"]
        self.began = time.perf_counter() - seconds
        self.evaluate = Evaluation(config)

    def save_checkpoint(self) -> None:
        torch.save({"config": self.config.to_dict(), "sac": self.sac.state_dict(),
                    "buffer": self.buffer.items, "demonstrations": self.demos.items,
                    "buffer_position": self.buffer.position,
                    "rng": self.rng.bit_generator.state, "sampler": self.sampler.get_state(),
                    "log": self.log, "step": self.step, "episode": self.episode,
                    "seconds": time.perf_counter() - self.began},
                   self.out / "checkpoint.pt")

    def evaluate_now(self, stats: dict[str, float]) -> dict[str, float]:
        """The curve's gauge; the actor of each gauge point is kept (``policy-STEP.pt``),
        so that a run's best point can be chosen on the gauge, not on test instances."""
        self.log["evals"].append({"step": self.step, "seconds":
                                  time.perf_counter() - self.began,
                                  **self.evaluate(self.sac.actor)})
        self.save_policy(self.out / f"policy-{self.step}.pt",
                         {"steps": self.step, "seed": self.config.seed,
                          "config": self.config.to_dict(), **self.log["evals"][-1]})
        return {**stats, **self.log["evals"][-1]}

    def save_policy(self, path: Path, meta: dict[str, Any]) -> None:
        """The actor, with the critics where their values are final-J differences (rollout
        labels, ``label_scale`` J per unit): what decoding by margin needs."""
        rollout = self.config.signal == "rollout"
        save_policy(self.sac.actor, path, meta, critics=self.sac.critics if rollout else (),
                    critic_unit=self.config.label_scale)


def train(out: Path, config: TrainConfig, *, device: str = "auto", resume: Path | None = None,
          on_step: Callable[[int, dict[str, float]], None] | None = None,
          stop_after: float | None = None, label_workers: int = 1) -> dict[str, Any]:
    """Train from scratch (or from ``resume``'s checkpoint) up to ``config.steps`` env
    steps; returns the summary written to ``curve.json``. ``stop_after`` (seconds of this
    call; rollout signal) ends the call early at an episode's end, with a checkpoint to
    resume from and the policy so far. ``label_workers`` > 1 runs the rollout labels in
    that many processes (``RolloutWorkers``: the same run, faster on as many cores); it is
    not part of the configuration, so a resumed run may use another number."""
    out.mkdir(parents=True, exist_ok=True)
    torch_device = resolve_device(device)
    checkpoint = None
    if resume is not None:
        checkpoint = torch.load(resume, map_location=torch_device, weights_only=False)
        # The run goes on as it was configured; only its length may change.
        config = TrainConfig.from_dict({**checkpoint["config"], "steps": config.steps})
    workers = RolloutWorkers(label_workers) if label_workers > 1 else None
    try:
        run = _Run(out, config, torch_device, checkpoint, workers)
        if config.signal == "td":
            _train_td(run, on_step)
        else:
            _train_rollout(run, on_step, stop_after)
    finally:
        if workers is not None:
            workers.close()
    seconds = time.perf_counter() - run.began
    meta = {"steps": run.step, "episode_count": run.episode, "seed": config.seed,
            "seconds": seconds, "device": str(torch_device), "torch": torch.__version__,
            "threads": torch.get_num_threads(), "config": config.to_dict()}
    run.save_policy(out / "policy.pt", meta)
    summary = {**meta, **run.log}
    (out / "curve.json").write_text(json.dumps(summary, indent=1))
    plot_curve(summary, out / "curve.png")
    return summary


def _train_td(run: _Run, on_step: Callable[[int, dict[str, float]], None] | None) -> None:
    """The per-decision reward and Eqs. 14-15 (the first shipped policy's signal)."""
    config, sac, rng, device = run.config, run.sac, run.rng, run.device
    env = TaskSelectionEnv(config.scales_at(run.step), max_steps=config.episode_steps,
                           features=config.features)
    demonstrator = (make_allocator(config.demonstrator) if config.demonstrator is not None
                    else None)

    def reset(**kwargs: Any) -> tuple[Observation, float, Any]:
        padded, info = env.reset(**kwargs)
        rule = demonstrator.rule(env.game.state) if demonstrator is not None else None
        return unpad(padded), info["J"], rule

    state, start_J, expert = reset(seed=int(rng.integers(2**31)))
    returns = 0.0
    stats: dict[str, float] = {}
    offset = env.features.offset
    while run.step < config.steps:
        if run.step < config.warmup and expert is not None:
            action = offset + env.game.visible.index(expert.select(env.view, rng))
        elif run.step < config.warmup:
            action = int(rng.choice(np.flatnonzero(state.action_mask)))
        else:
            with torch.no_grad():
                probs, _ = sac.actor.distribution(collate([state], device))
            action = int(torch.multinomial(probs[0].cpu(), 1, generator=run.sampler))
        padded, reward, terminated, truncated, info = env.step(action)
        next_state = unpad(padded)
        transition = Transition(state, action, reward, next_state, terminated)
        run.buffer.add(transition)
        if run.step < config.warmup and expert is not None:
            run.demos.add(transition)
        state, returns, run.step = next_state, returns + reward, run.step + 1
        step = run.step
        if step > config.warmup and step % config.update_every == 0:
            demonstrations = (Batch.of(run.demos.sample(config.sac.batch_size, rng), device)
                              if demonstrator is not None and len(run.demos) else None)
            stats = sac.update(Batch.of(run.buffer.sample(config.sac.batch_size, rng),
                                        device), demonstrations, config.clone_weight)
            if step % 50 < config.update_every:
                run.log["updates"].append({"step": step, **stats})
        if terminated or truncated:
            run.log["episodes"].append({"step": step, "return": returns, "J_start": start_J,
                                        "J_end": info["J"], "scales": list(env.scales)})
            run.episode += 1
            env.set_scales(config.scales_at(step))
            state, start_J, expert = reset()
            returns = 0.0
        if step == config.warmup and expert is not None:
            for i in range(config.pretrain_updates):
                stats = sac.imitate(Batch.of(run.buffer.sample(config.sac.batch_size, rng),
                                             device))
                if i % 50 == 0:
                    run.log.setdefault("pretrain", []).append({"update": i, **stats})
        if step % config.eval_every == 0 or step == config.steps:
            stats = run.evaluate_now(stats)
        if step % config.checkpoint_every == 0 or step == config.steps:
            run.save_checkpoint()
        if on_step is not None:
            on_step(step, stats)


class _Behaviour:
    """The selection rule that plays a training episode: the demonstrator during the
    warm-up, then the actor (sampled); it labels a share of the decisions with rollouts and
    takes the gradient steps."""

    def __init__(self, run: _Run, state: PlanningState,
                 on_step: Callable[[int, dict[str, float]], None] | None) -> None:
        config = run.config
        self.run, self.on_step = run, on_step
        self.features = FEATURE_SETS[config.features]
        self.demonstrator = (make_allocator(config.demonstrator).rule(state)
                             if config.demonstrator is not None else None)
        self.completion = make_allocator(config.completion).rule(state)
        self.stats: dict[str, float] = {}

    def select(self, view: DecisionView, rng: np.random.Generator) -> int:
        run, config, sac = self.run, self.run.config, self.run.sac
        observation = observe(view, self.features)
        valid = np.flatnonzero(observation.action_mask)
        warming = run.step < config.warmup
        if warming and self.demonstrator is not None:
            action = (self.features.offset
                      + view.game.visible.index(self.demonstrator.select(view, rng)))
            run.demos.add(Transition(observation, action, 0.0, observation, False))
        elif warming:
            action = int(rng.choice(valid))
        else:
            with torch.no_grad():
                probs, _ = sac.actor.distribution(collate([observation], run.device))
            action = int(torch.multinomial(probs[0].cpu(), 1, generator=run.sampler))
        if len(valid) > 1 and rng.random() < config.label_share:
            self.label(view, observation, valid, rng)
        run.step += 1
        step = run.step
        if step == config.warmup and self.demonstrator is not None:
            self.pretrain()
        if step % config.eval_every == 0 or step == config.steps:
            self.stats = run.evaluate_now(self.stats)
        if self.on_step is not None:
            self.on_step(step, self.stats)
        return action_choice(view, action, self.features)

    def label(self, view: DecisionView, observation: Observation, valid: np.ndarray,
              rng: np.random.Generator) -> None:
        run, config = self.run, self.run.config
        reference = (reference_action(view, self.completion, self.features, rng)
                     if config.distill_weight > 0 else None)
        actions = label_candidates(valid, config.label_candidates, rng, reference)
        finals = rollout_values(view.game, view, actions.tolist(), self.features,
                                self.completion, rollouts=config.rollouts,
                                seed=int(rng.integers(2**31)),
                                workers=run.workers).mean(axis=1)
        q = -(finals - finals.mean()) / config.label_scale
        run.buffer.add(Labelled(observation, tuple(actions.tolist()), tuple(q.tolist()),
                                best_label(actions.tolist(), finals.tolist(), reference,
                                           config.distill_margin)))
        run.log.setdefault("labels", []).append(
            {"step": run.step, "actions": len(actions), "spread_J": float(np.ptp(finals))})
        if run.step >= config.warmup:
            for _ in range(config.updates_per_label):
                self.stats = self.update()
            run.log["updates"].append({"step": run.step, **self.stats})

    def demonstrations(self) -> Batch | None:
        run = self.run
        if not len(run.demos):
            return None
        return Batch.of(run.demos.sample(run.config.sac.batch_size, run.rng), run.device)

    def update(self) -> dict[str, float]:
        run, config = self.run, self.run.config
        batch = LabelledBatch.of(run.buffer.sample(config.sac.batch_size, run.rng), run.device)
        weight = config.clone_weight_at(run.step)
        return run.sac.update_from_labels(batch, self.demonstrations() if weight > 0 else None,
                                          weight, config.distill_weight)

    def pretrain(self) -> None:
        """Imitation of the demonstrator's decisions; the critics fit the labels so far."""
        run, sac = self.run, self.run.sac
        for i in range(run.config.pretrain_updates):
            demos = self.demonstrations()
            assert demos is not None
            clone = sac.clone_loss(demos)
            sac.actor_optimizer.zero_grad()
            clone.backward()
            sac.actor_optimizer.step()
            stats = {"clone_loss": clone.item()}
            if len(run.buffer):
                batch = LabelledBatch.of(run.buffer.sample(run.config.sac.batch_size, run.rng),
                                         run.device)
                critic = sac.label_loss(batch)
                sac.critic_optimizer.zero_grad()
                critic.backward()
                sac.critic_optimizer.step()
                stats["critic_loss"] = critic.item()
            if i % 50 == 0:
                run.log.setdefault("pretrain", []).append({"update": i, **stats})


def training_moments(config: TrainConfig, step: int, rng: np.random.Generator
                     ) -> PlanningState:
    """The planning moment of the next episode (curriculum scales at ``step``)."""
    scales = config.scales_at(step)
    sampler: MomentSampler = (replan_moments(scales) if rng.random() < config.replan_share
                              else generated_moments(scales))
    return sampler(rng)


def _train_rollout(run: _Run, on_step: Callable[[int, dict[str, float]], None] | None,
                   stop_after: float | None = None) -> None:
    """Soft policy iteration with rollout labels (docs/tsac.md): episodes are OCF games on
    training moments played by ``_Behaviour``; a checkpoint is written at the end of the
    first episode after each ``checkpoint_every`` steps, and a resume starts a new episode."""
    config = run.config
    next_checkpoint = (run.step // config.checkpoint_every + 1) * config.checkpoint_every
    deadline = None if stop_after is None else time.perf_counter() + stop_after
    while run.step < config.steps:
        if deadline is not None and time.perf_counter() > deadline:
            run.save_checkpoint()
            break
        state = training_moments(config, run.step, run.rng)
        game = CoalitionGame(state, state.base_routes())
        behaviour = _Behaviour(run, state, on_step)
        start_J, began = game.cost, run.step
        stop = game.run(behaviour, np.random.default_rng(run.rng.integers(2**63)),
                        k_max=min(config.episode_steps, config.steps - run.step),
                        c_max=C_MAX)
        run.episode += 1
        run.log["episodes"].append({
            "step": run.step, "decisions": run.step - began, "J_start": start_J,
            "J_end": game.cost, "stop": stop, "time": state.time,
            "scale": state.instance.scale, "committed": sum(map(len, state.committed))})
        if run.step >= next_checkpoint or run.step >= config.steps:
            run.save_checkpoint()
            next_checkpoint = (run.step // config.checkpoint_every + 1) * config.checkpoint_every


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
        axes[1].semilogy(steps, [max(u["entropy"], 1e-4) for u in updates], label="entropy")
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
