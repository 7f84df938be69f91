"""The tables of a run with budgets per plan call: per mode, cost against budget with its
paired tests, and in static mode the primal-integral table (``budgets`` computes them;
Markdown and a ``longtable`` each, in the style of ``tables``'s long table)."""

from __future__ import annotations

import math
from typing import Any

import pandas as pd

from tsac_bench.planning.budget import (
    ONE_PASS,
    OVER_BUDGET_SECONDS,
    OVER_BUDGET_SHARE,
    reference_units,
)
from tsac_bench.reporting.data import (
    seconds_text,
)
from tsac_bench.reporting.tables import (
    fmt_value,
    latex_escape,
    longtable,
    lowest_printed,
    markdown_grid,
)

_OVER = (f"budget × {1 + OVER_BUDGET_SHARE:g} + {OVER_BUDGET_SECONDS:g} s")
BUDGET_NOTE_MARKDOWN = (
    "Each row: a method with the given seconds per plan call. Mean and median J over the "
    "instances (each J the mean over seeds); rank by mean J among the methods at the budget. "
    f"**Over budget**: plan calls that returned later than {_OVER}, of the plan calls timed. "
    "**Use**: anytime (improves its plan until the budget is spent), one pass (builds one "
    "plan and stops: the budget only caps it; its mean seconds per plan call), time limit "
    "(searches until the budget and returns its incumbent). Bold: the lowest printed value "
    "at a budget.")
BUDGET_NOTE_LATEX = (
    r"Mean and median $J$ over the instances (each $J$ the mean over seeds); Rank: by mean "
    r"$J$ among the methods at the budget; Over: plan calls that returned later than "
    rf"budget $\times$ {1 + OVER_BUDGET_SHARE:g} + {OVER_BUDGET_SECONDS:g}\,s, of the plan "
    r"calls timed; Use: anytime (improves its plan until the budget is spent), one pass "
    r"(builds one plan and stops: the budget only caps it; its mean seconds per plan call), "
    r"time limit (searches until the budget and returns its incumbent). Best two: the two "
    r"lowest mean $J$ at a budget on the instances both solved, the mean of $J$(second) $-$ "
    r"$J$(best) with its 95\,\% normal interval and the two-sided Wilcoxon signed-rank $p$. "
    r"Bold: the lowest printed value at a budget.")
TESTS_NOTE_MARKDOWN = (
    "The two lowest mean J at each budget, on the instances both solved: the mean of "
    "J(second) - J(best) with its 95 % normal interval, and the two-sided Wilcoxon "
    "signed-rank p.")
PRIMAL_NOTE_MARKDOWN = (
    "Static jobs at the largest budget T of each scale, over the jobs (instances and seeds). "
    "Primal gap p(t) = 1 before the first plan, else |J(t) - J_best| / max(|J(t)|, |J_best|), "
    "J(t) the best J found by time t of the plan call (its incumbent trace; a method without "
    "one: its J from its runtime on), J_best the best J known for the instance (every job of "
    "the store, and J*). **Primal integral**: the integral of p over [0, T] (Berthold 2013, as "
    "in the 12th DIMACS Implementation Challenge), mean over the jobs; / T: the mean primal "
    "gap. **Time to 1 % (5 %)**: median over the jobs of the first time p(t) <= 1 % (5 %), "
    "`--` where half of the jobs or more never get there within T; in parentheses the jobs "
    "that do.")
PRIMAL_NOTE_LATEX = (
    r"Static jobs at the largest budget $T$ of each scale, over the jobs (instances and "
    r"seeds). Primal gap $p(t) = 1$ before the first plan, else $|J(t) - J_{\mathrm{best}}| "
    r"/ \max(|J(t)|, |J_{\mathrm{best}}|)$, $J(t)$ the best $J$ found by time $t$ of the plan "
    r"call (its incumbent trace; a method without one: its $J$ from its runtime on), "
    r"$J_{\mathrm{best}}$ the best $J$ known for the instance (every job of the store, and "
    r"$J^*$). Integral: $\int_0^T p(t)\,dt$ (Berthold 2013, as in the 12th DIMACS "
    r"Implementation Challenge), mean over the jobs; $/T$: the mean primal gap. To 1\,\% "
    r"(5\,\%): median over the jobs of the first time $p(t) \leq$ 1\,\% (5\,\%), -- where half "
    r"of the jobs or more never get there within $T$; in parentheses the jobs that do.")


def budget_text(budget: float, calibration: dict[str, Any] | None) -> str:
    """``1 s (81.3 ref. units)``; the seconds alone without a calibration."""
    units = reference_units(budget, calibration)
    text = seconds_text(budget)
    return text if units is None else f"{text} ({units:.3g} ref. units)"


def budget_footing(rows: pd.DataFrame, calibration: dict[str, Any] | None) -> str:
    """What every row of a mode's budget table shares: the budgets, the reference unit, the
    start of every plan call and the methods that do not use a budget (plain text)."""
    budgets = ", ".join(budget_text(b, calibration) for b in sorted(rows["budget"].unique()))
    text = f"Budgets per plan call: {budgets}"
    if calibration:
        text += (f"; a reference unit is {float(calibration['seconds']):.4g} s, the time of "
                 f"the machine-speed reference workload on {calibration.get('host', '?')} "
                 f"(measured {calibration.get('measured_at', '?')})")
    else:
        text += " (no calibration recorded: seconds of the machines that ran the jobs)"
    text += ". Every method gets the same budget per plan call"
    if (rows["mode"] == "dynamic").any():
        # The starts differ at a re-plan, and a comparison must say how.
        text += (" and plans from the committed prefixes, except that DGA seeds half its "
                 "population from the plan in force and a label with init=incumbent starts "
                 "from it (see docs/methods.md, \"Budgets\").")
    else:
        text += " and plans from the committed prefixes, none in static mode (see docs/methods.md)."
    one_pass = sorted(rows.loc[rows["use"] == ONE_PASS, "method"].unique())
    if one_pass:
        text += (f" One pass (builds one plan and stops; the budget only caps it): "
                 f"{', '.join(one_pass)}.")
    return text


def _seconds(value: float) -> str:
    """Seconds to three significant digits in fixed point: plan calls and primal integrals
    span milliseconds to minutes, which no one number of decimals prints."""
    if value is None or math.isnan(value) or math.isinf(value):
        return "--"
    if value == 0:
        return "0"
    return f"{value:.{max(0, 2 - math.floor(math.log10(abs(value))))}f}"


def _use_text(use: str, seconds: float) -> str:
    if use == ONE_PASS:
        return f"one pass, {_seconds(seconds)} s"
    return use.replace("-", " ")


def _budget_cells(rows: pd.DataFrame) -> pd.DataFrame:
    """The printed cells of budget-table rows, the lowest mean and median J of a budget in
    ``**`` (for Markdown; LaTeX rewrites them)."""
    out = pd.DataFrame(index=rows.index)
    for column in ("J_mean", "J_median"):
        printed = rows[column].map(lambda v: fmt_value(v, 2))
        lowest = pd.Series(False, index=rows.index)
        for _, group in rows.groupby(["scale", "budget"], sort=False):
            lowest[group.index] = lowest_printed(printed[group.index])
        out[column] = [f"**{p}**" if b else p for p, b in zip(printed, lowest, strict=True)]
    out["rank"] = rows["rank"].map(lambda r: "--" if pd.isna(r) else str(int(r)))
    out["over"] = [f"{o}/{c}" for o, c in zip(rows["over_budget"], rows["plan_calls"],
                                               strict=True)]
    out["use"] = [_use_text(u, s) for u, s in zip(rows["use"], rows["seconds_per_call"],
                                                  strict=True)]
    return out


def _difference(test: Any) -> str:
    half = "" if math.isnan(test.diff_half_width) else f" ± {fmt_value(test.diff_half_width, 2)}"
    return f"{fmt_value(test.diff_mean, 2)}{half}"


def budget_markdown(table: pd.DataFrame, tests: pd.DataFrame, mode: str,
                    calibration: dict[str, Any] | None) -> str:
    """The budget table of one mode (``budgets.budget_table``) and its paired tests."""
    rows = table[table["mode"] == mode].reset_index(drop=True)
    cells = _budget_cells(rows)
    out = pd.DataFrame({
        "scale": rows["scale"],
        "budget": rows["budget"].map(lambda b: budget_text(b, calibration)),
        "method": rows["method"], "use": cells["use"], "n": rows["instances"].astype(str),
        "mean J": cells["J_mean"], "median J": cells["J_median"], "rank": cells["rank"],
        "over budget": cells["over"]})
    text = markdown_grid(out, text_columns=4) + "\n" + BUDGET_NOTE_MARKDOWN + "\n"
    tests = tests[tests["mode"] == mode]
    if not tests.empty:
        pairs = pd.DataFrame({
            "scale": tests["scale"],
            "budget": tests["budget"].map(lambda b: budget_text(b, calibration)),
            "best": tests["best"], "second": tests["second"],
            "n": tests["instances"].astype(str),
            "mean ΔJ (95 % CI)": [_difference(t) for t in tests.itertuples()],
            "Wilcoxon p": tests["p"].map(lambda v: fmt_value(v, 4))})
        text += "\n" + markdown_grid(pairs, text_columns=4) + "\n" + TESTS_NOTE_MARKDOWN + "\n"
    return text




def _latex_bold(text: str) -> str:
    """A Markdown-bold cell (``_budget_cells``) in LaTeX."""
    if text.startswith("**"):
        return rf"\textbf{{{text.strip('*')}}}"
    return text


def budget_latex(table: pd.DataFrame, tests: pd.DataFrame, mode: str,
                 calibration: dict[str, Any] | None) -> str:
    """The budget table of one mode as a booktabs ``longtable``: a row group per scale and
    budget, the paired test of its best two under it."""
    rows = table[table["mode"] == mode].reset_index(drop=True)
    cells = _budget_cells(rows)
    tests = tests[tests["mode"] == mode].set_index(["scale", "budget"])
    head = [r"Method & $n$ & \multicolumn{2}{c}{$J$} & Rank & Over & Use \\",
            r"\cmidrule(lr){3-4}",
            r" &  & Mean & Median &  &  &  \\"]
    body: list[str] = []
    for (scale, budget), group in rows.groupby(["scale", "budget"], sort=False):
        if body:
            body.append(r"\midrule")
        body.append(rf"\multicolumn{{7}}{{l}}{{$N/M$ = {latex_escape(str(scale))}, budget "
                    rf"{latex_escape(budget_text(budget, calibration))}}} \\")
        for i in group.index:
            body.append(" & ".join([
                latex_escape(str(rows.at[i, "method"])), str(rows.at[i, "instances"]),
                _latex_bold(cells.at[i, "J_mean"]), _latex_bold(cells.at[i, "J_median"]),
                cells.at[i, "rank"], cells.at[i, "over"], cells.at[i, "use"]]) + r" \\")
        if (scale, budget) in tests.index:
            test = tests.loc[(scale, budget)]
            half = ("" if math.isnan(test["diff_half_width"])
                    else rf" $\pm$ {fmt_value(test['diff_half_width'], 2)}")
            # A paragraph cell: two long method specs would not fit one line.
            body.append(
                r"\multicolumn{7}{p{0.9\linewidth}}{Best two: "
                rf"{latex_escape(str(test['best']))}, {latex_escape(str(test['second']))}; "
                rf"$\Delta J$ = {fmt_value(test['diff_mean'], 2)}{half}, $p$ = "
                rf"{fmt_value(test['p'], 4)}, $n$ = {int(test['instances'])}}} \\")
    budgets = ", ".join(latex_escape(budget_text(b, calibration))
                        for b in sorted(rows["budget"].unique()))
    caption = (rf"Total cost $J$ against the budget per plan call ({budgets}) per scale "
               rf"$N/M$ and method, {mode} mode.")
    note = latex_escape(budget_footing(rows, calibration)) + " " + BUDGET_NOTE_LATEX
    return longtable("lrrrrrl", head, caption, f"tab:tsac-bench-{mode}-budget", body, note)


def _time_cell(time: float, reached: int) -> str:
    return f"{_seconds(time)} ({reached})"


def primal_markdown(primal: pd.DataFrame, calibration: dict[str, Any] | None) -> str:
    """The primal-integral table (``budgets.primal_table``) in Markdown."""
    out = pd.DataFrame({
        "scale": primal["scale"],
        "T": primal["horizon"].map(lambda b: budget_text(b, calibration)),
        "method": primal["method"], "n": primal["jobs"].astype(str),
        "primal integral (s)": primal["integral"].map(_seconds),
        "integral / T": primal["integral_share"].map(lambda v: fmt_value(v, 3)),
        "time to 1 % (s)": [_time_cell(t, r) for t, r in zip(
            primal["time_1"], primal["reached_1"], strict=True)],
        "time to 5 % (s)": [_time_cell(t, r) for t, r in zip(
            primal["time_5"], primal["reached_5"], strict=True)]})
    return markdown_grid(out, text_columns=3) + "\n" + PRIMAL_NOTE_MARKDOWN + "\n"


def primal_latex(primal: pd.DataFrame, calibration: dict[str, Any] | None) -> str:
    """The primal-integral table as a booktabs ``longtable``, a row group per scale."""
    head = [r"Method & $n$ & Integral (s) & $/T$ & To 1\,\% (s) & To 5\,\% (s) \\"]
    body: list[str] = []
    for scale, group in primal.groupby("scale", sort=False):
        if body:
            body.append(r"\midrule")
        horizon = latex_escape(budget_text(group["horizon"].iloc[0], calibration))
        body.append(rf"\multicolumn{{6}}{{l}}{{$N/M$ = {latex_escape(str(scale))}, $T$ = "
                    rf"{horizon}}} \\")
        for row in group.itertuples():
            body.append(" & ".join([
                latex_escape(str(row.method)), str(row.jobs), _seconds(row.integral),
                fmt_value(row.integral_share, 3), _time_cell(row.time_1, row.reached_1),
                _time_cell(row.time_5, row.reached_5)]) + r" \\")
    caption = (r"Primal integral and times to target per scale $N/M$ and method, static "
               r"mode, at the largest budget $T$ of the scale.")
    return longtable("lrrrrr", head, caption, "tab:tsac-bench-static-primal", body,
                      PRIMAL_NOTE_LATEX)
