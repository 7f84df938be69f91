"""Statistics of a report: gap measures against the exact references, Dolan-More performance
ratios, win rates and Wilcoxon signed-rank tests against the best method (Holm-corrected).

Gap measures of a set of instances with costs J_i and references R_i > 0 (docs/reports.md):
* mean gap: mean_i (J_i - R_i) / R_i, the mean of per-instance relative gaps. An instance with
  a tiny R_i weighs in heavily (J = 2 against J* = 1 counts as much as J = 200 against 100);
* gap of sums: (sum_i J_i - sum_i R_i) / sum_i R_i, the relative excess of the total cost;
* SGM gap: SGM_s(J) / SGM_s(R) - 1 with the shifted geometric mean
  SGM_s(x) = exp(mean_i ln(x_i + s)) - s (Achterberg, Constraint Integer Programming, 2007;
  Mittelmann's solver benchmarks compare solvers by such ratios). The shift s damps the
  ratios of instances whose costs are small against s.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np
import pandas as pd

from tsac_bench.reporting.data import per_instance

#: Two costs closer than this (relative) tie for a win.
TIE_TOLERANCE = 1e-9
#: Shift of the shifted geometric mean, in units of J: with the default weights (100, 10, 1)
#: one unit is the operating cost of one AAV flying its whole range (docs/model.md, E_base), small
#: against a late (10) or an unserved task (110), so gaps of a fraction of a flight weigh
#: little.
SGM_SHIFT = 1.0


def normal_half_width(values: Sequence[float] | np.ndarray) -> float:
    """Half-width of the normal-approximation 95 % interval of the mean of ``values``: 1.96
    sample standard deviations over sqrt(n); nan for fewer than two values."""
    values = np.asarray(values, dtype=float)
    if len(values) < 2:
        return float("nan")
    return 1.96 * float(np.std(values, ddof=1)) / float(np.sqrt(len(values)))


def shifted_geometric_mean(values: Sequence[float] | np.ndarray,
                           shift: float = SGM_SHIFT) -> float:
    """exp(mean(ln(x + shift))) - shift; NaN for no values."""
    x = np.asarray(values, dtype=float)
    if x.size == 0:
        return float("nan")
    return float(np.exp(np.mean(np.log(x + shift))) - shift)


def gap_measures(costs: pd.Series, reference: pd.Series,
                 shift: float = SGM_SHIFT) -> dict[str, float]:
    """Mean gap, gap of sums and SGM gap (module notes) over the instances where both the
    cost and a positive reference are known, and how many those are (``n``)."""
    known = costs.notna() & (reference > 0)
    j, r = costs[known].to_numpy(dtype=float), reference[known].to_numpy(dtype=float)
    if j.size == 0:
        return {"mean": float("nan"), "sum": float("nan"), "sgm": float("nan"), "n": 0}
    return {"mean": float(np.mean((j - r) / r)),
            "sum": float((j.sum() - r.sum()) / r.sum()),
            "sgm": shifted_geometric_mean(j, shift) / shifted_geometric_mean(r, shift) - 1.0,
            "n": int(j.size)}


def performance_ratios(rows: pd.DataFrame) -> tuple[pd.DataFrame, str]:
    """Dolan-More ratios J / J_ref per instance (rows) and method (columns) of per-instance
    rows. J_ref is J* where known, else the best J any method reached on the instance; an
    instance a method did not solve has ratio inf (never within any tau). Also returns what
    J_ref was."""
    wide = rows.pivot(index="instance", columns="method", values="J")
    j_star = rows.groupby("instance")["J_star"].first().reindex(wide.index)
    known = j_star.where(j_star > 0)
    reference = known.fillna(wide.min(axis=1))
    ratios = wide.div(reference, axis=0).fillna(np.inf)
    basis = "J*" if known.notna().all() else ("J* where known, else the best J found"
                                              if known.notna().any() else "the best J found")
    return ratios, basis


def holm(p_values: Sequence[float]) -> list[float]:
    """Holm-Bonferroni adjusted p-values, in the input order."""
    m = len(p_values)
    order = sorted(range(m), key=lambda i: p_values[i])
    adjusted = [0.0] * m
    running = 0.0
    for rank, i in enumerate(order):
        running = max(running, min(1.0, (m - rank) * p_values[i]))
        adjusted[i] = running
    return adjusted


def comparisons(frame: pd.DataFrame, mode: str) -> tuple[pd.DataFrame, str | None, int]:
    """Win rates and Wilcoxon signed-rank tests against the best method of ``mode``.

    Uses the instances on which every method has a result; returns the table, the best
    method and the number of instances used."""
    from scipy.stats import wilcoxon

    table = per_instance(frame)
    wide = table[table["mode"] == mode].pivot(index="instance", columns="method", values="J")
    wide = wide.dropna()
    if wide.empty:
        return pd.DataFrame(), None, 0
    best_value = wide.min(axis=1)
    tie = best_value.abs() * TIE_TOLERANCE + TIE_TOLERANCE
    wins = wide.le(best_value + tie, axis=0).mean()
    means = wide.mean()
    best = str(means.idxmin())
    rows: list[dict[str, Any]] = []
    for method in sorted(wide.columns, key=lambda m: (means[m], m)):
        diff = wide[method] - wide[best]
        row = {"method": method, "instances": len(wide), "J_mean": means[method],
               "win_rate": wins[method], "diff_mean": diff.mean(), "W": np.nan, "p": np.nan}
        if method != best:
            if (diff.abs() <= tie).all():
                row["p"] = 1.0  # identical results: nothing to test
            else:
                result = wilcoxon(wide[method], wide[best])
                row["W"], row["p"] = float(result.statistic), float(result.pvalue)
        rows.append(row)
    result = pd.DataFrame(rows)
    tested = result["p"].notna()
    result["p_holm"] = np.nan
    result.loc[tested, "p_holm"] = holm(result.loc[tested, "p"].tolist())
    return result, best, len(wide)
