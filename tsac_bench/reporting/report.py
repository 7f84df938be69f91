"""The report of a run directory: ``tsac-bench report results/NAME --out reports/NAME``
writes ``index.md`` with the run's description, the tables of ``tables`` (Markdown, LaTeX
and CSV), the statistics of ``stats`` and the figures of ``figures``; a run with budgets per
plan call also gets, per mode, its cost against budget (``budgets``).

The report carries no absolute path of the machine that wrote it: the results store is given
relative to the report, and the command that made the run as the user would type it
(``tsac-bench ...``, paths under the working directory relative to it).
"""

from __future__ import annotations

import os
import shlex
from collections.abc import Callable
from pathlib import Path
from typing import Any

import pandas as pd

from tsac_bench.batch.store import OK
from tsac_bench.reporting.budget_tables import (
    budget_footing,
    budget_latex,
    budget_markdown,
    budget_text,
    primal_latex,
    primal_markdown,
)
from tsac_bench.reporting.budgets import (
    budget_curves,
    budget_table,
    budgeted,
    paired_tests,
    primal_table,
)
from tsac_bench.reporting.data import (
    below_reference,
    load,
    load_meta,
    ordered_modes,
    per_instance,
    references,
)
from tsac_bench.reporting.stats import comparisons
from tsac_bench.reporting.tables import (
    comparison_markdown,
    latex_pivot,
    latex_table,
    markdown_pivot,
    markdown_table,
    method_table,
)


def write_report(run_dir: str | Path, out: str | Path) -> Path:
    """Write tables, statistics, figures and ``index.md`` for a run; returns index.md."""
    run_dir, out = Path(run_dir), Path(out)
    frame = load(run_dir)
    meta = load_meta(run_dir)
    tables_dir = out / "tables"
    tables_dir.mkdir(parents=True, exist_ok=True)
    table = method_table(frame)
    instances = per_instance(frame)
    instances.to_csv(tables_dir / "per_instance.csv", index=False)
    table.to_csv(tables_dir / "summary.csv", index=False)

    index = [f"# tsac-bench report: {run_dir.name}", ""]
    index += _run_section(frame, meta, run_dir, out)
    budgets = budget_table(frame)
    for mode in ordered_modes(frame["mode"].unique()):
        index += [f"## {mode.capitalize()} mode", ""]
        index += _tables_section(table, mode, tables_dir)
        index += _comparison_section(frame, mode, tables_dir)
        if (budgets["mode"] == mode).any():
            index += _budget_section(frame, budgets, mode, meta.get("calibration"), out)
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
        index += [f"- `{r.key}`: {r.status}: {portable(str(r.message))}"
                  for r in failures.head(50).itertuples()]
        if len(failures) > 50:
            index.append(f"- ... and {len(failures) - 50} more (see the results store)")
        index.append("")
    path = out / "index.md"
    path.write_text("\n".join(index), encoding="utf-8")
    return path


def _tables_section(table: pd.DataFrame, mode: str, tables_dir: Path) -> list[str]:
    """The pivot and the long table of ``mode``, written as LaTeX and Markdown files."""
    pivot, long = f"pivot-{mode}", f"summary-{mode}"
    pivot_md, long_md = markdown_pivot(table, mode), markdown_table(table, mode)
    (tables_dir / f"{pivot}.tex").write_text(latex_pivot(table, mode), encoding="utf-8")
    (tables_dir / f"{pivot}.md").write_text(pivot_md, encoding="utf-8")
    (tables_dir / f"{long}.tex").write_text(latex_table(table, mode), encoding="utf-8")
    (tables_dir / f"{long}.md").write_text(long_md, encoding="utf-8")
    lines = [f"LaTeX: [tables/{pivot}.tex](tables/{pivot}.tex), the table a paper prints "
             f"(methods by scales, one column wide; `\\usepackage{{booktabs}}`), and "
             f"[tables/{long}.tex](tables/{long}.tex), every statistic (a `longtable`; "
             "`\\usepackage{booktabs,longtable}`).", "", pivot_md, "### Every cell", "",
             long_md]
    rows = table[table["mode"] == mode]
    if rows["gap_n"].sum() == 0:
        lines += ["No instance of this run has a known J* (no manifest entry, no proven "
                  "optimum of an exact method): no gaps to J*.", ""]
    elif (rows["gap_n"] < rows["instances"]).any():
        lines += ["Where J* is unknown, `tables/per_instance.csv` has `gap_best` (to the best "
                  "J known) and `gap_lb` (to the lower bound), which bracket the gap, and "
                  "`tables/summary.csv` their `gap_best_*` and `gap_lb_*` measures.", ""]
    return lines


def _comparison_section(frame: pd.DataFrame, mode: str, tables_dir: Path) -> list[str]:
    result, best, n = comparisons(frame, mode)
    if best is None:
        return ["No instance has a result from every method: no comparison.", ""]
    stats_md = comparison_markdown(result)
    (tables_dir / f"comparison-{mode}.md").write_text(stats_md, encoding="utf-8")
    result.to_csv(tables_dir / f"comparison-{mode}.csv", index=False)
    return [f"### Comparison with the best method ({best}, lowest mean J over the {n} "
            "instances every method solved)", "",
            "Win rate: share of these instances on which the method has the lowest J (ties "
            "count for each). Wilcoxon signed-rank test of the paired per-instance J against "
            "the best method, p-values Holm-corrected.", "", stats_md]


def _budget_section(frame: pd.DataFrame, budgets: pd.DataFrame, mode: str,
                    calibration: dict[str, Any] | None, out: Path) -> list[str]:
    """Cost against budget of ``mode``: the budget table and its paired tests, the figure
    of J against budget and, in static mode, the primal integrals."""
    tables_dir = out / "tables"
    rows = budgets[budgets["mode"] == mode]
    tests = paired_tests(frame, rows)
    name = f"budget-{mode}"
    budget_md = budget_markdown(rows, tests, mode, calibration)
    (tables_dir / f"{name}.md").write_text(budget_md, encoding="utf-8")
    (tables_dir / f"{name}.tex").write_text(budget_latex(rows, tests, mode, calibration),
                                           encoding="utf-8")
    rows.to_csv(tables_dir / f"{name}.csv", index=False)
    tests.to_csv(tables_dir / f"budget-tests-{mode}.csv", index=False)
    footing = budget_footing(rows, calibration)
    if frame.loc[frame["mode"] == mode, "budget"].isna().any():
        footing += (" A method named without `@` in the tables above ran by its own stopping "
                    "rule, without a budget.")
    lines = ["### Cost against budget", "", footing, "",
             f"LaTeX: [tables/{name}.tex](tables/{name}.tex) (a `longtable`; "
             f"`\\usepackage{{booktabs,longtable}}`); numbers: [tables/{name}.csv]"
             f"(tables/{name}.csv), [tables/budget-tests-{mode}.csv]"
             f"(tables/budget-tests-{mode}.csv).", "", budget_md]
    reference = float(calibration["seconds"]) if calibration else None
    lines += _draw(lambda figures: [figures.cost_against_budget(
        budget_curves(frame), mode, reference, out / "figures")], out)
    if mode == "static":
        primal = primal_table(frame)
        if not primal.empty:
            primal_md = primal_markdown(primal, calibration)
            (tables_dir / "primal-static.md").write_text(primal_md, encoding="utf-8")
            (tables_dir / "primal-static.tex").write_text(primal_latex(primal, calibration),
                                                          encoding="utf-8")
            primal.to_csv(tables_dir / "primal-static.csv", index=False)
            lines += ["#### Primal integral and time to target (static mode)", "",
                      "LaTeX: [tables/primal-static.tex](tables/primal-static.tex); numbers: "
                      "[tables/primal-static.csv](tables/primal-static.csv).", "", primal_md]
    return lines


def _run_section(frame: pd.DataFrame, meta: dict[str, Any], run_dir: Path,
                 out: Path) -> list[str]:
    ok = frame["status"] == OK
    versions: dict[str, str] = {}
    for v in frame["versions"]:
        versions.update(v or {})
    refs = references(frame)
    sources = refs["J_star_source"].value_counts().to_dict()
    known = ", ".join(f"{n} from {s}" for s, n in sources.items()) or "none"
    command = meta.get("command")
    lines = [
        f"- results store: `{relative_to(run_dir / 'results.sqlite', out)}` (relative to "
        "this report)",
        f"- command: `{shown_command(command) if isinstance(command, str) else '?'}`",
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
        *_budgets_line(frame, meta.get("calibration")),
        "- per-instance numbers: [tables/per_instance.csv](tables/per_instance.csv); "
        "all cells: [tables/summary.csv](tables/summary.csv)",
        "",
    ]
    return lines


def _budgets_line(frame: pd.DataFrame, calibration: dict[str, Any] | None) -> list[str]:
    """The run's budgets per plan call and its machine-speed reference, if it has budgets."""
    jobs = budgeted(frame)
    if jobs.empty:
        return []
    line = ("- budgets per plan call: "
            + ", ".join(budget_text(b, calibration) for b in sorted(jobs["budget"].unique())))
    if calibration:
        line += (f"; reference workload: {calibration.get('workload', '?')}, "
                 f"{float(calibration['seconds']):.4g} s on {calibration.get('host', '?')}")
    return [line]


# --- no path of this machine ------------------------------------------------------------
def relative_to(path: Path, start: Path) -> str:
    """``path`` relative to the folder ``start`` (``..`` where needed), in POSIX form; its
    name alone where no relative path exists (another drive)."""
    try:
        return Path(os.path.relpath(path.resolve(), start.resolve())).as_posix()
    except ValueError:
        return path.name


def shown_command(command: str, cwd: Path | None = None) -> str:
    """A recorded command line (``shlex.join(sys.argv)``) as a user types it: the
    tsac-bench executable (its console script, or ``tsac_bench/__main__.py`` of ``python -m
    tsac_bench``) as ``tsac-bench``; an absolute path under ``cwd`` (default: the working
    directory) relative to it, any other by its name after ``.../``."""
    try:
        words = shlex.split(command)
    except ValueError:  # not a shlex.join output: shown word by word as recorded
        words = command.split()
    if not words:
        return command
    base = (cwd or Path.cwd()).resolve()
    shown = [_shown_word(word, base) for word in words]
    first = Path(words[0])
    if first.name == "tsac-bench" or (first.name == "__main__.py"
                                      and first.parent.name == "tsac_bench"):
        shown[0] = "tsac-bench"
    return shlex.join(shown)


def _shown_word(word: str, base: Path) -> str:
    option, equals, value = word.partition("=")
    if equals and option.startswith("-"):
        return f"{option}={_shown_path(value, base)}"
    return _shown_path(word, base)


def _shown_path(word: str, base: Path) -> str:
    if not os.path.isabs(word):
        return word
    path = Path(word)
    if path.is_relative_to(base):
        return path.relative_to(base).as_posix()
    return f".../{path.name}"


def portable(text: str, cwd: Path | None = None) -> str:
    """``text`` (an error message) with the working directory's absolute path taken off the
    paths under it."""
    base = str((cwd or Path.cwd()).resolve())
    return text.replace(base + os.sep, "")


def _figure_section(frame: pd.DataFrame, instances: pd.DataFrame, run_dir: Path,
                    out: Path) -> list[str]:
    return ["## Figures", "", *_draw(lambda figures: figures.draw_all(
        frame, instances, run_dir, out / "figures"), out, level="###")]


def _draw(draw: Callable[[Any], list[tuple[str, list[Path], str]]], out: Path,
          level: str = "####") -> list[str]:
    """Index lines of the figures ``draw(figures module)`` saves: a heading of ``level`` per
    figure, its note, each PNG and a link to its PDF; one line where matplotlib is
    missing."""
    try:
        from tsac_bench.reporting import figures
    except ImportError as exc:
        return [f"Not drawn: {exc} (pip install -e '.[report]').", ""]
    lines = []
    for title, paths, note in draw(figures):
        lines += [f"{level} {title}", ""]
        if note:
            lines += [note, ""]
        for path in paths:
            rel = path.relative_to(out)
            lines += [f"![{title}]({rel.as_posix()})  ",
                      f"[PDF]({rel.with_suffix('.pdf').as_posix()})", ""]
    return lines
