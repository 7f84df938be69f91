"""Method tables of a run: the statistics of every (mode, scale, method) cell, and their
Markdown and LaTeX forms.

Two LaTeX tables per mode:
* the long table (``longtable``, breaks across pages): per scale and method, instances, mean,
  std and median J, the three gap measures of ``stats``, instances with J*, failed jobs;
* the pivot a paper prints (a one-column ``table`` float): methods as rows, scales as columns
  (at most ``PIVOT_SCALES`` side by side, more in further panels), mean J with the gap of sums
  below it, best in bold.
Every table carries the definitions of its gaps under it.

The tables of cost against budget are ``budget_tables``'s, in the long table's style.
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass
from typing import Any

import pandas as pd

from tsac_bench.batch.store import OK
from tsac_bench.reporting.data import (
    by_series,
    ordered_modes,
    per_instance,
    scale_order,
)
from tsac_bench.reporting.stats import SGM_SHIFT, gap_measures

#: Scales side by side in one panel of the pivot: six columns of numbers and the method
#: column fit the 345 pt text width of a one-column article at \small.
PIVOT_SCALES = 6


@dataclass(frozen=True)
class Cell:
    """Formatting of one statistic column: the frame column, its headers and precision."""

    column: str
    latex: str
    markdown: str
    digits: int
    percent: bool = False
    best: bool = True  # the lowest value is bold


J_CELLS = (
    Cell("J_mean", "Mean", "mean J", 2),
    Cell("J_std", "Std", "std J", 2, best=False),
    Cell("J_median", "Median", "median J", 2),
)
GAP_CELLS = (
    Cell("gap_mean", "Mean", "mean gap (%)", 1, percent=True),
    Cell("gap_sum", "Sum", "gap of sums (%)", 1, percent=True),
    Cell("gap_sgm", "SGM", "SGM gap (%)", 1, percent=True),
)
SUMMARY_CELLS = J_CELLS + GAP_CELLS

_SHIFT = f"{SGM_SHIFT:g}"
GAP_NOTE_MARKDOWN = (
    "Gaps to J* are over the instances with a proven optimum J* (`n with J*`), each J the "
    "mean over seeds. **Mean gap**: mean of (J - J*) / J*, dominated by instances with a "
    "small J*. **Gap of sums**: (ΣJ - ΣJ*) / ΣJ*. **SGM gap**: SGM(J) / SGM(J*) - 1, with the "
    f"shifted geometric mean SGM(x) = exp(mean(ln(x + s))) - s, shift s = {_SHIFT} (unit of "
    "J). Bold: the lowest printed value of a scale.")
GAP_NOTE_LATEX = (
    r"Gaps to $J^*$ are over the $n_{J^*}$ instances with a proven optimum $J^*$, each $J$ "
    r"the mean over seeds. Mean: mean of $(J - J^*)/J^*$, dominated by instances with a "
    r"small $J^*$. Sum: $(\sum J - \sum J^*)/\sum J^*$. SGM: "
    r"$\mathrm{SGM}_s(J)/\mathrm{SGM}_s(J^*) - 1$, with the shifted geometric mean "
    r"$\mathrm{SGM}_s(x) = \exp\bigl(\frac{1}{n}\sum_i \ln(x_i + s)\bigr) - s$, "
    rf"$s = {_SHIFT}$. Bold: the lowest printed value of a scale.")
PIVOT_NOTE_MARKDOWN = (
    "Each cell: mean J over the instances (each J the mean over seeds), and in parentheses "
    "the gap of sums (ΣJ - ΣJ*) / ΣJ* in % over the instances with a proven optimum J*; "
    "`[a, b]`: no J* known, the gap lies between a, the gap to the best J known B, "
    "(ΣJ - ΣB) / ΣB, and b, the gap to the lower bound LB, (ΣJ - ΣLB) / ΣLB; `part`: over "
    "only part of the cell's instances; `n=k`: mean over k instances, fewer than the "
    "scale's other methods (never bold). Bold: the lowest mean J of a scale.")
PIVOT_NOTE_LATEX = (
    r"Mean $J$ over the instances (each $J$ the mean over seeds) and, in parentheses, the "
    r"gap of sums $(\sum J - \sum J^*)/\sum J^*$ (\%) over those with a proven optimum "
    r"$J^*$; $[a, b]$: no $J^*$ known, the gap lies between $a$, the gap to the best $J$ "
    r"known, and $b$, the gap to the lower bound. $^a$: "
    r"over fewer instances than the scale's other methods; $^b$: over part of the cell's "
    r"instances. Bold: the lowest mean $J$ of a scale.")


def method_table(frame: pd.DataFrame) -> pd.DataFrame:
    """Per (mode, scale, method; a method at a budget is a method of its own,
    ``data.method_label``): jobs, failed jobs, instances with a result, mean/std/median J over
    instances; the gap measures to J* (``gap_*``, over the instances with a known J*)
    and where J* is unknown to the best J known (``gap_best_*``) and to the lower bound
    (``gap_lb_*``), which bracket the true gap."""
    table = per_instance(frame)
    keys = ["mode", "scale", "method"]
    rows = []
    for key, group in table.groupby(keys, sort=False):
        no_j_star = group["J_star"].isna()
        to_j_star = gap_measures(group["J"], group["J_star"])
        to_bound = gap_measures(group["J"], group["lower_bound"].where(no_j_star))
        to_best = gap_measures(group["J"], group["best_J"].where(no_j_star))
        rows.append({
            **dict(zip(keys, key, strict=True)), "instances": len(group),
            "J_mean": group["J"].mean(), "J_std": group["J"].std(),
            "J_median": group["J"].median(),
            **{f"gap_{name}": value for name, value in to_j_star.items()},
            **{f"gap_lb_{name}": value for name, value in to_bound.items()},
            **{f"gap_best_{name}": value for name, value in to_best.items()}})
    stats = pd.DataFrame(rows, columns=[
        *keys, "instances", "J_mean", "J_std", "J_median", "gap_mean", "gap_sum", "gap_sgm",
        "gap_n", "gap_lb_mean", "gap_lb_sum", "gap_lb_sgm", "gap_lb_n", "gap_best_mean",
        "gap_best_sum", "gap_best_sgm", "gap_best_n"]).set_index(keys)
    counts = by_series(frame).groupby(keys).agg(jobs=("status", "size"),
                                     failed=("status", lambda s: int((s != OK).sum())))
    stats = counts.join(stats, how="left").reset_index()
    for column in ("instances", "gap_n", "gap_lb_n", "gap_best_n"):
        stats[column] = stats[column].fillna(0).astype(int)
    order = {s: i for i, s in enumerate(scale_order(stats["scale"]))}
    modes = {m: i for i, m in enumerate(ordered_modes(stats["mode"]))}
    stats = stats.sort_values(["mode", "scale", "method"],
                              key=lambda col: col.map(order) if col.name == "scale"
                              else col.map(modes) if col.name == "mode" else col)
    return stats.reset_index(drop=True)


def summary(frame: pd.DataFrame) -> pd.DataFrame:
    """The runner's end-of-run table: jobs, failures, mean J and mean gap per cell."""
    table = method_table(frame)
    return table[["mode", "scale", "method", "jobs", "failed", "instances", "J_mean",
                  "gap_mean", "gap_n", "gap_lb_mean"]]


# --- formatting --------------------------------------------------------------------------
def fmt_value(value: Any, digits: int, percent: bool = False) -> str:
    if value is None or (isinstance(value, float) and math.isnan(value)):
        return "--"
    return f"{value * 100 if percent else value:.{digits}f}"


def _bold_mask(cells: pd.DataFrame) -> pd.DataFrame:
    """Per scale, which printed values are the best (lowest; printed ties are all bold)."""
    mask = pd.DataFrame(False, index=cells.index, columns=[c.column for c in SUMMARY_CELLS])
    for _, group in cells.groupby("scale", sort=False):
        for cell in SUMMARY_CELLS:
            if cell.best:
                printed = group[cell.column].map(
                    lambda v, c=cell: fmt_value(v, c.digits, c.percent))
                mask.loc[group.index, cell.column] = lowest_printed(printed)
    return mask


def lowest_printed(printed: pd.Series) -> pd.Series:
    """Which printed numbers equal the lowest one ("--" never)."""
    numbers = pd.to_numeric(printed.where(printed != "--"), errors="coerce")
    return (numbers == numbers.min()) if numbers.notna().any() else numbers.notna()


_LATEX_SPECIAL = {"\\": r"\textbackslash{}", "&": r"\&", "%": r"\%", "$": r"\$", "#": r"\#",
                  "_": r"\_", "{": r"\{", "}": r"\}", "~": r"\textasciitilde{}",
                  "^": r"\textasciicircum{}"}


def latex_escape(text: str) -> str:
    """Text as LaTeX typesets it literally (a method spec's ``:`` and ``=`` need nothing)."""
    return re.sub(r"[\\&%$#_{}~^]", lambda m: _LATEX_SPECIAL[m.group()], text)


def markdown_grid(table: pd.DataFrame, text_columns: int) -> str:
    """A Markdown table of pre-formatted cells, numbers right-aligned."""
    align = ["left"] * text_columns + ["right"] * (len(table.columns) - text_columns)
    return table.to_markdown(index=False, disable_numparse=True, colalign=align) + "\n"


# --- the long table ----------------------------------------------------------------------
def longtable(columns: str, head: list[str], caption: str, label: str,
               body: list[str], note: str) -> str:
    """A booktabs ``longtable`` in the long table's style (``latex_table``): ``head`` repeated
    on every page, ``note`` under it."""
    width = len(columns)
    return "\n".join([
        r"\begingroup",
        r"\footnotesize",
        r"\setlength{\tabcolsep}{3pt}",
        r"\begin{longtable}{" + columns + "}",
        rf"\caption{{{caption}}}",
        rf"\label{{{label}}} \\",
        r"\toprule", *head, r"\midrule",
        r"\endfirsthead",
        rf"\multicolumn{{{width}}}{{l}}{{\emph{{Table \thetable, continued}}}} \\",
        r"\toprule", *head, r"\midrule",
        r"\endhead",
        r"\midrule",
        rf"\multicolumn{{{width}}}{{r}}{{\emph{{continued on the next page}}}} \\",
        r"\endfoot",
        r"\bottomrule",
        r"\endlastfoot",
        *body,
        r"\end{longtable}",
        r"\endgroup",
        "",
        r"\noindent{\footnotesize " + note + r"\par}",
        ""])


def latex_table(table: pd.DataFrame, mode: str) -> str:
    """The long booktabs table of one mode as a ``longtable``: a row group per scale, best
    values in bold, the gap definitions under it."""
    rows = table[table["mode"] == mode].reset_index(drop=True)
    bold = _bold_mask(rows)
    width = 2 + len(SUMMARY_CELLS) + 2
    first = 3 + len(J_CELLS)
    head = [
        rf"Method & $n$ & \multicolumn{{{len(J_CELLS)}}}{{c}}{{$J$}} & "
        rf"\multicolumn{{{len(GAP_CELLS)}}}{{c}}{{Gap to $J^*$ (\%)}} & $n_{{J^*}}$ & "
        r"Failed \\",
        rf"\cmidrule(lr){{3-{first - 1}}}\cmidrule(lr){{{first}-{first + len(GAP_CELLS) - 1}}}",
        " & ".join(["", "", *[c.latex for c in SUMMARY_CELLS], "", ""]) + r" \\",
    ]
    body: list[str] = []
    previous = None
    for i, row in rows.iterrows():
        if row["scale"] != previous:
            if previous is not None:
                body.append(r"\midrule")
            body.append(rf"\multicolumn{{{width}}}{{l}}{{$N/M$ = "
                        rf"{latex_escape(str(row['scale']))}}} \\")
            previous = row["scale"]
        cells = [latex_escape(str(row["method"])), str(row["instances"])]
        for cell in SUMMARY_CELLS:
            text = fmt_value(row[cell.column], cell.digits, cell.percent)
            cells.append(rf"\textbf{{{text}}}" if bold.at[i, cell.column] else text)
        cells += [str(int(row["gap_n"])), str(int(row["failed"]))]
        body.append(" & ".join(cells) + r" \\")
    # Ten columns within the 345 pt text width (tests/report).
    caption = (rf"Total cost $J$ per scale $N/M$ ($N$ AAVs, $M$ tasks) and method, {mode} "
               r"mode: mean, standard deviation and median over the instances, and gaps to the "
               r"exact optimum $J^*$.")
    return longtable("l" + "r" * (width - 1), head, caption, f"tab:tsac-bench-{mode}", body,
                      GAP_NOTE_LATEX)


def markdown_table(table: pd.DataFrame, mode: str) -> str:
    rows = table[table["mode"] == mode].reset_index(drop=True)
    bold = _bold_mask(rows)
    out = pd.DataFrame({"scale": rows["scale"], "method": rows["method"],
                        "n": rows["instances"]})
    for cell in SUMMARY_CELLS:
        printed = rows[cell.column].map(lambda v, c=cell: fmt_value(v, c.digits, c.percent))
        out[cell.markdown] = [f"**{p}**" if b else p
                              for p, b in zip(printed, bold[cell.column], strict=True)]
    out["n with J*"] = rows["gap_n"].astype(int)
    out["failed"] = rows["failed"].astype(int)
    return markdown_grid(out, text_columns=2) + "\n" + GAP_NOTE_MARKDOWN + "\n"


# --- the pivot ---------------------------------------------------------------------------
@dataclass(frozen=True)
class PivotCell:
    """One (method, scale) entry of the pivot."""

    mean: float
    gap: float  # gap of sums to J*, else to the lower bound; NaN when neither is known
    to_bound: bool  # no J*: the gap is to the lower bound, an upper bound on the gap to J*
    gap_best: float  # where to_bound, the gap of sums to the best J known: a lower bound
    partial: bool  # the gap covers only part of the cell's instances
    fewer: bool  # the mean covers fewer instances than the scale's best-covered method
    instances: int
    best: bool


def pivot_cells(table: pd.DataFrame, mode: str) -> tuple[list[str], list[str],
                                                         dict[tuple[str, str], PivotCell]]:
    """Methods, scales and the cells of the pivot of one mode (cells absent where a method
    has no result at a scale)."""
    rows = table[(table["mode"] == mode) & (table["instances"] > 0)]
    scales = scale_order(rows["scale"].unique())
    methods = sorted(rows["method"].unique())
    cells: dict[tuple[str, str], PivotCell] = {}
    for scale in scales:
        group = rows[rows["scale"] == scale]
        most = group["instances"].max()
        full = group[group["instances"] == most]
        best = lowest_printed(full["J_mean"].map(lambda v: fmt_value(v, 2)))
        for _, row in group.iterrows():
            to_bound = row["gap_n"] == 0
            n_gap = row["gap_lb_n"] if to_bound else row["gap_n"]
            cells[(row["method"], scale)] = PivotCell(
                mean=row["J_mean"], gap=row["gap_lb_sum"] if to_bound else row["gap_sum"],
                to_bound=bool(to_bound and n_gap > 0),
                gap_best=row["gap_best_sum"] if to_bound else math.nan,
                partial=0 < n_gap < row["instances"],
                fewer=row["instances"] < most, instances=int(row["instances"]),
                best=bool(best.get(row.name, False)))
    return methods, scales, cells


def _panels(scales: list[str], per_panel: int) -> list[list[str]]:
    """Scales in panels of at most ``per_panel``, as even as possible (9 -> 5 + 4)."""
    count = -(-len(scales) // per_panel)
    sizes = [len(scales) // count + (i < len(scales) % count) for i in range(count)]
    starts = [sum(sizes[:i]) for i in range(count)]
    return [scales[start:start + size] for start, size in zip(starts, sizes, strict=True)]


def latex_pivot(table: pd.DataFrame, mode: str, per_panel: int = PIVOT_SCALES) -> str:
    """The pivot of one mode as a one-column booktabs ``table`` float (module notes)."""
    methods, scales, cells = pivot_cells(table, mode)
    panels = _panels(scales, per_panel)
    width = 1 + max((len(p) for p in panels), default=0)
    lines = [
        r"\begin{table}[t]",
        r"\centering",
        r"\small",
        r"\setlength{\tabcolsep}{4pt}",
        rf"\caption{{Mean total cost $J$ and gap to $J^*$ per method and scale $N/M$ "
        rf"({mode} mode).}}",
        rf"\label{{tab:tsac-bench-{mode}-pivot}}",
        r"\begin{tabular}{l" + "r" * (width - 1) + "}",
        r"\toprule",
    ]
    for p, panel in enumerate(panels):
        pad = [""] * (width - 1 - len(panel))
        if p:
            lines.append(r"\midrule")
        lines.append(" & ".join([r"Method \hfill $N/M$", *map(latex_escape, panel), *pad])
                     + r" \\")
        lines.append(r"\midrule")
        for method in methods:
            means, gaps = [latex_escape(method)], [""]
            for scale in panel:
                cell = cells.get((method, scale))
                means.append(_latex_mean(cell))
                gaps.append(_latex_gap(cell))
            # The gap sits close under its mean: a pair reads as one entry, and the table
            # stays within a page at ten methods and two panels.
            lines.append(" & ".join([*means, *pad]) + r" \\[-2pt]")
            lines.append(" & ".join([*gaps, *pad]) + r" \\")
    lines += [r"\bottomrule", r"\end{tabular}", "",
              r"\smallskip", r"\parbox{\linewidth}{\footnotesize " + PIVOT_NOTE_LATEX + "}",
              r"\end{table}", ""]
    return "\n".join(lines)


#: The pivot's footnote marks, set in the column gap (``\rlap``) so numbers stay aligned.
MARK_FEWER = r"\rlap{$^a$}"
MARK_PARTIAL = r"\rlap{$^b$}"


def _latex_mean(cell: PivotCell | None) -> str:
    if cell is None:
        return "--"
    text = fmt_value(cell.mean, 2)
    if cell.best:
        text = rf"\textbf{{{text}}}"
    return text + (MARK_FEWER if cell.fewer else "")


def _latex_gap(cell: PivotCell | None) -> str:
    if cell is None or math.isnan(cell.gap):
        return ""
    gap = fmt_value(cell.gap, 1, percent=True)
    text = f"[{fmt_value(cell.gap_best, 1, percent=True)}, {gap}]" if cell.to_bound else f"({gap})"
    return text + (MARK_PARTIAL if cell.partial else "")


def markdown_pivot(table: pd.DataFrame, mode: str) -> str:
    """The pivot of one mode in Markdown: one table, a cell "mean J (gap %)"."""
    methods, scales, cells = pivot_cells(table, mode)
    out = pd.DataFrame({"method": methods})
    for scale in scales:
        out[scale] = [_markdown_cell(cells.get((method, scale))) for method in methods]
    return markdown_grid(out, text_columns=1) + "\n" + PIVOT_NOTE_MARKDOWN + "\n"


def _markdown_cell(cell: PivotCell | None) -> str:
    if cell is None:
        return "--"
    text = fmt_value(cell.mean, 2)
    if cell.best:
        text = f"**{text}**"
    if cell.fewer:
        text += f" n={cell.instances}"
    if not math.isnan(cell.gap):
        gap = fmt_value(cell.gap, 1, percent=True)
        part = ", part" if cell.partial else ""
        text += (f" [{fmt_value(cell.gap_best, 1, percent=True)}, {gap}{part}]" if cell.to_bound
                 else f" ({gap}{part})")
    return text


# --- comparisons -------------------------------------------------------------------------
def comparison_markdown(result: pd.DataFrame) -> str:
    out = pd.DataFrame({
        "method": result["method"], "n": result["instances"],
        "mean J": result["J_mean"].map(lambda v: fmt_value(v, 2)),
        "win rate (%)": result["win_rate"].map(lambda v: fmt_value(v, 1, percent=True)),
        "mean ΔJ vs best": result["diff_mean"].map(lambda v: fmt_value(v, 2)),
        "Wilcoxon W": result["W"].map(lambda v: fmt_value(v, 1)),
        "p": result["p"].map(lambda v: fmt_value(v, 4)),
        "p (Holm)": result["p_holm"].map(lambda v: fmt_value(v, 4)),
    })
    return markdown_grid(out, text_columns=1)
