"""Arrival cuts of the master (docs/formulations.md, "Arrival cuts"): what a column pays in
one, how a violated one is found, and how their duals reach the pricing.

In a plan C_time = max over the members of their arrival terms, so for every tau the
indicator [C_time > tau] is at least [theta_k > tau] for each AAV k, and C_time = the
integral of that indicator over tau in [0, 1]. In the LP each AAV's columns give P_k(tau) =
sum of lambda over its columns arriving later than tau, and the per-AAV time rows integrate
one P_k each; integrating max_k P_k(tau) instead is the strongest bound on the latest member
that these marginals give (a comonotone coupling attains it). Two more sources join the max,
each as valid as its own row: the closers (sum of lambda over the columns that close m,
arriving later than tau: one closer, the latest member, in a plan) and the goods (the share
of R_m arriving later than tau: the goods-time row's argument, only on the tasks that row
has). A cut is the row
    Ctime_m - nobody_m - sum_c coef_c lambda_c >= 0,
one source per piece of [0, 1] (lo, hi, source), coef_c the length of [0, theta_cm) under
the pieces of c's sources; its dual prices an arrival by a non-decreasing piecewise linear
function (TaskPrices.arrival_cuts)."""

from __future__ import annotations

import bisect
import itertools
from collections.abc import Iterator, Sequence

import numpy as np
from numba import njit

from tsac_bench.formulations.branch_price.columns import Column

#: The sources of a cut's piece besides an AAV (>= 0): the closers, the goods.
CLOSERS, GOODS = -1, -2
#: A cut is added where the LP point violates it by more than this (in units of C_time).
ARRIVAL_CUT_VIOLATION = 1e-4

Piece = tuple[float, float, int]  # (lo, hi, source)


class TaskCuts:
    """One task's arrival cuts, iterable as (row, pieces) in the order added, and packed in
    arrays: a column's coefficients in all of them come from one compiled loop (the master
    takes columns by the ten thousand, each into every cut of each task it reaches)."""

    def __init__(self, task: int, demand: float) -> None:
        self.task = task
        self.demand = demand
        self._cuts: list[tuple[int, tuple[Piece, ...]]] = []
        self.rows = np.zeros(0, np.int64)
        self._packed = pack([])

    def add(self, row: int, pieces: Sequence[Piece]) -> None:
        self._cuts.append((row, tuple(pieces)))
        self.rows = np.array([r for r, _ in self._cuts], np.int64)
        self._packed = pack([pieces for _, pieces in self._cuts])

    def __iter__(self) -> Iterator[tuple[int, tuple[Piece, ...]]]:
        return iter(self._cuts)

    def __len__(self) -> int:
        return len(self._cuts)

    def coefficients(self, col: Column) -> np.ndarray:
        """The column's coefficient in each cut (``cut_coefficients``), by ``rows``."""
        return cut_coefficients(col, self.task, self.demand, self._packed)


def pack(cuts: Sequence[Sequence[Piece]]) -> tuple[np.ndarray, ...]:
    """Pieces of cuts as arrays lo, hi, source and the cut of each, the cuts' count last."""
    flat = [(lo, hi, source, c) for c, pieces in enumerate(cuts) for lo, hi, source in pieces]
    lo, hi, source, cut = zip(*flat, strict=True) if flat else ((), (), (), ())
    return (np.array(lo, float), np.array(hi, float), np.array(source, np.int64),
            np.array(cut, np.int64), np.int64(len(cuts)))


def cut_coefficients(col: Column, m: int, demand: float, packed: tuple[np.ndarray, ...]
                     ) -> np.ndarray:
    """The column's coefficient in each of task m's ``packed`` cuts: the part of
    [0, theta_cm) that the pieces of its own AAV, of the closers (when it closes m) and of
    the goods (weighed by its share a_cm / R_m) cover."""
    theta = col.theta.get(m)
    if theta is None:
        return np.zeros(int(packed[-1]))
    return _coefficients(theta, col.amounts[m] / demand, col.aav, m in col.closes, *packed)


@njit(cache=True)
def _coefficients(theta, share, aav, closes, lo, hi, source, cut, n_cuts):
    out = np.zeros(n_cuts)
    for p in range(lo.shape[0]):
        s = source[p]
        if theta > lo[p] and (s in (aav, GOODS) or (s == CLOSERS and closes)):
            out[cut[p]] += (min(theta, hi[p]) - lo[p]) * (share if s == GOODS else 1.0)
    return out


def later_shares(m: int, positive: Sequence[Column], x: np.ndarray, demand: float,
                 goods_row: bool) -> list[tuple[float, int, float]]:
    """Task m's (theta, source, weight) shares at the LP point ``x``: each positive column's
    lambda for its AAV, for the closers where it closes m, and its share of the goods where
    m has a goods-time row."""
    later = []
    for col in positive:
        lam = x[col.index]
        theta = col.theta.get(m)
        if theta is None or theta <= 0.0:
            continue
        later.append((theta, col.aav, lam))
        if goods_row:
            later.append((theta, GOODS, lam * col.amounts[m] / demand))
        if m in col.closes:
            later.append((theta, CLOSERS, lam))
    return later


def largest_share_pieces(later: Sequence[tuple[float, int, float]]
                         ) -> tuple[float, list[Piece]]:
    """A cut's separation for one task from its (theta, source, weight) shares: per interval
    between consecutive arrivals, the source with the most weight arriving later; (the
    integral of that largest share, the pieces (lo, hi, source), adjacent intervals of one
    source merged)."""
    breaks = sorted({0.0, *(theta for theta, _, _ in later)})
    pieces: list[Piece] = []
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


def priced_pieces(n: int, cuts: Sequence[tuple[int, tuple[Piece, ...]]], duals: np.ndarray,
                  demand: float) -> list[tuple[float, float, float, float, float]]:
    """A task's cuts as AAV n's pricing sees them: their duals summed into disjoint pieces
    (lo, hi, aav, closer, goods per kg), so that a label pays per visit for a few pieces
    rather than for every piece of every cut."""
    per_kg = 1.0 / demand
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
