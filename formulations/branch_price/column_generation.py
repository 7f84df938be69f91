"""Column generation at one node (docs/formulations.md, "Pricing"): pricing goes from
cheap to exact, the heuristic labelling; when it finds nothing, the ng relaxation
(``ng_size`` > 0), whose least reduced costs already give a Lagrangian bound and whose
elementary schedules are columns; when that finds no column, the exact labelling, only for
the AAVs whose relaxed least is negative (for the others the exact least is no lower than
the relaxed one, >= -tolerance). Then rounds of arrival cuts, each priced again."""

from __future__ import annotations

import math
import time
from collections.abc import Sequence
from typing import NamedTuple

import numpy as np

from tsac_bench.formulations.branch_price.columns import compatible
from tsac_bench.formulations.branch_price.duals import best_closes, prices
from tsac_bench.formulations.branch_price.master import RC_TOLERANCE, Master
from tsac_bench.formulations.pricing import Restrictions, TaskPrices

#: A node is pruned when its bound is within this (relative) of the incumbent.
PRUNE_TOLERANCE = 1e-9


class NodeLP(NamedTuple):
    """A node's column generation: the LP value, the best Lagrangian bound (-inf: none),
    the LP's lambda and whether it converged (False: cut short, the bound still valid)."""

    value: float
    bound: float
    x: np.ndarray
    converged: bool


class _Bounding(NamedTuple):
    """The relaxed and exact rounds: columns added, the sum of the negative least reduced
    costs of each (None where it did not run), and whether an exact call was cut short."""

    added: int
    relaxed: float | None
    exact: float | None
    cut_short: bool


def reaches(bound: float, cutoff: float) -> bool:
    """Whether a bound prunes against ``cutoff`` (the incumbent's J), within a relative
    PRUNE_TOLERANCE."""
    return bound >= cutoff - PRUNE_TOLERANCE * max(1.0, abs(cutoff))


class ColumnGeneration:
    """The pricing of ``master``'s AAVs and the node loop around it."""

    def __init__(self, master: Master) -> None:
        self.master = master
        self.options = master.options
        self._heuristic_next = 0  # the AAV the next heuristic round starts with

    def cut_and_price(self, restrictions: list[Restrictions], cutoff: float,
                      deadline: float, clock: dict[str, float]) -> NodeLP:
        """A node's column generation, then up to ``arrival_cut_rounds`` rounds of arrival
        cuts, each followed by column generation again, while cuts are violated; the bound
        the best of the rounds (each is valid)."""
        value, bound, x, converged = self.column_generation(restrictions, cutoff, deadline,
                                                            clock)
        for _ in range(self.options.arrival_cut_rounds):
            if not converged or reaches(bound, cutoff):
                break
            separating = time.perf_counter()
            added = self.master.separate_arrival_cuts(x)
            clock["cuts"] += time.perf_counter() - separating
            if not added:
                break
            value, later, x, converged = self.column_generation(restrictions, cutoff,
                                                                deadline, clock)
            bound = max(bound, later)
        return NodeLP(value, bound, x, converged)

    def column_generation(self, restrictions: list[Restrictions], cutoff: float,
                          deadline: float, clock: dict[str, float],
                          heuristic_only: bool = False) -> NodeLP:
        """Price and re-solve until nothing prices out. Stops early when the bound reaches
        ``cutoff`` or at ``deadline``; ``heuristic_only`` (a dive): once the heuristic
        pricing finds nothing, with no bound."""
        master = self.master
        bound = -math.inf
        columns_added = False  # the node's first LP follows bound changes: dual simplex
        center = None  # the smoothed duals the last heuristic round priced at
        while True:
            began = time.perf_counter()
            value, x, duals = master.solve_lp(
                primal=columns_added and self.options.primal_resolves)
            columns_added = True
            clock["lp"] += time.perf_counter() - began
            began = time.perf_counter()
            at = [prices(master, n, duals) for n in range(master.instance.n_aavs)]
            tolerance = RC_TOLERANCE * max(1.0, abs(value))
            added, center = self._heuristic(at, duals, center, restrictions, deadline)
            if heuristic_only and (added == 0 or time.perf_counter() >= deadline):
                clock["pricing"] += time.perf_counter() - began
                return NodeLP(value, -math.inf, master.padded(x), True)
            rounds = _Bounding(added, None, None, False)
            if added == 0:
                rounds = self._bounding(at, restrictions, deadline, tolerance)
            for total in (rounds.relaxed, rounds.exact):
                if total is not None:
                    bound = max(bound, value + total)
            clock["pricing"] += time.perf_counter() - began
            x = master.padded(x)
            if rounds.exact is not None and rounds.cut_short:
                return NodeLP(value, bound, x, False)  # a cut-short pricing settles nothing
            if rounds.exact is not None and rounds.added == 0:
                # Nothing new prices out: the LP value is the node's bound, unless the
                # schedules of negative reduced cost were already columns (float noise
                # between the labelling and HiGHS), where only the Lagrangian bound is sure.
                settled = rounds.exact >= -tolerance
                return NodeLP(value, max(bound, value) if settled else bound, x, True)
            if reaches(bound, cutoff) or time.perf_counter() >= deadline:
                return NodeLP(value, bound, x, False)

    def _heuristic(self, at: list[TaskPrices], duals: np.ndarray, center: np.ndarray | None,
                   restrictions: list[Restrictions], deadline: float
                   ) -> tuple[int, np.ndarray | None]:
        """The heuristic rounds of one LP: (columns added, the duals now at the center)."""
        if not self.options.heuristic_cap:
            return 0, center
        added = 0
        smoothing = self.options.dual_smoothing
        if center is not None and smoothing:
            # Wentges / Neame smoothing: the heuristic prices at a point between the last
            # one and the LP's duals, which jump between extreme points of a degenerate
            # master; if nothing new prices out there, at the LP's duals themselves (no
            # column is missed).
            center = smoothing * center + (1 - smoothing) * duals
            added = self._heuristic_round([prices(self.master, n, center)
                                           for n in range(len(at))], restrictions, deadline)
        else:
            center = duals
        if added == 0:
            added = self._heuristic_round(at, restrictions, deadline)
        return added, center

    def _bounding(self, at: list[TaskPrices], restrictions: list[Restrictions],
                  deadline: float, tolerance: float) -> _Bounding:
        """The relaxed round, then, if it adds nothing, the exact one; each AAV's least
        reduced cost from either bounds the LP (convexity = 1)."""
        n_aavs = len(at)
        least: list[float] | None = None  # per AAV: a lower bound on its least rc
        relaxed = None
        if self.options.ng_size:
            least, added = self._price_round(at, restrictions, range(n_aavs), deadline,
                                             relaxed=True)
            relaxed = sum(min(0.0, v) for v in least)
            if added:
                return _Bounding(added, relaxed, None, False)
        unsure = [n for n in range(n_aavs) if least is None or least[n] < -tolerance]
        exact_least, added = self._price_round(at, restrictions, unsure, deadline)
        known = list(least) if least is not None else [-math.inf] * n_aavs
        for n, v in zip(unsure, exact_least, strict=True):
            known[n] = max(known[n], v)  # -inf where cut short at the deadline
        return _Bounding(added, relaxed, sum(min(0.0, v) for v in known),
                         -math.inf in exact_least)

    def _heuristic_round(self, at: list[TaskPrices], restrictions: list[Restrictions],
                         deadline: float) -> int:
        """Heuristic pricing of the AAVs in turn, from where the last round stopped, until
        ``heuristic_round_columns`` columns are added (0: every AAV): with many AAVs the
        LP is cheap beside a pricing call, and fresh duals after a few AAVs steer the next
        ones better than the duals all of them were priced at. Columns added."""
        n_aavs = len(at)
        cap = self.options.heuristic_round_columns
        added = 0
        for step in range(n_aavs):
            n = (self._heuristic_next + step) % n_aavs
            added += self._price_round(at, restrictions, [n], deadline,
                                       label_cap=self.options.heuristic_cap)[1]
            if cap and added >= cap:
                self._heuristic_next = n + 1
                break
        return added

    def _price_round(self, at: list[TaskPrices], restrictions: list[Restrictions],
                     aavs: Sequence[int], deadline: float, *, label_cap: int | None = None,
                     relaxed: bool = False) -> tuple[list[float], int]:
        """Each of ``aavs`` priced once, its schedules added: (least reduced cost per AAV
        in ``aavs``, columns added)."""
        least, added = [], 0
        for n in aavs:
            v, found = self.master.pricers[n].price(
                at[n], restrictions[n], limit=self.options.columns_per_aav,
                label_cap=label_cap, relaxed=relaxed,
                growth_rounds=self.options.ng_growth_rounds, deadline=deadline)
            least.append(v)
            added += self._add_found(n, found, restrictions, at[n])
        return least, added

    def _add_found(self, n: int, found: list, restrictions: list[Restrictions],
                   at: TaskPrices) -> int:
        """The schedules priced for AAV n, as columns of n and of the AAVs identical to it
        (closed where a node's decisions exclude them); the columns added for n."""
        master = self.master
        added = 0
        for schedule in found:
            made = master.make_column(n, schedule.tail)
            closes = best_closes(made, at)
            for k in master.identical.get(n, (n,)):
                col = master.add_column(k, schedule.tail, closes, made)
                if col is None:
                    continue
                if not compatible(col, restrictions[k]):
                    master.h.changeColBounds(col.index, 0.0, 0.0)
                    master.closed.add(col.index)
                elif k == n:
                    added += 1
        return added
