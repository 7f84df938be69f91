"""The shape of the LaTeX tables on a wide run (9 scales, 10 methods, method specs among the
labels): checked everywhere, and compiled with pdflatex in a one-column article where it is
installed (they must fit the text width; the long table must break across pages)."""

import re
import shutil
import subprocess
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from tsac_bench.reporting.tables import (
    PIVOT_SCALES,
    latex_escape,
    latex_pivot,
    latex_table,
    method_table,
)

SCALES = ("2/4", "2/5", "2/6", "3/5", "3/6", "4/10", "8/20", "16/40", "32/80")
METHODS = ("cnp", "dga", "exact-cpsat:threads=2", "greedy", "hocf", "hocf:init=incumbent",
           "my_method&co", "pyvrp", "rocf", "tsac-ocf")


@pytest.fixture(scope="module")
def wide() -> pd.DataFrame:
    """Method table of a run with the widest numbers a report prints: J up to 8800 (80 tasks
    unserved), gaps in the thousands of %, references of every kind (J* on the first
    instance of a scale, only a lower bound on the second, none on the third; only bounds at
    32/80) and one method with fewer instances at 4/10."""
    rng = np.random.default_rng(0)
    rows = []
    for s, scale in enumerate(SCALES):
        for i in range(3):
            instance = f"{scale}-{i}"
            reference = 1.0 + s if s < 8 else 250.0
            for method in METHODS:
                if method == "exact-cpsat:threads=2" and scale == "4/10" and i == 2:
                    continue
                J = float(reference * (1 + rng.uniform(0, 45)) if s < 8 else 8800 * rng.uniform())
                rows.append({
                    "key": f"{instance}|{method}|static|0", "instance": instance,
                    "scale": scale, "method": method, "mode": "static", "seed": 0,
                    "status": "ok", "J": J, "J_load": J, "J_time": 0.0, "J_op": 0.0,
                    "runtime": 1.0, "stats": {},
                    "J_star": reference if i == 0 and s < 8 else np.nan,
                    "lower_bound": reference / 2 if i < 2 else np.nan})
    return method_table(pd.DataFrame(rows))


def tabular_rows(tex: str, environment: str) -> tuple[str, list[list[str]]]:
    """The column spec and the cell rows (lines ending in ``\\\\``, caption aside), checking
    that every row spans every column (a ``\\multicolumn{k}`` cell spans k)."""
    spec = re.search(rf"\\begin\{{{environment}\}}\{{([lrc]+)\}}", tex).group(1)
    body = tex[tex.index(rf"\begin{{{environment}}}"): tex.index(rf"\end{{{environment}}}")]
    rows = [re.sub(r" \\\\(\[-?[\d.]+pt\])?$", "", line).split(" & ")
            for line in body.splitlines()
            if re.search(r" \\\\(\[-?[\d.]+pt\])?$", line) and not line.startswith(r"\label")]
    for row in rows:
        spans = [int(m.group(1)) if (m := re.match(r"\\multicolumn\{(\d+)\}", cell)) else 1
                 for cell in row]
        assert sum(spans) == len(spec), row
    return spec, rows


def visible(cell: str) -> str:
    """What a cell prints: commands and math markup taken off, ``$\\leq$`` and ``$\\geq$``
    one character each."""
    cell = cell.replace(r"$\leq$", "<").replace(r"$\geq$", ">")
    cell = re.sub(r"\\rlap\{[^}]*\}", "", cell)
    cell = re.sub(r"\\textbf\{([^}]*)\}", r"\1", cell)
    return re.sub(r"\\(.)", r"\1", cell).replace("$", "")


def test_the_pivot_is_one_column_wide(wide):
    tex = latex_pivot(wide, "static")
    spec, rows = tabular_rows(tex, "tabular")
    assert spec == "l" + "r" * 5  # 9 scales: panels of 5 and 4, never more than PIVOT_SCALES
    assert len(spec) <= 1 + PIVOT_SCALES
    assert all(len(row) == len(spec) for row in rows)
    lines = tex.splitlines()
    assert lines.count(r"\toprule") == 1 and lines.count(r"\bottomrule") == 1
    assert r"\hline" not in tex
    headers = [row[1:] for row in rows if row[0] == r"Method \hfill $N/M$"]
    assert headers == [list(SCALES[:5]), [*SCALES[5:], ""]]
    # Bounded width: no number cell prints more than 15 characters ("[342.0, 3420.0]" where
    # J* is unknown, "8812.34"); the compile test below checks that it fits the page.
    numbers = [visible(cell) for row in rows for cell in row[1:]]
    assert max(map(len, numbers)) <= 15
    # Every method: a row of means and a row of gaps in each panel.
    methods = [row[0] for row in rows if row[0] not in ("", r"Method \hfill $N/M$")]
    assert methods == [latex_escape(m) for m in METHODS] * 2
    assert r"\parbox{\linewidth}{\footnotesize Mean $J$" in tex


def test_the_long_table_is_a_longtable(wide):
    tex = latex_table(wide, "static")
    spec, rows = tabular_rows(tex, "longtable")
    assert spec == "l" + "r" * 9
    methods = [row[0] for row in rows if row[0] and not row[0].startswith(r"\multicolumn")]
    assert methods == ["Method", "Method", *[latex_escape(m) for m in METHODS] * len(SCALES)]
    headings = [row[0] for row in rows if row[0].startswith(r"\multicolumn{10}{l}{$N/M$")]
    assert headings == [rf"\multicolumn{{10}}{{l}}{{$N/M$ = {s}}}" for s in SCALES]
    for command in (r"\toprule", r"\midrule", r"\bottomrule", r"\endfirsthead", r"\endhead",
                    r"\endfoot", r"\endlastfoot", r"\cmidrule(lr){3-5}\cmidrule(lr){6-8}"):
        assert command in tex.splitlines(), command
    assert r"\begin{table}" not in tex  # a longtable is no float: it breaks across pages


def test_method_specs_are_escaped_for_latex():
    assert latex_escape("hocf:init=incumbent") == "hocf:init=incumbent"
    assert latex_escape("my_method&co") == r"my\_method\&co"
    assert latex_escape(r"a\b~c^d%e$f#g{h}") == (r"a\textbackslash{}b\textasciitilde{}c"
                                                 r"\textasciicircum{}d\%e\$f\#g\{h\}")


def pdflatex(tmp_path: Path, table: str, name: str) -> tuple[str, int]:
    """Compile ``table`` in a one-column article (twice: a longtable settles its column
    widths on the second run); the log and the page count."""
    (tmp_path / f"{name}.tex").write_text(
        "\\documentclass{article}\n\\usepackage{booktabs}\n\\usepackage{longtable}\n"
        "\\begin{document}\n" + table + "\n\\end{document}\n", encoding="utf-8")
    for _ in range(2):
        done = subprocess.run(["pdflatex", "-interaction=nonstopmode", "-halt-on-error",
                               f"{name}.tex"], cwd=tmp_path, capture_output=True, text=True,
                              timeout=120)
    log = (tmp_path / f"{name}.log").read_text(errors="replace")
    assert done.returncode == 0, log[-2000:]
    pages = re.search(r"Output written on .* \((\d+) pages?", log)
    return log, int(pages.group(1))


@pytest.mark.skipif(shutil.which("pdflatex") is None, reason="pdflatex is not installed")
def test_both_tables_compile_and_fit_a_one_column_article(wide, tmp_path):
    log, pages = pdflatex(tmp_path, latex_pivot(wide, "static"), "pivot")
    assert "Overfull \\hbox" not in log and "Float too large" not in log
    assert pages == 1
    log, pages = pdflatex(tmp_path, latex_table(wide, "static"), "long")
    assert "Overfull \\hbox" not in log
    assert pages >= 2  # 90 rows and 9 group headings: the table breaks across pages


def test_a_mode_without_results_gives_empty_tables():
    failed = pd.DataFrame([{"key": "i|m|static|0", "instance": "i", "scale": "2/4",
                            "method": "m", "mode": "static", "seed": 0, "status": "error",
                            "J": np.nan, "J_load": np.nan, "J_time": np.nan, "J_op": np.nan,
                            "runtime": np.nan, "stats": {}, "J_star": np.nan,
                            "lower_bound": np.nan}])
    table = method_table(failed)
    assert table[["jobs", "failed", "instances", "gap_n"]].values.tolist() == [[1, 1, 0, 0]]
    spec, rows = tabular_rows(latex_pivot(table, "static"), "tabular")
    assert (spec, rows) == ("l", [])
