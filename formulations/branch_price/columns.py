"""The master's columns and the branching decisions that admit or exclude them (one enum
for what a decision fixes, one for its side), kept apart from the master and the branching
so that both read them."""

from __future__ import annotations

import enum
import math
from dataclasses import dataclass
from typing import Any

from tsac_bench.formulations.pricing import Restrictions
from tsac_bench.model import Route, Visit

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


class Kind(enum.Enum):
    """What a decision fixes, in the order the branching rule tries them."""

    VISIT = "visit"  # x_km, the lambda of k's columns that visit m (free part)
    TIME = "time"  # k's arrival term at m
    ARC = "arc"  # x_k(i, j, mode), the lambda of k's columns using the free arc
    AMOUNT = "amount"  # sum_c a_cm lambda_c of k at m


class Side(enum.Enum):
    EXCLUDED = "0"  # a visit or arc: no column of the AAV has it
    REQUIRED = "1"  # a visit or arc: a row sum lambda >= 1 (with an artificial column)
    AT_MOST = "le"  # an amount or arrival term no more than ``value``
    AT_LEAST = "ge"  # an amount no less than ``value``
    LATER = "gt"  # an arrival term later than ``value`` (a penalty row on earlier ones)


@dataclass(frozen=True)
class BranchDecision:
    kind: Kind
    aav: int
    key: Any  # task, or (tail, head, mode)
    side: Side
    value: float = 0  # the amount's or the arrival term's threshold


def compatible(col: Column, r: Restrictions) -> bool:
    """Whether a column keeps the pricing restrictions of a node (its bound stays open)."""
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


def in_required_row(key: tuple[Kind, int, Any], col: Column) -> bool:
    """Whether the column counts in the row of a "1" side (visit or arc) keyed ``key``."""
    kind, k, what = key
    if col.aav != k:
        return False
    return what in col.free_amounts if kind is Kind.VISIT else what in col.arcs


def early_visit(key: tuple[int, int, float], col: Column) -> bool:
    """Whether the column visits the key's task too early for its "later than" side (a
    free visit without an arrival term is late, past every threshold)."""
    k, m, threshold = key
    return col.aav == k and m in col.free_amounts and col.theta.get(m, math.inf) <= threshold
