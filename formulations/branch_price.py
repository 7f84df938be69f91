"""Branch-and-price for Problem 1 (``exact-bp``): a route master solved by column generation
in HiGHS (highspy), exact labelling pricing (formulations/pricing.py), best-bound branching.

Master LP (docs/formulations.md, "exact-bp"). A column c of AAV k is a whole schedule from k's
anchor (its committed prefix, then free visits, each trip from a depot, amounts fixed) with a
set S_c of the tasks it "closes", with op_c = w3 * sum of its q_k(m) (Eq. 9, range overrun
included), a_cm its on-time amount at task m and theta_cm = (t_cm - t_start(m)) / T_hor its
arrival term. Variables lambda_c >= 0, covered_m in [0, R_m], Ctime_m >= 0, nobody_m in [0, 1]:
  min  sum op_c lambda_c + sum_m w1 (1 - covered_m / R_m) + w2 Ctime_m
  s.t. sum_{c of k} lambda_c = 1                                 (convexity, per AAV)
       sum_c a_cm lambda_c - covered_m >= 0                      (coverage)
       sum_{c: m in S_c} lambda_c + nobody_m >= 1                (each task has a closer)
       Ctime_m - sum_{c: m in S_c} theta_cm lambda_c - nobody_m >= 0
       Ctime_m - sum_{c of k} theta_cm lambda_c - nobody_m >= 0  (every member's arrival)
       sum_{n in S} coef_n x_nm - covered_m >= -rest  (coalition cover cuts, as in the MILP:
                                                      x_nm = sum of n's columns visiting m)
       Ctime_m - nobody_m - sum_c coef_c lambda_c >= 0  (arrival cuts, separated:
                                                      BranchPrice.separate_arrival_cuts).
At a point with one column per AAV this is J exactly when the closer of each task is its
latest member: covered = min(R, on-time goods); the per-AAV rows make Ctime at least the
latest arrival, the closer no more; nobody = 1 exactly when no column closes m, which costs
C_time = 1. Any other choice of closers only raises the objective, so the integer optimum is
J*. Tasks whose committed visit is late keep C_time = 1 as a constant. The variants of one
schedule with every subset S are the LP of "closer" variables z_cm in [0, lambda_c]; pricing
picks the best S of a new schedule, so its reduced cost is
op_c - dual(conv_k) + sum_m [-dual(cover_m) a_cm + dual(aav_km) theta_cm
                             + min(0, dual(closer_time_m) theta_cm - dual(closer_m))],
the labelling's objective. With a lower bound rc_k on every AAV's least reduced cost (the
exact labelling's, or the ng relaxation's), the Lagrangian bound LP + sum_k min(0, rc_k) is
valid at every iteration.

Branching, in this order, on a fractional
1. visit x_km = sum of lambda over k's columns that visit m (free part; of the most
   fractional few, the one whose children's LPs over the present columns rise most),
2. arc x_k(i, j, mode) (the free arcs of k's columns),
3. amount sum_c a_cm lambda_c of k at m (a_km <= v or >= v + 1).
The "0" and "amount" sides are enforced in pricing (and on the existing columns), the "1"
sides as rows sum lambda >= 1 with an artificial column of prohibitive cost (the node is
infeasible if it stays positive). When all three are integral, every AAV's positive columns
share one route and their average amounts are integral and feasible (the load rows of a
route are an interval matrix), so that plan has J = the LP value and closes the node.
Plans come from the incumbent given, each node's LP (each AAV's column of largest lambda)
and dives (BranchPrice.dive) from the root and some nodes.
"""

from __future__ import annotations

import bisect
import heapq
import itertools
import math
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from tsac_bench.formulations.network import (
    DIRECT,
    aav_network,
    canonical_routes,
    coalition_cover_cuts,
    identical_groups,
    late_committed,
    parse_prefix,
    prefix_arrivals,
)
from tsac_bench.formulations.pricing import (
    Pricer,
    Restrictions,
    TaskPrices,
    anchor_of,
    arrival_cut_terms,
    schedule_route,
)
from tsac_bench.model import Instance, Route, Visit
from tsac_bench.planning import PlanningState

#: Arrival cuts (``BranchPrice.separate_arrival_cuts``): a cut is added where it is violated by
#: more than this (in units of C_time), and a node runs at most ``arrival_cut_rounds`` rounds.
ARRIVAL_CUT_VIOLATION = 1e-4
ARRIVAL_CUT_ROUNDS = 2
#: The sources of an arrival cut's piece besides an AAV (>= 0): the closers, the goods.
CLOSERS, GOODS = -1, -2
#: Strong branching scores a visit candidate until it has this many measured rises per
#: side (its own and its children's), then its pseudo-costs do (BranchPrice.strongest; 0:
#: strong branching always). On 4/10 seed 2 (600 s) strong branching at every node took 252
#: s and left the bound 3.2 % below J*; with 1 the search proved J* in 455-572 s, choosing
#: the branch in 6 s (docs/formulations.md).
STRONG_RELIABILITY = 1
#: Reduced costs above -this count as non-negative (column generation has converged).
RC_TOLERANCE = 1e-9
#: A node is pruned when its bound is within this (relative) of the incumbent.
PRUNE_TOLERANCE = 1e-9
#: A branching quantity within this of an integer counts as integral.
INTEGRALITY = 1e-6
#: HiGHS's ``simplex_strategy`` values.
DUAL_SIMPLEX, PRIMAL_SIMPLEX = 1, 4
#: From this many tasks up, by default, the ng relaxation before the exact labelling (with
#: neighbourhoods of NG_SIZE tasks). At 16/40 it gave the first bound (no exact pricing
#: round finished before), at 8/20 seed 0 a bound where none was found in 600 s; at 4/10
#: (10 tasks) it costs as much per call as the exact labelling (8 of 10 tasks remembered)
#: and is mostly followed by it.
NG_FROM_TASKS = 20
NG_SIZE = 8
#: From this many tasks up, by default, primal simplex re-solves after columns are added
#: (16/40 root: 0.64 s per re-solve against 1.5 s); at 4/10 their other duals changed the
#: tree (seed 4: 120 s -> 153 s).
PRIMAL_FROM_TASKS = 30
#: From this many tasks up, by default, the heuristic rounds price at duals smoothed by
#: this weight on the last point (Wentges; BranchPrice.column_generation). On 32/80 seed 1
#: the root LP after 300 s was 41.3 with it and 50.0 without (its optimum is lower still):
#: the master is degenerate and its duals jump between extreme points early on.
SMOOTHING_FROM_TASKS = 30
SMOOTHING = 0.7
#: The integer master (BranchPrice.integer_master_plan; off by default, ``master_mip_nodes``
#: 0) runs at the root and then whenever the columns have grown by this factor since its
#: last run, for at most this share of the time left (and MASTER_MIP_SECONDS without a time
#: limit).
MASTER_MIP_GROWTH = 1.5
MASTER_MIP_SHARE = 0.1
MASTER_MIP_SECONDS = 60.0
#: A relaxed pricing call whose negative paths all have cycles grows the neighbourhoods by
#: them and runs again, at most this many times (Pricer.price, ``growth_rounds``), before
#: the exact labelling is asked.
NG_GROWTH_ROUNDS = 5
#: Dives (BranchPrice.dive) from the root and then from the nodes reached while the dives
#: so far have solved at most this share of the master LPs (strong branching's included).
#: With strong branching at every node, on 4/10 seed 1 (300 s, a loaded machine) 0.1 gave 5
#: dives (15 s) that improved nothing, 0.25 gave 18 dives (50 s) that took the plan from
#: 17.995 to 17.286. With reliability branching and the arrival cuts, on 4/10 seed 2 0.1
#: proved J* in 455 s (3 dives, 27 s), 0.25 in 565 s (6 dives, 83 s); at 0.1 the search on
#: seed 1 still reaches J* (by a dive).
DIVE_SHARE = 0.1
#: A dive fixes to 0, with each step, the visits nearer to 0 than this (from 20 tasks up
#: it is otherwise a step per visit: 8/20 seed 2's root dive took 135 s, then 58 s).
DIVE_DROP = 0.1
#: Column management (BranchPrice.purge_columns): above this many columns per row of the
#: master as built (before arrival cuts and branching rows, which come and go by node) it
#: sheds its columns of largest reduced cost down to POOL_KEEP of that. Measured on 4/10
#: (173 rows) seeds 1-3, one thread, two runs side by side: a pool of 3 000 columns proved
#: them in 99, 198 and 147 s (117, 600 and 187 s keeping every column: seed 2's LPs had
#: 32 000); 6 000 took seeds 2 and 3 to 328 and 154 s, 1 500 to 385 and 123 s (the pricing
#: found the shed columns again: 186 000 priced on seed 2 against 93 000).
COLUMNS_PER_ROW = 16.0
POOL_KEEP = 0.5

Arc3 = tuple[int, int, int]


@dataclass
class Column:
    aav: int
    tail: tuple[Visit, ...]
    route: Route
    op: float
    amounts: dict[int, int]  # on-time amount per task (coverage)
    theta: dict[int, float]  # arrival term per timed task visited on time
    free_amounts: dict[int, int]  # amount per free task visit (branching)
    arcs: frozenset[Arc3]  # free arcs (branching)
    closes: frozenset[int] = frozenset()  # S_c: the timed tasks this column closes
    index: int = -1  # lambda's column in the LP


@dataclass(frozen=True)
class Decision:
    kind: str  # "visit" | "arc" | "time" | "amount"
    aav: int
    key: Any  # task, or (tail, head, mode)
    side: str  # "0" | "1" for visit/arc; "le" | "gt" for time; "le" | "ge" for amount
    value: float = 0  # the amount's or the arrival term's threshold


@dataclass
class BranchPriceResult:
    routes: tuple[Route, ...]
    J: float
    lower_bound: float | None  # None where no exact pricing finished in time
    status: str  # optimal | feasible | error
    stats: dict[str, Any]


class BranchPrice:
    """The whole method for one planning state (tasks, committed prefixes)."""

    def __init__(self, instance: Instance, tasks: Sequence[int] | None = None,
                 committed: Sequence[Route] | None = None, plan_time: float = 0.0, *,
                 heuristic_cap: int = 3,
                 columns_per_aav: int = 30, closer_rows: bool = True,
                 cover_cuts: bool = True, symmetry: bool = True, threads: int = 1,
                 strong_candidates: int = 8, strong_reliability: int | None = None,
                 time_branching: bool = True,
                 goods_time_rows: bool = True, ng_size: int | None = None,
                 ng_growth_rounds: int | None = None,
                 primal_resolves: bool | None = None,
                 heuristic_round_columns: int = 120, dual_smoothing: float | None = None,
                 master_mip_nodes: int = 0, dive_share: float | None = None,
                 arrival_cut_rounds: int | None = None,
                 columns_per_row: float | None = None) -> None:
        import highspy

        self.instance = instance
        n_aavs = instance.n_aavs
        self.committed = tuple(committed) if committed else tuple(() for _ in range(n_aavs))
        # Every free visit is planned at plan_time: the AAV leaves its anchor no earlier
        # (PlanningState.anchor), and this evaluator prices every column so.
        moment = PlanningState(instance, plan_time, frozenset(), self.committed)
        self.plan_time = plan_time
        self.evaluator = moment.evaluator()
        self.prefixes = [parse_prefix(instance, p) for p in self.committed]
        in_prefix = {m for p in self.prefixes for _, m, _, _ in p.steps}
        all_tasks = range(instance.n_tasks) if tasks is None else tasks
        self.tasks = sorted(set(all_tasks) | in_prefix)
        late = late_committed(instance, self.committed)
        self.late_tasks = {m for _, m in late}
        self.timed = frozenset(m for m in self.tasks if m not in self.late_tasks)
        self.heuristic_cap = heuristic_cap
        self.columns_per_aav = columns_per_aav
        self.closer_rows = closer_rows
        self.strong_candidates = strong_candidates
        self.strong_reliability = (STRONG_RELIABILITY if strong_reliability is None
                                   else strong_reliability)
        # Reliability branching's history, per (AAV, task): [rise per unit, count] of the
        # side to 0 and of the side to 1 (BranchPrice.strongest).
        self.pseudo_costs: dict[tuple[int, int], list[list]] = {}
        self.time_branching = time_branching
        # None: the large-instance measures from NG_FROM_TASKS / PRIMAL_FROM_TASKS up (docs).
        if ng_size is None:
            ng_size = NG_SIZE if len(self.tasks) >= NG_FROM_TASKS else 0
        self.ng_size = ng_size
        self.ng_growth_rounds = (NG_GROWTH_ROUNDS if ng_growth_rounds is None
                                 else ng_growth_rounds)
        self.primal_resolves = (primal_resolves if primal_resolves is not None
                                else len(self.tasks) >= PRIMAL_FROM_TASKS)
        self.heuristic_round_columns = heuristic_round_columns
        self.dual_smoothing = (dual_smoothing if dual_smoothing is not None else
                               SMOOTHING if len(self.tasks) >= SMOOTHING_FROM_TASKS else 0.0)
        self.master_mip_nodes = master_mip_nodes
        self.dive_share = DIVE_SHARE if dive_share is None else dive_share
        self.arrival_cut_rounds = (ARRIVAL_CUT_ROUNDS if arrival_cut_rounds is None
                                   else arrival_cut_rounds)
        self.threads = threads
        self.generated = 0  # columns ever added (purge_columns removes some)
        self.purged = 0
        self.lp_solves = 0  # master LPs solved (column generation, strong branching, dives)
        self._heuristic_next = 0  # the AAV the next heuristic round starts with
        w1, w2, w3 = instance.weights
        self.constant = (instance.unserved_task_cost * (instance.n_tasks - len(self.tasks))
                         + w1 * len(self.tasks) + w2 * len(self.late_tasks))

        self.pricers: list[Pricer] = []
        for n in range(n_aavs):
            prefix = self.prefixes[n]
            required = [(i, j, k) for i, j, k, _ in prefix.steps]
            trailing = None if prefix.trailing_depot is None else (prefix.last,
                                                                     prefix.trailing_depot)
            leaves = moment.anchor(n)
            network = aav_network(instance, n, self.tasks,
                                  prefix_arrivals(instance, n, self.committed[n]), required,
                                  trailing, prefix.last, leaves.time)
            anchor = anchor_of(instance, n, self.committed[n], prefix.trailing_depot,
                               prefix.last, leaves)
            self.pricers.append(Pricer(instance, n, network, anchor, self.timed,
                                       self.ng_size))
        self.identical = _identical(instance, self.committed)

        # --- the LP ----------------------------------------------------------------------
        h = highspy.Highs()
        h.setOptionValue("output_flag", False)
        h.setOptionValue("threads", int(threads))
        self.h = h
        self.inf = highspy.kHighsInf
        self.n_cols = 0
        self.n_rows = 0
        self.conv = [self._row(1.0, 1.0) for _ in range(n_aavs)]
        self.cover = {m: self._row(0.0, self.inf) for m in self.tasks}
        self.closer = {m: self._row(1.0, self.inf) for m in self.timed}
        self.closer_time = {m: self._row(0.0, self.inf) for m in self.timed}
        self.aav_time = {(k, m): self._row(0.0, self.inf) for k in range(n_aavs)
                         for m in self.pricers[k].network.tasks if m in self.timed}
        # Goods-weighted arrival rows R_m Ctime_m >= sum_c theta_cm a_cm lambda_c (docs:
        # valid for an optimum whose members bring no more than R_m in all), on the tasks
        # no committed visit has served yet.
        self.goods_time = {m: self._row(0.0, self.inf) for m in self.timed
                           if m not in in_prefix} if goods_time_rows else {}
        self.covered, self.ctime, self.nobody = {}, {}, {}
        for m in self.tasks:
            demand = instance.tasks[m].demand
            self.covered[m] = self._col(-w1 / demand, 0.0, demand, [(self.cover[m], -1.0)])
        for m in self.timed:
            ctime = [(self.closer_time[m], 1.0)] + [(r, 1.0) for (k, j), r in
                                                     self.aav_time.items() if j == m]
            if m in self.goods_time:
                ctime.append((self.goods_time[m], float(instance.tasks[m].demand)))
            self.ctime[m] = self._col(w2, 0.0, self.inf, ctime)
            nobody = [(self.closer[m], 1.0), (self.closer_time[m], -1.0)] + [
                (r, -1.0) for (k, j), r in self.aav_time.items() if j == m]
            self.nobody[m] = self._col(0.0, 0.0, 1.0, nobody)
        # Arrival cuts (separate_arrival_cuts) per task: (row, pieces (lo, hi, source)).
        self.arrival_cuts: dict[int, list[tuple[int, tuple[tuple[float, float, int], ...]]]] = {}
        # Coalition cover cuts (network.coalition_cover_cuts): (row, task, {AAV: coef}).
        self.cuts: list[tuple[int, int, dict[int, int]]] = []
        if cover_cuts:
            amount_cap = {}
            for n, prefix in enumerate(self.prefixes):
                for _, m, _, a in prefix.steps:
                    amount_cap[n, m] = a
            late_pairs = set(late)
            for m in self.tasks:
                demand = instance.tasks[m].demand
                upper = {n: max(min(instance.aavs[n].capacity, demand), amount_cap.get((n, m), 0))
                         for n in range(n_aavs) if m in self.pricers[n].network.tasks
                         and (n, m) not in late_pairs}
                for rest, coef in coalition_cover_cuts(upper, demand):
                    row = self._row(-float(rest), self.inf)
                    self.h.changeCoeff(row, self.covered[m], -1.0)
                    self.cuts.append((row, m, coef))
        # Identical AAVs n1 < n2 (same type and start, no prefix) ordered as in the MILP: n2
        # visits task j only if n1 visits a task i <= j (a plan's identical routes can be
        # permuted into that order). Rows x_{n1, i <= j} - x_{n2, j} >= 0: (row, n1, n2, j).
        self.symmetry: list[tuple[int, int, int, int]] = []
        if symmetry:
            for group in identical_groups(instance, self.committed):
                for n1, n2 in itertools.pairwise(group):
                    for j in self.pricers[n2].network.tasks:
                        self.symmetry.append((self._row(0.0, self.inf), n1, n2, j))
        if not closer_rows:
            for m in self.timed:
                h.changeRowBounds(self.closer[m], -self.inf, self.inf)
                h.changeRowBounds(self.closer_time[m], -self.inf, self.inf)
        full = sum(a.full_range_cost / instance.e_base for a in instance.aavs)
        self.big = 10.0 * (self.constant + len(self.tasks) * (w1 + w2 + w3 * full)) + 100.0
        per_row = COLUMNS_PER_ROW if columns_per_row is None else columns_per_row
        self.column_limit = int(per_row * self.n_rows)  # 0: every column stays
        self.columns: list[Column] = []
        self.column_at: dict[int, Column] = {}  # by LP column
        self.arriving: dict[int, list[Column]] = {}  # by timed task visited on time
        self.by_key: dict[tuple[int, tuple[Visit, ...], frozenset[int]], Column] = {}
        self.robust: dict[tuple, tuple[int, int]] = {}  # decision key -> (row, artificial)
        # Arrival-window branching's "later than" sides: (AAV, task, threshold) -> the row
        # sum of lambda over the AAV's columns that visit the task with theta <= threshold,
        # <= 0 where the decision holds (its dual prices early visits in the labelling,
        # where a hard floor would break the dominance of earlier labels).
        self.early: dict[tuple[int, int, float], int] = {}
        # The columns by (AAV, free task visited) and (AAV, free arc); the LP columns whose
        # upper bound is 0 at the current node.
        self.visiting: dict[tuple[int, int], list[Column]] = {}
        self.using_arc: dict[tuple[int, Arc3], list[Column]] = {}
        self.closed: set[int] = set()
        self.columns_of: list[list[int]] = [[] for _ in range(n_aavs)]
        for n in range(n_aavs):
            self.add_column(n, ())

    # --- LP plumbing ---------------------------------------------------------------------
    def _row(self, lower: float, upper: float,
             entries: Sequence[tuple[int, float]] = ()) -> int:
        self.h.addRow(lower, upper, len(entries), *_sparse(entries))
        self.n_rows += 1
        return self.n_rows - 1

    def _col(self, cost: float, lower: float, upper: float,
             entries: Sequence[tuple[int, float]]) -> int:
        self.h.addCol(cost, lower, upper, len(entries), *_sparse(entries))
        self.n_cols += 1
        return self.n_cols - 1

    def make_column(self, n: int, tail: tuple[Visit, ...],
                    closes: frozenset[int] | None = None) -> Column:
        """A column from its free visits (closing ``closes``, default every timed task it
        visits on time); every coefficient comes from the evaluator's walk of the route."""
        instance = self.instance
        route = schedule_route(instance, self.committed[n], tail)
        trace = self.evaluator.trace(n, route)
        if not trace.feasible:
            raise ValueError(f"infeasible schedule for AAV {n}: {trace.errors[0]}")
        w3 = instance.weights[2]
        amounts, theta = {}, {}
        for m, c in trace.contributions:
            task = instance.tasks[m]
            if task.on_time(c.arrival):
                amounts[m] = c.amount
                if m in self.timed:
                    theta[m] = (c.arrival - task.t_start) / instance.horizon
        op = w3 * math.fsum(c.op_cost for _, c in trace.contributions)
        anchor = self.pricers[n].anchor
        prev, mode, arcs, free = anchor.node, DIRECT, set(), {}
        if anchor.skip_depot_visit:
            mode = self.prefixes[n].trailing_depot
        for v in tail:
            if instance.is_depot(v.node):
                mode = v.node
                continue
            arcs.add((prev, v.node, mode))
            free[v.node] = v.amount
            prev, mode = v.node, DIRECT
        closes = frozenset(theta) if closes is None else closes & frozenset(theta)
        return Column(n, tail, route, op, amounts, theta, free, frozenset(arcs), closes)

    def add_column(self, n: int, tail: tuple[Visit, ...],
                   closes: frozenset[int] | None = None) -> Column | None:
        col = self.make_column(n, tail, closes)
        if (n, tail, col.closes) in self.by_key:
            return None
        entries = [(self.conv[n], 1.0)]
        entries += [(self.cover[m], float(a)) for m, a in col.amounts.items() if m in self.cover]
        entries += [(self.aav_time[n, m], -t) for m, t in col.theta.items()
                    if (n, m) in self.aav_time]
        entries += [(self.goods_time[m], -t * col.amounts[m]) for m, t in col.theta.items()
                    if m in self.goods_time]
        for key, (row, _) in self.robust.items():
            if _robust_matches(key, col):
                entries.append((row, 1.0))
        entries += [(row, 1.0) for key, row in self.early.items() if _early_visit(key, col)]
        entries += [(row, float(coef[n])) for row, m, coef in self.cuts
                    if n in coef and m in col.amounts]
        for row, n1, n2, j in self.symmetry:
            if n == n1 and any(i <= j for i in col.amounts):
                entries.append((row, float(sum(i <= j for i in col.amounts))))
            elif n == n2 and j in col.amounts:
                entries.append((row, -1.0))
        for m in col.closes:
            entries += [(self.closer[m], 1.0), (self.closer_time[m], -col.theta[m])]
        for m in col.theta:
            for row, pieces in self.arrival_cuts.get(m, ()):
                coef = self._arrival_cut_coef(col, m, pieces)
                if coef:
                    entries.append((row, -coef))
        col.index = self._col(col.op, 0.0, self.inf, entries)
        self.generated += 1
        self._register(col)
        return col

    def _register(self, col: Column) -> None:
        """Enter a live column into the indexes by LP column, AAV, task, arc and key."""
        self.columns.append(col)
        self.column_at[col.index] = col
        self.columns_of[col.aav].append(col.index)
        for m in col.theta:
            self.arriving.setdefault(m, []).append(col)
        for m in col.free_amounts:
            self.visiting.setdefault((col.aav, m), []).append(col)
        for arc in col.arcs:
            self.using_arc.setdefault((col.aav, arc), []).append(col)
        self.by_key[col.aav, col.tail, col.closes] = col

    def purge_columns(self, x: np.ndarray, queue: list) -> tuple[np.ndarray, list]:
        """Column management between nodes: once the master holds more than
        ``columns_per_row`` columns per row of the master as built, the columns of largest
        positive reduced cost at the node just solved leave the LP until POOL_KEEP of that
        limit is left. A column basic in the present LP or in an open node's saved basis
        stays (so every saved basis stays square and valid), and so does each AAV's first
        column (its empty schedule, which keeps every node's LP feasible). No bound depends
        on the pool: the exact pricing finds any schedule of negative reduced cost again,
        whether it was once a column or not.
        Returns the node's LP solution and ``queue`` in the LP's new column indices."""
        import highspy

        if not self.column_limit or len(self.columns) <= self.column_limit:
            return x, queue
        basic = highspy.HighsBasisStatus.kBasic
        saved = {id(entry[3]): entry[3] for entry in queue if entry[3] is not None}
        protected = {cols[0] for cols in self.columns_of}
        for cols, _ in [self.basis(), *saved.values()]:
            protected.update(j for j, status in enumerate(cols) if status == basic)
        # A column newer than the LP gets reduced cost 0: it is never shed unseen.
        reduced = self._padded(np.asarray(self.h.getSolution().col_dual))
        ranked = sorted((c for c in self.columns
                         if c.index not in protected and reduced[c.index] > RC_TOLERANCE),
                        key=lambda c: (-reduced[c.index], c.index))
        drop = ranked[:len(self.columns) - int(POOL_KEEP * self.column_limit)]
        if not drop:
            return x, queue
        keep = np.ones(self.n_cols, bool)
        keep[[c.index for c in drop]] = False
        self.h.deleteCols(len(drop), np.array(sorted(c.index for c in drop), np.int32))
        self.n_cols = int(keep.sum())
        renumber = np.cumsum(keep) - 1
        live = [c for c in self.columns if keep[c.index]]
        for col in live:
            col.index = int(renumber[col.index])
        self.columns, self.column_at, self.by_key = [], {}, {}
        self.arriving, self.visiting, self.using_arc = {}, {}, {}
        self.columns_of = [[] for _ in self.instance.aavs]
        for col in live:
            self._register(col)
        self.covered = {m: int(renumber[j]) for m, j in self.covered.items()}
        self.ctime = {m: int(renumber[j]) for m, j in self.ctime.items()}
        self.nobody = {m: int(renumber[j]) for m, j in self.nobody.items()}
        self.robust = {key: (row, int(renumber[j])) for key, (row, j) in self.robust.items()}
        self.closed = {int(renumber[j]) for j in self.closed if keep[j]}
        self.purged += len(drop)
        # A basis saved before the latest columns came is shorter than the mask.
        renumbered = {key: ([status for status, kept in zip(cols, keep[:len(cols)],
                                                            strict=True) if kept], rows)
                      for key, (cols, rows) in saved.items()}
        queue = [(bound, tie, decisions, None if basis is None else renumbered[id(basis)])
                 for bound, tie, decisions, basis in queue]
        heapq.heapify(queue)
        # HiGHS forgets the solution with the columns; the kept basis is optimal, so the
        # LP is back without a simplex iteration (strong branching reads its value).
        _, x, _ = self.solve_lp()
        return x, queue

    def _robust_row(self, key: tuple) -> tuple[int, int]:
        if key not in self.robust:
            row = self._row(-self.inf, self.inf)
            members = [c.index for c in self.columns if _robust_matches(key, c)]
            for j in members:
                self.h.changeCoeff(row, j, 1.0)
            artificial = self._col(self.big, 0.0, 0.0, [(row, 1.0)])
            self.robust[key] = (row, artificial)
        return self.robust[key]

    def _early_row(self, key: tuple[int, int, float]) -> int:
        if key not in self.early:
            row = self._row(-self.inf, self.inf)
            for col in self.visiting.get(key[:2], ()):
                if _early_visit(key, col):
                    self.h.changeCoeff(row, col.index, 1.0)
            self.early[key] = row
        return self.early[key]

    def basis(self) -> tuple[list, list]:
        """The LP's current basis (column and row statuses)."""
        basis = self.h.getBasis()
        return list(basis.col_status), list(basis.row_status)

    def restore_basis(self, saved: tuple[list, list] | None) -> None:
        """Start the next LP from ``saved`` (a parent node's final basis): best-bound search
        jumps across the tree, and from the last node's basis the first LP of a node took
        hundreds of simplex iterations. Columns and rows added since are nonbasic at their
        lower bound 0 and basic (slack) respectively, which keeps the basis square."""
        import highspy

        if saved is None:
            return
        cols, rows = saved
        basis = highspy.HighsBasis()
        basis.col_status = cols + [highspy.HighsBasisStatus.kLower] * (self.n_cols - len(cols))
        basis.row_status = rows + [highspy.HighsBasisStatus.kBasic] * (self.n_rows - len(rows))
        basis.valid = True
        self.h.setBasis(basis)

    def solve_lp(self, primal: bool = False) -> tuple[float, np.ndarray, np.ndarray]:
        """The LP's value (constants included), primal and row duals. ``primal``: by the
        primal simplex, for a re-solve after columns were added (the basis stays primal
        feasible; at 16/40 the dual simplex took twice as long per re-solve); a primal run
        that does not end optimal is repeated by the dual simplex (HiGHS's primal solver
        has had cycling reports)."""
        import highspy

        optimal = highspy.HighsModelStatus.kOptimal
        self.lp_solves += 1
        self.h.setOptionValue("simplex_strategy", PRIMAL_SIMPLEX if primal else DUAL_SIMPLEX)
        self.h.run()
        if primal and self.h.getModelStatus() != optimal:
            self.h.setOptionValue("simplex_strategy", DUAL_SIMPLEX)
            self.h.run()
        status = self.h.getModelStatus()
        if status != optimal:
            raise RuntimeError(f"master LP not optimal: {self.h.modelStatusToString(status)}")
        solution = self.h.getSolution()
        value = self.h.getInfo().objective_function_value + self.constant
        return value, np.asarray(solution.col_value), np.asarray(solution.row_dual)

    # --- a node's restrictions -----------------------------------------------------------
    def apply(self, decisions: Sequence[Decision]) -> list[Restrictions]:
        """Set the LP and the pricing restrictions to a node's decisions."""
        restrictions = [Restrictions(frozenset(), frozenset(), {}, {})
                        for _ in self.instance.aavs]
        active, early = set(), set()
        forbid_t = [set() for _ in self.instance.aavs]
        forbid_a = [set() for _ in self.instance.aavs]
        for d in decisions:
            r = restrictions[d.aav]
            if d.kind == "visit" and d.side == "0":
                forbid_t[d.aav].add(d.key)
            elif d.kind == "arc" and d.side == "0":
                forbid_a[d.aav].add(d.key)
            elif d.kind == "amount" and d.side == "le":
                r.amount_high[d.key] = min(r.amount_high.get(d.key, 10**9), d.value)
            elif d.kind == "amount" and d.side == "ge":
                r.amount_low[d.key] = max(r.amount_low.get(d.key, 1), d.value)
                active.add(("visit", d.aav, d.key))
            elif d.kind == "time" and d.side == "le":
                r.arrival_high[d.key] = min(r.arrival_high.get(d.key, math.inf), d.value)
            elif d.kind == "time":
                early.add((d.aav, d.key, d.value))
            else:
                active.add((d.kind, d.aav, d.key))
        for n, r in enumerate(restrictions):
            r.forbidden_tasks = frozenset(forbid_t[n])
            r.forbidden_arcs = frozenset(forbid_a[n])
        for key in active:
            self._robust_row(key)
        for key, (row, artificial) in self.robust.items():
            on = key in active
            self.h.changeRowBounds(row, 1.0 if on else -self.inf, self.inf)
            self.h.changeColBounds(artificial, 0.0, self.inf if on else 0.0)
        for key in early:
            self._early_row(key)
        for key, row in self.early.items():
            self.h.changeRowBounds(row, -self.inf, 0.0 if key in early else self.inf)
        # Only the columns whose bound changes since the last node are touched: the ones
        # each decision excludes are found through the visit and arc indexes.
        closed = set()
        for n, r in enumerate(restrictions):
            for m in r.forbidden_tasks:
                closed.update(c.index for c in self.visiting.get((n, m), ()))
            for arc in r.forbidden_arcs:
                closed.update(c.index for c in self.using_arc.get((n, arc), ()))
            for m in {*r.amount_low, *r.amount_high, *r.arrival_high}:
                closed.update(c.index for c in self.visiting.get((n, m), ())
                              if not _compatible(c, r))
        for index in closed - self.closed:
            self.h.changeColBounds(index, 0.0, 0.0)
        for index in self.closed - closed:
            self.h.changeColBounds(index, 0.0, self.inf)
        self.closed = closed
        return restrictions

    # --- arrival cuts ----------------------------------------------------------------------
    def _arrival_cut_coef(self, col: Column, m: int,
                          pieces: Sequence[tuple[float, float, int]]) -> float:
        """The column's coefficient in an arrival cut of task m: the part of [0, theta_cm)
        that the pieces of its own AAV, of the closers (when it closes m) and of the goods
        (weighed by its share a_cm / R_m) cover."""
        theta = col.theta.get(m)
        if theta is None:
            return 0.0
        share = col.amounts[m] / self.instance.tasks[m].demand
        coef = 0.0
        for lo, hi, source in pieces:
            if theta > lo and (source == col.aav or source == GOODS
                               or (source == CLOSERS and m in col.closes)):
                coef += (min(theta, hi) - lo) * (share if source == GOODS else 1.0)
        return coef

    def _arrival_pieces(self, n: int, m: int,
                        cuts: Sequence[tuple[int, tuple[tuple[float, float, int], ...]]],
                        duals: np.ndarray) -> list[tuple[float, float, float, float, float]]:
        """Task m's arrival cuts as AAV n's pricing sees them: their duals summed into
        disjoint pieces (lo, hi, aav, closer, goods per kg), so that a label pays per visit
        for a few pieces rather than for every piece of every cut."""
        per_kg = 1.0 / self.instance.tasks[m].demand
        weighted = []
        for row, pieces in cuts:
            dual = duals[row]
            if dual == 0.0:
                continue
            for lo, hi, source in pieces:
                if source == n:
                    weighted.append((lo, hi, (dual, 0.0, 0.0)))
                elif source == CLOSERS:
                    weighted.append((lo, hi, (0.0, dual, 0.0)))
                elif source == GOODS:
                    weighted.append((lo, hi, (0.0, 0.0, dual * per_kg)))
        breaks = sorted({b for lo, hi, _ in weighted for b in (lo, hi)})
        sums = np.zeros((max(len(breaks) - 1, 0), 3))
        for lo, hi, weights in weighted:
            sums[bisect.bisect_left(breaks, lo):bisect.bisect_left(breaks, hi)] += weights
        return [(lo, hi, *map(float, w)) for (lo, hi), w in
                zip(itertools.pairwise(breaks), sums, strict=True) if w.any()]

    def separate_arrival_cuts(self, x: np.ndarray) -> int:
        """Add the most violated arrival cut of every timed task whose LP point violates
        one; the number added.

        In a plan C_time = max over the members of their arrival terms, so for every tau
        the indicator [C_time > tau] is at least [theta_k > tau] for each AAV k, and
        C_time = the integral of that indicator over tau in [0, 1]. In the LP each AAV's
        columns give P_k(tau) = sum of lambda over its columns arriving later than tau,
        and the per-AAV time rows integrate one P_k each; integrating max_k P_k(tau)
        instead is the strongest bound on the latest member that these marginals give (a
        comonotone coupling attains it). Two more sources join the max, each as valid as
        its own row: the closers (sum of lambda over the columns that close m, arriving
        later than tau: one closer, the latest member, in a plan) and the goods (the share
        of R_m arriving later than tau: the goods-time row's argument, only on the tasks
        that row has). A cut is the row
            Ctime_m - nobody_m - sum_c coef_c lambda_c >= 0,
        one source per piece of [0, 1] (lo, hi, source), coef_c the length of [0, theta_cm)
        under the pieces of c's sources; its dual prices an arrival by a non-decreasing
        piecewise linear function (TaskPrices.arrival_cuts)."""
        added = 0
        positive = [self.column_at[j] for j in np.flatnonzero(x > INTEGRALITY)
                    if j in self.column_at]
        for m in sorted(self.timed):
            demand = self.instance.tasks[m].demand
            later: list[tuple[float, int, float]] = []  # (theta, source, weight)
            for col in positive:
                lam = x[col.index]
                theta = col.theta.get(m)
                if theta is None or theta <= 0.0:
                    continue
                later.append((theta, col.aav, lam))
                if m in self.goods_time:
                    later.append((theta, GOODS, lam * col.amounts[m] / demand))
                if m in col.closes:
                    later.append((theta, CLOSERS, lam))
            total, pieces = _largest_share_pieces(later)
            if total + x[self.nobody[m]] - x[self.ctime[m]] <= ARRIVAL_CUT_VIOLATION:
                continue
            entries = [(self.ctime[m], 1.0), (self.nobody[m], -1.0)]
            for col in self.arriving.get(m, ()):
                coef = self._arrival_cut_coef(col, m, pieces)
                if coef:
                    entries.append((col.index, -coef))
            row = self._row(0.0, self.inf, entries)
            self.arrival_cuts.setdefault(m, []).append((row, tuple(pieces)))
            added += 1
        return added

    def artificial_value(self, x: np.ndarray) -> float:
        return sum(x[a] for _, a in self.robust.values())

    def prices(self, n: int, duals: np.ndarray) -> TaskPrices:
        cover = {m: duals[r] for m, r in self.cover.items()}
        aav_time = {m: duals[r] for (k, m), r in self.aav_time.items() if k == n}
        closer = {m: duals[r] for m, r in self.closer.items()}
        closer_time = {m: duals[r] for m, r in self.closer_time.items()}
        goods_time = {m: duals[r] for m, r in self.goods_time.items()}
        visit_bonus, arc_bonus = {}, {}
        for (kind, k, key), (row, _) in self.robust.items():
            if k == n and duals[row] != 0.0:
                (visit_bonus if kind == "visit" else arc_bonus)[key] = duals[row]
        cut_bonus: dict[int, float] = {}
        for row, m, coef in self.cuts:
            if n in coef and duals[row] != 0.0:
                cut_bonus[m] = cut_bonus.get(m, 0.0) + coef[n] * duals[row]
        for row, n1, n2, j in self.symmetry:
            if duals[row] == 0.0:
                continue
            if n == n1:  # every visit to a task i <= j counts once
                for i in self.pricers[n].network.tasks:
                    if i <= j:
                        cut_bonus[i] = cut_bonus.get(i, 0.0) + duals[row]
            elif n == n2:
                cut_bonus[j] = cut_bonus.get(j, 0.0) - duals[row]
        early_penalty: dict[int, list[tuple[float, float]]] = {}
        for (k, m, threshold), row in self.early.items():
            if k == n and duals[row] < 0.0:  # a <= row: its dual is <= 0
                early_penalty.setdefault(m, []).append((threshold, -duals[row]))
        arrival_cuts = {m: self._arrival_pieces(n, m, cuts, duals)
                        for m, cuts in self.arrival_cuts.items()}
        prices = TaskPrices(0.0, cover, aav_time, closer, closer_time,
                            visit_bonus=visit_bonus, arc_bonus=arc_bonus, cut_bonus=cut_bonus,
                            goods_time=goods_time, early_penalty=early_penalty,
                            arrival_cuts=arrival_cuts)
        prices.base = self.reduced_cost(self.make_column(n, ()), prices) - duals[self.conv[n]]
        return prices

    @staticmethod
    def best_closes(col: Column, prices: TaskPrices) -> frozenset[int]:
        """The tasks whose closing lowers this schedule's reduced cost."""
        return frozenset(m for m, t in col.theta.items()
                         if BranchPrice._closing_term(m, t, prices) < 0)

    @staticmethod
    def _closing_term(m: int, theta: float, prices: TaskPrices) -> float:
        """What closing task m at arrival term ``theta`` adds to a reduced cost (the
        labelling takes its min with 0)."""
        cut = arrival_cut_terms(prices.arrival_cuts.get(m, ()), theta)[1]
        return prices.closer_time.get(m, 0.0) * theta + cut - prices.closer.get(m, 0.0)

    @classmethod
    def reduced_cost(cls, col: Column, prices: TaskPrices) -> float:
        """Reduced cost of a column's schedule with its best closing set, without the
        convexity dual."""
        rc = col.op - math.fsum(prices.cover.get(m, 0.0) * a for m, a in col.amounts.items())
        for m, t in col.theta.items():
            cut_aav, _, cut_goods = arrival_cut_terms(prices.arrival_cuts.get(m, ()), t)
            rc += prices.aav_time.get(m, 0.0) * t + cut_aav
            rc += (prices.goods_time.get(m, 0.0) * t + cut_goods) * col.amounts[m]
        for m in cls.best_closes(col, prices):
            rc += cls._closing_term(m, col.theta[m], prices)
        rc -= sum(prices.visit_bonus.get(m, 0.0) for m in col.free_amounts)
        rc -= sum(prices.cut_bonus.get(m, 0.0) for m in col.amounts)
        rc -= sum(prices.arc_bonus.get(a, 0.0) for a in col.arcs)
        for m, steps in prices.early_penalty.items():
            rc += sum(p for threshold, p in steps if _early_visit((col.aav, m, threshold), col))
        return rc

    # --- column generation at one node ---------------------------------------------------
    def column_generation(self, restrictions: list[Restrictions], cutoff: float,
                          deadline: float, clock: dict[str, float],
                          heuristic_only: bool = False
                          ) -> tuple[float, float, np.ndarray, bool]:
        """(LP value, best Lagrangian bound, primal, converged). Stops early when the
        bound reaches ``cutoff`` or at ``deadline``; ``heuristic_only`` (a dive): once the
        heuristic pricing finds nothing, with no bound.

        Pricing goes from cheap to exact: the heuristic labelling; when it finds nothing,
        the ng relaxation (``ng_size`` > 0), whose least reduced costs already give a
        Lagrangian bound and whose elementary schedules are columns; when that finds no
        column, the exact labelling, only for the AAVs whose relaxed least is negative
        (for the others the exact least is no lower than the relaxed one, >= -tolerance)."""
        bound = -math.inf
        n_aavs = self.instance.n_aavs
        columns_added = False  # the node's first LP follows bound changes: dual simplex
        center = None  # the smoothed duals the last heuristic round priced at
        while True:
            began = time.perf_counter()
            value, x, duals = self.solve_lp(primal=columns_added and self.primal_resolves)
            columns_added = True
            clock["lp"] += time.perf_counter() - began
            began = time.perf_counter()
            prices = [self.prices(n, duals) for n in range(n_aavs)]
            tolerance = RC_TOLERANCE * max(1.0, abs(value))
            added = 0
            if self.heuristic_cap:
                if center is not None and self.dual_smoothing:
                    # Wentges / Neame smoothing: the heuristic prices at a point between
                    # the last one and the LP's duals, which jump between extreme points
                    # of a degenerate master; if nothing new prices out there, at the
                    # LP's duals themselves (no column is missed).
                    center = self.dual_smoothing * center + (1 - self.dual_smoothing) * duals
                    added = self._heuristic_round([self.prices(n, center)
                                                   for n in range(n_aavs)],
                                                  restrictions, deadline)
                else:
                    center = duals
                if added == 0:
                    added = self._heuristic_round(prices, restrictions, deadline)
            if heuristic_only and (added == 0 or time.perf_counter() >= deadline):
                clock["pricing"] += time.perf_counter() - began
                return value, -math.inf, self._padded(x), True
            least: list[float] | None = None  # per AAV: a lower bound on its least rc
            if added == 0 and self.ng_size:
                least, added = self._price_round(prices, restrictions, range(n_aavs),
                                                 deadline, relaxed=True)
                bound = max(bound, value + sum(min(0.0, v) for v in least))
            exact = added == 0
            if exact:
                unsure = [n for n in range(n_aavs) if least is None or least[n] < -tolerance]
                exact_least, added = self._price_round(prices, restrictions, unsure, deadline)
                known = list(least) if least is not None else [-math.inf] * n_aavs
                for n, v in zip(unsure, exact_least, strict=True):
                    known[n] = max(known[n], v)  # -inf where cut short at the deadline
                least_total = sum(min(0.0, v) for v in known)
                bound = max(bound, value + least_total)
            clock["pricing"] += time.perf_counter() - began
            x = self._padded(x)
            if exact and -math.inf in exact_least:  # a cut-short pricing settles nothing
                return value, bound, x, False
            if exact and added == 0:
                # Nothing new prices out: the LP value is the node's bound, unless the
                # schedules of negative reduced cost were already columns (float noise
                # between the labelling and HiGHS), where only the Lagrangian bound is sure.
                settled = least_total >= -tolerance
                return value, max(bound, value) if settled else bound, x, True
            if _reaches(bound, cutoff):
                return value, bound, x, False
            if time.perf_counter() >= deadline:
                return value, bound, x, False

    def cut_and_price(self, restrictions: list[Restrictions], cutoff: float,
                      deadline: float, clock: dict[str, float]
                      ) -> tuple[float, float, np.ndarray, bool]:
        """A node's column generation, then up to ``arrival_cut_rounds`` rounds of arrival
        cuts, each followed by column generation again, while cuts are violated; the same
        (LP value, bound, primal, converged) as column_generation, the bound the best of
        the rounds (each is valid)."""
        value, bound, x, converged = self.column_generation(restrictions, cutoff, deadline,
                                                            clock)
        for _ in range(self.arrival_cut_rounds):
            if not converged or _reaches(bound, cutoff):
                break
            separating = time.perf_counter()
            added = self.separate_arrival_cuts(x)
            clock["cuts"] += time.perf_counter() - separating
            if not added:
                break
            value, later, x, converged = self.column_generation(restrictions, cutoff,
                                                                deadline, clock)
            bound = max(bound, later)
        return value, bound, x, converged

    def _padded(self, x: np.ndarray) -> np.ndarray:
        """An LP's per-column vector (lambda, reduced costs) with 0 for the columns added
        after that LP."""
        return np.concatenate([x, np.zeros(self.n_cols - len(x))])

    def _heuristic_round(self, prices: list[TaskPrices], restrictions: list[Restrictions],
                         deadline: float) -> int:
        """Heuristic pricing of the AAVs in turn, from where the last round stopped, until
        ``heuristic_round_columns`` columns are added (0: every AAV): with many AAVs the
        LP is cheap beside a pricing call, and fresh duals after a few AAVs steer the next
        ones better than the duals all of them were priced at. Columns added."""
        n_aavs = self.instance.n_aavs
        added = 0
        for step in range(n_aavs):
            n = (self._heuristic_next + step) % n_aavs
            added += self._price_round(prices, restrictions, [n], deadline,
                                       label_cap=self.heuristic_cap)[1]
            if self.heuristic_round_columns and added >= self.heuristic_round_columns:
                self._heuristic_next = n + 1
                break
        return added

    def _price_round(self, prices: list[TaskPrices], restrictions: list[Restrictions],
                     aavs: Sequence[int], deadline: float, *, label_cap: int | None = None,
                     relaxed: bool = False) -> tuple[list[float], int]:
        """Each of ``aavs`` priced once, its schedules added: (least reduced cost per AAV
        in ``aavs``, columns added)."""
        least, added = [], 0
        for n in aavs:
            v, found = self.pricers[n].price(prices[n], restrictions[n],
                                             limit=self.columns_per_aav, label_cap=label_cap,
                                             relaxed=relaxed,
                                             growth_rounds=self.ng_growth_rounds,
                                             deadline=deadline)
            least.append(v)
            added += self._add_found(n, found, restrictions, prices[n])
        return least, added

    def _add_found(self, n: int, found: list, restrictions: list[Restrictions],
                   prices: TaskPrices) -> int:
        added = 0
        for schedule in found:
            closes = self.best_closes(self.make_column(n, schedule.tail), prices)
            for k in self.identical.get(n, (n,)):
                col = self.add_column(k, schedule.tail, closes)
                if col is None:
                    continue
                if not _compatible(col, restrictions[k]):
                    self.h.changeColBounds(col.index, 0.0, 0.0)
                    self.closed.add(col.index)
                elif k == n:
                    added += 1
        return added

    # --- reading plans off the LP --------------------------------------------------------
    def dive(self, decisions: tuple[Decision, ...], x: np.ndarray, deadline: float
             ) -> list[tuple[Route, ...]]:
        """Diving (Sadykov, Lazarev, Shmonin, Uchoa, Vanderbeck and Yakovlev 2019): from a
        node's LP solution, fix the fractional visit x_km nearest to 0 or 1 to that value
        (and the visits nearer to 0 than DIVE_DROP to 0), re-run column generation with
        heuristic pricing only, and repeat; once the visits are integral, go down the
        branching rule's later steps (the earlier side of an arrival window, arcs and
        amounts rounded) until the LP is integral or needs its artificial columns. Returns
        the plans read off the way (each AAV's column of largest lambda, and the integral
        LP's plan). The best-bound search reaches such deep plans late or never: on 8/20
        seed 2 of benchmarks/exact_scaling.py the root's dive found J 6.907 where 600 s of
        search had kept 11.699. The node's bounds are restored by the next ``apply``; the
        columns priced on the way stay (columns like any other)."""
        plans = []
        clock = dict.fromkeys(("lp", "pricing"), 0.0)  # the caller times the dive whole
        while time.perf_counter() < deadline:
            plans.append(self.rounded_plan(x))
            fractional = [(min(v, 1.0 - v), key, v) for key, v in self.visits(x).items()
                          if INTEGRALITY < v < 1.0 - INTEGRALITY]
            if fractional:
                # The visit nearest to 0 or 1 goes there, and with it every visit nearer
                # to 0 than DIVE_DROP (a "0" side never empties the LP; several "1"s of an
                # AAV could): from 20 tasks up a dive is otherwise a step per visit.
                _, (k, m), v = min(fractional)
                steps = [Decision("visit", k, m, "1" if v >= 0.5 else "0")]
                steps += [Decision("visit", *key, "0") for _, key, w in fractional
                          if w < DIVE_DROP and key != (k, m)]
            else:
                step = self.branching_candidates(x)
                if not isinstance(step, Decision):
                    plans.append(step)  # the LP is integral: this plan is its solution
                    return plans
                steps = [self._dive_side(step, x)]
            decisions = (*decisions, *steps)
            _, _, x, _ = self.column_generation(self.apply(decisions), math.inf, deadline,
                                                clock, heuristic_only=True)
            if self.artificial_value(x) > 1e-9:
                break
        return plans

    def _dive_side(self, choice: Decision, x: np.ndarray) -> Decision:
        """The side of a (non-visit) branching decision nearer to the LP solution: the
        earlier side of an arrival window, an arc rounded to 0 or 1, an amount rounded."""
        if choice.kind == "time":
            return choice
        cols = [c for c in self.columns if c.aav == choice.aav and x[c.index] > 1e-12]
        if choice.kind == "arc":
            flow = math.fsum(x[c.index] for c in cols if choice.key in c.arcs)
            return Decision("arc", choice.aav, choice.key, "1" if flow >= 0.5 else "0")
        amount = math.fsum(x[c.index] * c.free_amounts.get(choice.key, 0) for c in cols)
        if amount - choice.value < 0.5:
            return choice
        return Decision("amount", choice.aav, choice.key, "ge", choice.value + 1)

    def integer_master_plan(self, cutoff: float, time_limit: float
                            ) -> tuple[Route, ...] | None:
        """A plan from the master with lambda integer over its columns (HiGHS's
        MIP, at most ``master_mip_nodes`` nodes and ``time_limit`` s, pruning at
        ``cutoff``): it puts together columns that no single LP solution does, or None.
        Its objective is at least the J of its plan, and equal with the right closing
        sets. The live LP is left at the root's bounds (each node sets its own)."""
        import highspy

        self.apply(())
        mip = highspy.Highs()
        mip.setOptionValue("output_flag", False)
        mip.setOptionValue("threads", self.threads)
        mip.setOptionValue("mip_max_nodes", self.master_mip_nodes)
        mip.setOptionValue("time_limit", max(time_limit, 0.01))
        mip.setOptionValue("objective_bound", cutoff - self.constant)
        mip.passModel(self.h.getLp())
        lambdas = np.array([c.index for c in self.columns], np.int32)
        mip.changeColsIntegrality(len(lambdas), lambdas,
                                  np.full(len(lambdas), highspy.HighsVarType.kInteger))
        mip.run()
        if not mip.getInfo().primal_solution_status:
            return None
        return self.rounded_plan(np.asarray(mip.getSolution().col_value))

    def rounded_plan(self, x: np.ndarray) -> tuple[Route, ...]:
        """Each AAV's column of largest lambda (a feasible plan)."""
        best: dict[int, tuple[float, Column]] = {}
        for col in self.columns:
            v = x[col.index]
            if col.aav not in best or v > best[col.aav][0]:
                best[col.aav] = (v, col)
        return tuple(best[n][1].route for n in range(self.instance.n_aavs))

    def visits(self, x: np.ndarray) -> dict[tuple[int, int], float]:
        """x_km: the lambda of AAV k's columns that visit task m (free part)."""
        visit: dict[tuple[int, int], float] = {}
        for col in self.columns:
            if x[col.index] > 1e-12:
                for m in col.free_amounts:
                    visit[col.aav, m] = visit.get((col.aav, m), 0.0) + x[col.index]
        return visit

    def branching_candidates(self, x: np.ndarray) -> Decision | tuple[Route, ...]:
        """The most fractional visit, then the widest spread arrival, then the most
        fractional arc, then amount; or the integral plan."""
        arc: dict[tuple[int, Arc3], float] = {}
        amount: dict[tuple[int, int], float] = {}
        arrivals: dict[tuple[int, int], list[tuple[float, float]]] = {}
        for col in self.columns:
            v = x[col.index]
            if v <= 1e-12:
                continue
            for m, a in col.free_amounts.items():
                amount[col.aav, m] = amount.get((col.aav, m), 0.0) + v * a
                if m in col.theta:
                    arrivals.setdefault((col.aav, m), []).append((v, col.theta[m]))
            for e in col.arcs:
                arc[col.aav, e] = arc.get((col.aav, e), 0.0) + v
        visit = self.visits(x)
        frac = _most_fractional_first(visit)
        if frac:
            if self.strong_candidates > 1 and len(frac) > 1:
                k, m = self.strongest([(key, visit[key])
                                       for key in frac[:self.strong_candidates]])
            else:
                (k, m) = frac[0]
            return Decision("visit", k, m, "0")
        if self.time_branching:
            split = self.widest_arrival(arrivals)
            if split is not None:
                (k, m), threshold = split
                return Decision("time", k, m, "le", threshold)
        frac = _most_fractional_first(arc)
        if frac:
            (k, e) = frac[0]
            return Decision("arc", k, e, "0")
        frac = [(abs(v - math.floor(v) - 0.5), key) for key, v in sorted(amount.items())
                if abs(v - round(v)) > INTEGRALITY]
        if frac:
            k, m = min(frac)[1]
            return Decision("amount", k, m, "le", math.floor(amount[k, m]))
        routes = []
        for n in range(self.instance.n_aavs):
            cols = [c for c in self.columns if c.aav == n and x[c.index] > 1e-12]
            route = max(cols, key=lambda c: x[c.index]).route
            routes.append(tuple(Visit(v.node, round(amount[n, v.node]))
                                if v.node in cols[0].free_amounts else v for v in route))
        return tuple(routes)

    @staticmethod
    def widest_arrival(arrivals: dict[tuple[int, int], list[tuple[float, float]]]
                       ) -> tuple[tuple[int, int], float] | None:
        """With every visit integral, an AAV's columns still mix visit orders, and the time
        rows see the lambda-average of their arrivals where the plan pays the latest
        member's (the leak of the root bound, docs/formulations.md). Of the (AAV, task)
        pairs whose arrival term is spread over columns, the one of largest mean absolute
        deviation, split at its mean (both sides then carry weight)."""
        best, best_spread = None, 0.0
        for key, points in sorted(arrivals.items()):
            weight = math.fsum(v for v, _ in points)
            mean = math.fsum(v * t for v, t in points) / weight
            spread = math.fsum(v * abs(t - mean) for v, t in points) / weight
            below = math.fsum(v for v, t in points if t <= mean)
            if spread > best_spread and INTEGRALITY < below < weight - INTEGRALITY:
                best, best_spread = (key, mean), spread
        return best

    def strongest(self, candidates: list[tuple[tuple[int, int], float]]) -> tuple[int, int]:
        """Of the (AAV, task) visit candidates with their x_km, the one whose two children's
        LPs rise the most, by the product of the two rises. A candidate is scored by strong
        branching (its children's LPs over the present columns, no pricing: a score, not a
        bound) until each side has ``strong_reliability`` measured rises (strong branching's
        or, from the search, its children's), and from then on by its pseudo-costs, the mean
        rise per unit of x_km moved on each side (reliability branching, Achterberg, Koch and
        Martin 2005). The LP is left as it was (bounds and basis)."""
        import highspy

        value = self.h.getInfo().objective_function_value
        saved = None
        best, best_score = candidates[0][0], -math.inf
        for (k, m), v in candidates:
            moves = (v, 1.0 - v)  # to 0, to 1
            history = self.pseudo_costs.get((k, m))
            if self.strong_reliability and history is not None and \
                    min(count for _, count in history) >= self.strong_reliability:
                rises = [move * total / count for move, (total, count)
                         in zip(moves, history, strict=True)]
            else:
                if saved is None:
                    saved = self.basis()
                    self.h.setOptionValue("simplex_strategy", DUAL_SIMPLEX)  # bounds only
                visiting = {c.index for c in self.visiting.get((k, m), ())}
                rises = []
                for close in (visiting, set(self.columns_of[k]) - visiting):
                    newly = np.array(sorted(close - self.closed), np.int32)
                    if len(newly):
                        self.h.changeColsBounds(len(newly), newly, np.zeros(len(newly)),
                                                np.zeros(len(newly)))
                    self.h.run()
                    self.lp_solves += 1
                    ok = self.h.getModelStatus() == highspy.HighsModelStatus.kOptimal
                    child = self.h.getInfo().objective_function_value if ok else math.inf
                    rises.append(child - value)
                    if len(newly):
                        self.h.changeColsBounds(len(newly), newly, np.zeros(len(newly)),
                                                np.full(len(newly), self.inf))
                    self.restore_basis(saved)
                for side, (rise, move) in enumerate(zip(rises, moves, strict=True)):
                    self.record_rise((k, m), side, rise, move)
            score = max(rises[0], 1e-9) * max(rises[1], 1e-9)
            if score > best_score:
                best, best_score = (k, m), score
        return best

    def record_rise(self, key: tuple[int, int], side: int, rise: float, move: float) -> None:
        """A child's LP rise over its parent's when x_km moved by ``move`` to 0 (side 0) or
        to 1 (side 1), into the candidate's pseudo-costs."""
        if math.isfinite(rise):  # an infeasible child says nothing per unit
            history = self.pseudo_costs.setdefault(key, [[0.0, 0], [0.0, 0]])
            history[side][0] += max(rise, 0.0) / move
            history[side][1] += 1

    def root(self, time_limit: float | None = None) -> dict[str, float]:
        """The root LP by column generation alone (no incumbent, no branching): its value,
        the Lagrangian bound, whether it converged, columns and seconds."""
        began = time.perf_counter()
        deadline = math.inf if time_limit is None else began + time_limit
        clock = {"lp": 0.0, "pricing": 0.0, "cuts": 0.0}
        value, bound, _, converged = self.cut_and_price(self.apply(()), math.inf, deadline,
                                                        clock)
        return {"lp": value, "bound": bound if not converged else value,
                "converged": converged, "columns": self.generated,
                "seconds": time.perf_counter() - began}

    # --- the search ----------------------------------------------------------------------
    def solve(self, incumbent: Sequence[Route], time_limit: float | None = None,
              log: Callable[[str], None] | None = None) -> BranchPriceResult:
        began = time.perf_counter()
        deadline = math.inf if time_limit is None else began + time_limit
        clock = {"lp": 0.0, "pricing": 0.0, "cuts": 0.0, "branching": 0.0,
                 "master_mip": 0.0, "dive": 0.0}
        mip_improved = dive_improved = dives = dive_lps = 0
        instance = self.instance
        free = [len(p) for p in self.committed]
        best_routes = canonical_routes(instance, incumbent, free, self.plan_time)
        best_J = self.evaluator.cost(best_routes)
        # The incumbent's columns, each task closed by its latest member (its J exactly).
        latest: dict[int, tuple[float, int]] = {}
        for trace in self.evaluator.evaluate(best_routes).traces:
            for m, c in trace.contributions:
                latest[m] = max(latest.get(m, (-math.inf, -1)), (c.arrival, trace.aav))
        for n, route in enumerate(best_routes):
            tail = tuple(route[free[n]:])
            if tail and instance.is_depot(tail[-1].node):
                tail = tail[:-1]
            if tail:
                self.add_column(n, tail, frozenset(m for m, (_, k) in latest.items() if k == n))
        counter = itertools.count()
        # Open nodes: (bound, tie-break, decisions, the parent's final LP basis or None).
        queue: list[tuple[float, int, tuple[Decision, ...], Any]] = [
            (-math.inf, next(counter), (), None)]
        nodes = 0
        branches = dict.fromkeys(("visit", "time", "arc", "amount"), 0)
        root_bound = None
        global_bound = -math.inf
        status = "optimal"
        stop_reason = "optimal"

        def offer(plan: tuple[Route, ...]) -> tuple[float, bool]:
            """The plan's J, and whether it replaced the incumbent."""
            nonlocal best_J, best_routes
            J = self.evaluator.cost(plan)
            if not _reaches(J, best_J):
                best_J, best_routes = J, plan
                return J, True
            return J, False

        mip_columns = 0  # the columns at the integer master's last run (0: not yet run)
        # The children of visit branches, by their queue tie-break: (AAV, task), side, how
        # far x_km moves, the parent's LP value. The rise of a child explored further feeds
        # the pseudo-costs (a pruned child's LP is mostly cut short at the incumbent).
        moved: dict[int, tuple[tuple[int, int], int, float, float]] = {}
        while queue:
            bound, tie, decisions, basis = heapq.heappop(queue)
            parent = moved.pop(tie, None)
            if _reaches(bound, best_J):
                continue
            if time.perf_counter() >= deadline:
                heapq.heappush(queue, (bound, next(counter), decisions, basis))
                status, stop_reason = "feasible", "time limit"
                break
            if nodes and self.master_mip_nodes and \
                    self.generated >= MASTER_MIP_GROWTH * mip_columns:
                # Between nodes: it leaves the LP at the root's bounds.
                mip_columns = self.generated
                solving = time.perf_counter()
                left = deadline - solving
                plan = self.integer_master_plan(
                    best_J, MASTER_MIP_SECONDS if left == math.inf else MASTER_MIP_SHARE * left)
                clock["master_mip"] += time.perf_counter() - solving
                if plan is not None:
                    mip_improved += offer(plan)[1]
                if _reaches(bound, best_J):
                    continue
            nodes += 1
            restrictions = self.apply(decisions)
            self.restore_basis(basis)
            value, node_bound, x, converged = self.cut_and_price(restrictions, best_J,
                                                                 deadline, clock)
            node_bound = max(node_bound, bound)
            if root_bound is None:
                root_bound = node_bound
            offer(self.rounded_plan(x))
            if _reaches(node_bound, best_J):
                continue
            if not converged:  # the deadline: keep the node open with its bound
                heapq.heappush(queue, (node_bound, next(counter), decisions, basis))
                continue
            if self.artificial_value(x) > 1e-9:
                continue  # infeasible node
            if parent is not None:
                key, side, move, parent_value = parent
                self.record_rise(key, side, value - parent_value, move)
            # The dives' share is counted in master LPs, not seconds: the same search
            # then dives from the same nodes on any machine (same seed, same result).
            if self.dive_share and dive_lps <= self.dive_share * (self.lp_solves - dive_lps):
                diving, solves = time.perf_counter(), self.lp_solves
                saved = self.basis()
                for plan in self.dive(decisions, x, deadline):
                    dive_improved += offer(plan)[1]
                self.apply(decisions)
                self.restore_basis(saved)
                _, x, _ = self.solve_lp()  # the node's LP again, for branching
                dives += 1
                dive_lps += self.lp_solves - solves
                clock["dive"] += time.perf_counter() - diving
                if _reaches(node_bound, best_J):
                    continue
            if time.perf_counter() >= deadline:
                # The node stays open rather than strong branching past the limit (a dive
                # cut short by it took 16/40 seed 2 to 659 s of 600).
                heapq.heappush(queue, (node_bound, next(counter), decisions, basis))
                continue
            # Here the LP is the node's (its reduced costs rank the columns) and the basis
            # its children will start from is the present one.
            x, queue = self.purge_columns(x, queue)
            choosing = time.perf_counter()
            choice = self.branching_candidates(x)
            clock["branching"] += time.perf_counter() - choosing
            if isinstance(choice, Decision):
                branches[choice.kind] += 1
                if choice.kind == "amount":
                    sides = [choice, Decision("amount", choice.aav, choice.key, "ge",
                                              choice.value + 1)]
                elif choice.kind == "time":
                    sides = [choice, Decision("time", choice.aav, choice.key, "gt",
                                              choice.value)]
                else:
                    sides = [choice, Decision(choice.kind, choice.aav, choice.key, "1")]
                basis = self.basis()
                v = self.visits(x).get((choice.aav, choice.key), 0.0) \
                    if choice.kind == "visit" else None
                for index, side in enumerate(sides):
                    order = next(counter)
                    if v is not None:
                        moved[order] = ((choice.aav, choice.key), index, (v, 1.0 - v)[index],
                                        value)
                    heapq.heappush(queue, (node_bound, order, (*decisions, side), basis))
                if log:
                    log(f"node {nodes}: LP {value:.6f} bound {node_bound:.6f} "
                        f"best {best_J:.6f} branch {choice}")
                continue
            J, _ = offer(choice)
            if value + 1e-6 * max(1.0, abs(value)) < J:
                status, stop_reason = "error", (f"integral LP {value} but its plan has J {J}")
                break
        open_bounds = [b for b, _, _, _ in queue]
        global_bound = min([best_J, *open_bounds]) if status != "optimal" else best_J
        if status == "feasible" and not open_bounds:
            status, stop_reason = "optimal", "optimal"
        stats = {
            "status": status,
            "stop_reason": stop_reason,
            "J": best_J,
            "lower_bound": _finite(global_bound),
            "root_bound": _finite(root_bound),
            "nodes": nodes,
            "open_nodes": len(queue),
            **{f"{kind}_branches": count for kind, count in branches.items()},
            "columns": self.generated,
            "purged_columns": self.purged,
            "lp_solves": self.lp_solves,
            "lp_time": clock["lp"],
            "pricing_time": clock["pricing"],
            "arrival_cuts": sum(map(len, self.arrival_cuts.values())),
            "cut_time": clock["cuts"],
            "branching_time": clock["branching"],
            "master_mip_time": clock["master_mip"],
            "master_mip_improvements": mip_improved,
            "dive_time": clock["dive"],
            "dives": dives,
            "dive_improvements": dive_improved,
            "other_time": time.perf_counter() - began - sum(clock.values()),
            "wall_time": time.perf_counter() - began,
        }
        return BranchPriceResult(tuple(best_routes), best_J, _finite(global_bound), status, stats)


def _sparse(entries: Sequence[tuple[int, float]]) -> tuple[np.ndarray, np.ndarray]:
    """(indices, values) of a row's or column's entries, as highspy takes them."""
    return (np.array([j for j, _ in entries], np.int32),
            np.array([v for _, v in entries], float))


def _largest_share_pieces(later: Sequence[tuple[float, int, float]]
                          ) -> tuple[float, list[tuple[float, float, int]]]:
    """An arrival cut's separation for one task from its (theta, source, weight) shares:
    per interval between consecutive arrivals, the source with the most weight arriving
    later; (the integral of that largest share, the pieces (lo, hi, source), adjacent
    intervals of one source merged)."""
    breaks = sorted({0.0, *(theta for theta, _, _ in later)})
    pieces: list[tuple[float, float, int]] = []
    total = 0.0
    for lo, hi in itertools.pairwise(breaks):
        mass: dict[int, float] = {}
        for theta, source, weight in later:
            if theta > lo:
                mass[source] = mass.get(source, 0.0) + weight
        source = max(sorted(mass), key=mass.__getitem__)
        total += mass[source] * (hi - lo)
        if pieces and pieces[-1][2] == source and pieces[-1][1] == lo:
            pieces[-1] = (pieces[-1][0], hi, source)
        else:
            pieces.append((lo, hi, source))
    return total, pieces


def _reaches(bound: float, cutoff: float) -> bool:
    """Whether a bound prunes against ``cutoff`` (the incumbent's J), within a relative
    PRUNE_TOLERANCE."""
    return bound >= cutoff - PRUNE_TOLERANCE * max(1.0, abs(cutoff))


def _most_fractional_first(values: dict[tuple, float]) -> list[tuple]:
    """The keys of the fractional 0-1 values, nearest to 0.5 first (ties by key)."""
    return [key for _, key in sorted((abs(v - 0.5), key) for key, v in values.items()
                                     if INTEGRALITY < v < 1 - INTEGRALITY)]


def _finite(value: float | None) -> float | None:
    """A bound, or None where none was proven (no exact pricing finished in time)."""
    return value if value is not None and math.isfinite(value) else None


def _identical(instance: Instance, committed: Sequence[Route]) -> dict[int, tuple[int, ...]]:
    groups = {}
    for group in identical_groups(instance, committed):
        for n in group:
            groups[n] = tuple(group)
    return groups


def _robust_matches(key: tuple, col: Column) -> bool:
    kind, k, what = key
    if col.aav != k:
        return False
    return what in col.free_amounts if kind == "visit" else what in col.arcs


def _early_visit(key: tuple[int, int, float], col: Column) -> bool:
    """Whether the column visits the key's task too early for its "later than" side (a
    free visit without an arrival term is late, past every threshold)."""
    k, m, threshold = key
    return col.aav == k and m in col.free_amounts and col.theta.get(m, math.inf) <= threshold


def _compatible(col: Column, r: Restrictions) -> bool:
    if any(m in r.forbidden_tasks for m in col.free_amounts):
        return False
    if any(a in r.forbidden_arcs for a in col.arcs):
        return False
    for m, hi in r.amount_high.items():
        if col.free_amounts.get(m, 0) > hi:
            return False
    # A free visit without an arrival term is late (past every threshold).
    for m, hi in r.arrival_high.items():
        if m in col.free_amounts and col.theta.get(m, math.inf) > hi:
            return False
    return all(col.free_amounts.get(m, lo) >= lo for m, lo in r.amount_low.items())

