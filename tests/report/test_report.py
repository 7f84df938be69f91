"""Tables and statistics of a hand-made results store: every number is worked out by hand
or recomputed with pandas straight from the store."""

import re
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from tsac_bench.batch.store import ResultStore, job_key
from tsac_bench.reporting.report import (
    below_reference,
    comparisons,
    holm,
    latex_table,
    method_table,
    per_instance,
    references,
    write_report,
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


def parse_latex_rows(tex: str) -> tuple[list[str], list[list[str]]]:
    """Header and body rows of a booktabs tabular, checking its shape on the way."""
    spec = re.search(r"\\begin\{tabular\}\{([lrc]+)\}", tex).group(1)
    lines = tex.splitlines()
    assert lines.index(r"\toprule") < lines.index(r"\midrule") < lines.index(r"\bottomrule")
    body = lines[lines.index(r"\toprule") + 1: lines.index(r"\bottomrule")]
    rows = []
    for line in body:
        if line == r"\midrule":
            continue
        assert line.endswith(r" \\")
        cells = line[: -len(r" \\")].split(" & ")
        assert len(cells) == len(spec)
        rows.append(cells)
    return rows[0], rows[1:]


def test_latex_table_numbers_equal_a_pandas_computation_from_the_store(run_dir, tmp_path):
    write_report(run_dir, tmp_path / "report")
    tex = (tmp_path / "report" / "tables" / "summary-static.tex").read_text()
    assert r"\begin{table}" in tex and r"\end{tabular}" in tex
    header, rows = parse_latex_rows(tex)
    assert header[:4] == ["Scale", "Method", "$n$", r"Mean $J$"]

    # The same numbers, straight from the store with pandas.
    with ResultStore(run_dir) as store:
        frame = store.frame()
    ok = frame[frame["status"] == "ok"]
    per_seed_mean = ok.groupby(["scale", "instance", "method"])["J"].mean().reset_index()
    j_star = {"i1": 100.0, "i2": 50.0, "i3": 80.0}  # manifest, and i3's proven exact run
    per_seed_mean["gap"] = [(j - j_star[i]) / j_star[i] if i in j_star else np.nan
                            for i, j in zip(per_seed_mean["instance"], per_seed_mean["J"],
                                            strict=True)]
    expected = per_seed_mean.groupby(["scale", "method"]).agg(
        n=("J", "size"), mean=("J", "mean"), std=("J", "std"), median=("J", "median"),
        gap=("gap", "mean"), with_j_star=("gap", "count"))
    failed = frame.groupby(["scale", "method"])["status"].apply(lambda s: (s != "ok").sum())

    def plain(cell):
        return cell.removeprefix(r"\textbf{").removesuffix("}")

    assert [(r[0], r[1]) for r in rows] == [("2/4", "A"), ("2/4", "B"), ("3/6", "A"),
                                            ("3/6", "B"), ("3/6", "exact")]
    for cells in rows:
        e = expected.loc[(cells[0], cells[1])]
        assert int(cells[2]) == e["n"]
        assert float(plain(cells[3])) == pytest.approx(e["mean"], abs=0.005)
        assert float(plain(cells[4])) == pytest.approx(e["std"], abs=0.005)
        assert float(plain(cells[5])) == pytest.approx(e["median"], abs=0.005)
        assert float(plain(cells[6])) == pytest.approx(100 * e["gap"], abs=0.005)
        assert int(cells[7]) == e["with_j_star"]
        assert int(cells[8]) == failed[(cells[0], cells[1])]
    bold = {(r[0], r[1], i) for r in rows for i, c in enumerate(r) if c.startswith(r"\textbf")}
    # 2/4: B has the lower mean and median J, A the lower gap; 3/6: exact is best everywhere.
    assert bold == {("2/4", "B", 3), ("2/4", "B", 5), ("2/4", "A", 6),
                    ("3/6", "exact", 3), ("3/6", "exact", 5), ("3/6", "exact", 6)}
    assert "| 2/4     | B        |" in (tmp_path / "report" / "tables" /
                                        "summary-static.md").read_text()


def test_latex_escapes_method_names():
    table = pd.DataFrame([{"mode": "static", "scale": "2/4", "method": "my_method&co",
                           "instances": 1, "failed": 0, "J_mean": 1.0, "J_std": np.nan,
                           "J_median": 1.0, "gap_mean": np.nan, "gap_n": 0}])
    assert r"my\_method\&co" in latex_table(table, "static")


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
