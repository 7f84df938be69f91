"""``tsac-ocf``: the OCF game with a learned task-selection policy (paper Sec. III-C).

The engine of ``solvers/ocf/engine.py`` plays Algorithm 1 (random AAV permutations, ADD/REMOVE,
strict-improvement acceptance, tabu list); the selection rule here feeds the deciding AAV's
state (Eq. 20, ``tsac_env.observe``) to a frozen transformer actor and samples the task from
the masked distribution (Eq. 21) with the engine's seeded generator, so a run is
deterministic per seed. The default policy ships with the package
(``solvers/tsac/policies/tsac-default.pt``; how it was trained: docs/tsac.md).
"""

from __future__ import annotations

import json
from functools import cache
from pathlib import Path
from typing import Any

import numpy as np
import torch

from tsac_bench.errors import TsacBenchError
from tsac_bench.planning import (
    ExistingFile,
    Interval,
    NoneOr,
    PlanningState,
    PlanResult,
    declare,
)
from tsac_bench.solvers.ocf.engine import (
    C_MAX,
    INIT,
    K_MAX,
    SAMPLES,
    DecisionView,
    OCFAllocator,
    SelectionRule,
)
from tsac_bench.solvers.tsac.env import (
    AGENT_DIM,
    DEPOT_DIM,
    FEATURE_SETS,
    FeatureSet,
    action_choice,
    observe,
)
from tsac_bench.solvers.tsac.net import NetConfig, PolicyNet, collate

DEFAULT_POLICY = Path(__file__).parent / "policies" / "tsac-default.pt"
POLICY_FORMAT = "tsac-bench/policy@1"


class PolicyFileError(TsacBenchError):
    """A policy file that cannot be read or does not fit this version's features."""


def save_policy(actor: PolicyNet, path: Path, meta: dict[str, Any]) -> None:
    """Write the actor alone (no critics, no optimiser): what ``tsac-ocf`` loads."""
    path.parent.mkdir(parents=True, exist_ok=True)
    # Plain JSON types only, so that the file loads with weights_only=True.
    meta = json.loads(json.dumps(meta, default=str))
    torch.save({"format": POLICY_FORMAT, "config": actor.config.to_dict(),
                "actor": actor.state_dict(), "meta": meta}, path)


def load_policy(path: Path | str = DEFAULT_POLICY) -> PolicyNet:
    """The frozen actor of a policy file, on the CPU, in evaluation mode."""
    path = Path(path)
    try:
        payload = torch.load(path, map_location="cpu", weights_only=True)
    except (OSError, RuntimeError, ValueError) as exc:
        raise PolicyFileError(f"{path}: cannot read the policy ({exc})") from None
    if not isinstance(payload, dict) or payload.get("format") != POLICY_FORMAT:
        raise PolicyFileError(f"{path}: format: expected {POLICY_FORMAT!r}")
    # Files written before feature set 2 existed carry no "features": they are version 1.
    config = NetConfig(**payload["config"])
    features = FEATURE_SETS.get(config.features)
    if features is None:
        raise PolicyFileError(f"{path}: config.features: feature set {config.features} is "
                              f"unknown here (known: {', '.join(map(str, FEATURE_SETS))})")
    shape = (AGENT_DIM, features.task_dim, DEPOT_DIM, features.pass_action)
    if (config.agent_dim, config.task_dim, config.depot_dim, config.pass_action) != shape:
        raise PolicyFileError(
            f"{path}: config: the network's inputs (agent {config.agent_dim}, task "
            f"{config.task_dim}, depot {config.depot_dim}, pass {config.pass_action}) do not "
            f"fit feature set {features.version} of this version {shape}: retrain the policy")
    actor = PolicyNet(config)
    try:
        actor.load_state_dict(payload["actor"])
    except RuntimeError as exc:
        raise PolicyFileError(f"{path}: actor: does not fit this network ({exc})") from None
    actor.eval()
    actor.requires_grad_(False)
    return actor


@cache
def _cached_policy(path: str) -> PolicyNet:
    return load_policy(path)


class PolicySelection:
    """Selection rule: sample m* ~ pi(.|s) (Eq. 21). ``temperature`` divides the logits;
    0 takes the most probable task (lowest index on ties)."""

    def __init__(self, actor: PolicyNet, temperature: float = 1.0) -> None:
        self.actor = actor
        self.temperature = temperature
        self.features: FeatureSet = FEATURE_SETS[actor.config.features]

    def probabilities(self, view: DecisionView) -> np.ndarray:
        """pi(.|s) over the actions (the pass first with feature set 2, then
        ``view.game.visible``): exactly 0 outside the valid ones."""
        with torch.inference_mode():
            logits = self.actor(collate([observe(view, self.features)]))[0].double()
        if self.temperature > 0:
            return torch.softmax(logits / self.temperature, dim=-1).numpy()
        best = torch.zeros_like(logits)
        best[int(torch.argmax(logits))] = 1.0
        return best.numpy()

    def select(self, view: DecisionView, rng: np.random.Generator) -> int:
        p = self.probabilities(view)
        return action_choice(view, int(rng.choice(len(p), p=p)), self.features)


class TSACOCFAllocator(OCFAllocator):
    """Settings: ``policy`` (a policy file; default the shipped one), ``temperature`` and
    the engine's ``k_max``, ``c_max``, ``init``."""

    name = "tsac-ocf"
    setting_constraints = declare(**OCFAllocator.setting_constraints,
                                  policy=NoneOr(ExistingFile()),
                                  temperature=Interval(float, 0, None))

    def __init__(self, policy: str | None = None, temperature: float = 1.0,
                 k_max: int = K_MAX, c_max: int = C_MAX, init: str = INIT,
                 samples: int = SAMPLES) -> None:
        super().__init__(k_max=k_max, c_max=c_max, init=init, samples=samples)
        self.policy = policy
        self.temperature = temperature

    def rule(self, state: PlanningState) -> SelectionRule:
        del state
        actor = _cached_policy(str(Path(self.policy) if self.policy else DEFAULT_POLICY))
        return PolicySelection(actor, self.temperature)

    def plan(self, state: PlanningState, *, seed: int = 0,
             time_limit: float | None = None) -> PlanResult:
        # One small state at a time runs fastest on one thread; restored for the caller.
        threads = torch.get_num_threads()
        torch.set_num_threads(1)
        try:
            return super().plan(state, seed=seed, time_limit=time_limit)
        finally:
            torch.set_num_threads(threads)
