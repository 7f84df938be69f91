"""Cost against budget: what the jobs of a run with budgets per plan call (``tsac-bench run
--budget``) say per method and budget, and, from the incumbent traces of its static jobs, how
fast each method gets close to the best plan known.

* ``budget_table``: per mode, scale, budget and method, mean and median J over the instances
  (each J the mean over seeds, as in every table), the rank by mean J among the methods at
  that budget, the plan calls over the budget (``budget.is_over_budget``) and how the method
  uses a budget (``planning.budget``: a one-pass method builds one plan and stops, so its
  mean seconds per plan call are given instead of the budget it did not use);
* ``paired_tests``: the best two methods at each budget compared instance by instance
  (``stats.comparisons``: Wilcoxon signed-rank), the mean paired difference with its 95 %
  normal interval;
* ``budget_curves``: quartiles of J over the instances per method and budget, for a figure;
* ``primal_table``: primal integral and times to target.

Primal integral (T. Berthold, Measuring the impact of primal heuristics, Oper. Res. Lett. 41
(2013) 611-614; the 12th DIMACS Implementation Challenge ranked vehicle routing solvers by
it): with J(t) the best J a plan call has found by time t and J_best the best J known for the
instance, the primal gap p(t) is 1 before the first incumbent, else
|J(t) - J_best| / max(|J(t)|, |J_best|) (0 if both are 0); the primal integral is the
integral of p over [0, T], T the largest budget, and the integral / T the mean gap over the
call. The time to target is the first time within [0, T] at which p(t) is at most 1 % (5 %).
J(t) is the job's incumbent trace (``stats["trace"]``); a method that records none (a
one-pass or exact method) has the single point (runtime, J): p = 1 until it returns.
J_best is the smallest J of any ok job of the instance in the store, every method, budget
and mode (an executed dynamic plan is a feasible static one too), or J* where smaller.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Any

import numpy as np
import pandas as pd

from tsac_bench.batch.store import OK
from tsac_bench.planning import allocator_class, parse_method_spec
from tsac_bench.planning.budget import TIME_LIMIT, budget_use
from tsac_bench.reporting.data import (
    ordered_modes,
    per_instance,
    replan_records,
    scale_order,
    series_labels,
)
from tsac_bench.reporting.stats import comparisons, normal_half_width

#: Primal gaps of the times to target: within 1 % and within 5 % of the best J known.
TARGETS = (0.01, 0.05)

Curve = Sequence[tuple[float, float]]


def method_budget_use(label: str) -> str:
    """How the method of a stored label uses a budget (``planning.budget``)."""
    try:
        return budget_use(allocator_class(parse_method_spec(label).name))
    except Exception:  # unknown or not installed here: what a method declaring nothing does
        return TIME_LIMIT


def budgeted(frame: pd.DataFrame) -> pd.DataFrame:
    """The jobs that had a budget per plan call."""
    if "budget" not in frame.columns:
        return frame.iloc[:0]
    return frame[frame["budget"].notna()]


def plan_calls(stats: Any, mode: str) -> int:
    """The plan calls of a job: one in static mode, one per re-plan in dynamic mode."""
    return max(1, len(replan_records(stats))) if mode == "dynamic" else 1


def _series(jobs: pd.DataFrame) -> pd.DataFrame:
    """Each budgeted series (``data.method_label``) with its method and budget."""
    return (jobs.assign(series=series_labels(jobs))[["series", "method", "budget"]]
            .drop_duplicates("series").set_index("series"))


def budgeted_instances(frame: pd.DataFrame) -> pd.DataFrame:
    """``data.per_instance`` rows of the budgeted series, with ``method`` the method's label
    again, ``series`` its label at the budget and ``budget``."""
    jobs = budgeted(frame)
    rows = per_instance(frame).rename(columns={"method": "series"})
    return rows.merge(_series(jobs), left_on="series", right_index=True, how="inner")


def budget_table(frame: pd.DataFrame) -> pd.DataFrame:
    """Per (mode, scale, budget, method) of the budgeted jobs: jobs, failed jobs, instances
    with a result, mean and median J, rank by mean J at the budget (1 the lowest; ties share
    the better rank), plan calls timed and ``over_budget`` of them, ``use``
    (``planning.budget``) and ``seconds_per_call`` (the mean over the plan calls of the ok
    jobs)."""
    columns = ["mode", "scale", "budget", "method", "series", "use", "jobs", "failed",
               "instances", "J_mean", "J_median", "rank", "plan_calls", "over_budget",
               "seconds_per_call"]
    jobs = budgeted(frame)
    if jobs.empty:
        return pd.DataFrame(columns=columns)
    ok = jobs["status"] == OK
    timed = jobs["over_budget"].notna()
    calls = pd.Series([plan_calls(s, m) for s, m in zip(jobs["stats"], jobs["mode"],
                                                         strict=True)], index=jobs.index)
    jobs = jobs.assign(
        series=series_labels(jobs),
        failed=~ok, timed_calls=calls.where(timed, 0), ok_calls=calls.where(ok, 0),
        ok_runtime=jobs["runtime"].where(ok, 0.0))
    keys = ["mode", "scale", "series"]
    table = jobs.groupby(keys).agg(
        method=("method", "first"), budget=("budget", "first"), jobs=("status", "size"),
        failed=("failed", "sum"), plan_calls=("timed_calls", "sum"),
        over_budget=("over_budget", "sum"), ok_calls=("ok_calls", "sum"),
        ok_runtime=("ok_runtime", "sum"))
    table["seconds_per_call"] = table["ok_runtime"] / table["ok_calls"].where(
        table["ok_calls"] > 0)
    means = budgeted_instances(frame).groupby(keys)["J"].agg(
        instances="size", J_mean="mean", J_median="median")
    table = table.join(means).reset_index()
    table["instances"] = table["instances"].fillna(0).astype(int)
    table[["failed", "plan_calls", "over_budget"]] = table[
        ["failed", "plan_calls", "over_budget"]].astype(int)
    table["rank"] = table.groupby(["mode", "scale", "budget"])["J_mean"].rank(method="min")
    table["use"] = table["method"].map(method_budget_use)
    modes = {m: i for i, m in enumerate(ordered_modes(table["mode"]))}
    scales = {s: i for i, s in enumerate(scale_order(table["scale"]))}
    table = table.sort_values(
        ["mode", "scale", "budget", "rank", "method"], na_position="last",
        key=lambda col: col.map(modes) if col.name == "mode"
        else col.map(scales) if col.name == "scale" else col)
    return table[columns].reset_index(drop=True)


def paired_difference(rows: pd.DataFrame, first: str, second: str) -> tuple[float, float, int]:
    """Per-instance rows (``instance``, ``method``, ``J``): the mean of J(first) - J(second)
    over the instances both have, its 95 % normal half-width and the instance count."""
    wide = rows.pivot_table(index="instance", columns="method", values="J")
    diff = (wide[first] - wide[second]).dropna()
    return float(diff.mean()), normal_half_width(diff.to_numpy()), len(diff)


def paired_tests(frame: pd.DataFrame, table: pd.DataFrame) -> pd.DataFrame:
    """Per (mode, scale, budget) of ``budget_table``: its two lowest mean J compared on the
    instances both solved; ``best`` has the lower mean J there, ``diff_mean`` is the mean of
    J(second) - J(best) with the 95 % half-width ``diff_half_width``, ``p`` the two-sided
    Wilcoxon signed-rank p-value (``stats.comparisons``)."""
    columns = ["mode", "scale", "budget", "best", "second", "instances", "diff_mean",
               "diff_half_width", "p"]
    jobs = budgeted(frame)
    jobs = jobs.assign(series=series_labels(jobs))
    rows = []
    for (mode, scale, budget), group in table.groupby(["mode", "scale", "budget"],
                                                      sort=False):
        two = group[group["instances"] > 0].sort_values(["J_mean", "method"]).head(2)
        if len(two) < 2:
            continue
        pair = jobs[(jobs["mode"] == mode) & (jobs["scale"] == scale)
                    & (jobs["budget"] == budget) & jobs["series"].isin(two["series"])]
        result, best, n = comparisons(pair, mode)
        if best is None:
            continue
        second = next(s for s in two["series"] if s != best)
        diff_mean, half_width, _ = paired_difference(per_instance(pair), second, best)
        method = two.set_index("series")["method"]
        rows.append({"mode": mode, "scale": scale, "budget": budget, "best": method[best],
                     "second": method[second], "instances": n, "diff_mean": diff_mean,
                     "diff_half_width": half_width,
                     "p": float(result.set_index("method").at[second, "p"])})
    return pd.DataFrame(rows, columns=columns)


def budget_curves(frame: pd.DataFrame) -> pd.DataFrame:
    """Per (mode, scale, method, budget): the quartiles of J over the instances (``q1``,
    ``median``, ``q3``), the data of the figure of J against budget."""
    rows = budgeted_instances(frame)
    columns = ["mode", "scale", "method", "budget", "q1", "median", "q3"]
    if rows.empty:
        return pd.DataFrame(columns=columns)
    grouped = rows.groupby(["mode", "scale", "method", "budget"])["J"]
    curves = pd.DataFrame({"q1": grouped.quantile(0.25), "median": grouped.median(),
                           "q3": grouped.quantile(0.75)})
    return curves.reset_index()[columns]


# --- primal integral ---------------------------------------------------------------------
def primal_gap(cost: float, best: float) -> float:
    """|J - J_best| / max(|J|, |J_best|), 0 where both are 0 (module notes)."""
    scale = max(abs(cost), abs(best))
    return 0.0 if scale == 0 else abs(cost - best) / scale


def incumbent_curve(stats: Any, runtime: float, cost: float) -> list[tuple[float, float]]:
    """A static job's ``[seconds, J]`` at each improvement: its trace, else (runtime, J)."""
    trace = stats.get("trace") if isinstance(stats, dict) else None
    if trace:
        return [(float(t), float(j)) for t, j in trace]
    return [(float(runtime), float(cost))]


def primal_integral(curve: Curve, best: float, horizon: float) -> float:
    """The integral of the primal gap over [0, horizon] (module notes); ``curve`` in time
    order."""
    total, since, gap = 0.0, 0.0, 1.0
    for t, cost in curve:
        t = min(max(t, 0.0), horizon)
        total += gap * (t - since)
        since, gap = t, primal_gap(cost, best)
    return total + gap * (horizon - since)


def time_to_target(curve: Curve, best: float, target: float, horizon: float) -> float:
    """The first time within [0, horizon] at which the primal gap is at most ``target``;
    inf if never."""
    return next((t for t, cost in curve if t <= horizon and primal_gap(cost, best) <= target),
                math.inf)


def best_known(frame: pd.DataFrame) -> pd.Series:
    """Per instance: the smallest J of its ok jobs, or its J* where smaller."""
    found = frame[frame["status"] == OK].groupby("instance")["J"].min()
    j_star = frame.groupby("instance")["J_star"].min()
    return pd.concat([found, j_star], axis=1).min(axis=1)


def primal_table(frame: pd.DataFrame) -> pd.DataFrame:
    """Per scale and method, the ok static jobs at the scale's largest budget T: jobs, the
    mean primal integral (``integral``, seconds) and integral / T (``integral_share``), the
    median times to target (``time_1``, ``time_5``; NaN where half or more never get there)
    and how many jobs get there (``reached_1``, ``reached_5``)."""
    names = [f"{round(t * 100)}" for t in TARGETS]
    columns = ["scale", "method", "use", "horizon", "jobs", "integral", "integral_share",
               *[f"time_{n}" for n in names], *[f"reached_{n}" for n in names]]
    jobs = budgeted(frame)
    jobs = jobs[(jobs["mode"] == "static") & (jobs["status"] == OK)]
    if jobs.empty:
        return pd.DataFrame(columns=columns)
    jobs = jobs[jobs["budget"] == jobs.groupby("scale")["budget"].transform("max")]
    best = best_known(frame)
    rows = []
    for row in jobs.itertuples(index=False):
        curve = incumbent_curve(row.stats, row.runtime, row.J)
        horizon, reference = float(row.budget), float(best[row.instance])
        integral = primal_integral(curve, reference, horizon)
        rows.append({"scale": row.scale, "method": row.method, "horizon": horizon,
                     "integral": integral, "integral_share": integral / horizon,
                     **{f"time_{n}": time_to_target(curve, reference, t, horizon)
                        for n, t in zip(names, TARGETS, strict=True)}})
    per_job = pd.DataFrame(rows)
    grouped = per_job.groupby(["scale", "method"])
    table = grouped.agg(horizon=("horizon", "first"), jobs=("integral", "size"),
                        integral=("integral", "mean"),
                        integral_share=("integral_share", "mean"))
    for n in names:
        times = grouped[f"time_{n}"]
        table[f"time_{n}"] = times.median().replace(math.inf, np.nan)
        table[f"reached_{n}"] = times.apply(lambda s: int(np.isfinite(s).sum()))
    table = table.reset_index()
    table["use"] = table["method"].map(method_budget_use)
    scales = {s: i for i, s in enumerate(scale_order(table["scale"]))}
    table = table.sort_values(["scale", "integral", "method"],
                              key=lambda col: col.map(scales) if col.name == "scale" else col)
    return table[columns].reset_index(drop=True)
