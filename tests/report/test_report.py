"""Tables and statistics of a hand-made results store: every number is worked out by hand
or recomputed with pandas straight from the store."""

import math
import re
import shlex
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from tsac_bench.batch.store import ResultStore, job_key
from tsac_bench.reporting.data import below_reference, per_instance, references
from tsac_bench.reporting.report import shown_command, write_report
from tsac_bench.reporting.stats import comparisons, gap_measures, holm, shifted_geometric_mean
from tsac_bench.reporting.tables import (
    GAP_NOTE_LATEX,
    GAP_NOTE_MARKDOWN,
    PIVOT_NOTE_LATEX,
    PIVOT_NOTE_MARKDOWN,
    latex_pivot,
    markdown_pivot,
    method_table,
)

DATA = Path(__file__).parent.parent / "data"

#: (instance, scale, method, seed) -> J; None marks a failed job.
RUNS = {
    ("i1", "2/4", "A", 0): 110.0, ("i1", "2/4", "A", 1): 130.0,
    ("i2", "2/4", "A", 0): 55.0, ("i2", "2/4", "A", 1): 55.0,
    ("i3", "3/6", "A", 0): 90.0, ("i3", "3/6", "A", 1): 100.0,
    ("i4", "3/6", "A", 0): 70.0, ("i4", "3/6", "A", 1): 72.0,
    ("i1", "2/4", "B", 0): 105.0, ("i1", "2/4", "B", 1): 105.0,
    ("i2", "2/4", "B", 0): 60.0, ("i2", "2/4", "B", 1): 70.0,
    ("i3", "3/6", "B", 0): 85.0, ("i3", "3/6", "B", 1): None,
    ("i4", "3/6", "B", 0): 75.0, ("i4", "3/6", "B", 1): 75.0,
    ("i3", "3/6", "exact", 0): 80.0, ("i4", "3/6", "exact", 0): 65.0,
}
MANIFEST_J_STAR = {"i1": 100.0, "i2": 50.0}
EXACT_STATS = {"i3": {"status": "optimal", "lower_bound": 80.0},
               "i4": {"status": "feasible", "lower_bound": 60.0}}


def record(store, instance, scale, method, seed, J, mode="static", **extra):
    row = {"key": job_key(instance, method, mode, seed), "instance": instance,
           "instance_set": "hand-made", "scale": scale, "method": method, "mode": mode,
           "seed": seed, "status": "ok" if J is not None else "error",
           "message": "" if J is not None else "RuntimeError: no", "J": J,
           "J_load": None if J is None else J / 2, "J_time": None if J is None else J / 4,
           "J_op": None if J is None else J / 4, "J_star": MANIFEST_J_STAR.get(instance),
           "reference": "manifest" if instance in MANIFEST_J_STAR else None,
           "stats": {}, "versions": {"tsac-bench": "0.1.0"}, "host": "test", **extra}
    store.record(row)


@pytest.fixture
def run_dir(tmp_path) -> Path:
    with ResultStore(tmp_path / "run") as store:
        for (instance, scale, method, seed), J in RUNS.items():
            stats = EXACT_STATS[instance] if method == "exact" else {}
            record(store, instance, scale, method, seed, J, stats=stats)
    return tmp_path / "run"


def test_references_take_the_manifest_then_proven_exact_runs(run_dir):
    with ResultStore(run_dir) as store:
        refs = references(store.frame())
    assert refs["J_star"].to_dict() == pytest.approx(
        {"i1": 100.0, "i2": 50.0, "i3": 80.0, "i4": np.nan}, nan_ok=True)
    assert refs["J_star_source"].dropna().to_dict() == {"i1": "manifest", "i2": "manifest",
                                                        "i3": "exact run"}
    assert refs.at["i4", "lower_bound"] == 60.0  # from a non-optimal exact run


def test_method_table_by_hand(run_dir):
    with ResultStore(run_dir) as store:
        table = method_table(store.frame()).set_index(["scale", "method"])
    a = table.loc[("2/4", "A")]
    assert (a["instances"], a["J_mean"], a["J_median"]) == (2, 87.5, 87.5)
    assert a["J_std"] == pytest.approx(np.std([120, 55], ddof=1), rel=1e-12)
    assert a["gap_mean"] == pytest.approx((0.2 + 0.1) / 2, rel=1e-12)
    b = table.loc[("3/6", "B")]
    assert (b["jobs"], b["failed"], b["J_mean"]) == (4, 1, 80.0)
    assert b["gap_mean"] == pytest.approx(0.0625, rel=1e-12)  # i3 only: i4 has no J*
    assert b["gap_lb_mean"] == pytest.approx(75 / 60 - 1, rel=1e-12)
    assert table.loc[("3/6", "exact"), "gap_mean"] == 0.0


def test_gap_measures_of_a_cell_by_hand(run_dir):
    with ResultStore(run_dir) as store:
        table = method_table(store.frame()).set_index(["scale", "method"])
    # 2/4, A: J = 120 (mean of 110, 130) and 55 against J* = 100 and 50.
    a = table.loc[("2/4", "A")]
    assert a["gap_mean"] == pytest.approx((0.2 + 0.1) / 2, rel=1e-12)
    assert a["gap_sum"] == pytest.approx((175 - 150) / 150, rel=1e-12)
    # SGM_1(J) = sqrt(121 * 56) - 1, SGM_1(J*) = sqrt(101 * 51) - 1.
    assert a["gap_sgm"] == pytest.approx((math.sqrt(121 * 56) - 1) / (math.sqrt(101 * 51) - 1)
                                         - 1, rel=1e-12)
    assert a["gap_n"] == 2 and a["gap_lb_n"] == 0 and np.isnan(a["gap_lb_sum"])
    # 3/6, B: J* only for i3 (85 against 80); i4 has only the bound 60 (J = 75).
    b = table.loc[("3/6", "B")]
    assert (b["gap_mean"], b["gap_sum"]) == (pytest.approx(5 / 80), pytest.approx(5 / 80))
    assert b["gap_sgm"] == pytest.approx(5 / 80, rel=1e-12)  # of one instance: its gap
    assert b["gap_lb_sum"] == pytest.approx(15 / 60, rel=1e-12) and b["gap_lb_n"] == 1


def test_the_mean_gap_is_dominated_by_a_small_reference_the_others_are_not():
    costs, j_star = pd.Series([2.0, 100.0]), pd.Series([1.0, 100.0])
    gaps = gap_measures(costs, j_star)
    assert gaps["mean"] == 0.5 and gaps["n"] == 2
    assert gaps["sum"] == pytest.approx(1 / 101, rel=1e-12)
    assert gaps["sgm"] == pytest.approx((math.sqrt(3 * 101) - 1) / (math.sqrt(2 * 101) - 1) - 1,
                                        rel=1e-12)
    assert gap_measures(costs, j_star, shift=0.0)["sgm"] == pytest.approx(math.sqrt(2) - 1)
    # No reference, a zero reference and a missing cost are left out.
    assert gap_measures(pd.Series([5.0, np.nan, 3.0]), pd.Series([np.nan, 2.0, 0.0]))["n"] == 0
    assert shifted_geometric_mean([1.0, 3.0]) == pytest.approx(math.sqrt(8) - 1, rel=1e-12)
    assert math.isnan(shifted_geometric_mean([]))


def parse_longtable(tex: str) -> tuple[list[list[str]], list[list[str]]]:
    """Header and body rows of a booktabs longtable, checking its shape on the way; a body
    row is prefixed with the scale of its group."""
    spec = re.search(r"\\begin\{longtable\}\{([lrc]+)\}", tex).group(1)
    lines = tex.splitlines()
    for rule in (r"\toprule", r"\midrule", r"\bottomrule", r"\endfirsthead", r"\endhead",
                 r"\endfoot", r"\endlastfoot", r"\end{longtable}"):
        assert rule in lines, rule
    head = lines[lines.index(r"\toprule") + 1: lines.index(r"\endfirsthead")]
    header = [line[: -len(r" \\")].split(" & ") for line in head if line.endswith(r" \\")]
    assert len(header[1]) == len(spec)
    body = lines[lines.index(r"\endlastfoot") + 1: lines.index(r"\end{longtable}")]
    rows, scale = [], None
    for line in body:
        if line == r"\midrule":
            continue
        assert line.endswith(r" \\")
        group = re.fullmatch(rf"\\multicolumn\{{{len(spec)}\}}\{{l\}}\{{\$N/M\$ = (.*)\}} \\\\",
                             line)
        if group:
            scale = group.group(1)
            continue
        cells = line[: -len(r" \\")].split(" & ")
        assert len(cells) == len(spec)
        rows.append([scale, *cells])
    return header, rows


def test_latex_table_numbers_equal_a_pandas_computation_from_the_store(run_dir, tmp_path):
    write_report(run_dir, tmp_path / "report")
    tex = (tmp_path / "report" / "tables" / "summary-static.tex").read_text()
    header, rows = parse_longtable(tex)
    assert header[1][:5] == ["", "", "Mean", "Std", "Median"]
    assert header[1][5:8] == ["Mean", "Sum", "SGM"]
    assert GAP_NOTE_LATEX in tex

    # The same numbers, straight from the store with pandas.
    with ResultStore(run_dir) as store:
        frame = store.frame()
    ok = frame[frame["status"] == "ok"]
    per_seed_mean = ok.groupby(["scale", "instance", "method"])["J"].mean().reset_index()
    j_star = {"i1": 100.0, "i2": 50.0, "i3": 80.0}  # manifest, and i3's proven exact run
    per_seed_mean["J_star"] = per_seed_mean["instance"].map(j_star)
    per_seed_mean["gap"] = (per_seed_mean["J"] - per_seed_mean["J_star"]) / per_seed_mean["J_star"]
    with_j_star = per_seed_mean[per_seed_mean["J_star"].notna()]
    sums = with_j_star.groupby(["scale", "method"])[["J", "J_star"]].sum()
    shifted = np.log(with_j_star[["J", "J_star"]] + 1).groupby(
        [with_j_star["scale"], with_j_star["method"]]).mean().pipe(np.exp) - 1
    expected = per_seed_mean.groupby(["scale", "method"]).agg(
        n=("J", "size"), mean=("J", "mean"), std=("J", "std"), median=("J", "median"),
        gap=("gap", "mean"), with_j_star=("gap", "count"))
    expected["sum"] = sums["J"] / sums["J_star"] - 1
    expected["sgm"] = shifted["J"] / shifted["J_star"] - 1
    failed = frame.groupby(["scale", "method"])["status"].apply(lambda s: (s != "ok").sum())

    def number(cell):
        return float(cell.removeprefix(r"\textbf{").removesuffix("}"))

    assert [(r[0], r[1]) for r in rows] == [("2/4", "A"), ("2/4", "B"), ("3/6", "A"),
                                            ("3/6", "B"), ("3/6", "exact")]
    for scale, method, n, *cells, n_j_star, n_failed in rows:
        e = expected.loc[(scale, method)]
        assert int(n) == e["n"]
        for cell, value in zip(cells, [e["mean"], e["std"], e["median"]], strict=False):
            assert number(cell) == pytest.approx(value, abs=0.005)
        for cell, value in zip(cells[3:], [e["gap"], e["sum"], e["sgm"]], strict=True):
            assert number(cell) == pytest.approx(100 * value, abs=0.0501)  # % to 0.1
        assert int(n_j_star) == e["with_j_star"]
        assert int(n_failed) == failed[(scale, method)]
    bold = {(r[0], r[1], i) for r in rows for i, c in enumerate(r) if c.startswith(r"\textbf")}
    # 2/4: B has the lower mean and median J and gap of sums (20 / 150 against 25 / 150), A
    # the lower mean gap and SGM gap; 3/6: exact is best everywhere.
    assert bold == {("2/4", "B", 3), ("2/4", "B", 5), ("2/4", "A", 6), ("2/4", "B", 7),
                    ("2/4", "A", 8), ("3/6", "exact", 3), ("3/6", "exact", 5),
                    ("3/6", "exact", 6), ("3/6", "exact", 7), ("3/6", "exact", 8)}
    markdown = (tmp_path / "report" / "tables" / "summary-static.md").read_text()
    assert "| 2/4     | B        |" in markdown and GAP_NOTE_MARKDOWN in markdown


def test_the_pivot_by_hand(run_dir):
    with ResultStore(run_dir) as store:
        record(store, "i4", "3/6", "C", 0, 66.0)  # one instance, J* unknown, bound 60
        table = method_table(store.frame())
    tex = latex_pivot(table, "static")
    body = tex[tex.index(r"\toprule"): tex.index(r"\bottomrule")].splitlines()
    assert r"\begin{tabular}{lrr}" in tex and PIVOT_NOTE_LATEX in tex
    assert body == [
        r"\toprule",
        r"Method \hfill $N/M$ & 2/4 & 3/6 \\",
        r"\midrule",
        # 2/4: J* of both instances known: (175 - 150) / 150 and (170 - 150) / 150.
        r"A & 87.50 & 83.00 \\[-2pt]",
        r" & (16.7) & (18.8)\rlap{$^b$} \\",  # 3/6: (95 - 80) / 80 on i3, the one with J*
        r"B & \textbf{85.00} & 80.00 \\[-2pt]",
        r" & (13.3) & (6.2)\rlap{$^b$} \\",
        # C: i4 only (fewer instances: never bold), no J*: at least the gap to the best J
        # known, exact's (66 - 65) / 65, at most the gap to its bound, (66 - 60) / 60.
        r"C & -- & 66.00\rlap{$^a$} \\[-2pt]",
        r" &  & [1.5, 10.0] \\",
        r"exact & -- & \textbf{72.50} \\[-2pt]",
        r" &  & (0.0)\rlap{$^b$} \\",
    ]
    markdown = markdown_pivot(table, "static")
    cells = [[cell.strip() for cell in line.split("|")[1:-1]]
             for line in markdown.splitlines()[:6]]
    assert cells == [["method", "2/4", "3/6"], [":---------", "-----------------:",
                                                "----------------------:"],
                     ["A", "87.50 (16.7)", "83.00 (18.8, part)"],
                     ["B", "**85.00** (13.3)", "80.00 (6.2, part)"],
                     ["C", "--", "66.00 n=1 [1.5, 10.0]"],
                     ["exact", "--", "**72.50** (0.0, part)"]]
    assert PIVOT_NOTE_MARKDOWN in markdown


def test_holm_by_hand():
    assert holm([0.01, 0.04, 0.03]) == pytest.approx([0.03, 0.06, 0.06], rel=1e-12)
    assert holm([0.5, 0.5]) == [1.0, 1.0]
    assert holm([]) == []


def test_win_rates_and_wilcoxon_against_the_best_method(run_dir):
    with ResultStore(run_dir) as store:
        result, best, n = comparisons(store.frame(), "static")
    # Every method has a result on i3 and i4 only; exact is best on both.
    assert (best, n) == ("exact", 2)
    result = result.set_index("method")
    assert result["win_rate"].to_dict() == {"exact": 1.0, "B": 0.0, "A": 0.0}
    assert result.at["A", "J_mean"] == 83.0 and result.at["B", "diff_mean"] == 7.5
    # Two positive differences: the exact two-sided signed-rank p-value is 2 * 1/4.
    assert result.at["A", "p"] == pytest.approx(0.5) and result.at["B", "p"] == pytest.approx(0.5)
    assert result.at["A", "p_holm"] == 1.0 and result.at["B", "p_holm"] == 1.0
    assert np.isnan(result.at["exact", "p"])


def test_per_instance_averages_seeds_before_instances(run_dir):
    with ResultStore(run_dir) as store:
        table = per_instance(store.frame()).set_index(["instance", "method"])
    assert table.at[("i1", "A"), "J"] == 120.0 and table.at[("i1", "A"), "seeds"] == 2
    assert table.at[("i3", "B"), "J"] == 85.0 and table.at[("i3", "B"), "seeds"] == 1
    assert table.at[("i1", "A"), "gap"] == pytest.approx(0.2, rel=1e-12)


def test_a_cost_below_the_exact_reference_is_flagged(run_dir, tmp_path):
    with ResultStore(run_dir) as store:
        assert below_reference(store.frame()).empty
        record(store, "i1", "2/4", "C", 0, 99.0)  # below i1's J* = 100 (manifest)
        record(store, "i4", "3/6", "C", 0, 59.0)  # below i4's bound 60 (an exact run's stats)
        record(store, "i2", "2/4", "C", 0, 50.0 * (1 - 1e-7))  # within solver tolerance
        flagged = below_reference(store.frame())
    assert sorted(flagged["key"]) == ["i1|C|static|0", "i4|C|static|0"]
    index = write_report(run_dir, tmp_path / "report").read_text()
    assert "- `i1|C|static|0`: J = 99.000000, J* = 100.0, LB = nan" in index


def test_the_command_is_shown_as_typed_without_paths_of_the_machine():
    home = Path("/home/u/proj")
    recorded = shlex.join(["/home/u/venv/bin/tsac-bench", "run", "/home/u/proj/instances/quick",
                           "--out=/home/u/proj/results/x", "--methods", "hocf:init=incumbent",
                           "--scheduler", "/data/elsewhere/sched.json"])
    assert shown_command(recorded, home) == ("tsac-bench run instances/quick --out=results/x "
                                             "--methods hocf:init=incumbent --scheduler "
                                             ".../sched.json")
    module = shlex.join(["/home/u/proj/tsac_bench/__main__.py", "report", "results/x"])
    assert shown_command(module, home) == "tsac-bench report results/x"
    script = "benchmarks/paper_reproduction.py run --per-scale 100 --jobs 2"
    assert shown_command(script, home) == script


def test_the_report_carries_no_absolute_path(run_dir, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    with ResultStore(run_dir) as store:
        store.set_meta({"command": shlex.join([str(tmp_path / "venv" / "bin" / "tsac-bench"),
                                               "run", str(tmp_path / "instances"), "--out",
                                               str(run_dir)])})
        store.record({**store.frame().iloc[0].to_dict(), "key": "i1|D|static|0",
                      "method": "D", "status": "error", "J": None,
                      "message": f"InputError: {tmp_path / 'instances' / 'i1.json'}: bad"})
    index = write_report(run_dir, tmp_path / "reports" / "run").read_text()
    assert str(tmp_path) not in index
    assert "- results store: `../../run/results.sqlite` (relative to this report)" in index
    assert "- command: `tsac-bench run instances --out run`" in index
    assert "- `i1|D|static|0`: error: InputError: instances/i1.json: bad" in index


def test_normal_half_width_is_1_96_standard_errors_and_nan_below_two_values() -> None:
    from tsac_bench.reporting.stats import normal_half_width

    # Sample standard deviation of (1, 2, 3) is 1: 1.96 / sqrt(3).
    assert normal_half_width([1.0, 2.0, 3.0]) == pytest.approx(1.131607, abs=1e-6)
    assert math.isnan(normal_half_width([4.0]))
