"""The overlapping coalition formation (OCF) game of the paper's Sec. III-C (Algorithm 1).

Players are the AAVs; a coalition is the set of AAVs that serve a task, each with its own
amount, and an AAV belongs to as many coalitions as its route has task visits (overlap). The
coalition structure lives on top of the evaluator's ``PlanState`` (routes plus per-task
contributions), so every price is the exact change of J.

One *decision* (an iteration k of Algorithm 1):

1. AAV n, whose turn it is, sees the structure as the AAVs before it left it; the residual
   demand of task m it sees is Eq. 19: R_m minus what the *other* AAVs bring on time.
2. Its *candidates* are its valid tasks (``valid_tasks``): visible tasks it could join
   (residual >= 1, reachable by the deadline and within range from where its free route
   begins: the validity mask) and its own removable tasks (visits at or after its first free
   position), less the tasks already rejected for it under the present structure.
3. The selection rule (``SelectionRule``: where ROCF, HOCF and TSAC-OCF differ) picks m*.
4. m* not in its route: ADD, join m*'s coalition at the best position, with or without a depot
   visit before it, with as much of the residual as fits (``insertion.best_insertion``).
   m* in its route: REMOVE, leave the coalition (``insertion.removal_route``).
5. The move is accepted iff J strictly decreases (Eq. 22) and the resulting structure is not
   in the tabu list; every structure the game passes through enters the tabu list.

Decisions run in rounds; each round activates the AAVs in a fresh random permutation
(Eq. 18). The game stops after ``k_max`` decisions, ``c_max`` consecutive rejections, at the
time limit, or when a whole round finds no AAV with a candidate: then no AAV has a single
ADD or REMOVE that lowers J and is not tabu, i.e. the structure is Nash-stable.

Why the rejected-candidate memory is exact: a move's outcome depends only on the deciding
AAV's route and on the coalitions of the tasks its route touches (and on the tabu list, which
only grows). After an accepted move by AAV n, the memory is cleared for n and for every AAV
in a coalition whose contributions changed, and those tasks are forgotten for everyone else;
every other rejected (AAV, task) pair would be rejected again, so it is not re-evaluated.
"""

from __future__ import annotations

import copy
import itertools
import math
import time
from abc import ABC, abstractmethod
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from functools import cached_property
from types import MappingProxyType
from typing import Any, ClassVar, NamedTuple, Protocol

import numpy as np

from tsac_bench.model import Route
from tsac_bench.model.evaluator import Contribution, PlanState, Proposal
from tsac_bench.planning import (
    Anchor,
    Interval,
    NoneOr,
    Options,
    PlanningState,
    PlanResult,
    Settings,
    declare,
)
from tsac_bench.planning.budget import ANYTIME, IncumbentTrace, WorkStop, require_a_stop
from tsac_bench.planning.insertion import best_insertion, removal_route

#: A move must lower J by more than this to count as a strict decrease (Eq. 22): J is a sum
#: of floats, and a "gain" below this is rounding, which could otherwise cycle.
STRICT_DECREASE = 1e-9

ADD, REMOVE, PASS_OP = "add", "remove", "pass"
#: What a selection rule returns to pass its turn (the depot action of M_t U D): the AAV
#: does nothing this turn. Allowed once per AAV per coalition structure (``can_pass``), so
#: passes cannot stall the game and "stable" keeps its meaning (docs/methods.md).
PASS = -1


class Move(NamedTuple):
    op: str  # ADD or REMOVE
    aav: int
    task: int
    proposal: Proposal


class Decision(NamedTuple):
    """One iteration of Algorithm 1 as recorded: ``J`` after it (unchanged when rejected)."""

    k: int
    aav: int
    task: int
    op: str
    accepted: bool
    J: float


def structure_key(n: int, route: Route, n_tasks: int) -> int:
    """AAV n's part of the coalition-structure key: its (task, amount) memberships. The
    whole structure's key is the XOR over AAVs, so one AAV's change updates it in O(route)."""
    key = 0
    for v in route:
        if v.node < n_tasks:
            key ^= hash((n, v.node, v.amount))
    return key


class CoalitionGame:
    """The coalition structure of one planning moment and the ADD/REMOVE moves on it."""

    def __init__(self, state: PlanningState, routes: Sequence[Route] | None = None) -> None:
        self.state = state
        self.instance = instance = state.instance
        self.evaluator = state.evaluator()
        self.plan: PlanState = self.evaluator.state(
            routes if routes is not None else state.base_routes())
        self.n_aavs, self.n_tasks = instance.n_aavs, instance.n_tasks
        self.first_free = [state.first_free(n) for n in range(self.n_aavs)]
        self.anchors = [state.anchor(n) for n in range(self.n_aavs)]
        self.visible = sorted(state.visible)
        self.visible_nodes = np.asarray(self.visible, dtype=int)
        # Per visible task, in ``visible`` order: its position, demand and deadline, once
        # per game rather than once per decision.
        self.visible_index = {m: i for i, m in enumerate(self.visible)}
        tasks = [instance.tasks[m] for m in self.visible]
        self.visible_demand = np.array([t.demand for t in tasks], dtype=int)
        self.visible_t_end = np.array([t.t_end for t in tasks], dtype=float)
        self._latest_on_time = [t.latest_on_time for t in instance.tasks]
        self._speed = [a.speed for a in instance.aavs]
        self._range = [a.max_range for a in instance.aavs]
        self._aav_keys = [structure_key(n, t.route, self.n_tasks)
                          for n, t in enumerate(self.plan.traces)]
        self.key = 0
        for k in self._aav_keys:
            self.key ^= k
        self.tabu: set[int] = {self.key}
        self.rejected: list[set[int]] = [set() for _ in range(self.n_aavs)]
        self.passed: set[int] = set()  # AAVs that passed under the present structure
        self._proximity: tuple[int, Any] | None = None  # route_proximity's, per structure
        self._residuals: tuple[tuple[int, int], np.ndarray] | None = None  # per (AAV, structure)
        # route_proximity's rows per AAV with the trace they were computed on; the list is
        # replaced, never changed in place, so that a fork may share it.
        self._proximity_rows: list[tuple[Any, np.ndarray, np.ndarray] | None] = (
            [None] * self.n_aavs)
        self.trajectory: list[float] = [self.plan.cost]
        # perf_counter time of each trajectory entry: an anytime call's incumbent trace.
        self.trajectory_at: list[float] = [time.perf_counter()]
        self.decisions: list[Decision] = []
        self.tabu_hits = 0

    def fork(self) -> CoalitionGame:
        """An independent copy of the game as it stands (structure, tabu list, candidate
        memory, passes, history): what a look-ahead plays on."""
        other = copy.copy(self)
        other.plan = self.evaluator.state(self.plan.routes)
        other._aav_keys = list(self._aav_keys)
        other.tabu = set(self.tabu)
        other.rejected = [set(r) for r in self.rejected]
        other.passed = set(self.passed)
        other.trajectory = list(self.trajectory)
        other.trajectory_at = list(self.trajectory_at)
        other.decisions = list(self.decisions)
        return other

    # --- what AAV n sees ---------------------------------------------------------------
    @property
    def cost(self) -> float:
        return self.plan.cost

    def route(self, n: int) -> Route:
        return self.plan.traces[n].route

    def anchor(self, n: int) -> Anchor:
        """Where AAV n's free route begins and when it can leave (fixed by its prefix)."""
        return self.anchors[n]

    def residuals(self, n: int) -> np.ndarray:
        """Eq. 19 for AAV n over the visible tasks (``visible`` order): each task's demand
        less what the AAVs other than n bring on time, at least 0. Kept for the last
        (AAV, structure) asked: the validity mask, the rule and the learned policy's state all
        need it."""
        key = (n, len(self.trajectory))
        if self._residuals is not None and self._residuals[0] == key:
            return self._residuals[1]
        on_time = self.plan.on_time
        covered = np.array([on_time[m] for m in self.visible], dtype=int)
        # Only the tasks n serves differ from the plan's on-time sums.
        for m, _ in self.own_visits(n):
            covered[self.visible_index[m]] = self.plan.covered(m, exclude=n)
        residuals = np.maximum(0, self.visible_demand - covered)
        residuals.flags.writeable = False  # shared by every caller until the next move
        self._residuals = (key, residuals)
        return residuals

    def residual(self, n: int, m: int) -> int:
        """``residuals(n)`` of visible task m."""
        return int(self.residuals(n)[self.visible_index[m]])

    def own_visits(self, n: int) -> list[tuple[int, Contribution]]:
        """AAV n's contribution to each visible task it serves."""
        members, index = self.plan.members, self.visible_index
        return [(m, members[m][n]) for m in dict(self.plan.traces[n].contributions)
                if m in index]

    def earliest_arrivals(self, n: int, tasks: np.ndarray) -> np.ndarray:
        """A lower bound on AAV n's arrival at each of ``tasks`` wherever it is inserted
        (triangle inequality: every later position is reached via the anchor)."""
        anchor = self.anchors[n]
        return anchor.time + self.instance.dist[anchor.node, tasks] / self._speed[n]

    def removable(self, n: int) -> list[int]:
        """AAV n's task visits at or after its first free position."""
        return [v.node for v in self.route(n)[self.first_free[n]:] if v.node < self.n_tasks]

    def valid_tasks(self, n: int) -> list[int]:
        """The validity mask: tasks AAV n could join (residual left, reachable on time and
        within range from its anchor) plus its own removable tasks, ascending."""
        own = {v.node for v in self.route(n)}
        removable = set(self.removable(n))
        valid = []
        for m, reachable, residual in zip(self.visible, self._reachable_rows[n],
                                          self.residuals(n).tolist(), strict=True):
            if m in own:
                if m in removable:
                    valid.append(m)
            elif reachable and residual >= 1:
                valid.append(m)
        return valid

    @cached_property
    def reachable(self) -> np.ndarray:
        """Per (AAV, visible task): whether the AAV reaches the task on time and within range
        from its anchor. Anchors are fixed for a game, so this is computed once."""
        visible = self.visible_nodes
        legs = self.instance.dist[np.ix_([a.node for a in self.anchors], visible)]
        range_left = np.array([r - a.flown for r, a in zip(self._range, self.anchors,
                                                           strict=True)])[:, None]
        arrivals = np.array([self.earliest_arrivals(n, visible) for n in range(self.n_aavs)])
        latest = np.array(self._latest_on_time)[visible]
        return (legs <= range_left) & (arrivals <= latest)

    @cached_property
    def _reachable_rows(self) -> list[list[bool]]:
        return self.reachable.tolist()

    def candidates(self, n: int) -> tuple[int, ...]:
        rejected = self.rejected[n]
        return tuple(m for m in self.valid_tasks(n) if m not in rejected)

    def route_proximity(self) -> tuple[np.ndarray, np.ndarray]:
        """Per (AAV, visible task), the distance from the nearest node of its free route
        (anchor included) and its spare capacity there (capacity less the load it carries
        when it leaves that node). It depends on the structure only, which changes exactly
        when a move is accepted, so it is computed once per accepted move (most decisions
        are rejections), and then only for the AAV whose route the move changed."""
        accepted = len(self.trajectory)
        if self._proximity is not None and self._proximity[0] == accepted:
            return self._proximity[1]
        instance, visible = self.instance, self.visible_nodes
        columns = np.arange(len(visible))
        rows = list(self._proximity_rows)
        for k, anchor in enumerate(self.anchors):
            trace = self.plan.traces[k]
            if rows[k] is not None and rows[k][0] is trace:
                continue
            ff = self.first_free[k]
            nodes = [anchor.node, *(v.node for v in trace.route[ff:])]
            loads = np.array([trace.loads[ff - 1] if ff else 0, *trace.loads[ff:]])
            legs = instance.dist[np.ix_(nodes, visible)]
            closest = legs.argmin(axis=0)
            rows[k] = (trace, legs[closest, columns],
                       instance.aavs[k].capacity - loads[closest])
        self._proximity_rows = rows
        near = np.array([row[1] for row in rows], dtype=float).reshape(self.n_aavs, len(visible))
        spare = np.array([row[2] for row in rows], dtype=float).reshape(self.n_aavs, len(visible))
        self._proximity = (accepted, (near, spare))
        return near, spare

    # --- moves -------------------------------------------------------------------------
    def move(self, n: int, m: int) -> Move | None:
        """AAV n's move on task m: REMOVE if m is in its route, ADD otherwise; None when no
        feasible ADD exists (no capacity left where it could go, nothing left to cover)."""
        route = self.route(n)
        ff = self.first_free[n]
        if any(v.node == m for v in route):
            proposal = self.plan.propose(n, removal_route(self.instance, route, m, ff))
            return None if proposal is None else Move(REMOVE, n, m, proposal)
        proposal = best_insertion(self.plan, n, m, ff, self.residual(n, m))
        return None if proposal is None else Move(ADD, n, m, proposal)

    def can_pass(self, n: int) -> bool:
        """A pass is allowed unless AAV n already passed under the present structure: a
        second pass could only repeat the first, and if every AAV kept passing the game
        would stop (or loop) on a structure nobody has checked for improving moves."""
        return n not in self.passed

    def pass_turn(self, n: int) -> None:
        """AAV n does nothing this turn: the structure, the tabu list and the candidate
        memory stay as they are; the pass is recorded as a decision."""
        if not self.can_pass(n):
            raise ValueError(f"AAV {n} already passed under the present structure")
        self.passed.add(n)
        self.decisions.append(Decision(len(self.decisions), n, PASS, PASS_OP, False,
                                       self.trajectory[-1]))

    def key_after(self, move: Move) -> int:
        n = move.aav
        return self.key ^ self._aav_keys[n] ^ structure_key(n, move.proposal.trace.route,
                                                            self.n_tasks)

    def acceptable(self, move: Move | None) -> bool:
        """Eq. 22 and the tabu list."""
        if move is None or not move.proposal.delta < -STRICT_DECREASE:
            return False
        if self.key_after(move) in self.tabu:
            self.tabu_hits += 1
            return False
        return True

    def decide(self, n: int, m: int) -> bool:
        """One iteration of Algorithm 1 for AAV n on its chosen task m."""
        move = self.move(n, m)
        accepted = self.acceptable(move)
        if accepted:
            assert move is not None
            self._apply(move)
        else:
            self.rejected[n].add(m)
        op = move.op if move is not None else (REMOVE if m in self.removable(n) else ADD)
        self.decisions.append(Decision(len(self.decisions), n, m, op, accepted,
                                       self.trajectory[-1]))
        return accepted

    def _apply(self, move: Move) -> None:
        n, proposal = move.aav, move.proposal
        old = dict(self.plan.traces[n].contributions)
        new = dict(proposal.trace.contributions)
        changed = {m for m in old.keys() | new.keys() if old.get(m) != new.get(m)}
        self.key = self.key_after(move)
        self._aav_keys[n] = structure_key(n, proposal.trace.route, self.n_tasks)
        self.plan.apply(proposal)
        self.tabu.add(self.key)
        self.trajectory.append(self.plan.cost)
        self.trajectory_at.append(time.perf_counter())
        # Forget the rejections whose outcome this move may have changed (module docstring).
        self.rejected[n].clear()
        self.passed.clear()
        stale = {k for m in changed for k in self.plan.members[m]}
        for k in range(self.n_aavs):
            if k in stale:
                self.rejected[k].clear()
            else:
                self.rejected[k] -= changed

    # --- Algorithm 1 -------------------------------------------------------------------
    def run(self, rule: SelectionRule, rng: np.random.Generator, *, k_max: int, c_max: int,
            stop: WorkStop | None = None) -> str:
        """Play until a stop condition; returns which one: "stable", "k_max", "c_max", or
        ``stop``'s reason ("time-limit", "work": a plan call's time or decision budget,
        each decision, a pass included, one unit of its work). A pass counts as a decision
        (``k_max``) but not as a rejection.

        ``rng`` draws the AAV orders; the rule draws from a stream spawned from it, which
        does not advance it: the orders of a seed are the same whichever rule plays, so
        methods compared on a seed differ by their choices, not by their orders (a rule that
        drew from the order stream changed every later order, and J varies by tens of per
        cent over orders)."""
        choices = rng.spawn(1)[0]
        consecutive = 0
        while True:
            decided = False
            for n in rng.permutation(self.n_aavs).tolist():
                if len(self.decisions) >= k_max:
                    return "k_max"
                if consecutive >= c_max:
                    return "c_max"
                reason = None if stop is None else stop.reached()
                if reason is not None:
                    return reason
                candidates = self.candidates(n)
                if not candidates:
                    continue
                decided = True
                if stop is not None:
                    stop.done()
                view = DecisionView(self, n, candidates)
                m = rule.select(view, choices)
                if m == PASS and view.can_pass:
                    self.pass_turn(n)
                    continue
                if m not in candidates:
                    raise ValueError(f"{type(rule).__name__} chose task {m}, which is not "
                                     f"a candidate of AAV {n}")
                consecutive = 0 if self.decide(n, m) else consecutive + 1
            if not decided:
                return "stable"


# --- the decision interface of selection rules ----------------------------------------
@dataclass(frozen=True)
class DecisionView:
    """What a selection rule sees: the game (its structure, the visible tasks, the
    depots), the deciding AAV and its candidate tasks, with that AAV's Eq. 19 residuals."""

    game: CoalitionGame
    aav: int
    candidates: tuple[int, ...]

    @property
    def anchor(self) -> Anchor:
        return self.game.anchor(self.aav)

    @property
    def can_pass(self) -> bool:
        """Whether ``PASS`` is a valid choice (``CoalitionGame.can_pass``)."""
        return self.game.can_pass(self.aav)

    def is_member(self, m: int) -> bool:
        return self.aav in self.game.plan.members[m]

    def residuals(self) -> np.ndarray:
        """``CoalitionGame.residuals`` of the deciding AAV (``game.visible`` order)."""
        return self.game.residuals(self.aav)

    def residual(self, m: int) -> int:
        return self.game.residual(self.aav, m)

    def earliest_arrivals(self, tasks: np.ndarray) -> np.ndarray:
        return self.game.earliest_arrivals(self.aav, tasks)


class SelectionRule(Protocol):
    """Picks the task the deciding AAV acts on, one of ``view.candidates``, or ``PASS``
    when ``view.can_pass``; ``rng`` is the game's stream for the rule's own draws (not the
    one of the AAV orders, ``CoalitionGame.run``)."""

    def select(self, view: DecisionView, rng: np.random.Generator) -> int: ...


# --- the allocators built on the game ---------------------------------------------------
INITS = ("empty", "incumbent", "greedy")
#: Defaults shared by every OCF method (hocf, rocf, tsac-ocf), so that their comparisons
#: start from the same structure with the same budget. ``INIT``: measured in dynamic runs
#: (docs/methods.md), "empty" gave every method but rocf a lower mean J than "incumbent".
K_MAX, C_MAX, INIT, SAMPLES = 200_000, 5_000, "empty", 1


def sample_rng(seed: int, sample: int) -> np.random.Generator:
    """The generator of game ``sample`` of a plan call: game 0 uses the call's seed itself
    (so ``samples=1`` is the plain game), the others independent streams derived from it."""
    return np.random.default_rng(seed if sample == 0 else [seed, sample])


class OCFAllocator(Settings, ABC):
    """Common driver of the OCF methods; subclasses supply the selection rule.

    Settings: ``k_max`` (most decisions per game), ``c_max`` (most consecutive
    rejections), ``init``, the structure the game starts from: ``"empty"`` (the committed
    prefixes alone: every plan call forms the coalitions afresh), ``"incumbent"`` (the plan
    in force, without what is no longer visible; the committed prefixes alone at t = 0) or
    ``"greedy"`` (the ``greedy`` method's plan of this planning state); ``samples``, the
    number of games per plan call (None: no cap), each from the same start with its own
    random stream (``sample_rng``): the plan of the game with the lowest J is returned
    (ties: the earlier game); ``decisions``, the most decisions of all games of a plan call
    together (None: no cap), the work count that reproduces a budgeted call.

    An anytime method (``tsac_bench.planning.budget``): under a budget it plays games until
    the budget is spent. A time limit is shared by the games and checked before each
    decision, so the game it interrupts returns the structure it has reached (every
    structure of a game is a plan); the first game always starts."""

    name: ClassVar[str]
    setting_constraints = declare(k_max=Interval(int, 0, None), c_max=Interval(int, 1, None),
                                  init=Options(*INITS),
                                  samples=NoneOr(Interval(int, 1, None)),
                                  decisions=NoneOr(Interval(int, 0, None)))
    budget_use: ClassVar[str] = ANYTIME
    unbounded_settings: ClassVar[Mapping[str, Any]] = MappingProxyType({"samples": None})
    work_setting: ClassVar[str] = "decisions"
    work_unit: ClassVar[str] = "decisions"

    def __init__(self, k_max: int = K_MAX, c_max: int = C_MAX, init: str = INIT,
                 samples: int | None = SAMPLES, decisions: int | None = None) -> None:
        self.k_max = k_max
        self.c_max = c_max
        self.init = init
        self.samples = samples
        self.decisions = decisions

    def initial_routes(self, state: PlanningState) -> tuple[Route, ...]:
        if self.init == "incumbent":
            return state.warm_routes()
        if self.init == "greedy":
            from tsac_bench.solvers.greedy import GreedyAllocator

            return GreedyAllocator().plan(state).routes
        return state.base_routes()

    @abstractmethod
    def rule(self, state: PlanningState) -> SelectionRule:
        """The selection rule of a plan call's first game."""

    def restart_rule(self, state: PlanningState) -> SelectionRule:
        """The selection rule of the games after the first (by default the same rule: the
        games differ by their AAV orders and the rule's own draws)."""
        return self.rule(state)

    def plan(self, state: PlanningState, *, seed: int = 0,
             time_limit: float | None = None) -> PlanResult:
        require_a_stop(self.name, "samples", time_limit, self.samples, self.decisions)
        stop = WorkStop(time_limit, self.decisions)
        trace = IncumbentTrace(stop.began)
        start = self.initial_routes(state)
        first_rule = self.rule(state)
        later_rule = None
        best: tuple[CoalitionGame, str] | None = None
        sample_costs: list[float] = []
        games = itertools.count() if self.samples is None else range(self.samples)
        for sample in games:
            if best is not None and stop.reached() is not None:
                break
            if sample == 1:
                later_rule = self.restart_rule(state)
            game = CoalitionGame(state, start)
            ended = game.run(first_rule if sample == 0 else later_rule, sample_rng(seed, sample),
                             k_max=self.k_max, c_max=self.c_max, stop=stop)
            sample_costs.append(game.cost)
            for J, at in zip(game.trajectory, game.trajectory_at, strict=True):
                trace.offer(J, at)
            if best is None or game.cost < best[0].cost:
                best = (game, ended)
            # A game without a decision found no AAV with a candidate at the start, which
            # holds in any order: every later game would be the same.
            if self.samples is None and not game.decisions:
                break
        assert best is not None
        game, ended = best
        accepted = len(game.trajectory) - 1
        stats: dict[str, Any] = {
            "stop": ended,
            "decisions": len(game.decisions),
            "accepted": accepted,
            "rejected": sum(1 for d in game.decisions if d.op != PASS_OP) - accepted,
            "passes": sum(1 for d in game.decisions if d.op == PASS_OP),
            "tabu_hits": game.tabu_hits,
            "J_initial": game.trajectory[0],
            "trajectory": game.trajectory,
            "sample_J": sample_costs,
            "sample": sample_costs.index(game.cost),
            "games": len(sample_costs),
            "work": stop.work,
            "trace": trace.points,
            "seconds": stop.elapsed(),
        }
        cost = game.cost
        assert math.isfinite(cost)
        return PlanResult(game.plan.routes, stats, cost)
