"""Branching (docs/formulations.md, "Branching and search"), in this order, on a fractional
1. visit x_km = sum of lambda over k's columns that visit m (free part; of the most
   fractional few, the one whose children's LPs rise most: strong branching, then
   pseudo-costs once a candidate is reliable),
2. arrival window of k at m (with every visit integral, the most spread arrival term),
3. arc x_k(i, j, mode) (the free arcs of k's columns),
4. amount sum_c a_cm lambda_c of k at m (a_km <= v or >= v + 1).
When all are integral, every AAV's positive columns share one route and their average
amounts are integral and feasible (the load rows of a route are an interval matrix), so
that plan has J = the LP value and closes the node."""

from __future__ import annotations

import math

import numpy as np

from tsac_bench.formulations.branch_price.columns import BranchDecision, Kind, Side
from tsac_bench.formulations.branch_price.master import (
    DUAL_SIMPLEX,
    INTEGRALITY,
    POSITIVE,
    Master,
)
from tsac_bench.model import Route, Visit

Candidate = tuple[tuple[int, int], float]  # ((AAV, task), x_km)


class Brancher:
    """The branching rule over ``master``'s LP, with the pseudo-costs it learns."""

    def __init__(self, master: Master) -> None:
        self.master = master
        self.options = master.options
        # Reliability branching's history, per (AAV, task): [rise per unit, count] of the
        # side to 0 and of the side to 1 (strongest).
        self.pseudo_costs: dict[tuple[int, int], list[list]] = {}

    def choose(self, x: np.ndarray) -> BranchDecision | tuple[Route, ...]:
        """The first side of the branching decision at the LP point ``x``, or the integral
        plan."""
        visit = self.master.visits(x)
        frac = _most_fractional_first(visit)
        if frac:
            if self.options.strong_candidates > 1 and len(frac) > 1:
                k, m = self.strongest([(key, visit[key])
                                       for key in frac[:self.options.strong_candidates]])
            else:
                (k, m) = frac[0]
            return BranchDecision(Kind.VISIT, k, m, Side.EXCLUDED)
        arc, amount, arrivals = self._flows(x)
        if self.options.time_branching:
            split = widest_arrival(arrivals)
            if split is not None:
                (k, m), threshold = split
                return BranchDecision(Kind.TIME, k, m, Side.AT_MOST, threshold)
        frac = _most_fractional_first(arc)
        if frac:
            (k, e) = frac[0]
            return BranchDecision(Kind.ARC, k, e, Side.EXCLUDED)
        frac = [(abs(v - math.floor(v) - 0.5), key) for key, v in sorted(amount.items())
                if abs(v - round(v)) > INTEGRALITY]
        if frac:
            k, m = min(frac)[1]
            return BranchDecision(Kind.AMOUNT, k, m, Side.AT_MOST, math.floor(amount[k, m]))
        return self._integral_plan(x, amount)

    def _flows(self, x: np.ndarray) -> tuple[dict, dict, dict]:
        """Per (AAV, free arc) its flow, per (AAV, task) its amount and its (lambda,
        arrival term) points, at the LP point ``x``."""
        arc: dict[tuple[int, tuple[int, int, int]], float] = {}
        amount: dict[tuple[int, int], float] = {}
        arrivals: dict[tuple[int, int], list[tuple[float, float]]] = {}
        for col in self.master.columns:
            v = x[col.index]
            if v <= POSITIVE:
                continue
            for m, a in col.free_amounts.items():
                amount[col.aav, m] = amount.get((col.aav, m), 0.0) + v * a
                if m in col.theta:
                    arrivals.setdefault((col.aav, m), []).append((v, col.theta[m]))
            for e in col.arcs:
                arc[col.aav, e] = arc.get((col.aav, e), 0.0) + v
        return arc, amount, arrivals

    def _integral_plan(self, x: np.ndarray, amount: dict[tuple[int, int], float]
                       ) -> tuple[Route, ...]:
        """The plan of an integral LP: each AAV's route with its average amounts."""
        routes = []
        for n in range(self.master.instance.n_aavs):
            cols = [c for c in self.master.columns if c.aav == n and x[c.index] > POSITIVE]
            route = max(cols, key=lambda c: x[c.index]).route
            routes.append(tuple(Visit(v.node, round(amount[n, v.node]))
                                if v.node in cols[0].free_amounts else v for v in route))
        return tuple(routes)

    def strongest(self, candidates: list[Candidate]) -> tuple[int, int]:
        """Of the (AAV, task) visit candidates with their x_km, the one whose two children's
        LPs rise the most, by the product of the two rises. A candidate is scored by strong
        branching (its children's LPs over the present columns, no pricing: a score, not a
        bound) until each side has ``strong_reliability`` measured rises (strong branching's
        or, from the search, its children's), and from then on by its pseudo-costs, the mean
        rise per unit of x_km moved on each side (reliability branching, Achterberg, Koch and
        Martin 2005). The LP is left as it was (bounds and basis)."""
        value = self.master.h.getInfo().objective_function_value
        saved = None
        best, best_score = candidates[0][0], -math.inf
        for (k, m), v in candidates:
            moves = (v, 1.0 - v)  # to 0, to 1
            history = self.pseudo_costs.get((k, m))
            reliability = self.options.strong_reliability
            if reliability and history is not None and \
                    min(count for _, count in history) >= reliability:
                rises = [move * total / count for move, (total, count)
                         in zip(moves, history, strict=True)]
            else:
                if saved is None:
                    saved = self.master.basis()
                    self.master.h.setOptionValue("simplex_strategy", DUAL_SIMPLEX)  # bounds
                rises = self._child_rises(k, m, value, saved)
                for side, (rise, move) in enumerate(zip(rises, moves, strict=True)):
                    self.record_rise((k, m), side, rise, move)
            score = max(rises[0], 1e-9) * max(rises[1], 1e-9)
            if score > best_score:
                best, best_score = (k, m), score
        return best

    def _child_rises(self, k: int, m: int, value: float, saved: tuple[list, list]
                     ) -> list[float]:
        """The rise of each child's LP over the present columns (x_km to 0, then to 1)
        over ``value``; inf for an infeasible child. The bounds and ``saved`` are put back."""
        import highspy

        master = self.master
        h = master.h
        visiting = {c.index for c in master.visiting.get((k, m), ())}
        rises = []
        for close in (visiting, set(master.columns_of[k]) - visiting):
            newly = np.array(sorted(close - master.closed), np.int32)
            if len(newly):
                h.changeColsBounds(len(newly), newly, np.zeros(len(newly)),
                                   np.zeros(len(newly)))
            h.run()
            master.lp_solves += 1
            ok = h.getModelStatus() == highspy.HighsModelStatus.kOptimal
            child = h.getInfo().objective_function_value if ok else math.inf
            rises.append(child - value)
            if len(newly):
                h.changeColsBounds(len(newly), newly, np.zeros(len(newly)),
                                   np.full(len(newly), master.inf))
            master.restore_basis(saved)
        return rises

    def record_rise(self, key: tuple[int, int], side: int, rise: float, move: float) -> None:
        """A child's LP rise over its parent's when x_km moved by ``move`` to 0 (side 0) or
        to 1 (side 1), into the candidate's pseudo-costs."""
        if math.isfinite(rise):  # an infeasible child says nothing per unit
            history = self.pseudo_costs.setdefault(key, [[0.0, 0], [0.0, 0]])
            history[side][0] += max(rise, 0.0) / move
            history[side][1] += 1

    def dive_side(self, choice: BranchDecision, x: np.ndarray) -> BranchDecision:
        """The side of a (non-visit) branching decision nearer to the LP solution: the
        earlier side of an arrival window, an arc rounded to 0 or 1, an amount rounded."""
        if choice.kind is Kind.TIME:
            return choice
        cols = [c for c in self.master.columns
                if c.aav == choice.aav and x[c.index] > POSITIVE]
        if choice.kind is Kind.ARC:
            flow = math.fsum(x[c.index] for c in cols if choice.key in c.arcs)
            return BranchDecision(Kind.ARC, choice.aav, choice.key,
                                  Side.REQUIRED if flow >= 0.5 else Side.EXCLUDED)
        amount = math.fsum(x[c.index] * c.free_amounts.get(choice.key, 0) for c in cols)
        if amount - choice.value < 0.5:
            return choice
        return BranchDecision(Kind.AMOUNT, choice.aav, choice.key, Side.AT_LEAST,
                              choice.value + 1)


def other_side(choice: BranchDecision) -> BranchDecision:
    """The second child's decision of a branching ``choice`` (its first side)."""
    if choice.kind is Kind.AMOUNT:
        return BranchDecision(Kind.AMOUNT, choice.aav, choice.key, Side.AT_LEAST,
                              choice.value + 1)
    if choice.kind is Kind.TIME:
        return BranchDecision(Kind.TIME, choice.aav, choice.key, Side.LATER, choice.value)
    return BranchDecision(choice.kind, choice.aav, choice.key, Side.REQUIRED)


def widest_arrival(arrivals: dict[tuple[int, int], list[tuple[float, float]]]
                   ) -> tuple[tuple[int, int], float] | None:
    """With every visit integral, an AAV's columns still mix visit orders, and the time
    rows see the lambda-average of their arrivals where the plan pays the latest member's
    (the leak of the root bound, docs/formulations.md). Of the (AAV, task) pairs whose
    arrival term is spread over columns, the one of largest mean absolute deviation, split
    at its mean (both sides then carry weight)."""
    best, best_spread = None, 0.0
    for key, points in sorted(arrivals.items()):
        weight = math.fsum(v for v, _ in points)
        mean = math.fsum(v * t for v, t in points) / weight
        spread = math.fsum(v * abs(t - mean) for v, t in points) / weight
        below = math.fsum(v for v, t in points if t <= mean)
        if spread > best_spread and INTEGRALITY < below < weight - INTEGRALITY:
            best, best_spread = (key, mean), spread
    return best


def _most_fractional_first(values: dict[tuple, float]) -> list[tuple]:
    """The keys of the fractional 0-1 values, nearest to 0.5 first (ties by key)."""
    return [key for _, key in sorted((abs(v - 0.5), key) for key, v in values.items()
                                     if INTEGRALITY < v < 1 - INTEGRALITY)]
