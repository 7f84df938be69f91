"""The learned policy's state of one decision of the OCF game (Eq. 20) and its actions.

The state is built here from what the engine exposes to every selection rule (the game, its
plan, the deciding AAV's view): the deciding AAV, one row per visible task, one per depot,
scaled to O(1), with the validity mask. The actions are the pass (action 0: the depot action
of M_t U D, "do nothing this turn") followed by the visible tasks (action i = task row
i - 1). A policy file names the version of this state it was trained on (``FEATURES``);
``policy.read_policy`` refuses any other. Columns: docs/tsac.md, "The state and the actions".
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np

from tsac_bench.planning import PlanningState
from tsac_bench.solvers.ocf.engine import PASS, CoalitionGame, DecisionView

#: The version of the state and action space built here (a policy file's
#: ``config.features``). Versions 1 and 2 (no teacher columns; 1 also without competition
#: columns and the pass) were those of policies never shipped or shipped before policy 3.
FEATURES = 3

#: The deciding AAV: where its free route begins (its anchor) and when, its constants, how
#: many free visits it has and the load it carries at the anchor (share of its capacity).
AGENT_FEATURES = ("x_km", "y_km", "time", "speed", "capacity", "range_left_km", "alpha",
                  "lam", "free_visits", "delivery_load", "pickup_load")
#: Per visible task, as the deciding AAV sees it: the residual demand is Eq. 19's (the
#: demand less what the *other* AAVs bring on time); coalition size and covered kg are the
#: coalition feedback; slack is t_end less the earliest arrival from the anchor.
TASK_FEATURES = ("x_km", "y_km", "is_delivery", "demand", "residual", "t_start", "t_end",
                 "release", "coalition_size", "covered", "member", "own_amount",
                 "distance_km", "slack", "candidate")
#: Derived from those: the task's position relative to the anchor; the share of its demand
#: the AAV could still cover alone, min(residual, capacity) / demand; the distance from the
#: nearest node of the AAV's free route (anchor included), which prices an insertion better
#: than the distance from the anchor; whether the AAV's own visit is late.
EXTRA_TASK_FEATURES = ("dx", "dy", "coverable_share", "route_distance", "own_late")
#: The other AAVs as the deciding AAV sees them. "Nearest other" is the other AAV whose free
#: route (anchor included) passes nearest to the task; its spare capacity is its capacity
#: less the load it carries when it leaves that node (kg); reach is the share of the other
#: AAVs that could arrive on time and within range from their anchors; a detour cost is the
#: operating cost (w3 C_op) of flying to the task and back from the nearest node of a free
#: route, the cheapest over the other AAVs and the deciding AAV's own. Estimates, not
#: insertions: 31 x 80 exact insertions per decision would cost more than the whole game.
COMPETITION_FEATURES = ("other_distance_km", "other_spare", "other_reach",
                        "other_detour_cost", "own_detour_cost")
#: HOCF's priority of the task for the deciding AAV (its default weights, divided by their
#: sum, so in [0, 1]) and whether the task is HOCF's own choice in this state. Why: every
#: policy trained without them, re-deriving HOCF's rule from raw columns, imitated it only
#: approximately, and that error was as large as what the learning signal added; with the
#: teacher's choice in the state, following HOCF is one weight, and what the critics learn
#: is where to deviate from it.
TEACHER_FEATURES = ("teacher_priority", "teacher_choice")
DEPOT_FEATURES = ("x_km", "y_km", "distance_km")

#: Divisors that bring the raw columns to O(1) (kg by the heavy type's 30 kg capacity, km
#: by the 10 km area, the TABLE 1 maxima for the AAV's constants; times are already shares
#: of the horizon). Detour costs are w3 C_op in J's units: a 2 km round trip of the paper's
#: AAV types costs 0.01-0.03, so 0.05 brings them to O(1).
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
COMPETITION_SCALE: Mapping[str, float] = {
    "other_distance_km": 10.0, "other_spare": 30.0, "other_reach": 1.0,
    "other_detour_cost": 0.05, "own_detour_cost": 0.05,
}
DEPOT_SCALE: Mapping[str, float] = {"x_km": 10.0, "y_km": 10.0, "distance_km": 10.0}


def _divisor(names: Sequence[str], table: Mapping[str, float]) -> np.ndarray:
    return np.array([table[name] for name in names], dtype=np.float32)


_AGENT_DIVISOR = _divisor(AGENT_FEATURES, AGENT_SCALE)
_TASK_DIVISOR = _divisor(TASK_FEATURES, TASK_SCALE)
_COMPETITION_DIVISOR = _divisor(COMPETITION_FEATURES, COMPETITION_SCALE)
_DEPOT_DIVISOR = _divisor(DEPOT_FEATURES, DEPOT_SCALE)
AGENT_DIM = len(AGENT_FEATURES)
TASK_DIM = (len(TASK_FEATURES) + len(EXTRA_TASK_FEATURES) + len(COMPETITION_FEATURES)
            + len(TEACHER_FEATURES))
DEPOT_DIM = len(DEPOT_FEATURES)
#: Where the teacher-choice column sits in a task row, counted from its end (the teacher
#: columns close the row).
TEACHER_CHOICE_COLUMN = TEACHER_FEATURES.index("teacher_choice") - len(TEACHER_FEATURES)


@dataclass(frozen=True)
class Observation:
    """Eq. 20's state, unpadded: rows of ``tasks`` follow ``game.visible``; ``pass_token``
    is the depot row nearest to the anchor (where doing nothing leaves the AAV) and
    ``action_mask[0]`` says whether it may pass."""

    agent: np.ndarray  # (AGENT_DIM,)
    tasks: np.ndarray  # (M_t, TASK_DIM)
    depots: np.ndarray  # (K, DEPOT_DIM)
    action_mask: np.ndarray  # (1 + M_t,) bool: the pass, then the visible tasks
    pass_token: np.ndarray  # (DEPOT_DIM,)


def agent_columns(view: DecisionView) -> np.ndarray:
    """``AGENT_FEATURES`` of the deciding AAV, unscaled."""
    game, n = view.game, view.aav
    aav, instance = game.instance.aavs[n], game.instance
    anchor = view.anchor
    x, y = instance.positions[anchor.node]
    ff = game.first_free[n]
    trace = game.plan.traces[n]
    d, p = (trace.delivery_load[ff - 1], trace.pickup_load[ff - 1]) if ff else (0, 0)
    return np.array([x / 1000, y / 1000, anchor.time / instance.horizon, aav.speed,
                     aav.capacity, (aav.max_range - anchor.flown) / 1000, aav.alpha,
                     aav.lam, len(trace.route) - ff, d / aav.capacity,
                     p / aav.capacity], dtype=float)


#: The columns of ``task_columns`` that depend on the visible tasks alone, for the last
#: planning state asked (every game of a plan call, and every fork, shares its state): they
#: are computed once per plan call rather than once per decision.
_fixed: tuple[PlanningState, np.ndarray] | None = None


def _task_only_columns(game: CoalitionGame) -> np.ndarray:
    global _fixed
    if _fixed is None or _fixed[0] is not game.state:
        horizon = game.instance.horizon
        tasks = [game.instance.tasks[m] for m in game.visible]
        _fixed = (game.state, np.array(
            [(t.x / 1000, t.y / 1000, float(t.is_delivery), t.demand, t.t_start / horizon,
              t.t_end / horizon, t.release / horizon) for t in tasks],
            dtype=float).reshape(-1, 7))
    return _fixed[1]


def task_columns(view: DecisionView) -> np.ndarray:
    """One row per visible task (``game.visible`` order), ``TASK_FEATURES``, unscaled."""
    game, n = view.game, view.aav
    index = game.visible_index
    fixed = _task_only_columns(game)
    distance = game.instance.dist[view.anchor.node, game.visible_nodes]
    slack = game.visible_t_end - view.earliest_arrivals(game.visible_nodes)
    members, on_time = game.plan.members, game.plan.on_time
    coalition = np.array([(len(members[m]), on_time[m]) for m in game.visible],
                         dtype=float).reshape(-1, 2)
    member, own_amount, candidate = np.zeros((3, len(game.visible)))
    for m, own in game.own_visits(n):
        member[index[m]], own_amount[index[m]] = 1.0, own.amount
    candidate[[index[m] for m in view.candidates]] = 1.0
    return np.column_stack([fixed[:, :4], view.residuals(), fixed[:, 4:7], coalition,
                            member, own_amount, distance / 1000,
                            slack / game.instance.horizon, candidate]
                           ).reshape(-1, len(TASK_FEATURES))


def competition_columns(view: DecisionView) -> np.ndarray:
    """One row per visible task (``game.visible`` order), ``COMPETITION_FEATURES``,
    unscaled. With no other AAV, the absent competitor is as far as the instance's largest
    distance, with no spare capacity, out of reach, at the deciding AAV's cost rate."""
    game, n = view.game, view.aav
    visible = game.visible_nodes
    dist = game.instance.dist
    # The evaluator's rates (its q_n of Eq. 9 per metre, times w3): the cost rule stays
    # with its owner.
    rate = np.array(game.evaluator.op_per_metre) * game.evaluator.w3
    near, spare = game.route_proximity()
    others = np.array([k for k in range(game.n_aavs) if k != n], dtype=int)
    own_detour = 2.0 * near[n] * rate[n]
    if len(others) == 0:
        absent = np.full(len(visible), float(dist.max()))
        return np.column_stack([absent / 1000, np.zeros(len(visible)),
                                np.zeros(len(visible)), 2.0 * absent * rate[n],
                                own_detour]).reshape(-1, len(COMPETITION_FEATURES))
    near_others = near[others]
    nearest = others[near_others.argmin(axis=0)]
    spare_nearest = spare[nearest, np.arange(len(visible))]
    reach = game.reachable[others]
    return np.column_stack([
        near_others.min(axis=0) / 1000, spare_nearest, reach.mean(axis=0),
        (2.0 * near_others * rate[others][:, None]).min(axis=0), own_detour,
    ]).reshape(-1, len(COMPETITION_FEATURES))


def teacher_columns(view: DecisionView) -> np.ndarray:
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


def depot_columns(view: DecisionView) -> np.ndarray:
    """One row per depot, ``DEPOT_FEATURES``, unscaled."""
    instance = view.game.instance
    row = instance.dist_rows[view.anchor.node]
    return np.array([(d.x / 1000, d.y / 1000, row[k] / 1000) for k, d in
                     zip(instance.depot_nodes, instance.depots, strict=True)],
                    dtype=float).reshape(-1, len(DEPOT_FEATURES))


def observe(view: DecisionView) -> Observation:
    """The deciding AAV's state, scaled, with its validity mask."""
    game, n = view.game, view.aav
    agent_raw = agent_columns(view)
    tasks_raw = task_columns(view)
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
    tasks = np.concatenate([tasks, relative, coverable[:, None], route_distance[:, None],
                            own_late[:, None],
                            competition_columns(view) / _COMPETITION_DIVISOR,
                            teacher_columns(view)], axis=1).astype(np.float32)
    depots = (depot_columns(view) / _DEPOT_DIVISOR).astype(np.float32)
    action_mask = np.zeros(1 + len(game.visible), dtype=bool)
    action_mask[1:] = tasks_raw[:, column["candidate"]] > 0
    # Passing is offered only with a candidate to pass over (a terminal state has none).
    action_mask[0] = bool(view.candidates) and view.can_pass
    pass_token = depots[int(np.argmin(depots[:, DEPOT_FEATURES.index("distance_km")]))]
    return Observation(agent, tasks, depots, action_mask, pass_token)


def action_choice(view: DecisionView, action: int) -> int:
    """The engine's choice (a task or ``PASS``) of an action index."""
    return PASS if action == 0 else view.game.visible[action - 1]


def action_of(view: DecisionView, choice: int) -> int:
    """The action index of an engine choice (a task or ``PASS``)."""
    return 0 if choice == PASS else 1 + view.game.visible_index[choice]


def teacher_action(observation: Observation) -> int:
    """HOCF's choice as an action index (its teacher-choice column; no row set means HOCF
    passes, action 0)."""
    chosen = np.flatnonzero(observation.tasks[:, TEACHER_CHOICE_COLUMN])
    return 0 if len(chosen) == 0 else 1 + int(chosen[0])
