"""``tsac-ocf``: the OCF game with a learned task-selection policy (paper Sec. III-C).

The engine of ``solvers/ocf/engine.py`` plays Algorithm 1 (random AAV permutations, ADD/REMOVE,
strict-improvement acceptance, tabu list); the selection rule here feeds the deciding AAV's
state (Eq. 20, ``features.observe``) to the frozen networks of a policy file and decodes a
task in one of two ways (``decode``):

* ``sample``: m* ~ pi(.|s), the actor's masked distribution (Eq. 21);
* ``margin``: HOCF's choice (the teacher column of the state) unless the minimum of the
  run's twin critics rates another valid action more than ``margin`` J above it. Why: the
  critics of a run trained on rollout labels rank actions well only near the states they
  were trained on; a deviation they back by a wide margin pays, a close call does not
  (reports/archive/tsac-learnability.md measures both). With ``verify`` (a number), the policy
  file's verifier (``solvers/tsac/verify.py``) must also rate the deviation more than
  ``verify`` J above HOCF's choice.

Either way the engine's seeded generator drives the game, so a run is deterministic per seed.
The default policy ships with the package (``solvers/tsac/policies/tsac-default.pt``, decoded
by margin; how it was trained and measured: docs/tsac.md).
"""

from __future__ import annotations

import json
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from functools import cache, cached_property
from pathlib import Path
from typing import Any

import numpy as np
import torch
from torch import Tensor

from tsac_bench.errors import TsacBenchError
from tsac_bench.planning import (
    ExistingFile,
    Interval,
    NoneOr,
    Options,
    PlanningState,
    PlanResult,
    Refused,
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
from tsac_bench.solvers.tsac.features import (
    AGENT_DIM,
    DEPOT_DIM,
    FEATURES,
    TASK_DIM,
    Observation,
    action_choice,
    observe,
    teacher_action,
)
from tsac_bench.solvers.tsac.net import NetConfig, PolicyNet, QNet, StackedHeads, collate

DEFAULT_POLICY = Path(__file__).parent / "policies" / "tsac-default.pt"
#: Where ``solvers/`` sits, so that the shipped policy is named by its repository path.
_PACKAGE_ROOT = Path(__file__).parents[2]
#: The actor, the run's twin critics (``critics``) with the J one unit of their values
#: stands for (``critic_unit``), and the deviation verifier (``verifier``, possibly none).
#: Versions 1 (the actor alone) and 2 (no verifier) were those of policies shipped before.
POLICY_FORMAT = "tsac-bench/policy@3"
#: The margins of ``decode="margin"`` (J): the critics' and the verifier's (None: no
#: verifier check), chosen together on generated instances apart from the evaluation's
#: (seeds 900000..900299, reports/archive/tsac-learnability.md, "A verifier of the critics'
#: deviations"); before the verifier the critics' alone, 0.75.
MARGIN = 0.5
VERIFY: float | None = 0.25
#: How the games after a plan call's first decode (``restart``). The default is chosen on
#: validation instances apart from paper-mc, under equal budgets (docs/tsac.md, "Under a
#: budget").
RESTARTS = ("margin", "sample")
RESTART = "margin"


class PolicyFileError(TsacBenchError):
    """A policy file that cannot be read or does not fit this version's features."""


@dataclass(frozen=True)
class Policy:
    """A policy file's frozen networks, on the CPU: the actor and, from a run trained on
    rollout labels, its twin critics, whose values times ``critic_unit`` are J, and
    possibly a deviation verifier (``solvers/tsac/verify.py``) in the same unit."""

    actor: PolicyNet
    critics: tuple[QNet, ...] = ()
    critic_unit: float = 1.0
    verifier: QNet | None = None

    @cached_property
    def _critic_pass(self) -> StackedHeads:
        return StackedHeads(self.critics)

    def values(self, obs: Mapping[str, Tensor]) -> Tensor:
        """The pessimistic (minimum) twin-critic value of each action, in J."""
        return self._critic_pass(obs).min(dim=0).values * self.critic_unit

    def verified(self, obs: Mapping[str, Tensor]) -> Tensor:
        """The verifier's value of each action, in J."""
        assert self.verifier is not None
        return self.verifier(obs) * self.critic_unit


def save_policy(actor: PolicyNet, path: Path, meta: dict[str, Any],
                critics: Sequence[QNet] = (), critic_unit: float = 1.0,
                verifier: QNet | None = None) -> None:
    """Write what ``tsac-ocf`` loads: the actor, and the critics to decode by margin (only
    critics whose values are final-J differences, ``critic_unit`` J each) and their
    verifier, if any; no optimiser."""
    path.parent.mkdir(parents=True, exist_ok=True)
    # Plain JSON types only, so that the file loads with weights_only=True.
    meta = json.loads(json.dumps(meta, default=str))
    payload = {"format": POLICY_FORMAT, "config": actor.config.to_dict(),
               "actor": actor.state_dict(), "critics": [q.state_dict() for q in critics],
               "critic_unit": float(critic_unit), "meta": meta}
    if verifier is not None:
        payload["verifier"] = verifier.state_dict()
    torch.save(payload, path)


def policy_meta(path: Path | str = DEFAULT_POLICY) -> dict[str, Any]:
    """What a policy file says of how it was made (its ``meta``)."""
    return torch.load(path, map_location="cpu", weights_only=True).get("meta", {})


def read_policy(path: Path | str = DEFAULT_POLICY) -> Policy:
    """The networks of a policy file, frozen; PolicyFileError (one line) if it is not one
    this version can run."""
    path = Path(path)
    try:
        payload = torch.load(path, map_location="cpu", weights_only=True)
    # torch's restricted unpickler raises many kinds of error for a file that is not a
    # torch archive (KeyError, UnpicklingError, EOFError...): all mean "not a policy".
    except Exception as exc:
        raise PolicyFileError(f"{path}: cannot read the policy ({type(exc).__name__}: "
                              f"{exc})") from None
    if not isinstance(payload, dict) or payload.get("format") != POLICY_FORMAT:
        raise PolicyFileError(f"{path}: format: expected {POLICY_FORMAT!r}")
    config = NetConfig(**payload["config"])
    if config.features != FEATURES:
        raise PolicyFileError(f"{path}: config.features: feature set {config.features}, this "
                              f"version builds {FEATURES}: retrain the policy")
    shape = (AGENT_DIM, TASK_DIM, DEPOT_DIM, True)
    if (config.agent_dim, config.task_dim, config.depot_dim, config.pass_action) != shape:
        raise PolicyFileError(
            f"{path}: config: the network's inputs (agent {config.agent_dim}, task "
            f"{config.task_dim}, depot {config.depot_dim}, pass {config.pass_action}) do not "
            f"fit this version's {shape}: retrain the policy")
    actor = _frozen(PolicyNet(config), payload["actor"], path, "actor")
    critics = tuple(_frozen(QNet(config), state, path, "critics")
                    for state in payload["critics"])
    verifier = (_frozen(QNet(config), payload["verifier"], path, "verifier")
                if "verifier" in payload else None)
    return Policy(actor, critics, float(payload["critic_unit"]), verifier)


def _frozen(network: PolicyNet | QNet, state: dict[str, Tensor], path: Path,
            field: str) -> Any:
    try:
        network.load_state_dict(state)
    except RuntimeError as exc:
        raise PolicyFileError(f"{path}: {field}: does not fit this network ({exc})") from None
    network.eval()
    network.requires_grad_(False)
    return network


def load_policy(path: Path | str = DEFAULT_POLICY) -> PolicyNet:
    """The frozen actor of a policy file, on the CPU, in evaluation mode."""
    return read_policy(path).actor


@cache
def _cached_policy(path: str) -> Policy:
    return read_policy(path)


def policy_at(path: str | None) -> Policy:
    """The policy a ``policy`` setting names (None: the shipped one), read once."""
    return _cached_policy(str(Path(path) if path else DEFAULT_POLICY))


def margin_problem(policy: Policy) -> str | None:
    """Why ``decode="margin"`` cannot run this policy, or None if it can."""
    if len(policy.critics) < 2:
        return "its file carries no twin critics"
    return None


class PolicyFile(ExistingFile):
    """A policy file ``tsac-ocf`` can run (read here, so that a bad one is a bad setting)."""

    def convert(self, value: Any) -> Any:
        path = super().convert(value)
        try:
            policy_at(path)
        except PolicyFileError as exc:
            raise Refused(str(exc)) from None
        return path

    def describe(self, context: Mapping[str, Any]) -> str:
        return "the path of a tsac-ocf policy file"


class ShippedOr(NoneOr):
    """None, which stands for the shipped policy, or a policy file ``inner`` admits."""

    def describe(self, context: Mapping[str, Any]) -> str:
        return f"none (the shipped policy) or {self.inner.describe(context)}"

    def describe_default(self, value: Any) -> str:
        if value is None:
            return f"the shipped policy 3 ({DEFAULT_POLICY.relative_to(_PACKAGE_ROOT)})"
        return super().describe_default(value)


class Decoding(Options):
    """``sample``, or ``margin`` with a policy that can run it (``margin_problem``)."""

    def __init__(self) -> None:
        super().__init__("sample", "margin")

    def admits(self, value: Any, context: Mapping[str, Any]) -> bool:
        return value == "sample" or margin_problem(policy_at(context.get("policy"))) is None

    def depends_on(self) -> tuple[str, ...]:
        return ("policy",)

    def describe(self, context: Mapping[str, Any]) -> str:
        problem = (margin_problem(policy_at(context.get("policy")))
                   if context.get("decode") == "margin" else None)
        plain = super().describe(context)
        return (plain if problem is None else f"{plain}; not 'margin' with this policy: "
                f"{problem}; decode=sample runs its actor")


class VerifyMargin(Interval):
    """A number of J, with a policy whose file carries a verifier; any number with
    ``decode=sample``, which ignores it (as ``decode=margin`` ignores ``temperature``)."""

    def __init__(self) -> None:
        super().__init__(float, None, None)

    def admits(self, value: Any, context: Mapping[str, Any]) -> bool:
        return (context.get("decode", "margin") != "margin"
                or policy_at(context.get("policy")).verifier is not None)

    def depends_on(self) -> tuple[str, ...]:
        return ("policy", "decode")

    def describe(self, context: Mapping[str, Any]) -> str:
        if (context.get("decode", "margin") == "margin"
                and policy_at(context.get("policy")).verifier is None):
            return ("a number (J) only with a policy file that carries a verifier (this "
                    "one carries none: verify=none decodes by the critics alone)")
        return "a number (J)"


class PolicySelection:
    """Selection rule: sample m* ~ pi(.|s) (Eq. 21). ``temperature`` divides the logits;
    0 takes the most probable task (lowest index on ties)."""

    def __init__(self, actor: PolicyNet, temperature: float = 1.0) -> None:
        self.actor = actor
        self.temperature = temperature

    def probabilities(self, view: DecisionView) -> np.ndarray:
        """pi(.|s) over the actions (the pass first, then ``view.game.visible``): exactly 0
        outside the valid ones."""
        with torch.inference_mode():
            logits = self.actor(collate([observe(view)]))[0].double()
        if self.temperature > 0:
            return torch.softmax(logits / self.temperature, dim=-1).numpy()
        best = torch.zeros_like(logits)
        best[int(torch.argmax(logits))] = 1.0
        return best.numpy()

    def select(self, view: DecisionView, rng: np.random.Generator) -> int:
        p = self.probabilities(view)
        return action_choice(view, int(rng.choice(len(p), p=p)))


def margin_choice(values: np.ndarray, valid: np.ndarray, teacher: int, margin: float) -> int:
    """The valid action of highest value if it beats the teacher's (a valid action) by more
    than ``margin``, else the teacher's."""
    best = int(np.argmax(np.where(valid, values, -np.inf)))
    return best if values[best] - values[teacher] > margin else teacher


#: Whether a deviation from HOCF's choice is taken: (view, state, the deviation's action,
#: HOCF's action) -> bool.
Confirmation = Callable[[DecisionView, Observation, int, int], bool]


class MarginSelection:
    """Selection rule: HOCF's choice unless ``values`` (a batch of states ->
    one value per action, in J) rates another valid action more than ``margin`` above it
    and ``confirm`` (if given) confirms that deviation."""

    def __init__(self, values: Callable[[Mapping[str, Tensor]], Tensor], margin: float,
                 confirm: Confirmation | None = None) -> None:
        self.values, self.margin, self.confirm = values, margin, confirm

    def select(self, view: DecisionView, rng: np.random.Generator) -> int:
        del rng  # deterministic given the state: the engine's generator orders the AAVs
        state = observe(view)
        with torch.inference_mode():
            values = self.values(collate([state]))[0].double().numpy()
        teacher = teacher_action(state)
        action = margin_choice(values, state.action_mask, teacher, self.margin)
        if action != teacher and self.confirm is not None and not self.confirm(
                view, state, action, teacher):
            action = teacher
        return action_choice(view, action)


class VerifierCheck:
    """Confirms a deviation iff ``verified`` (a batch of states -> one value per action, in
    J) rates it more than ``margin`` above HOCF's action."""

    def __init__(self, verified: Callable[[Mapping[str, Tensor]], Tensor], margin: float
                 ) -> None:
        self.verified, self.margin = verified, margin

    def __call__(self, view: DecisionView, state: Observation, action: int,
                 teacher: int) -> bool:
        del view
        with torch.inference_mode():
            values = self.verified(collate([state]))[0].double()
        return float(values[action] - values[teacher]) > self.margin


class TSACOCFAllocator(OCFAllocator):
    """Settings: ``policy`` (a policy file; default the shipped one), ``decode`` (``margin``:
    HOCF's choice unless the policy's critics back another by ``margin`` J and, with
    ``verify`` a number, its verifier by ``verify`` J; ``sample``: from the actor at
    ``temperature``), ``restart`` (how the games after a plan call's first decode: ``margin``,
    the first game's rule on new AAV orders, or ``sample``, from the actor at
    ``temperature``: best-of-K sampling, where a learned policy's worth under a budget is its
    diversity), and the engine's ``k_max``, ``c_max``, ``init``, ``samples``, ``decisions``."""

    name = "tsac-ocf"
    setting_constraints = declare(**OCFAllocator.setting_constraints,
                                  policy=ShippedOr(PolicyFile()),
                                  decode=Decoding(),
                                  temperature=Interval(float, 0, None),
                                  margin=Interval(float, 0, None),
                                  verify=NoneOr(VerifyMargin()),
                                  restart=Options(*RESTARTS))

    def __init__(self, policy: str | None = None, decode: str = "margin",
                 temperature: float = 1.0, margin: float = MARGIN,
                 verify: float | None = VERIFY, restart: str = RESTART, k_max: int = K_MAX,
                 c_max: int = C_MAX, init: str = INIT, samples: int | None = SAMPLES,
                 decisions: int | None = None) -> None:
        super().__init__(k_max=k_max, c_max=c_max, init=init, samples=samples,
                         decisions=decisions)
        self.policy = policy
        self.decode = decode
        self.temperature = temperature
        self.margin = margin
        self.verify = verify
        self.restart = restart

    def rule(self, state: PlanningState) -> SelectionRule:
        del state
        policy = policy_at(self.policy)
        if self.decode == "margin":
            # Reached unchecked only by a caller that built the allocator without make_allocator.
            problem = margin_problem(policy)
            if problem is not None:
                raise PolicyFileError(f"{self.policy or DEFAULT_POLICY}: decode=margin: {problem}")
            if self.verify is not None and policy.verifier is None:
                raise PolicyFileError(f"{self.policy or DEFAULT_POLICY}: verify: its file "
                                      f"carries no verifier")
            confirm = (None if self.verify is None
                       else VerifierCheck(policy.verified, self.verify))
            return MarginSelection(policy.values, self.margin, confirm)
        return PolicySelection(policy.actor, self.temperature)

    def restart_rule(self, state: PlanningState) -> SelectionRule:
        if self.restart == "sample":
            return PolicySelection(policy_at(self.policy).actor, self.temperature)
        return self.rule(state)

    def plan(self, state: PlanningState, *, seed: int = 0,
             time_limit: float | None = None) -> PlanResult:
        # One small state at a time runs fastest on one thread; restored for the caller.
        threads = torch.get_num_threads()
        torch.set_num_threads(1)
        try:
            return super().plan(state, seed=seed, time_limit=time_limit)
        finally:
            torch.set_num_threads(threads)
