"""The deviation verifier of ``decode=margin``: a network that checks the critics' deviations.

Why: the twin critics rate every valid action from rollout labels of uniformly drawn
candidates, and the margin rule acts on their maximum, so the deviations it takes are the
ones the critics overrate most (the optimiser's curse). Checked by rollouts (a measurement:
each deviation the critics back by 0.3 J, completed 4 times by HOCF against HOCF's own
choice), about half of them lose, and keeping only those the rollouts confirm turns the 0.3
margin from 19 % above HOCF at 8/20 into 9-20 % below it (reports/archive/tsac-learnability.md).

The verifier learns that check, so that decoding plays one game with no rollouts:

* labels (``label_deviations``): the margin rule plays dynamic runs of generated instances
  and each deviation it proposes is checked by ``rollouts`` HOCF completions after it and
  after HOCF's choice, with the same AAV orders (``sac.rollout_values``); the label is the
  mean final J after HOCF's choice minus that after the deviation (its gain), and the run
  goes on with the deviation only where the gain is positive: the states of the labels are
  those the verified rule meets;
* the verifier (``fit_verifier``) is a critic network initialised from the policy's first
  critic, fitted so that its value of the deviation minus its value of HOCF's choice is the
  gain (Huber loss); a share of the instances of each scale is held out.

``train_verifier`` does both and writes a policy file: the policy's networks and the
verifier, which ``tsac-ocf``'s ``verify`` setting uses.
"""

from __future__ import annotations

import json
import time
from collections.abc import Mapping, Sequence
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any, ClassVar

import numpy as np
import torch
from torch.nn import functional as F

from tsac_bench.model.generator import generate
from tsac_bench.planning import PlanningState, make_allocator
from tsac_bench.planning.settings import Constraint, Interval, declare
from tsac_bench.planning.solve import solve
from tsac_bench.solvers.ocf.engine import DecisionView, SelectionRule
from tsac_bench.solvers.tsac.features import Observation
from tsac_bench.solvers.tsac.net import QNet, collate
from tsac_bench.solvers.tsac.policy import (
    DEFAULT_POLICY,
    MarginSelection,
    Policy,
    TSACOCFAllocator,
    policy_at,
    policy_meta,
    save_policy,
)
from tsac_bench.solvers.tsac.sac import rollout_values


@dataclass(frozen=True)
class DeviationLabel:
    """A deviation the margin rule proposed: the state, the proposed action, HOCF's action,
    and the gain (mean final J after HOCF's action minus after the proposed one)."""

    state: Observation
    action: int
    teacher: int
    gain: float
    scale: str
    instance_seed: int


class RolloutCheck:
    """Confirms a deviation iff ``rollouts`` completions by ``completion`` after it end
    lower on average than after HOCF's action (common AAV orders, generator ``rng``);
    appends each check to ``labels``."""

    def __init__(self, completion: SelectionRule, rollouts: int, rng: np.random.Generator,
                 labels: list[DeviationLabel], scale: str, instance_seed: int) -> None:
        self.completion, self.rollouts, self.rng = completion, rollouts, rng
        self.labels, self.scale, self.instance_seed = labels, scale, instance_seed

    def __call__(self, view: DecisionView, state: Observation, action: int,
                 teacher: int) -> bool:
        finals = rollout_values(view.game, view, [action, teacher], self.completion,
                                rollouts=self.rollouts,
                                seed=int(self.rng.integers(2**31))).mean(axis=1)
        gain = float(finals[1] - finals[0])
        self.labels.append(DeviationLabel(state, action, teacher, gain, self.scale,
                                          self.instance_seed))
        return gain > 0


class _CheckedMarginRule(TSACOCFAllocator):
    """tsac-ocf's margin rule with ``RolloutCheck`` confirming its deviations."""

    def __init__(self, policy: str | None, margin: float, rollouts: int, scale: str,
                 instance_seed: int) -> None:
        super().__init__(policy=policy, margin=margin)
        self.rollouts, self.scale, self.instance_seed = rollouts, scale, instance_seed
        self.labels: list[DeviationLabel] = []
        self.rng = np.random.default_rng(instance_seed)

    def rule(self, state: PlanningState) -> SelectionRule:
        check = RolloutCheck(make_allocator("hocf").rule(state), self.rollouts, self.rng,
                             self.labels, self.scale, self.instance_seed)
        return MarginSelection(policy_at(self.policy).values, self.margin, confirm=check)


def label_deviations(scale: str, instance_seed: int, policy: str | None, margin: float,
                     rollouts: int) -> list[DeviationLabel]:
    """The labels of one dynamic run (simulator seed 0) of the generated instance
    ``instance_seed`` of ``scale``. A module-level function of picklable arguments, so
    that instances can be labelled in worker processes."""
    labelling = _CheckedMarginRule(policy, margin, rollouts, scale, instance_seed)
    solve(generate(scale, instance_seed), labelling, seed=0, mode="dynamic")
    return labelling.labels


@dataclass(frozen=True)
class VerifierConfig:
    #: The margin of the rule whose deviations are labelled (the verifier learns to check
    #: that rule's deviations; decoding may use another).
    margin: float = 0.3
    rollouts: int = 4  # HOCF completions per action of a label
    #: Generated training instances per scale, seeds first_seed, first_seed + 1, ...: apart
    #: from the evaluations' (900000.. and instances/).
    instances: tuple[tuple[str, int], ...] = (("4/10", 100), ("8/20", 300), ("16/40", 200),
                                              ("32/80", 60))
    first_seed: int = 700_000
    #: The last share of each scale's instances (at least one): validation only.
    held_out: float = 0.1
    epochs: int = 30
    batch_size: int = 64
    lr: float = 3e-4
    huber: float = 5.0  # J: the gains of unmet demand (up to 110 J) do not swamp the rest
    seed: int = 0

    #: The fields ``tsac-bench train-verifier --set`` may change (all but ``instances``).
    setting_constraints: ClassVar[Mapping[str, Constraint]] = declare(
        margin=Interval(float, 0, None),
        rollouts=Interval(int, 1, None),
        first_seed=Interval(int, 0, None),
        held_out=Interval(float, 0, 1, closed="neither"),
        epochs=Interval(int, 0, None),
        batch_size=Interval(int, 1, None),
        lr=Interval(float, 0, None, closed="neither"),
        huber=Interval(float, 0, None, closed="neither"),
        seed=Interval(int, 0, None),
    )

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)


def _batches(labels: Sequence[DeviationLabel], size: int, rng: np.random.Generator | None):
    order = np.arange(len(labels)) if rng is None else rng.permutation(len(labels))
    for start in range(0, len(labels), size):
        part = [labels[i] for i in order[start:start + size]]
        yield (collate([label.state for label in part]),
               torch.tensor([label.action for label in part]),
               torch.tensor([label.teacher for label in part]),
               torch.tensor([label.gain for label in part], dtype=torch.float32))


def _deviation_gains(verifier: QNet, states: dict[str, torch.Tensor], actions: torch.Tensor,
                     teachers: torch.Tensor, unit: float) -> torch.Tensor:
    """The verifier's value (J) of each state's deviation minus that of HOCF's action."""
    values = verifier(states) * unit
    return (values.gather(1, actions[:, None]) - values.gather(1, teachers[:, None]))[:, 0]


def predicted_gains(verifier: QNet, labels: Sequence[DeviationLabel], unit: float = 1.0
                    ) -> np.ndarray:
    """The verifier's gain (J) of each label's deviation over HOCF's action."""
    out = []
    with torch.inference_mode():
        for states, actions, teachers, _ in _batches(labels, 256, None):
            out.append(_deviation_gains(verifier, states, actions, teachers, unit).numpy())
    return np.concatenate(out) if out else np.zeros(0)


def agreement(predicted: np.ndarray, labels: Sequence[DeviationLabel]) -> dict[str, float]:
    """How a verifier's gains compare with the rollouts': the share of labels whose sign it
    gets right, and the mean gain of the deviations it would keep (> 0) and refuse."""
    gains = np.array([label.gain for label in labels])
    keep = predicted > 0
    return {"labels": len(gains), "sign_right": float(np.mean(keep == (gains > 0))),
            "kept": float(np.mean(keep)),
            "gain_kept": float(gains[keep].mean()) if keep.any() else 0.0,
            "gain_refused": float(gains[~keep].mean()) if (~keep).any() else 0.0,
            "gain_all": float(gains.mean())}


def fit_verifier(policy: Policy, train: Sequence[DeviationLabel],
                 validation: Sequence[DeviationLabel], config: VerifierConfig
                 ) -> tuple[QNet, list[dict[str, float]]]:
    """The verifier fitted on ``train`` (module docstring) and one log row per epoch."""
    torch.manual_seed(config.seed)
    verifier = QNet(policy.actor.config)
    verifier.load_state_dict(policy.critics[0].state_dict())
    optimizer = torch.optim.Adam(verifier.parameters(), lr=config.lr)
    rng = np.random.default_rng(config.seed)
    unit = policy.critic_unit
    log = [{"epoch": 0, **_scores(verifier, train, validation, unit, config.huber)}]
    for epoch in range(1, config.epochs + 1):
        verifier.train()
        for states, actions, teachers, gains in _batches(train, config.batch_size, rng):
            predicted = _deviation_gains(verifier, states, actions, teachers, unit)
            loss = F.huber_loss(predicted, gains, delta=config.huber)
            optimizer.zero_grad()
            loss.backward()
            optimizer.step()
        verifier.eval()
        log.append({"epoch": epoch, **_scores(verifier, train, validation, unit,
                                              config.huber)})
    verifier.requires_grad_(False)
    return verifier, log


def _scores(verifier: QNet, train: Sequence[DeviationLabel],
            validation: Sequence[DeviationLabel], unit: float, huber: float
            ) -> dict[str, float]:
    scores = {}
    for name, labels in (("train", train), ("validation", validation)):
        predicted = predicted_gains(verifier, labels, unit)
        gains = np.array([label.gain for label in labels])
        scores[f"{name}_huber"] = float(F.huber_loss(torch.tensor(predicted),
                                                     torch.tensor(gains), delta=huber))
        scores[f"{name}_sign_right"] = agreement(predicted, labels)["sign_right"]
    return scores


@dataclass(frozen=True)
class Labelling:
    """The labels of a call of ``label_all`` and the seconds they took (0: read from a file)."""

    labels: list[DeviationLabel]
    seconds: float


def label_all(policy: str | None, config: VerifierConfig, workers: int = 1) -> Labelling:
    """The labels of every training instance of ``config``, in the order of its
    ``instances`` (the same with any number of workers)."""
    jobs = [(scale, config.first_seed + i) for scale, count in config.instances
            for i in range(count)]
    began = time.perf_counter()
    if workers > 1:
        import multiprocessing
        from concurrent.futures import ProcessPoolExecutor

        with ProcessPoolExecutor(workers, mp_context=multiprocessing.get_context(
                "forkserver")) as pool:
            parts = list(pool.map(label_deviations, *zip(*jobs, strict=True),
                                  [policy] * len(jobs), [config.margin] * len(jobs),
                                  [config.rollouts] * len(jobs)))
    else:
        parts = [label_deviations(scale, seed, policy, config.margin, config.rollouts)
                 for scale, seed in jobs]
    return Labelling([label for part in parts for label in part], time.perf_counter() - began)


def split(labels: Sequence[DeviationLabel], config: VerifierConfig
          ) -> tuple[list[DeviationLabel], list[DeviationLabel]]:
    """Training and held-out labels: the last ``held_out`` share of each scale's instances
    is held out."""
    last_trained = {scale: config.first_seed + count - max(1, round(config.held_out * count))
                    for scale, count in config.instances}
    train = [label for label in labels if label.instance_seed < last_trained[label.scale]]
    held = [label for label in labels if label.instance_seed >= last_trained[label.scale]]
    return train, held


def train_verifier(out: Path, policy: str | None, config: VerifierConfig,
                   workers: int = 1, labels: Path | None = None) -> dict[str, Any]:
    """Label (or read the ``labels.pt`` of an earlier call, made with the same policy and
    labelling settings), fit, and write ``out/policy.pt`` (the policy's networks with the
    verifier), ``out/labels.pt`` (the labels, to refit without labelling again) and
    ``out/verifier.json`` (times, counts, the fit's log, the held-out agreement per scale)."""
    out.mkdir(parents=True, exist_ok=True)
    source = policy_at(policy)
    if labels is None:
        run = label_all(policy, config, workers)
        torch.save(run.labels, out / "labels.pt")
    else:
        # Our own file of dataclasses: not loadable with weights_only.
        run = Labelling(torch.load(labels, weights_only=False), 0.0)
    began = time.perf_counter()
    train, held = split(run.labels, config)
    verifier, log = fit_verifier(source, train, held, config)
    seconds_fit = time.perf_counter() - began
    predicted = predicted_gains(verifier, held, source.critic_unit)
    by_scale = {scale: agreement(predicted[[i for i, h in enumerate(held) if h.scale == scale]],
                                 [h for h in held if h.scale == scale])
                for scale, _ in config.instances if any(h.scale == scale for h in held)}
    summary = {"config": config.to_dict(), "policy": str(policy or "shipped"),
               "labels": len(run.labels), "train": len(train), "held_out": len(held),
               "seconds_labelling": run.seconds, "seconds_fit": seconds_fit,
               "labels_from": str(labels) if labels else None, "workers": workers,
               "fit": log, "held_out_by_scale": by_scale}
    save_policy(source.actor, out / "policy.pt",
                {**policy_meta(policy or DEFAULT_POLICY), "verifier": summary},
                critics=source.critics, critic_unit=source.critic_unit, verifier=verifier)
    (out / "verifier.json").write_text(json.dumps(summary, indent=1))
    return summary
