"""The task-selection decision of the OCF game as a Gymnasium environment (paper Sec. III-C).

One episode is one OCF game (Algorithm 1) on one planning moment of a generated instance.
One step is one decision: the AAV whose turn it is observes Eq. 20's state, the action picks
one of its candidate tasks (the validity mask), the engine performs the ADD or REMOVE and
accepts it iff J strictly decreases and the structure is not tabu (Eq. 22). The reward is
minus the change in J divided by ``reward_scale`` (default w1 + w2, the cost of one unserved
task), so it is >= 0 and the undiscounted return of an episode is (J_start - J_end) / scale.

Turns follow the engine: rounds of random AAV permutations (Eq. 18), AAVs without a candidate
skipped; the episode terminates when a whole round finds no AAV with a candidate (the
structure is Nash-stable) and is truncated after ``max_steps`` decisions.

Observations are a Dict of arrays padded to ``max_tasks`` task and ``max_depots`` depot rows,
with masks; ``observe`` gives the unpadded form that the policy uses inside the game.
Features are in docs/tsac.md.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass

import gymnasium as gym
import numpy as np

from tsac_bench.model import Instance
from tsac_bench.model.generator import ScenarioGenerator, parse_scale
from tsac_bench.planning import PlanningState, PlanResult
from tsac_bench.solvers.ocf.engine import (
    AGENT_FEATURES,
    COMPETITION_FEATURES,
    DEPOT_FEATURES,
    PASS,
    TASK_FEATURES,
    CoalitionGame,
    DecisionView,
)

#: Divisors that bring the engine's raw feature columns to O(1) (kg by the heavy type's 30
#: kg capacity, km by the 10 km area, the TABLE 1 maxima for the AAV's constants).
AGENT_SCALE: Mapping[str, float] = {
    "x_km": 10.0, "y_km": 10.0, "time": 1.0, "speed": 20.0, "capacity": 30.0,
    "range_left_km": 60.0, "alpha": 20.0, "lam": 2000.0, "free_visits": 10.0,
    "delivery_load": 1.0, "pickup_load": 1.0,
}
TASK_SCALE: Mapping[str, float] = {
    "x_km": 10.0, "y_km": 10.0, "is_delivery": 1.0, "demand": 30.0, "residual": 30.0,
    "t_start": 1.0, "t_end": 1.0, "release": 1.0, "coalition_size": 4.0, "covered": 30.0,
    "member": 1.0, "own_amount": 30.0, "distance_km": 10.0, "slack": 1.0, "candidate": 1.0,
}
DEPOT_SCALE: Mapping[str, float] = {"x_km": 10.0, "y_km": 10.0, "distance_km": 10.0}
#: Detour costs are w3 C_op in J's units: a 2 km round trip of the paper's AAV types costs
#: 0.01-0.03, so 0.05 brings them to O(1).
COMPETITION_SCALE: Mapping[str, float] = {
    "other_distance_km": 10.0, "other_spare": 30.0, "other_reach": 1.0,
    "other_detour_cost": 0.05, "own_detour_cost": 0.05,
}
#: Derived task columns appended after the engine's: the task's position relative to the
#: deciding AAV's anchor (km / 10); the share of the task's demand the AAV could still cover
#: alone, min(residual, capacity) / demand; the distance from the nearest node of the AAV's
#: free route (its anchor included) to the task (km / 10), which prices an insertion better
#: than the distance from the anchor; whether the AAV's own visit to the task is late.
EXTRA_TASK_FEATURES = ("dx", "dy", "coverable_share", "route_distance", "own_late")
#: Teacher columns (feature set 3): HOCF's priority of the task for the deciding AAV (its
#: default weights, divided by their sum, so in [0, 1]) and whether the task is HOCF's own
#: choice in this state. Why: a network that must re-derive HOCF's rule from raw columns
#: imitates it only approximately, and every policy trained so far sat within a few per
#: cent of HOCF either way: the imitation error was as large as what the learning signal
#: could add. With the teacher's choice in the state, following HOCF is one weight, and
#: what the critic has to learn is where to deviate from it.
TEACHER_FEATURES = ("teacher_priority", "teacher_choice")
#: Where the teacher-choice column sits in a task row, counted from its end (the teacher
#: columns close the row).
TEACHER_CHOICE_COLUMN = TEACHER_FEATURES.index("teacher_choice") - len(TEACHER_FEATURES)


def _scales(names: Sequence[str], table: Mapping[str, float]) -> np.ndarray:
    missing = [name for name in names if name not in table]
    if missing:
        raise KeyError(f"no scale for the engine's feature column(s) {missing}")
    return np.array([table[name] for name in names], dtype=np.float32)


_AGENT_DIVISOR = _scales(AGENT_FEATURES, AGENT_SCALE)
_TASK_DIVISOR = _scales(TASK_FEATURES, TASK_SCALE)
_DEPOT_DIVISOR = _scales(DEPOT_FEATURES, DEPOT_SCALE)
_COMPETITION_DIVISOR = _scales(COMPETITION_FEATURES, COMPETITION_SCALE)
AGENT_DIM = len(AGENT_FEATURES)
TASK_DIM = len(TASK_FEATURES) + len(EXTRA_TASK_FEATURES)
DEPOT_DIM = len(DEPOT_FEATURES)


@dataclass(frozen=True)
class FeatureSet:
    """A versioned state and action space; a policy file names the version it was trained
    on. 1: the task rows of ``TASK_FEATURES`` + ``EXTRA_TASK_FEATURES``, actions = the
    tasks. 2: the task rows also carry ``COMPETITION_FEATURES``, and the pass token leads
    the actions (action 0 = ``PASS``, action i = task row i - 1). 3: as 2, the task rows
    also carrying ``TEACHER_FEATURES``."""

    version: int
    competition: bool
    pass_action: bool
    teacher: bool = False

    @property
    def task_dim(self) -> int:
        return (TASK_DIM + (len(COMPETITION_FEATURES) if self.competition else 0)
                + (len(TEACHER_FEATURES) if self.teacher else 0))

    @property
    def offset(self) -> int:
        """Index of the first task among the actions."""
        return int(self.pass_action)


FEATURE_SETS: Mapping[int, FeatureSet] = {1: FeatureSet(1, False, False),
                                          2: FeatureSet(2, True, True),
                                          3: FeatureSet(3, True, True, teacher=True)}


def teacher_features(view: DecisionView) -> np.ndarray:
    """``TEACHER_FEATURES`` per visible task (HOCF with its default weights)."""
    from tsac_bench.solvers.ocf.hocf import HeuristicSelection, HOCFAllocator

    teacher = HOCFAllocator()
    weights = teacher.w_urgency, teacher.w_distance, teacher.w_residual
    rule = HeuristicSelection(view.game.instance, *weights)
    priority = rule.priorities(view, view.game.visible)
    total = sum(weights)
    # A terminal state (no candidate) has no choice to mark.
    choice = rule.choice(view, priority.__getitem__) if view.candidates else None
    return np.array([(priority[m] / total, float(m == choice)) for m in view.game.visible])


@dataclass(frozen=True)
class Observation:
    """Eq. 20's state, unpadded: rows of ``tasks`` follow ``game.visible``. With a pass
    token (feature set 2) ``pass_token`` is the depot row nearest to the anchor (where
    "doing nothing" leaves the AAV) and ``action_mask[0]`` says whether it may pass."""

    agent: np.ndarray  # (AGENT_DIM,)
    tasks: np.ndarray  # (M_t, task_dim)
    depots: np.ndarray  # (K, DEPOT_DIM)
    action_mask: np.ndarray  # (offset + M_t,) bool: pass (if any), then the candidates
    pass_token: np.ndarray | None = None  # (DEPOT_DIM,)


def action_choice(view: DecisionView, action: int, features: FeatureSet) -> int:
    """The engine's choice (a task or ``PASS``) of an action index."""
    if features.pass_action and action == 0:
        return PASS
    return view.game.visible[action - features.offset]


def teacher_action(observation: Observation) -> int:
    """HOCF's choice as an action index of a feature-set-3 state (its teacher-choice column;
    no row set means HOCF passes, action 0)."""
    chosen = np.flatnonzero(observation.tasks[:, TEACHER_CHOICE_COLUMN])
    return 0 if len(chosen) == 0 else FEATURE_SETS[3].offset + int(chosen[0])


def observe(view: DecisionView, features: FeatureSet = FEATURE_SETS[1]) -> Observation:
    """The deciding AAV's state, scaled, with its validity mask."""
    game, n = view.game, view.aav
    agent_raw = view.agent_features()
    tasks_raw = view.task_features()
    agent = (agent_raw / _AGENT_DIVISOR).astype(np.float32)
    tasks = tasks_raw / _TASK_DIVISOR
    column = {name: i for i, name in enumerate(TASK_FEATURES)}
    here = agent_raw[[AGENT_FEATURES.index("x_km"), AGENT_FEATURES.index("y_km")]]
    relative = (tasks_raw[:, [column["x_km"], column["y_km"]]] - here) / 10.0
    demand = tasks_raw[:, column["demand"]]
    capacity = game.instance.aavs[n].capacity
    coverable = np.minimum(tasks_raw[:, column["residual"]], capacity) / demand
    route_distance = game.route_proximity()[0][n] / 10_000.0
    own_late = np.zeros(len(game.visible))
    for m, own in game.own_visits(n):
        own_late[game.visible_index[m]] = own.arrival > game.instance.tasks[m].latest_on_time
    columns = [tasks, relative, coverable[:, None], route_distance[:, None], own_late[:, None]]
    if features.competition:
        columns.append(view.competition_features() / _COMPETITION_DIVISOR)
    if features.teacher:
        columns.append(teacher_features(view))
    tasks = np.concatenate(columns, axis=1).astype(np.float32)
    depots = (view.depot_features() / _DEPOT_DIVISOR).astype(np.float32)
    action_mask = np.zeros(features.offset + len(game.visible), dtype=bool)
    action_mask[features.offset:] = tasks_raw[:, column["candidate"]] > 0
    pass_token = None
    if features.pass_action:
        # Passing is offered only with a candidate to pass over (a terminal state has none).
        action_mask[0] = bool(view.candidates) and view.can_pass
        pass_token = depots[int(np.argmin(depots[:, DEPOT_FEATURES.index("distance_km")]))]
    return Observation(agent, tasks, depots, action_mask, pass_token)


def pad(observation: Observation, max_tasks: int, max_depots: int) -> dict[str, np.ndarray]:
    """The Gymnasium form: arrays padded with zeros, ``task_mask``/``depot_mask`` marking
    the real rows (1) and ``action_mask`` the valid actions."""
    m, k = len(observation.tasks), len(observation.depots)
    if m > max_tasks or k > max_depots:
        raise ValueError(f"a state with {m} tasks and {k} depots does not fit the "
                         f"observation space ({max_tasks} tasks, {max_depots} depots)")
    offset = int(observation.pass_token is not None)
    tasks = np.zeros((max_tasks, observation.tasks.shape[1]), dtype=np.float32)
    tasks[:m] = observation.tasks
    depots = np.zeros((max_depots, DEPOT_DIM), dtype=np.float32)
    depots[:k] = observation.depots
    task_mask = np.zeros(max_tasks, dtype=np.int8)
    task_mask[:m] = 1
    depot_mask = np.zeros(max_depots, dtype=np.int8)
    depot_mask[:k] = 1
    action_mask = np.zeros(offset + max_tasks, dtype=np.int8)
    action_mask[:offset + m] = observation.action_mask
    padded = {"agent": observation.agent, "tasks": tasks, "task_mask": task_mask,
              "depots": depots, "depot_mask": depot_mask, "action_mask": action_mask}
    if observation.pass_token is not None:
        padded["pass_token"] = observation.pass_token
    return padded


def unpad(padded: Mapping[str, np.ndarray]) -> Observation:
    m = int(np.asarray(padded["task_mask"]).sum())
    k = int(np.asarray(padded["depot_mask"]).sum())
    pass_token = padded.get("pass_token")
    offset = int(pass_token is not None)
    return Observation(np.asarray(padded["agent"], dtype=np.float32),
                       np.asarray(padded["tasks"][:m], dtype=np.float32),
                       np.asarray(padded["depots"][:k], dtype=np.float32),
                       np.asarray(padded["action_mask"][:offset + m], dtype=bool),
                       None if pass_token is None else np.asarray(pass_token, np.float32))


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
        instance: Instance = generator.generate(n, m, int(rng.integers(2**31)))
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
    from tsac_bench.planning import make_allocator
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


class TaskSelectionEnv(gym.Env):
    """Gymnasium environment of the OCF game's task-selection decision (module docstring).

    ``moments`` draws the planning moment of each episode (default: ``generated_moments``
    over ``scales``); ``max_tasks``/``max_depots`` fix the padded observation space;
    ``features`` is the version of ``FEATURE_SETS`` (2: competition columns and the pass
    action 0; a pass earns reward 0)."""

    metadata = {"render_modes": []}  # noqa: RUF012 - Gymnasium's convention

    def __init__(self, scales: Sequence[str] = ("4/10", "8/20"), *, max_tasks: int = 80,
                 max_depots: int = 8, max_steps: int = 400,
                 reward_scale: float | None = None,
                 moments: MomentSampler | None = None, features: int = 1) -> None:
        self.max_tasks, self.max_depots, self.max_steps = max_tasks, max_depots, max_steps
        self.features = FEATURE_SETS[features]
        offset = self.features.offset
        self.reward_scale = reward_scale
        self.scales = tuple(scales)
        self.moments = moments or generated_moments(self.scales)
        box = gym.spaces.Box
        self.observation_space = gym.spaces.Dict({
            "agent": box(-np.inf, np.inf, (AGENT_DIM,), np.float32),
            "tasks": box(-np.inf, np.inf, (max_tasks, self.features.task_dim), np.float32),
            "task_mask": gym.spaces.MultiBinary(max_tasks),
            "depots": box(-np.inf, np.inf, (max_depots, DEPOT_DIM), np.float32),
            "depot_mask": gym.spaces.MultiBinary(max_depots),
            "action_mask": gym.spaces.MultiBinary(offset + max_tasks),
            **({"pass_token": box(-np.inf, np.inf, (DEPOT_DIM,), np.float32)}
               if self.features.pass_action else {}),
        })
        self.action_space = gym.spaces.Discrete(offset + max_tasks)
        self.game: CoalitionGame | None = None

    @property
    def view(self) -> DecisionView:
        """The deciding AAV's view of the game (what a hand-written selection rule reads)."""
        return self._view

    def set_scales(self, scales: Sequence[str]) -> None:
        """Draw the next episodes from ``generated_moments(scales)`` (the curriculum)."""
        if tuple(scales) != self.scales:
            self.scales = tuple(scales)
            self.moments = generated_moments(self.scales)

    # --- the engine's turn order -----------------------------------------------------
    def _next_turn(self) -> bool:
        """Move to the next AAV with a candidate; False when the structure is stable."""
        assert self.game is not None
        while True:
            while self._queue:
                n = self._queue.pop()
                candidates = self.game.candidates(n)
                if candidates:
                    self._view = DecisionView(self.game, n, candidates)
                    self._decided = True
                    return True
            if not self._decided:
                return False
            self._decided = False
            self._queue = self.np_random.permutation(self.game.n_aavs).tolist()[::-1]

    def _observation(self) -> dict[str, np.ndarray]:
        return pad(observe(self._view, self.features), self.max_tasks, self.max_depots)

    def reset(self, *, seed: int | None = None,
              options: dict | None = None) -> tuple[dict[str, np.ndarray], dict]:
        super().reset(seed=seed)
        while True:
            state = self.moments(self.np_random)
            # The engine's default start (init="empty"): the committed prefixes alone.
            self.game = CoalitionGame(state, state.base_routes())
            self._queue, self._decided = [], True
            if self._next_turn():
                break
        self._steps = 0
        self._scale = self.reward_scale or state.instance.unserved_task_cost
        return self._observation(), {"J": self.game.cost, "instance": state.instance.name}

    def step(self, action: int) -> tuple[dict[str, np.ndarray], float, bool, bool, dict]:
        game = self.game
        if game is None:
            raise RuntimeError("call reset() before step()")
        index = int(action)
        mask = observe(self._view, self.features).action_mask
        if not 0 <= index < len(mask) or not mask[index]:
            raise ValueError(f"action {index} is not a valid task for AAV {self._view.aav}")
        before = game.cost
        choice = action_choice(self._view, index, self.features)
        if choice == PASS:
            game.pass_turn(self._view.aav)
            accepted = False
        else:
            accepted = game.decide(self._view.aav, choice)
        reward = (before - game.cost) / self._scale
        self._steps += 1
        terminated = not self._next_turn()
        truncated = not terminated and self._steps >= self.max_steps
        if terminated:
            # The deciding AAV's state with no candidate left: an all-zero action mask.
            self._view = DecisionView(game, self._view.aav, ())
        return (self._observation(), reward, terminated, truncated,
                {"J": game.cost, "accepted": accepted})
