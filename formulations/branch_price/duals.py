"""The master's duals as one AAV's pricing sees them (``TaskPrices``), and the reduced cost
of a column at them: the labelling's objective (formulations/pricing.py), which the tests
check against HiGHS's own reduced costs."""

from __future__ import annotations

import math

import numpy as np

from tsac_bench.formulations.branch_price.columns import Column, Kind, early_visit
from tsac_bench.formulations.branch_price.cuts import priced_pieces
from tsac_bench.formulations.branch_price.master import Master
from tsac_bench.formulations.pricing import TaskPrices, arrival_cut_terms


def prices(master: Master, n: int, duals: np.ndarray) -> TaskPrices:
    """AAV n's prices at the row duals ``duals``, its empty schedule's terms and the
    convexity dual in ``base``."""
    cover = {m: duals[r] for m, r in master.cover.items()}
    aav_time = {m: duals[r] for (k, m), r in master.aav_time.items() if k == n}
    closer = {m: duals[r] for m, r in master.closer.items()}
    closer_time = {m: duals[r] for m, r in master.closer_time.items()}
    goods_time = {m: duals[r] for m, r in master.goods_time.items()}
    visit_bonus, arc_bonus = {}, {}
    for (kind, k, key), (row, _) in master.required.items():
        if k == n and duals[row] != 0.0:
            (visit_bonus if kind is Kind.VISIT else arc_bonus)[key] = duals[row]
    early_penalty: dict[int, list[tuple[float, float]]] = {}
    for (k, m, threshold), row in master.early.items():
        if k == n and duals[row] < 0.0:  # a <= row: its dual is <= 0
            early_penalty.setdefault(m, []).append((threshold, -duals[row]))
    arrival_cuts = {m: priced_pieces(n, cuts, duals, master.instance.tasks[m].demand)
                    for m, cuts in master.arrival_cuts.items()}
    result = TaskPrices(0.0, cover, aav_time, closer, closer_time,
                        visit_bonus=visit_bonus, arc_bonus=arc_bonus,
                        cut_bonus=_cut_bonus(master, n, duals), goods_time=goods_time,
                        early_penalty=early_penalty, arrival_cuts=arrival_cuts)
    result.base = reduced_cost(master.make_column(n, ()), result) - duals[master.conv[n]]
    return result


def _cut_bonus(master: Master, n: int, duals: np.ndarray) -> dict[int, float]:
    """Per task, what a visit of AAV n earns in the cover cuts and the symmetry rows."""
    bonus: dict[int, float] = {}
    for row, m, coef in master.cuts:
        if n in coef and duals[row] != 0.0:
            bonus[m] = bonus.get(m, 0.0) + coef[n] * duals[row]
    for row, n1, n2, j in master.symmetry:
        if duals[row] == 0.0:
            continue
        if n == n1:  # every visit to a task i <= j counts once
            for i in master.pricers[n].network.tasks:
                if i <= j:
                    bonus[i] = bonus.get(i, 0.0) + duals[row]
        elif n == n2:
            bonus[j] = bonus.get(j, 0.0) - duals[row]
    return bonus


def best_closes(col: Column, at: TaskPrices) -> frozenset[int]:
    """The tasks whose closing lowers this schedule's reduced cost."""
    return frozenset(m for m, t in col.theta.items() if _closing_term(m, t, at) < 0)


def _closing_term(m: int, theta: float, at: TaskPrices) -> float:
    """What closing task m at arrival term ``theta`` adds to a reduced cost (the labelling
    takes its min with 0)."""
    cut = arrival_cut_terms(at.arrival_cuts.get(m, ()), theta)[1]
    return at.closer_time.get(m, 0.0) * theta + cut - at.closer.get(m, 0.0)


def reduced_cost(col: Column, at: TaskPrices) -> float:
    """Reduced cost of a column's schedule with its best closing set, without the convexity
    dual."""
    rc = col.op - math.fsum(at.cover.get(m, 0.0) * a for m, a in col.amounts.items())
    for m, t in col.theta.items():
        cut_aav, _, cut_goods = arrival_cut_terms(at.arrival_cuts.get(m, ()), t)
        rc += at.aav_time.get(m, 0.0) * t + cut_aav
        rc += (at.goods_time.get(m, 0.0) * t + cut_goods) * col.amounts[m]
    for m in best_closes(col, at):
        rc += _closing_term(m, col.theta[m], at)
    rc -= sum(at.visit_bonus.get(m, 0.0) for m in col.free_amounts)
    rc -= sum(at.cut_bonus.get(m, 0.0) for m in col.amounts)
    rc -= sum(at.arc_bonus.get(a, 0.0) for a in col.arcs)
    for m, steps in at.early_penalty.items():
        rc += sum(p for threshold, p in steps if early_visit((col.aav, m, threshold), col))
    return rc
