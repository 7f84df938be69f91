"""The route master of one planning state (docs/formulations.md, "Master"): its LP in
HiGHS, the pricers of its AAVs, the column pool, the cut rows and the rows and bounds by
which a node's branching decisions restrict it."""

from __future__ import annotations

import dataclasses
import heapq
import itertools
import math
from collections.abc import Sequence
from typing import Any

import numpy as np

from tsac_bench.formulations.branch_price.columns import (
    Arc3,
    BranchDecision,
    Column,
    Kind,
    Side,
    compatible,
    early_visit,
    in_required_row,
)
from tsac_bench.formulations.branch_price.cuts import (
    ARRIVAL_CUT_VIOLATION,
    TaskCuts,
    cut_coefficients,
    largest_share_pieces,
    later_shares,
    pack,
)
from tsac_bench.formulations.branch_price.options import BranchPriceOptions
from tsac_bench.formulations.network import (
    DIRECT,
    aav_network,
    coalition_cover_cuts,
    identical_groups,
    late_committed,
    parse_prefix,
    prefix_arrivals,
)
from tsac_bench.formulations.pricing import Pricer, Restrictions, anchor_of, schedule_route
from tsac_bench.model import Instance, Route, Visit
from tsac_bench.planning import PlanningState

#: Reduced costs above -this count as non-negative (column generation has converged).
RC_TOLERANCE = 1e-9
#: A branching quantity within this of an integer counts as integral.
INTEGRALITY = 1e-6
#: A lambda above this is part of the LP solution (below: HiGHS's zero).
POSITIVE = 1e-12
#: The artificial columns of "1" sides above this: the node is infeasible.
ARTIFICIAL = 1e-9
#: Shedding leaves this share of the pool's limit (``columns_per_row``): the pool does not
#: refill at the next node.
POOL_KEEP = 0.5
#: HiGHS's ``simplex_strategy`` values.
DUAL_SIMPLEX, PRIMAL_SIMPLEX = 1, 4


class Master:
    """The master LP, its columns (``columns``, indexed by LP column, AAV, task and arc) and
    the rows that cuts and decisions add; ``options`` decided for the state's size."""

    def __init__(self, instance: Instance, tasks: Sequence[int] | None,
                 committed: Sequence[Route] | None, plan_time: float,
                 options: BranchPriceOptions,
                 reach: Sequence[frozenset[int] | None] | None = None) -> None:
        import highspy

        self.instance = instance
        moment, in_prefix, late = self._state(tasks, committed, plan_time)
        self.reach = tuple(reach) if reach is not None else None
        self.options = options.for_tasks(len(self.tasks))
        self.pricers = [self._pricer(moment, n) for n in range(instance.n_aavs)]
        self.identical = _identical(instance, self.committed, self.reach)
        self.h = highspy.Highs()
        self.h.setOptionValue("output_flag", False)
        self.h.setOptionValue("threads", int(self.options.threads))
        self.inf = highspy.kHighsInf
        self.n_cols = 0
        self.n_rows = 0
        self._task_rows(in_prefix)
        self._task_variables()
        # Arrival cuts (separate_arrival_cuts) per task, each a row and its pieces.
        self.arrival_cuts: dict[int, TaskCuts] = {}
        # Coalition cover cuts (network.coalition_cover_cuts): (row, task, {AAV: coef}).
        self.cuts: list[tuple[int, int, dict[int, int]]] = []
        if self.options.cover_cuts:
            self._cover_cuts(late)
        # Identical AAVs n1 < n2: (row, n1, n2, j) (_symmetry_rows).
        self.symmetry: list[tuple[int, int, int, int]] = []
        if self.options.symmetry:
            self._symmetry_rows()
        if not self.options.closer_rows:
            for m in self.timed:
                self.h.changeRowBounds(self.closer[m], -self.inf, self.inf)
                self.h.changeRowBounds(self.closer_time[m], -self.inf, self.inf)
        w1, w2, w3 = instance.weights
        full = sum(a.full_range_cost / instance.e_base for a in instance.aavs)
        self.big = 10.0 * (self.constant + len(self.tasks) * (w1 + w2 + w3 * full)) + 100.0
        self.column_limit = int(self.options.columns_per_row * self.n_rows)  # 0: no limit
        self._empty_pool()
        # Decision rows: a "1" side's key -> (row, artificial); an arrival window's "later
        # than" side (AAV, task, threshold) -> the row sum of lambda over the AAV's columns
        # that visit the task with theta <= threshold, <= 0 where the decision holds (its
        # dual prices early visits in the labelling, where a hard floor would break the
        # dominance of earlier labels).
        self.required: dict[tuple[Kind, int, Any], tuple[int, int]] = {}
        self.early: dict[tuple[int, int, float], int] = {}
        self.closed: set[int] = set()  # the LP columns whose upper bound is 0 at the node
        self.generated = 0  # columns ever added (purge_columns removes some)
        self.purged = 0
        self.lp_solves = 0  # master LPs solved (column generation, strong branching, dives)
        for n in range(instance.n_aavs):
            self.add_column(n, ())

    # --- building ----------------------------------------------------------------------
    def _state(self, tasks: Sequence[int] | None, committed: Sequence[Route] | None,
               plan_time: float) -> tuple[PlanningState, set[int], list[tuple[int, int]]]:
        """The planning state's tasks, prefixes and constant; (the state, the tasks in a
        prefix, the late committed (AAV, task) visits)."""
        instance = self.instance
        self.committed = tuple(committed) if committed else tuple(
            () for _ in range(instance.n_aavs))
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
        w1, w2, _ = instance.weights
        self.constant = (instance.unserved_task_cost * (instance.n_tasks - len(self.tasks))
                         + w1 * len(self.tasks) + w2 * len(self.late_tasks))
        return moment, in_prefix, late

    def _pricer(self, moment: PlanningState, n: int) -> Pricer:
        instance, prefix = self.instance, self.prefixes[n]
        required = [(i, j, k) for i, j, k, _ in prefix.steps]
        trailing = None if prefix.trailing_depot is None else (prefix.last,
                                                                 prefix.trailing_depot)
        leaves = moment.anchor(n)
        tasks = self.tasks
        if self.reach is not None and self.reach[n] is not None:
            own = {m for _, m, _, _ in prefix.steps}
            tasks = [m for m in tasks if m in self.reach[n] or m in own]
        network = aav_network(instance, n, tasks,
                              prefix_arrivals(instance, n, self.committed[n]), required,
                              trailing, prefix.last, leaves.time)
        anchor = anchor_of(instance, n, self.committed[n], prefix.trailing_depot,
                           prefix.last, leaves)
        return Pricer(instance, n, network, anchor, self.timed, self.options.ng_size,
                      self.options.completion_steps)

    def _task_rows(self, in_prefix: set[int]) -> None:
        """Convexity, coverage, closer, closer time, per-AAV time and goods-time rows."""
        self.conv = [self._row(1.0, 1.0) for _ in range(self.instance.n_aavs)]
        self.cover = {m: self._row(0.0, self.inf) for m in self.tasks}
        self.closer = {m: self._row(1.0, self.inf) for m in self.timed}
        self.closer_time = {m: self._row(0.0, self.inf) for m in self.timed}
        self.aav_time = {(k, m): self._row(0.0, self.inf) for k in range(self.instance.n_aavs)
                         for m in self.pricers[k].network.tasks if m in self.timed}
        # Goods-weighted arrival rows R_m Ctime_m >= sum_c theta_cm a_cm lambda_c (docs:
        # valid for an optimum whose members bring no more than R_m in all), on the tasks
        # no committed visit has served yet.
        self.goods_time = {m: self._row(0.0, self.inf) for m in self.timed
                           if m not in in_prefix} if self.options.goods_time_rows else {}

    def _task_variables(self) -> None:
        """covered_m, Ctime_m and nobody_m with their entries in the task rows."""
        instance = self.instance
        w1, w2, _ = instance.weights
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

    def _cover_cuts(self, late: list[tuple[int, int]]) -> None:
        instance = self.instance
        amount_cap = {}
        for n, prefix in enumerate(self.prefixes):
            for _, m, _, a in prefix.steps:
                amount_cap[n, m] = a
        late_pairs = set(late)
        for m in self.tasks:
            demand = instance.tasks[m].demand
            upper = {n: max(min(instance.aavs[n].capacity, demand), amount_cap.get((n, m), 0))
                     for n in range(instance.n_aavs) if m in self.pricers[n].network.tasks
                     and (n, m) not in late_pairs}
            for rest, coef in coalition_cover_cuts(upper, demand):
                row = self._row(-float(rest), self.inf)
                self.h.changeCoeff(row, self.covered[m], -1.0)
                self.cuts.append((row, m, coef))

    def _symmetry_rows(self) -> None:
        """Identical AAVs n1 < n2 (same type and start, no prefix) ordered as in the MILP: n2
        visits task j only if n1 visits a task i <= j (a plan's identical routes can be
        permuted into that order). Rows x_{n1, i <= j} - x_{n2, j} >= 0."""
        for group in identical_groups(self.instance, self.committed, self.reach):
            for n1, n2 in itertools.pairwise(group):
                for j in self.pricers[n2].network.tasks:
                    self.symmetry.append((self._row(0.0, self.inf), n1, n2, j))

    def _empty_pool(self) -> None:
        self.columns: list[Column] = []
        self.column_at: dict[int, Column] = {}  # by LP column
        self.arriving: dict[int, list[Column]] = {}  # by timed task visited on time
        self.by_key: dict[tuple[int, tuple[Visit, ...], frozenset[int]], Column] = {}
        self.visiting: dict[tuple[int, int], list[Column]] = {}  # by (AAV, free task)
        self.using_arc: dict[tuple[int, Arc3], list[Column]] = {}  # by (AAV, free arc)
        self.columns_of: list[list[int]] = [[] for _ in self.instance.aavs]

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
        feasible); a primal run that does not end optimal is repeated by the dual simplex
        (HiGHS's primal solver has had cycling reports)."""
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

    def padded(self, x: np.ndarray) -> np.ndarray:
        """An LP's per-column vector (lambda, reduced costs) with 0 for the columns added
        after that LP."""
        return np.concatenate([x, np.zeros(self.n_cols - len(x))])

    # --- columns -------------------------------------------------------------------------
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
        return Column(n, tail, route, op, amounts, theta, free, frozenset(arcs),
                      _closing(theta, closes))

    def add_column(self, n: int, tail: tuple[Visit, ...],
                   closes: frozenset[int] | None = None, made: Column | None = None
                   ) -> Column | None:
        """The column of AAV n's schedule ``tail`` added to the LP and the pool, or None if
        the pool has it with the same closing set. ``made``: the schedule's column as
        ``make_column`` gave it for n or an AAV identical to n (same type and start, no
        prefix: the same walk), copied instead of walking the route again."""
        if made is None:
            col = self.make_column(n, tail, closes)
        else:
            col = dataclasses.replace(made, aav=n, closes=_closing(made.theta, closes))
        if (n, tail, col.closes) in self.by_key:
            return None
        col.index = self._col(col.op, 0.0, self.inf, self._entries(col))
        self.generated += 1
        self._register(col)
        return col

    def _entries(self, col: Column) -> list[tuple[int, float]]:
        """The column's coefficients in every row of the master."""
        n = col.aav
        entries = [(self.conv[n], 1.0)]
        entries += [(self.cover[m], float(a)) for m, a in col.amounts.items() if m in self.cover]
        entries += [(self.aav_time[n, m], -t) for m, t in col.theta.items()
                    if (n, m) in self.aav_time]
        entries += [(self.goods_time[m], -t * col.amounts[m]) for m, t in col.theta.items()
                    if m in self.goods_time]
        entries += [(row, 1.0) for key, (row, _) in self.required.items()
                    if in_required_row(key, col)]
        entries += [(row, 1.0) for key, row in self.early.items() if early_visit(key, col)]
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
            if m in self.arrival_cuts:
                cuts = self.arrival_cuts[m]
                entries += [(int(row), -float(coef)) for row, coef
                            in zip(cuts.rows, cuts.coefficients(col), strict=True) if coef]
        return entries

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
        whether it was once a column or not. ``queue`` holds the open nodes (bound, tie,
        decisions, saved basis or None). Returns the node's LP solution and ``queue`` in
        the LP's new column indices."""
        if not self.column_limit or len(self.columns) <= self.column_limit:
            return x, queue
        saved = {id(entry[3]): entry[3] for entry in queue if entry[3] is not None}
        drop = self._sheddable(saved.values())
        if not drop:
            return x, queue
        keep = np.ones(self.n_cols, bool)
        keep[[c.index for c in drop]] = False
        self.h.deleteCols(len(drop), np.array(sorted(c.index for c in drop), np.int32))
        self._renumber(keep)
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

    def _sheddable(self, saved: Any) -> list[Column]:
        """The columns to shed, largest reduced cost first, none basic in the present LP or
        in a ``saved`` basis, and no AAV's first column."""
        import highspy

        basic = highspy.HighsBasisStatus.kBasic
        protected = {cols[0] for cols in self.columns_of}
        for cols, _ in [self.basis(), *saved]:
            protected.update(j for j, status in enumerate(cols) if status == basic)
        # A column newer than the LP gets reduced cost 0: it is never shed unseen.
        reduced = self.padded(np.asarray(self.h.getSolution().col_dual))
        ranked = sorted((c for c in self.columns
                         if c.index not in protected and reduced[c.index] > RC_TOLERANCE),
                        key=lambda c: (-reduced[c.index], c.index))
        return ranked[:len(self.columns) - int(POOL_KEEP * self.column_limit)]

    def _renumber(self, keep: np.ndarray) -> None:
        """The pool and every index of LP columns after the columns not in ``keep`` left."""
        self.n_cols = int(keep.sum())
        renumber = np.cumsum(keep) - 1
        live = [c for c in self.columns if keep[c.index]]
        for col in live:
            col.index = int(renumber[col.index])
        self._empty_pool()
        for col in live:
            self._register(col)
        self.covered = {m: int(renumber[j]) for m, j in self.covered.items()}
        self.ctime = {m: int(renumber[j]) for m, j in self.ctime.items()}
        self.nobody = {m: int(renumber[j]) for m, j in self.nobody.items()}
        self.required = {key: (row, int(renumber[j]))
                         for key, (row, j) in self.required.items()}
        self.closed = {int(renumber[j]) for j in self.closed if keep[j]}

    # --- a node's decisions --------------------------------------------------------------
    def apply(self, decisions: Sequence[BranchDecision]) -> list[Restrictions]:
        """Set the LP to a node's decisions; the pricing restrictions per AAV."""
        restrictions, required, early = _restrictions(decisions, self.instance.n_aavs)
        for key in required:
            self._required_row(key)
        for key, (row, artificial) in self.required.items():
            on = key in required
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
                              if not compatible(c, r))
        for index in closed - self.closed:
            self.h.changeColBounds(index, 0.0, 0.0)
        for index in self.closed - closed:
            self.h.changeColBounds(index, 0.0, self.inf)
        self.closed = closed
        return restrictions

    def _required_row(self, key: tuple[Kind, int, Any]) -> None:
        """The row of a "1" side, sum lambda >= 1 where it holds, with an artificial column
        of prohibitive cost that keeps the LP feasible."""
        if key not in self.required:
            row = self._row(-self.inf, self.inf)
            for j in [c.index for c in self.columns if in_required_row(key, c)]:
                self.h.changeCoeff(row, j, 1.0)
            artificial = self._col(self.big, 0.0, 0.0, [(row, 1.0)])
            self.required[key] = (row, artificial)

    def _early_row(self, key: tuple[int, int, float]) -> None:
        if key not in self.early:
            row = self._row(-self.inf, self.inf)
            for col in self.visiting.get(key[:2], ()):
                if early_visit(key, col):
                    self.h.changeCoeff(row, col.index, 1.0)
            self.early[key] = row

    def infeasible(self, x: np.ndarray) -> bool:
        """Whether the node's LP needs its artificial columns (no plan keeps its "1" sides)."""
        return sum(x[a] for _, a in self.required.values()) > ARTIFICIAL

    # --- arrival cuts --------------------------------------------------------------------
    def separate_arrival_cuts(self, x: np.ndarray) -> int:
        """Add the most violated arrival cut (formulations/branch_price/cuts.py) of every
        timed task whose LP point ``x`` violates one; the number added."""
        added = 0
        positive = [self.column_at[j] for j in np.flatnonzero(x > INTEGRALITY)
                    if j in self.column_at]
        for m in sorted(self.timed):
            demand = self.instance.tasks[m].demand
            later = later_shares(m, positive, x, demand, m in self.goods_time)
            total, pieces = largest_share_pieces(later)
            if total + x[self.nobody[m]] - x[self.ctime[m]] <= ARRIVAL_CUT_VIOLATION:
                continue
            entries = [(self.ctime[m], 1.0), (self.nobody[m], -1.0)]
            packed = pack([pieces])
            for col in self.arriving.get(m, ()):
                coef = float(cut_coefficients(col, m, demand, packed)[0])
                if coef:
                    entries.append((col.index, -coef))
            row = self._row(0.0, self.inf, entries)
            self.arrival_cuts.setdefault(m, TaskCuts(m, demand)).add(row, pieces)
            added += 1
        return added

    # --- plans off the LP ----------------------------------------------------------------
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
            if x[col.index] > POSITIVE:
                for m in col.free_amounts:
                    visit[col.aav, m] = visit.get((col.aav, m), 0.0) + x[col.index]
        return visit

    def integer_master_plan(self, cutoff: float, time_limit: float
                            ) -> tuple[Route, ...] | None:
        """A plan from the master with lambda integer over its columns (HiGHS's MIP, at most
        ``master_mip_nodes`` nodes and ``time_limit`` s, pruning at ``cutoff``): it puts
        together columns that no single LP solution does, or None. Only the
        ``master_mip_columns`` columns of least reduced cost at the last LP solved take
        part (and each AAV's empty schedule): over the whole pool HiGHS's MIP finds no
        good plan in the time it has. Its objective is at least the J of its plan, and
        equal with the right closing sets. The live LP is left at the root's bounds (each
        node sets its own)."""
        import highspy

        reduced = self.padded(np.asarray(self.h.getSolution().col_dual))
        self.apply(())
        mip = highspy.Highs()
        mip.setOptionValue("output_flag", False)
        mip.setOptionValue("threads", self.options.threads)
        mip.setOptionValue("mip_max_nodes", self.options.master_mip_nodes)
        mip.setOptionValue("time_limit", max(time_limit, 0.01))
        mip.setOptionValue("objective_bound", cutoff - self.constant)
        mip.passModel(self.h.getLp())
        lambdas = np.array([c.index for c in self.columns], np.int32)
        mip.changeColsIntegrality(len(lambdas), lambdas,
                                  np.full(len(lambdas), highspy.HighsVarType.kInteger))
        keep = self.options.master_mip_columns
        if keep:
            empty = {cols[0] for cols in self.columns_of}
            ranked = sorted((c.index for c in self.columns if c.index not in empty),
                            key=lambda j: (reduced[j], j))
            left_out = np.array(ranked[keep:], np.int32)
            mip.changeColsBounds(len(left_out), left_out, np.zeros(len(left_out)),
                                 np.zeros(len(left_out)))
        mip.run()
        if not mip.getInfo().primal_solution_status:
            return None
        return self.rounded_plan(np.asarray(mip.getSolution().col_value))


def _restrictions(decisions: Sequence[BranchDecision], n_aavs: int
                  ) -> tuple[list[Restrictions], set[tuple[Kind, int, Any]],
                             set[tuple[int, int, float]]]:
    """A node's decisions as (pricing restrictions per AAV, the keys of its "1" sides
    (a visit an amount's lower side implies included), its "later than" sides)."""
    restrictions = [Restrictions(frozenset(), frozenset(), {}, {}) for _ in range(n_aavs)]
    required, early = set(), set()
    forbid_t = [set() for _ in range(n_aavs)]
    forbid_a = [set() for _ in range(n_aavs)]
    for d in decisions:
        r = restrictions[d.aav]
        if d.kind is Kind.VISIT and d.side is Side.EXCLUDED:
            forbid_t[d.aav].add(d.key)
        elif d.kind is Kind.ARC and d.side is Side.EXCLUDED:
            forbid_a[d.aav].add(d.key)
        elif d.kind is Kind.AMOUNT and d.side is Side.AT_MOST:
            r.amount_high[d.key] = min(r.amount_high.get(d.key, 10**9), d.value)
        elif d.kind is Kind.AMOUNT:
            r.amount_low[d.key] = max(r.amount_low.get(d.key, 1), d.value)
            required.add((Kind.VISIT, d.aav, d.key))
        elif d.kind is Kind.TIME and d.side is Side.AT_MOST:
            r.arrival_high[d.key] = min(r.arrival_high.get(d.key, math.inf), d.value)
        elif d.kind is Kind.TIME:
            early.add((d.aav, d.key, d.value))
        else:
            required.add((d.kind, d.aav, d.key))
    for n, r in enumerate(restrictions):
        r.forbidden_tasks = frozenset(forbid_t[n])
        r.forbidden_arcs = frozenset(forbid_a[n])
    return restrictions, required, early


def _closing(theta: dict[int, float], closes: frozenset[int] | None) -> frozenset[int]:
    """A column's closing set: ``closes`` (None: every timed task) among the timed tasks
    it visits on time."""
    return frozenset(theta) if closes is None else closes & frozenset(theta)


def _sparse(entries: Sequence[tuple[int, float]]) -> tuple[np.ndarray, np.ndarray]:
    """(indices, values) of a row's or column's entries, as highspy takes them."""
    return (np.array([j for j, _ in entries], np.int32),
            np.array([v for _, v in entries], float))


def _identical(instance: Instance, committed: Sequence[Route],
               reach: Sequence[frozenset[int] | None] | None
               ) -> dict[int, tuple[int, ...]]:
    """Each AAV of a group of identical ones, with its group (pricing one prices all)."""
    groups = {}
    for group in identical_groups(instance, committed, reach):
        for n in group:
            groups[n] = tuple(group)
    return groups
