"""Where does deviating from HOCF pay, and can a policy learn it? (issue 17)

Every policy trained with HOCF in its state (reports/archive/tsac-teacher.md) follows HOCF in about
99 % of its states, and its deviations are no better than random ones, while the one-step
look-ahead that its rollout labels encode is 13 % below HOCF at 16/40. Two measurements
separate "the labels carry no signal" from "the signal is there but not learnable":

* ``repeat``: HOCF plays static t = 0 games on the first instances of ``instances/paper-mc/``
  at one scale; in a share of its states the candidate actions (HOCF's choice among them)
  are labelled twice, by rollouts with two independent seeds (``rollout_values``, HOCF
  finishing the game). Against HOCF's own label: the gain of the first labels' best action
  on the first labels (what the look-ahead believes), on the second (what it gets: the
  noise-free one-step gain of its choice) and the correlation of the two labellings'
  advantages.

      python benchmarks/experiments/tsac_learnability.py repeat --scale 16/40 --instances 10 \
          [--workers 2]

* ``held-out``: the labelled states of training runs (their checkpoints, in run order),
  split by time; two models learn each action's advantage over HOCF's choice from the first
  share: the transformer critic of the method (``QNet``, trained offline on the labels) and
  gradient-boosted trees on the action's task row, HOCF's row, their difference and the
  state's context (scikit-learn). On the later states each model deviates to its best
  action where it predicts a gain above ``tau``; the table gives the mean gain in J per
  state (against HOCF's label), trained on a quarter, half and all of the first share.

      python benchmarks/experiments/tsac_learnability.py held-out \
          results/teacher-kl-0.3-long [RUN ...]

* ``margin``: what a training run's values are worth in whole games. HOCF's game (dynamic
  mode, the first instances of ``instances/paper-mc/``) in which each decision deviates from
  HOCF's choice to the action of highest value where that value exceeds HOCF's choice's by
  more than ``tau`` J; the value is the minimum of the run's twin critics (``critic``) or the
  actor's logits less the teacher prior's log-probabilities times the run's
  ``teacher_prior`` weight (``actor``: the critic the KL-regularised actor implies); two
  variants of ``critic``: ``agree`` deviates only where each twin alone rates the action
  more than tau above HOCF's choice, ``veto`` lets the critic choose only between HOCF's
  choice and passing (HOCF proposes, the critic may refuse). Paired against HOCF's J per
  instance, with the J each row spends on unmet demand. ``--first-seed`` plays generated
  instances instead, apart from the evaluation's, to choose tau on.

      python benchmarks/experiments/tsac_learnability.py margin \
          results/teacher-kl-0.3-r16-long --scale 32/80

Each prints its table (markdown) last.
"""

from __future__ import annotations

import argparse
import os
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from tsac_bench.model.io import read_instance
from tsac_bench.planning import PlanningState, make_allocator
from tsac_bench.reporting.stats import normal_half_width
from tsac_bench.solvers.ocf.engine import (
    C_MAX,
    K_MAX,
    CoalitionGame,
    DecisionView,
    SelectionRule,
    sample_rng,
)
from tsac_bench.solvers.ocf.hocf import HOCFAllocator

if TYPE_CHECKING:  # torch is loaded where it is used
    import torch

    from tsac_bench.planning.solve import SolveOutcome
    from tsac_bench.solvers.tsac.features import Observation
    from tsac_bench.solvers.tsac.sac import Labelled, RolloutWorkers

TAUS = (0.0, 0.25, 0.5, 1.0)


# ----------------------------------------------------------------- labels and their gains


@dataclass(frozen=True)
class Advantages:
    """A labelled state's other labelled actions and their labels less HOCF's (in J:
    positive means a lower final J than HOCF's choice)."""

    item: Labelled
    reference: int
    actions: tuple[int, ...]
    gains: np.ndarray

    @classmethod
    def of(cls, item: Labelled) -> Advantages | None:
        """None where HOCF's choice was not labelled or nothing else was."""
        from tsac_bench.solvers.tsac.features import teacher_action

        reference = teacher_action(item.state)
        if reference not in item.actions or len(item.actions) < 2:
            return None
        q = dict(zip(item.actions, item.q, strict=True))
        others = tuple(a for a in item.actions if a != reference)
        return cls(item, reference, others, np.array([q[a] - q[reference] for a in others]))

    @property
    def state(self) -> Observation:
        return self.item.state


def deviation_gain(predicted: Sequence[np.ndarray], true: Sequence[np.ndarray],
                   tau: float) -> tuple[float, float, int]:
    """Mean gain per state of deviating to the action of largest predicted advantage where
    that advantage exceeds ``tau`` (HOCF's choice, gain 0, elsewhere), measured by ``true``;
    the half-width of its 95 % interval (1.96 standard errors); the number of states where
    it deviates."""
    gains, deviations = [], 0
    for guess, truth in zip(predicted, true, strict=True):
        best = int(np.argmax(guess))
        if guess[best] > tau:
            gains.append(float(truth[best]))
            deviations += 1
        else:
            gains.append(0.0)
    return float(np.mean(gains)), normal_half_width(gains), deviations


# ----------------------------------------------------------------------------- repeat


def with_reference(valid: np.ndarray, most: int, rng: np.random.Generator,
                   reference: int) -> np.ndarray:
    """The actions to label, ascending: every valid one if at most ``most``, otherwise
    ``reference`` (HOCF's) and ``most`` - 1 others drawn uniformly."""
    if len(valid) <= most:
        return valid
    others = rng.choice(valid[valid != reference], most - 1, replace=False)
    return np.sort(np.append(others, reference))


class RepeatedLabels:
    """Selection rule: HOCF's choice; in a share of the states with two or more candidate
    actions, labels up to ``candidates`` of them (HOCF's among them) twice, with independent
    rollout seeds, and keeps both labellings' advantages over HOCF's choice."""

    def __init__(self, hocf: SelectionRule, *, share: float, candidates: int, rollouts: int,
                 workers: RolloutWorkers | None = None) -> None:
        self.hocf, self.share, self.candidates = hocf, share, candidates
        self.rollouts, self.workers = rollouts, workers
        self.pairs: list[tuple[np.ndarray, np.ndarray]] = []

    def select(self, view: DecisionView, rng: np.random.Generator) -> int:
        from tsac_bench.solvers.tsac.features import action_of, observe
        from tsac_bench.solvers.tsac.sac import rollout_values

        valid = np.flatnonzero(observe(view).action_mask)
        reference = action_of(view, self.hocf.select(view, rng))
        if len(valid) > 1 and rng.random() < self.share:
            actions = with_reference(valid, self.candidates, rng, reference).tolist()
            where = actions.index(reference)
            first, second = (
                -rollout_values(view.game, view, actions, self.hocf,
                                rollouts=self.rollouts, seed=int(rng.integers(2**31)),
                                workers=self.workers).mean(axis=1)
                for _ in range(2))
            self.pairs.append((np.delete(first - first[where], where),
                               np.delete(second - second[where], where)))
        return self.hocf.select(view, rng)


def repeat_summary(pairs: Sequence[tuple[np.ndarray, np.ndarray]]) -> dict[str, float]:
    """What the first labelling's best action gains by the first labels and by the second,
    per labelled state (0 where HOCF's own label is the best); how often it is not HOCF's
    choice; the correlation of the two labellings' advantages."""
    believed = [max(0.0, float(first.max())) for first, _ in pairs]
    got = [float(second[first.argmax()]) if first.max() > 0 else 0.0
           for first, second in pairs]
    first = np.concatenate([p[0] for p in pairs])
    second = np.concatenate([p[1] for p in pairs])
    return {"states": len(pairs), "believed": float(np.mean(believed)),
            "got": float(np.mean(got)),
            "deviates": float(np.mean([f.max() > 0 for f, _ in pairs])),
            "correlation": float(np.corrcoef(first, second)[0, 1])}


def run_repeat(args: argparse.Namespace) -> list[str]:
    from paper_reproduction import instance_files

    from tsac_bench.solvers.tsac.sac import RolloutWorkers

    workers = RolloutWorkers(args.workers) if args.workers > 1 else None
    pairs: list[tuple[np.ndarray, np.ndarray]] = []
    try:
        for path in instance_files(args.scale, args.instances):
            state = PlanningState.static(read_instance(path))
            rule = RepeatedLabels(make_allocator("hocf").rule(state), share=args.share,
                                  candidates=args.candidates, rollouts=args.rollouts,
                                  workers=workers)
            CoalitionGame(state, state.base_routes()).run(rule, sample_rng(0, 0), k_max=K_MAX,
                                                          c_max=C_MAX)
            pairs += rule.pairs
            print(f"{path.stem}: {len(rule.pairs)} labelled states", flush=True)
    finally:
        if workers is not None:
            workers.close()
    s = repeat_summary(pairs)
    return [
        "| scale | rollouts per action | labelled states | best action not HOCF's | "
        "gain believed (labels 1) | gain got (labels 2) | correlation of the advantages |",
        "|---|---:|---:|---:|---:|---:|---:|",
        f"| {args.scale} | {args.rollouts} | {s['states']} | {100 * s['deviates']:.1f} % | "
        f"{s['believed']:+.3f} J | {s['got']:+.3f} J | {s['correlation']:.3f} |",
    ]


# --------------------------------------------------------------------------- held-out


def boosting_rows(example: Advantages) -> np.ndarray:
    """One row per other action: the state's context (agent, task count, valid count,
    whether HOCF passes), whether the action is the pass, its task row, HOCF's task row and
    their difference (a pass's row is zeros)."""
    state = example.state
    width = state.tasks.shape[1]

    def row(action: int) -> np.ndarray:
        return state.tasks[action - 1] if action > 0 else np.zeros(width)

    context = np.r_[state.agent, len(state.tasks), state.action_mask.sum(),
                    example.reference == 0]
    ours = row(example.reference)
    return np.array([np.r_[context, action == 0, row(action), ours, row(action) - ours]
                     for action in example.actions])


def fit_boosting(train: Sequence[Advantages], seed: int) -> Callable[[Advantages], np.ndarray]:
    from sklearn.ensemble import HistGradientBoostingRegressor
    from threadpoolctl import threadpool_limits

    model = HistGradientBoostingRegressor(max_iter=300, learning_rate=0.05, max_leaf_nodes=15,
                                          l2_regularization=1.0, random_state=seed)
    # One OpenMP thread: on a machine whose cores are busy, its spinning threads took 30
    # times as long.
    with threadpool_limits(limits=1):
        model.fit(np.vstack([boosting_rows(e) for e in train]),
                  np.concatenate([e.gains for e in train]))

    def predict(example: Advantages) -> np.ndarray:
        with threadpool_limits(limits=1):
            return model.predict(boosting_rows(example))

    return predict


def fit_critic(train: Sequence[Advantages], net: dict, epochs: int,
               seed: int) -> Callable[[Advantages], np.ndarray]:
    """The method's critic network, trained offline on the Huber loss over the labelled
    actions, as in training, but with its output centred per state over them like the
    labels (training regresses the output itself: its actor is blind to a per-state
    constant, and so is ``deviation_gain``)."""
    import torch

    from tsac_bench.solvers.tsac.net import NetConfig, QNet
    from tsac_bench.solvers.tsac.sac import LabelledBatch

    torch.manual_seed(seed)
    critic = QNet(NetConfig(**net))
    optimizer = torch.optim.Adam(critic.parameters(), lr=1e-3)
    labelled = [e.item for e in train]
    rng = np.random.default_rng(seed)
    for _ in range(epochs):
        order = rng.permutation(len(labelled))
        for start in range(0, len(order), 64):
            batch = LabelledBatch.of([labelled[i] for i in order[start:start + 64]], "cpu")
            q = critic(batch.states)
            mask = batch.label_mask
            centred = q - (q * mask).sum(1, keepdim=True) / mask.sum(1, keepdim=True)
            loss = torch.nn.functional.huber_loss(centred[mask], batch.labels[mask])
            optimizer.zero_grad()
            loss.backward()
            optimizer.step()
    critic.eval()

    def predict(example: Advantages) -> np.ndarray:
        from tsac_bench.solvers.tsac.net import collate

        with torch.no_grad():
            q = critic(collate([example.state], "cpu"))[0].numpy()
        return q[list(example.actions)] - q[example.reference]

    return predict


def run_held_out(args: argparse.Namespace) -> list[str]:
    import torch

    torch.set_num_threads(1)
    examples: list[Advantages] = []
    net = None
    for run in args.runs:
        checkpoint = torch.load(Path(run) / "checkpoint.pt", weights_only=False,
                                map_location="cpu")
        net = net or checkpoint["config"]["net"]
        for item in checkpoint["buffer"]:
            example = Advantages.of(item) if hasattr(item, "q") else None
            if example is not None:
                examples.append(example)
    cut = int(args.train_share * len(examples))
    train, test = examples[:cut], examples[cut:]
    truth = [e.gains for e in test]
    oracle = np.mean([max(0.0, g.max()) for g in truth])
    uniform = np.mean([g.mean() for g in truth])
    lines = [
        f"Labelled states with HOCF's choice labelled: {len(examples)}; trained on the first "
        f"{len(train)} (or the last quarter / half of them), tested on the last {len(test)}. "
        f"On the test states, the best labelled action gains {oracle:+.3f} J per state "
        f"against HOCF's label (the labels' own look-ahead, noise included), a uniformly "
        f"drawn other action {uniform:+.3f} J.",
        "",
        "| model | training states | "
        + " | ".join(f"tau {tau:g}: gain per state, 95 % (deviations)" for tau in TAUS) + " |",
        "|---|---:|" + "---:|" * len(TAUS),
    ]
    fits = {"gradient boosting": lambda part: fit_boosting(part, args.seed),
            "transformer critic": lambda part: fit_critic(part, net, args.epochs, args.seed)}
    for name, fit in fits.items():
        for size in (len(train) // 4, len(train) // 2, len(train)):
            predict = fit(train[len(train) - size:])
            predicted = [predict(e) for e in test]
            cells = []
            for tau in TAUS:
                gain, half_width, deviations = deviation_gain(predicted, truth, tau)
                cells.append(f"{gain:+.3f} +- {half_width:.3f} J ({deviations})")
            lines.append(f"| {name} | {size} | " + " | ".join(cells) + " |")
            print(lines[-1], flush=True)
    return lines


# ----------------------------------------------------------------------------- margin


def run_scores(checkpoint: dict) -> dict[str, Callable[[dict[str, torch.Tensor]], torch.Tensor]]:
    """The value functions of a training run's checkpoint (see ``margin``)."""
    import torch

    from tsac_bench.solvers.tsac.policy import Policy
    from tsac_bench.solvers.tsac.sac import DiscreteSAC, teacher_choice, teacher_prior_of
    from tsac_bench.solvers.tsac.training import TrainConfig

    config = TrainConfig.from_dict(checkpoint["config"])
    sac = DiscreteSAC(config.net, config.sac, "cpu", config.teacher_prior)
    sac.load_state_dict(checkpoint["sac"])
    for network in (sac.actor, *sac.critics):
        network.eval()
    policy = Policy(sac.actor, tuple(sac.critics), config.label_scale)

    def teacher_column(obs: dict[str, torch.Tensor]) -> torch.Tensor:
        return teacher_choice(obs).argmax(dim=-1, keepdim=True)

    def agree(obs: dict[str, torch.Tensor]) -> torch.Tensor:
        teacher = teacher_column(obs)
        gains = [q - q.gather(1, teacher) for q in (critic(obs) for critic in sac.critics)]
        return torch.minimum(*gains) * config.label_scale

    def veto(obs: dict[str, torch.Tensor]) -> torch.Tensor:
        values = policy.values(obs)
        kept = torch.zeros_like(obs["action_mask"]).scatter_(1, teacher_column(obs), True)
        kept[:, 0] |= obs["action_mask"][:, 0]  # the pass action
        return torch.where(kept, values, torch.full_like(values, -torch.inf))

    return {"critic": policy.values,
            "actor": lambda obs: sac.teacher_prior * (sac.actor(obs) - teacher_prior_of(obs)),
            "agree": agree, "veto": veto}


class MarginAllocator(HOCFAllocator):
    """HOCF with ``MarginSelection`` as its rule: HOCF's AAV orders, start and budget."""

    def __init__(self, score: Callable[[dict[str, torch.Tensor]], torch.Tensor],
                 tau: float) -> None:
        super().__init__()
        self.score, self.tau = score, tau

    def rule(self, state: PlanningState) -> SelectionRule:
        from tsac_bench.solvers.tsac.policy import MarginSelection

        del state
        return MarginSelection(self.score, self.tau)


def unmet_load(outcomes: Sequence[SolveOutcome]) -> float:
    """Mean J spent on unmet demand (the evaluator's weighted C_load term)."""
    return float(np.mean([outcome.evaluation.terms["load"] for outcome in outcomes]))


def run_margin(args: argparse.Namespace) -> list[str]:
    import torch
    from paper_reproduction import instance_files

    from tsac_bench.model.generator import generate
    from tsac_bench.planning.solve import solve

    torch.set_num_threads(1)
    checkpoint = torch.load(Path(args.run) / "checkpoint.pt", weights_only=False,
                            map_location="cpu")
    if checkpoint["config"]["teacher_prior"] <= 0:
        raise SystemExit(f"{args.run}: margin needs a run with teacher_prior > 0")
    scores = run_scores(checkpoint)
    if args.first_seed is None:
        instances = [read_instance(path) for path in instance_files(args.scale, args.instances)]
        source = f"the first {args.instances} instances of `instances/paper-mc/`"
    else:  # held-out instances apart from paper-mc's, to choose tau on
        seeds = range(args.first_seed, args.first_seed + args.instances)
        instances = [generate(args.scale, seed) for seed in seeds]
        source = f"generated instances of seeds {seeds.start}..{seeds.stop - 1}"
    hocf_outcomes = [solve(i, "hocf", seed=0, mode="dynamic") for i in instances]
    hocf = [outcome.cost for outcome in hocf_outcomes]
    footing = make_allocator("hocf").settings()
    lines = [f"Dynamic mode, {source} at {args.scale}, method seed 0; every row is HOCF's "
             f"game with its start ({footing['init']}), games per plan call "
             f"({footing['samples']}) and budget (k_max {footing['k_max']}, c_max "
             f"{footing['c_max']}, no time limit); HOCF's mean J {np.mean(hocf):.2f}, of which "
             f"{unmet_load(hocf_outcomes):.2f} unmet load (the w1 C_load term). d = J(row) - "
             "J(HOCF) per instance (negative: cheaper).",
             "",
             "| scale | value | tau | mean J | mean d, 95 % | mean d / mean J(HOCF) | "
             "lower / higher | unmet load | mean wall (s) |",
             "|---|---|---:|---:|---:|---:|---:|---:|---:|"]
    for name in args.score:
        for tau in args.tau:
            allocator = MarginAllocator(scores[name], tau)
            outcomes, walls = [], []
            for instance in instances:
                began = time.perf_counter()
                outcomes.append(solve(instance, allocator, seed=0, mode="dynamic"))
                walls.append(time.perf_counter() - began)
            costs = [outcome.cost for outcome in outcomes]
            d = np.subtract(costs, hocf)
            lines.append(f"| {args.scale} | {name} | {tau:g} | {np.mean(costs):.2f} | "
                         f"{d.mean():+.2f} +- {normal_half_width(d):.2f} | "
                         f"{100 * d.mean() / np.mean(hocf):+.1f} % | "
                         f"{int((d < 0).sum())} / {int((d > 0).sum())} | "
                         f"{unmet_load(outcomes):.2f} | {np.mean(walls):.2f} |")
            print(lines[-1], flush=True)
    return lines


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parts = parser.add_subparsers(dest="part", required=True)
    repeat = parts.add_parser("repeat")
    repeat.add_argument("--scale", default="16/40")
    repeat.add_argument("--instances", type=int, default=10)
    repeat.add_argument("--share", type=float, default=0.1)
    repeat.add_argument("--candidates", type=int, default=16)
    repeat.add_argument("--rollouts", type=int, default=4)
    repeat.add_argument("--workers", type=int, default=1)
    held_out = parts.add_parser("held-out")
    held_out.add_argument("runs", nargs="+", help="training run folders (their checkpoint.pt)")
    held_out.add_argument("--train-share", type=float, default=0.75)
    held_out.add_argument("--epochs", type=int, default=30)
    held_out.add_argument("--seed", type=int, default=0)
    margin = parts.add_parser("margin")
    margin.add_argument("run", help="a training run folder (its checkpoint.pt)")
    margin.add_argument("--scale", default="16/40")
    margin.add_argument("--instances", type=int, default=100)
    margin.add_argument("--first-seed", type=int, default=None,
                        help="generated instances from this seed instead of paper-mc's")
    margin.add_argument("--tau", type=float, action="append", default=None)
    margin.add_argument("--score", choices=("critic", "actor", "agree", "veto"), action="append",
                        default=None)
    args = parser.parse_args()
    if args.part == "margin":
        args.tau = args.tau or [0.5, 1.0]
        args.score = args.score or ["critic", "actor"]
    if (args.part == "margin" or (args.part == "repeat" and args.workers == 1)) and hasattr(
            os, "sched_setaffinity"):
        os.sched_setaffinity(0, {min(os.sched_getaffinity(0))})
    run = {"repeat": run_repeat, "held-out": run_held_out, "margin": run_margin}[args.part]
    lines = run(args)
    print("\n".join(lines))


if __name__ == "__main__":
    main()
