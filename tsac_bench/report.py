"""Tables and statistics of a run directory (pandas + scipy), and the report that ties them
to the figures of ``tsac_bench.figures``: ``tsac-bench report results/NAME --out reports/NAME``.

How the numbers are made (docs/reports.md says the same for readers of a report):
* Only jobs with status ``ok`` have a J; failed jobs are counted, never averaged.
* Per instance, J is first averaged over seeds; the statistics of a (mode, scale, method) cell
  (mean, std, median) are then taken over its instances.
* J* of an instance is the manifest's ``J_star``; failing that, the smallest J of a static run
  of an exact method (``exact``, ``exact-cpsat``, ``exact-bp``) whose stats say
  ``status: optimal``. The
  lower bound is the largest of the manifest's ``lower_bound`` and those runs' ``lower_bound``.
  gap = (J - J*) / J*; where only a lower bound is known, ``gap_lb`` = (J - LB) / LB, an upper
  bound on the true gap, is reported instead and marked.
* The best method of a mode is the one with the lowest mean J over the instances every method
  solved; win rates and the Wilcoxon signed-rank tests (Holm-corrected) use those instances.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from tsac_bench.runner import EXACT_METHODS, OK
from tsac_bench.store import ResultStore

#: Two costs closer than this (relative) tie for a win.
TIE_TOLERANCE = 1e-9
MODE_ORDER = ("static", "dynamic")


def load(run_dir: str | Path) -> pd.DataFrame:
    with ResultStore(run_dir, create=False) as store:
        return store.frame()


def scale_order(scales: Sequence[str]) -> list[str]:
    """``N/M`` labels by fleet size then task count (4/10 before 16/40)."""

    def key(scale: str) -> tuple[int, ...]:
        try:
            return tuple(int(part) for part in scale.split("/"))
        except ValueError:
            return (math.inf,)  # type: ignore[return-value]

    return sorted(set(scales), key=lambda s: (key(s), s))


def ordered_modes(modes: Sequence[str]) -> list[str]:
    known = [m for m in MODE_ORDER if m in set(modes)]
    return known + sorted(set(modes) - set(MODE_ORDER))


# --- references and gaps -----------------------------------------------------------------
def references(frame: pd.DataFrame) -> pd.DataFrame:
    """Per instance: J_star, lower_bound and where J* came from (see the module notes)."""
    instances = frame["instance"].drop_duplicates().sort_values()
    refs = pd.DataFrame(index=pd.Index(instances, name="instance"))
    manifest = frame.groupby("instance")[["J_star", "lower_bound"]].max()
    refs["J_star"] = manifest["J_star"]
    refs["lower_bound"] = manifest["lower_bound"]
    refs["J_star_source"] = np.where(refs["J_star"].notna(), "manifest", None)
    exact = frame[frame["method"].isin(EXACT_METHODS) & (frame["mode"] == "static")
                  & (frame["status"] == OK)]
    for instance, rows in exact.groupby("instance"):
        stats = rows["stats"].map(lambda s: s if isinstance(s, dict) else {})
        optimal = rows[stats.map(lambda s: s.get("status") == "optimal")]
        if pd.isna(refs.at[instance, "J_star"]) and not optimal.empty:
            refs.at[instance, "J_star"] = optimal["J"].min()
            refs.at[instance, "J_star_source"] = "exact run"
        bounds = [float(s["lower_bound"]) for s in stats
                  if isinstance(s.get("lower_bound"), int | float)]
        if bounds:
            refs.at[instance, "lower_bound"] = np.nanmax([refs.at[instance, "lower_bound"],
                                                          *bounds])
    return refs


def per_instance(frame: pd.DataFrame) -> pd.DataFrame:
    """One row per (mode, scale, instance, method): J and its terms averaged over the seeds
    that succeeded, with the instance's references and gaps."""
    ok = frame[frame["status"] == OK]
    keys = ["mode", "scale", "instance", "method"]
    values = ["J", "J_load", "J_time", "J_op", "runtime"]
    if ok.empty:
        table = pd.DataFrame(columns=[*keys, *values, "seeds"])
    else:
        grouped = ok.groupby(keys, sort=True)
        table = grouped[values].mean()
        table["seeds"] = grouped.size()
        table = table.reset_index()
    table = table.merge(references(frame), left_on="instance", right_index=True, how="left")
    j_star = table["J_star"].where(table["J_star"] > 0)
    bound = table["lower_bound"].where(table["lower_bound"] > 0)
    table["gap"] = (table["J"] - j_star) / j_star
    table["gap_lb"] = ((table["J"] - bound) / bound).where(j_star.isna())
    return table


#: Relative slack below J* or the lower bound that is put down to solver tolerances.
REFERENCE_TOLERANCE = 1e-6


def below_reference(frame: pd.DataFrame) -> pd.DataFrame:
    """Jobs whose J is below their instance's J* or lower bound. MODEL.md: every executed
    plan is a feasible offline solution, so J >= J* >= LB always; a row here is a bug in an
    exact model, the evaluator or the simulator (or a wrong manifest)."""
    ok = frame[frame["status"] == OK].drop(columns=["J_star", "lower_bound"])
    ok = ok.merge(references(frame), left_on="instance", right_index=True, how="left")
    floor = ok[["J_star", "lower_bound"]].max(axis=1)
    below = ok["J"] < floor * (1 - REFERENCE_TOLERANCE) - 1e-9
    return ok.loc[below, ["key", "J", "J_star", "lower_bound", "J_star_source"]]


@dataclass(frozen=True)
class Cell:
    """Formatting of one statistic column: the frame column, its header and precision."""

    column: str
    latex: str
    markdown: str
    digits: int
    percent: bool = False
    best: bool = True  # the lowest value is bold


SUMMARY_CELLS = (
    Cell("J_mean", r"Mean $J$", "mean J", 2),
    Cell("J_std", r"Std $J$", "std J", 2, best=False),
    Cell("J_median", r"Median $J$", "median J", 2),
    Cell("gap_mean", r"Gap to $J^*$ (\%)", "gap to J* (%)", 2, percent=True),
)


def method_table(frame: pd.DataFrame) -> pd.DataFrame:
    """Per (mode, scale, method): instances with a result, failed jobs, mean/std/median J over
    instances, mean gap to J* (over the instances with a known J*) and mean gap to the lower
    bound where J* is unknown."""
    table = per_instance(frame)
    keys = ["mode", "scale", "method"]
    stats = table.groupby(keys).agg(
        instances=("J", "size"), J_mean=("J", "mean"), J_std=("J", "std"),
        J_median=("J", "median"), gap_mean=("gap", "mean"), gap_n=("gap", "count"),
        gap_lb_mean=("gap_lb", "mean"), gap_lb_n=("gap_lb", "count"))
    counts = frame.groupby(keys).agg(jobs=("status", "size"),
                                     failed=("status", lambda s: int((s != OK).sum())))
    stats = counts.join(stats, how="left").reset_index()
    for column in ("instances", "gap_n", "gap_lb_n"):
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


class SolutionLoader:
    """Instances and stored solutions of a run, read back (instances cached by file)."""

    def __init__(self, run_dir: Path) -> None:
        self.run_dir = run_dir
        self._instances: dict[str, Any] = {}

    def instance(self, row: Any) -> Any | None:
        from tsac_bench.errors import InputError
        from tsac_bench.io import read_instance

        path = row["instance_file"]
        if not isinstance(path, str):
            return None
        if path not in self._instances:
            try:
                self._instances[path] = read_instance(path)
            except InputError:
                self._instances[path] = None  # moved since the run: its figures are skipped
        return self._instances[path]

    def solution(self, row: Any) -> tuple[Any, Any] | None:
        """(instance, solution) of an ok row, or None where a file is gone."""
        from tsac_bench.errors import InputError
        from tsac_bench.io import read_solution

        instance = self.instance(row)
        if instance is None or not isinstance(row["solution_file"], str):
            return None
        try:
            return instance, read_solution(self.run_dir / row["solution_file"], instance)
        except InputError:
            return None


def coalition_sizes(frame: pd.DataFrame, run_dir: Path) -> pd.DataFrame:
    """Per served task of every ok job: its demand and coalition size, as the evaluator
    computes them from the stored solution (the data of the paper's Fig. 6)."""
    from tsac_bench.evaluator import CostEvaluator

    loader = SolutionLoader(run_dir)
    rows = []
    for _, row in frame[frame["status"] == OK].iterrows():
        loaded = loader.solution(row)
        if loaded is None:
            continue
        instance, solution = loaded
        evaluation = CostEvaluator(instance).evaluate(solution)
        for task, breakdown in zip(instance.tasks, evaluation.per_task, strict=True):
            if breakdown.coalition:
                rows.append({"mode": row["mode"], "method": row["method"],
                             "instance": row["instance"], "seed": row["seed"],
                             "task": task.id, "demand": task.demand,
                             "coalition_size": len(breakdown.coalition)})
    return pd.DataFrame(rows, columns=["mode", "method", "instance", "seed", "task", "demand",
                                       "coalition_size"])


# --- statistics --------------------------------------------------------------------------
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
    rows = []
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


# --- rendering ---------------------------------------------------------------------------
def _fmt(value: Any, digits: int, percent: bool = False) -> str:
    if value is None or (isinstance(value, float) and math.isnan(value)):
        return "--"
    return f"{value * 100 if percent else value:.{digits}f}"


def _bold_mask(cells: pd.DataFrame) -> pd.DataFrame:
    """Per scale, which printed values are the best (lowest; printed ties are all bold)."""
    mask = pd.DataFrame(False, index=cells.index, columns=[c.column for c in SUMMARY_CELLS])
    for _, group in cells.groupby("scale", sort=False):
        for cell in SUMMARY_CELLS:
            if not cell.best:
                continue
            printed = group[cell.column].map(lambda v, c=cell: _fmt(v, c.digits, c.percent))
            numbers = pd.to_numeric(printed.where(printed != "--"), errors="coerce")
            if numbers.notna().any():
                mask.loc[group.index, cell.column] = numbers == numbers.min()
    return mask


def _latex_escape(text: str) -> str:
    for char in ("\\", "&", "%", "$", "#", "_", "{", "}"):
        text = text.replace(char, "\\" + char)
    return text


def latex_table(table: pd.DataFrame, mode: str) -> str:
    """A booktabs table of one mode: rows grouped by scale, best values in bold."""
    rows = table[table["mode"] == mode].reset_index(drop=True)
    bold = _bold_mask(rows)
    header = ["Scale", "Method", "$n$", *[c.latex for c in SUMMARY_CELLS], "$n_{J^*}$",
              "Failed"]
    lines = [
        r"\begin{table}[t]",
        r"\centering",
        rf"\caption{{Total cost $J$ per method and scale ({mode} mode): mean, standard "
        r"deviation and median over instances (each the mean over seeds), and mean gap to "
        r"the exact optimum $J^*$.}",
        rf"\label{{tab:tsac-bench-{mode}}}",
        r"\begin{tabular}{ll" + "r" * (len(header) - 2) + "}",
        r"\toprule",
        " & ".join(header) + r" \\",
    ]
    previous = None
    for i, row in rows.iterrows():
        if row["scale"] != previous:
            lines.append(r"\midrule")
            previous = row["scale"]
        cells = [_latex_escape(str(row["scale"])), _latex_escape(str(row["method"])),
                 str(row["instances"])]
        for cell in SUMMARY_CELLS:
            text = _fmt(row[cell.column], cell.digits, cell.percent)
            cells.append(rf"\textbf{{{text}}}" if bold.at[i, cell.column] else text)
        cells += [str(int(row["gap_n"])), str(int(row["failed"]))]
        lines.append(" & ".join(cells) + r" \\")
    lines += [r"\bottomrule", r"\end{tabular}", r"\end{table}", ""]
    return "\n".join(lines)


def markdown_table(table: pd.DataFrame, mode: str) -> str:
    rows = table[table["mode"] == mode].reset_index(drop=True)
    bold = _bold_mask(rows)
    out = pd.DataFrame({"scale": rows["scale"], "method": rows["method"],
                        "n": rows["instances"]})
    for cell in SUMMARY_CELLS:
        printed = rows[cell.column].map(lambda v, c=cell: _fmt(v, c.digits, c.percent))
        out[cell.markdown] = [f"**{p}**" if b else p
                              for p, b in zip(printed, bold[cell.column], strict=True)]
    out["n with J*"] = rows["gap_n"].astype(int)
    out["failed"] = rows["failed"].astype(int)
    return _markdown(out, text_columns=2)


def comparison_markdown(result: pd.DataFrame) -> str:
    out = pd.DataFrame({
        "method": result["method"], "n": result["instances"],
        "mean J": result["J_mean"].map(lambda v: _fmt(v, 2)),
        "win rate (%)": result["win_rate"].map(lambda v: _fmt(v, 1, percent=True)),
        "mean ΔJ vs best": result["diff_mean"].map(lambda v: _fmt(v, 2)),
        "Wilcoxon W": result["W"].map(lambda v: _fmt(v, 1)),
        "p": result["p"].map(lambda v: _fmt(v, 4)),
        "p (Holm)": result["p_holm"].map(lambda v: _fmt(v, 4)),
    })
    return _markdown(out, text_columns=1)


def _markdown(table: pd.DataFrame, text_columns: int) -> str:
    """A Markdown table of pre-formatted cells, numbers right-aligned."""
    align = ["left"] * text_columns + ["right"] * (len(table.columns) - text_columns)
    return table.to_markdown(index=False, disable_numparse=True, colalign=align) + "\n"


# --- the report --------------------------------------------------------------------------
def write_report(run_dir: str | Path, out: str | Path) -> Path:
    """Write tables, statistics, figures and ``index.md`` for a run; returns index.md."""
    run_dir, out = Path(run_dir), Path(out)
    frame = load(run_dir)
    with ResultStore(run_dir, create=False) as store:
        meta = store.meta()
    tables_dir = out / "tables"
    tables_dir.mkdir(parents=True, exist_ok=True)
    table = method_table(frame)
    instances = per_instance(frame)
    instances.to_csv(tables_dir / "per_instance.csv", index=False)
    table.to_csv(tables_dir / "summary.csv", index=False)

    index = [f"# tsac-bench report: {run_dir.name}", ""]
    index += _run_section(frame, meta, run_dir)
    modes = ordered_modes(frame["mode"].unique())
    for mode in modes:
        (tables_dir / f"summary-{mode}.tex").write_text(latex_table(table, mode),
                                                        encoding="utf-8")
        md = markdown_table(table, mode)
        (tables_dir / f"summary-{mode}.md").write_text(md, encoding="utf-8")
        index += [f"## {mode.capitalize()} mode", "",
                  f"LaTeX: [tables/summary-{mode}.tex](tables/summary-{mode}.tex) "
                  "(needs `\\usepackage{booktabs}`)", "", md]
        rows = table[table["mode"] == mode]
        if rows["gap_n"].fillna(0).sum() == 0:
            index += ["No instance of this run has a known J* (no manifest entry, no proven "
                      "optimum of an exact method): no gaps.", ""]
        elif (rows["gap_n"].fillna(0) < rows["instances"]).any():
            index += ["Gap to J* is averaged over the instances with a known J*; where only a "
                      "lower bound is known, `tables/per_instance.csv` has `gap_lb`.", ""]
        result, best, n = comparisons(frame, mode)
        if best is None:
            index += ["No instance has a result from every method: no comparison.", ""]
        else:
            stats_md = comparison_markdown(result)
            (tables_dir / f"comparison-{mode}.md").write_text(stats_md, encoding="utf-8")
            result.to_csv(tables_dir / f"comparison-{mode}.csv", index=False)
            index += [f"### Comparison with the best method ({best}, lowest mean J over the "
                      f"{n} instances every method solved)", "",
                      "Win rate: share of these instances on which the method has the lowest J "
                      "(ties count for each). Wilcoxon signed-rank test of the paired "
                      "per-instance J against the best method, p-values Holm-corrected.", "",
                      stats_md]
    index += _figure_section(frame, instances, run_dir, out)
    below = below_reference(frame)
    if not below.empty:
        index += ["## Costs below the exact reference (a bug: J >= J* >= LB must hold)", ""]
        index += [f"- `{r.key}`: J = {r.J:.6f}, J* = {r.J_star}, LB = {r.lower_bound}"
                  for r in below.itertuples()]
        index.append("")
    failures = frame[frame["status"] != OK]
    if not failures.empty:
        index += ["## Failed jobs", "", f"{len(failures)} job(s) did not produce a solution:",
                  ""]
        index += [f"- `{r.key}`: {r.status}: {r.message}" for r in failures.head(50).itertuples()]
        if len(failures) > 50:
            index.append(f"- ... and {len(failures) - 50} more (see the results store)")
        index.append("")
    path = out / "index.md"
    path.write_text("\n".join(index), encoding="utf-8")
    return path


def _run_section(frame: pd.DataFrame, meta: dict[str, Any], run_dir: Path) -> list[str]:
    ok = frame["status"] == OK
    versions: dict[str, str] = {}
    for v in frame["versions"]:
        versions.update(v or {})
    refs = references(frame)
    sources = refs["J_star_source"].value_counts().to_dict()
    known = ", ".join(f"{n} from {s}" for s, n in sources.items()) or "none"
    lines = [
        f"- results store: `{run_dir / 'results.sqlite'}`",
        f"- command: `{meta.get('command', '?')}`",
        f"- jobs: {len(frame)} ({int(ok.sum())} ok, {int((~ok).sum())} failed); "
        f"{frame['instance'].nunique()} instances in sets "
        f"{', '.join(sorted(frame['instance_set'].dropna().unique()))}; "
        f"methods {', '.join(sorted(frame['method'].unique()))}; "
        f"seeds {int(frame['seed'].nunique())}",
        f"- J* known for {int(refs['J_star'].notna().sum())} of {len(refs)} instances "
        f"({known}); lower bound only for "
        f"{int((refs['J_star'].isna() & refs['lower_bound'].notna()).sum())}",
        f"- versions: {', '.join(f'{k} {v}' for k, v in sorted(versions.items()))}",
        f"- hosts: {', '.join(sorted(frame['host'].dropna().unique()))}",
        "- per-instance numbers: [tables/per_instance.csv](tables/per_instance.csv); "
        "all cells: [tables/summary.csv](tables/summary.csv)",
        "",
    ]
    return lines


def _figure_section(frame: pd.DataFrame, instances: pd.DataFrame, run_dir: Path,
                    out: Path) -> list[str]:
    try:
        from tsac_bench import figures
    except ImportError as exc:
        return ["## Figures", "", f"Not drawn: {exc} (pip install -e '.[report]').", ""]
    lines = ["## Figures", ""]
    for title, paths, note in figures.draw_all(frame, instances, run_dir, out / "figures"):
        lines += [f"### {title}", ""]
        if note:
            lines += [note, ""]
        for path in paths:
            rel = path.relative_to(out)
            lines += [f"![{title}]({rel.as_posix()})  ",
                      f"[PDF]({rel.with_suffix('.pdf').as_posix()})", ""]
    return lines
