"""The training run behind ``tsac-bench train``: episodes, curriculum, warm-up, gauges and
files around the algorithm of ``sac``.

* Episodes are OCF games on planning moments of generated instances (``training_moments``):
  t = 0 moments and moments of simulated dynamic runs, over a curriculum of scales.
* The first decisions are HOCF's, and the actor is pre-trained to imitate them.

``TrainConfig``'s defaults are the recipe of the shipped policy (its file's
``meta.config``). Files written to the output folder: ``checkpoint.pt`` (everything needed to
resume), ``policy.pt`` (what ``tsac-ocf`` loads: the actor and the critics;
``policy-STEP.pt`` at each gauge point), ``curve.json`` and ``curve.png``.
"""


from __future__ import annotations

import json
import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any, ClassVar

import numpy as np
import torch

from tsac_bench.model.evaluator import CostEvaluator
from tsac_bench.model.generator import ScenarioGenerator, generate, parse_scale
from tsac_bench.planning import PlanningState, PlanResult, make_allocator
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
    CoalitionGame,
    DecisionView,
)
from tsac_bench.solvers.tsac.features import (
    AGENT_DIM,
    DEPOT_DIM,
    FEATURES,
    TASK_DIM,
    Observation,
    action_choice,
    action_of,
    observe,
)
from tsac_bench.solvers.tsac.net import NetConfig, PolicyNet, collate
from tsac_bench.solvers.tsac.policy import PolicySelection, save_policy
from tsac_bench.solvers.tsac.sac import (
    Demonstration,
    DiscreteSAC,
    Labelled,
    LabelledBatch,
    ReplayBuffer,
    RolloutWorkers,
    SACConfig,
    descend,
    label_candidates,
    rollout_values,
)

#: (share of the steps from which the stage applies, the scales episodes are drawn from)
#: The small scales stay to the end: a short run that dropped 8/20 at 40 % of its steps
#: ended 22 % above HOCF there while level with it at 16/40 and 32/80.
DEFAULT_CURRICULUM: tuple[tuple[float, tuple[str, ...]], ...] = (
    (0.0, ("4/10", "8/20", "16/40")),
    (0.3, ("8/20", "16/40", "32/80")),
)
#: The OCF methods whose selection rule can take the warm-up decisions or finish a rollout.
RULE_METHODS = ("hocf", "rocf")


@dataclass(frozen=True)
class TrainConfig:
    """The defaults are the recipe of the shipped policy 3 (its file's ``meta.config``;
    tests/solvers/test_tsac.py holds them to it)."""

    steps: int = 27_128
    seed: int = 0
    warmup: int = 1_000  # decisions taken by the demonstrator before the first update
    #: Who takes the warm-up decisions: a registered OCF method's selection rule (its
    #: decisions then also pre-train the actor by imitation) or None (uniformly random).
    demonstrator: str | None = "hocf"
    pretrain_updates: int = 500  # imitation (+ critic) steps after the warm-up
    #: The actor's regulariser: this weight (J units, fixed) times its KL divergence from
    #: the teacher prior (HOCF's choice, ``teacher_prior_of``): the soft-greedy policy is
    #: prior x exp(Q / weight), HOCF's choice unless the critics put another action ahead
    #: by about 5 weights. With an entropy bonus instead, the actor followed the critics
    #: wherever they ranked actions, and their errors (0.5-1 J) drove it away from HOCF
    #: where nothing was to gain.
    teacher_prior: float = 0.3
    curriculum: tuple[tuple[float, tuple[str, ...]], ...] = DEFAULT_CURRICULUM
    #: Share of the episodes played on a moment of a simulated dynamic run (t = 0 or a
    #: re-plan); the others are t = 0 moments (static or released-only).
    replan_share: float = 0.5
    label_share: float = 0.1  # share of the decisions whose actions are labelled
    label_candidates: int = 16  # most actions labelled per state (drawn uniformly)
    #: Completions per labelled action (common AAV orders). 16: two labellings of 4
    #: rollouts agreed with correlation 0.32-0.51, of 16 with 0.71-0.79.
    rollouts: int = 16
    completion: str = "hocf"  # the OCF method that finishes the game
    #: J units per unit of Q. 1: label differences (0.1-5 J) stand well above the
    #: regulariser; at 10 a policy went near-uniform.
    label_scale: float = 1.0
    updates_per_label: int = 2  # gradient steps per labelled state
    episode_steps: int = 600  # truncation of one episode (one OCF game)
    eval_every: int = 2_000
    eval_scale: str = "16/40"
    eval_instances: int = 3
    checkpoint_every: int = 1_000
    net: NetConfig = field(default_factory=lambda: NetConfig(
        AGENT_DIM, TASK_DIM, DEPOT_DIM, d_model=32, heads=4, layers=2, feedforward=64,
        features=FEATURES, pass_action=True))
    sac: SACConfig = field(default_factory=SACConfig)

    #: The fields ``tsac-bench train --set`` may change: the scalar ones, less steps and seed
    #: (options of their own) and eval_scale (a scale has no constraint to check it by).
    setting_constraints: ClassVar[Mapping[str, Constraint]] = declare(
        warmup=Interval(int, 0, None),
        demonstrator=NoneOr(Options(*RULE_METHODS)),
        pretrain_updates=Interval(int, 0, None),
        teacher_prior=Interval(float, 0, None, closed="neither"),
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


class Gauge:
    """The training curve's gauge: final J of the actor-driven game (sampled) on fixed
    static moments, against HOCF's."""

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
        self.buffer: ReplayBuffer[Labelled] = ReplayBuffer(config.sac.buffer_size)
        self.demos: ReplayBuffer[Demonstration] = ReplayBuffer(config.warmup)
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
        self.gauge = Gauge(config)

    def save_checkpoint(self) -> None:
        torch.save({"config": self.config.to_dict(), "sac": self.sac.state_dict(),
                    "buffer": self.buffer.items, "demonstrations": self.demos.items,
                    "buffer_position": self.buffer.position,
                    "rng": self.rng.bit_generator.state, "sampler": self.sampler.get_state(),
                    "log": self.log, "step": self.step, "episode": self.episode,
                    "seconds": time.perf_counter() - self.began},
                   self.out / "checkpoint.pt")

    def evaluate_now(self, stats: dict[str, float]) -> dict[str, float]:
        """The curve's gauge; the policy of each gauge point is kept (``policy-STEP.pt``),
        so that a run's best point can be chosen on the gauge, not on test instances."""
        self.log["evals"].append({"step": self.step, "seconds":
                                  time.perf_counter() - self.began,
                                  **self.gauge(self.sac.actor)})
        self.save_policy(self.out / f"policy-{self.step}.pt",
                         {"steps": self.step, "seed": self.config.seed,
                          "config": self.config.to_dict(), **self.log["evals"][-1]})
        return {**stats, **self.log["evals"][-1]}

    def save_policy(self, path: Path, meta: dict[str, Any]) -> None:
        """The actor and the critics, whose values are final-J differences
        (``label_scale`` J per unit): what decoding by margin needs."""
        save_policy(self.sac.actor, path, meta, critics=self.sac.critics,
                    critic_unit=self.config.label_scale)


def train(out: Path, config: TrainConfig, *, device: str = "auto", resume: Path | None = None,
          on_step: Callable[[int, dict[str, float]], None] | None = None,
          stop_after: float | None = None, label_workers: int = 1) -> dict[str, Any]:
    """Train from scratch (or from ``resume``'s checkpoint) up to ``config.steps`` env
    steps; returns the summary written to ``curve.json``. ``stop_after`` (seconds of this
    call) ends the call early at an episode's end, with a checkpoint to resume from and the
    policy so far. ``label_workers`` > 1 runs the rollout labels in that many processes
    (``RolloutWorkers``: the same run, faster on as many cores); it is not part of the
    configuration, so a resumed run may use another number."""
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
        _train(run, on_step, stop_after)
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


class _Behaviour:
    """The selection rule that plays a training episode: the demonstrator during the
    warm-up, then the actor (sampled); it labels a share of the decisions with rollouts and
    takes the gradient steps."""

    def __init__(self, run: _Run, state: PlanningState,
                 on_step: Callable[[int, dict[str, float]], None] | None) -> None:
        config = run.config
        self.run, self.on_step = run, on_step
        self.demonstrator = (make_allocator(config.demonstrator).rule(state)
                             if config.demonstrator is not None else None)
        self.completion = make_allocator(config.completion).rule(state)
        self.stats: dict[str, float] = {}

    def select(self, view: DecisionView, rng: np.random.Generator) -> int:
        run, config, sac = self.run, self.run.config, self.run.sac
        observation = observe(view)
        valid = np.flatnonzero(observation.action_mask)
        warming = run.step < config.warmup
        if warming and self.demonstrator is not None:
            action = action_of(view, self.demonstrator.select(view, rng))
            run.demos.add(Demonstration(observation, action))
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
        return action_choice(view, action)

    def label(self, view: DecisionView, observation: Observation, valid: np.ndarray,
              rng: np.random.Generator) -> None:
        run, config = self.run, self.run.config
        actions = label_candidates(valid, config.label_candidates, rng)
        finals = rollout_values(view.game, view, actions.tolist(), self.completion,
                                rollouts=config.rollouts, seed=int(rng.integers(2**31)),
                                workers=run.workers).mean(axis=1)
        q = -(finals - finals.mean()) / config.label_scale
        run.buffer.add(Labelled(observation, tuple(actions.tolist()), tuple(q.tolist())))
        run.log.setdefault("labels", []).append(
            {"step": run.step, "actions": len(actions), "spread_J": float(np.ptp(finals))})
        if run.step >= config.warmup:
            for _ in range(config.updates_per_label):
                self.stats = run.sac.update_from_labels(LabelledBatch.of(
                    run.buffer.sample(config.sac.batch_size, run.rng), run.device))
            run.log["updates"].append({"step": run.step, **self.stats})

    def pretrain(self) -> None:
        """Imitation of the demonstrator's decisions; the critics fit the labels so far."""
        run, sac = self.run, self.run.sac
        for i in range(run.config.pretrain_updates):
            clone = sac.clone_loss(run.demos.sample(run.config.sac.batch_size, run.rng))
            descend(sac.actor_optimizer, clone)
            stats = {"clone_loss": clone.item()}
            if len(run.buffer):
                batch = LabelledBatch.of(run.buffer.sample(run.config.sac.batch_size, run.rng),
                                         run.device)
                critic = sac.label_loss(batch)
                descend(sac.critic_optimizer, critic)
                stats["critic_loss"] = critic.item()
            if i % 50 == 0:
                run.log.setdefault("pretrain", []).append({"update": i, **stats})


#: Builds the planning moment of an episode from a random generator.
MomentSampler = Callable[[np.random.Generator], PlanningState]


def generated_moments(scales: Sequence[str], released_only: float = 0.5,
                      generator: ScenarioGenerator | None = None) -> MomentSampler:
    """Planning moments at t = 0 of generated instances of the given scales: with
    probability ``released_only`` the tasks released at 0 (a dynamic run's first plan),
    otherwise all tasks (a static run)."""
    generator = generator or ScenarioGenerator()
    sizes = [parse_scale(s) for s in scales]

    def sample(rng: np.random.Generator) -> PlanningState:
        n, m = sizes[int(rng.integers(len(sizes)))]
        instance = generator.generate(n, m, int(rng.integers(2**31)))
        if rng.random() < released_only:
            visible = frozenset(i for i, t in enumerate(instance.tasks) if t.release <= 0)
        else:
            visible = frozenset(range(instance.n_tasks))
        return PlanningState(instance, 0.0, visible)

    return sample


def replan_moments(scales: Sequence[str], method: str = "hocf",
                   generator: ScenarioGenerator | None = None) -> MomentSampler:
    """The planning moments a dynamic run meets: a generated instance of one of ``scales``
    is run through the simulator with ``method`` (seeded from ``rng``), and one of its plan
    calls' states is drawn uniformly: t = 0 or a re-plan with committed prefixes and the
    tasks released by then (the simulator owns those rules)."""
    from tsac_bench.planning.simulator import simulate

    generator = generator or ScenarioGenerator()
    sizes = [parse_scale(s) for s in scales]
    allocator = make_allocator(method)

    class Recorder:
        name = allocator.name

        def __init__(self) -> None:
            self.states: list[PlanningState] = []

        def plan(self, state: PlanningState, *, seed: int = 0,
                 time_limit: float | None = None) -> PlanResult:
            self.states.append(state)
            return allocator.plan(state, seed=seed, time_limit=time_limit)

    def sample(rng: np.random.Generator) -> PlanningState:
        n, m = sizes[int(rng.integers(len(sizes)))]
        instance = generator.generate(n, m, int(rng.integers(2**31)))
        recorder = Recorder()
        simulate(instance, recorder, seed=int(rng.integers(2**31)))
        return recorder.states[int(rng.integers(len(recorder.states)))]

    return sample


def training_moments(config: TrainConfig, step: int, rng: np.random.Generator
                     ) -> PlanningState:
    """The planning moment of the next episode (curriculum scales at ``step``)."""
    scales = config.scales_at(step)
    sampler: MomentSampler = (replan_moments(scales) if rng.random() < config.replan_share
                              else generated_moments(scales))
    return sampler(rng)


def _train(run: _Run, on_step: Callable[[int, dict[str, float]], None] | None,
           stop_after: float | None = None) -> None:
    """Episodes are OCF games on training moments played by ``_Behaviour``; a checkpoint is
    written at the end of the first episode after each ``checkpoint_every`` steps, and a
    resume starts a new episode."""
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
        axes[1].semilogy(steps, [max(u["entropy"], 1e-4) for u in updates], label="entropy")
        axes[1].legend()
    axes[1].set(title="critics and actor", xlabel="env step")
    evals = summary["evals"]
    if evals:
        axes[2].plot([e["step"] for e in evals], [e["eval_ratio_hocf"] for e in evals], "o-")
        axes[2].axhline(1.0, color="grey", lw=0.8)
    axes[2].set(title="held-out static 16/40: J(policy) / J(HOCF)", xlabel="env step")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
