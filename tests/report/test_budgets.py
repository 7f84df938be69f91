"""Cost against budget on a hand-made results store: every number worked out by hand."""

import math
import shutil
from pathlib import Path

import pandas as pd
import pytest
from test_tables import pdflatex, tabular_rows

from tsac_bench.batch.store import ResultStore, job_key
from tsac_bench.reporting.budget_tables import budget_latex, budget_markdown, primal_latex
from tsac_bench.reporting.budgets import (
    budget_curves,
    budget_table,
    incumbent_curve,
    paired_tests,
    primal_gap,
    primal_integral,
    primal_table,
    time_to_target,
)
from tsac_bench.reporting.data import load, load_meta, method_label, per_instance
from tsac_bench.reporting.report import write_report
from tsac_bench.reporting.tables import method_table, summary

#: (method, budget) -> J on instances i1, i2, i3 (scale 2/4, static, seed 0). greedy is a
#: one-pass method: the same plans at both budgets.
J = {("hocf", 0.5): (15.0, 24.0, 31.5), ("hocf", 2.0): (10.0, 18.0, 27.0),
     ("greedy", 0.5): (11.0, 22.0, 33.0), ("greedy", 2.0): (11.0, 22.0, 33.0),
     ("hocf", None): (16.0, 23.0, 29.0)}
#: hocf's incumbent traces at the largest budget, 2 s; each ends at the job's J.
TRACES = {"i1": [[0.5, 12.0], [1.5, 10.0]], "i2": [[0.2, 18.5], [1.0, 18.0]],
          "i3": [[1.0, 27.0]]}
INSTANCES = ("i1", "i2", "i3")
#: A reference unit of 0.25 s: 0.5 s is 2 units, 2 s is 8.
CALIBRATION = {"host": "bench_host", "seconds": 0.25, "workload": "one hocf plan call",
               "repeats": [0.25], "measured_at": "2025-01-01T00:00:00+00:00"}


def record(store, instance, method, budget, J, mode="static", **extra):
    row = {"key": job_key(instance, method, mode, 0, budget), "instance": instance,
           "instance_set": "hand-made", "scale": "2/4", "method": method, "mode": mode,
           "seed": 0, "budget": budget, "time_limit": budget, "status": "ok", "J": J,
           "J_load": J, "J_time": 0.0, "J_op": 0.0,
           "J_star": 25.0 if instance == "i3" else None, "stats": {}, "runtime": 1.0,
           "over_budget": None if budget is None else 0, "versions": {}, "host": "test",
           **extra}
    store.record(row)


@pytest.fixture
def run_dir(tmp_path) -> Path:
    with ResultStore(tmp_path / "run") as store:
        store.set_meta({"calibration": CALIBRATION})
        for (method, budget), costs in J.items():
            for n, (instance, cost) in enumerate(zip(INSTANCES, costs, strict=True)):
                extra = {}
                if method == "greedy":
                    extra["runtime"] = 0.01 * (n + 1)
                elif budget == 2.0:
                    extra["stats"] = {"trace": TRACES[instance], "work": 5}
                elif budget == 0.5 and instance == "i1":
                    extra["over_budget"] = 1
                record(store, instance, method, budget, cost, **extra)
        # A dynamic job of three plan calls, two of them over the budget.
        replans = [{"wall_time": 0.5, "J": 40.0, "stats": {}} for _ in range(3)]
        record(store, "i1", "hocf", 0.5, 14.0, mode="dynamic", over_budget=2,
               stats={"replans": replans}, runtime=1.5)
    return tmp_path / "run"


# --- primal integral and time to target --------------------------------------------------
def test_the_primal_integral_of_a_trace_by_hand():
    trace = [[0.5, 12.0], [2.0, 10.0]]
    # p = 1 on [0, 0.5), |12 - 10| / 12 = 1/6 on [0.5, 2), 0 after: 0.5 + 1.5 / 6.
    assert primal_integral(trace, 10.0, 4.0) == pytest.approx(0.75, rel=1e-12)
    # A horizon before the second point: 0.5 + 0.5 / 6.
    assert primal_integral(trace, 10.0, 1.0) == pytest.approx(0.5 + 0.5 / 6, rel=1e-12)
    assert primal_integral([], 10.0, 4.0) == 4.0  # never a plan: p = 1 throughout
    assert time_to_target(trace, 10.0, 0.01, 4.0) == 2.0
    assert time_to_target(trace, 10.0, 0.2, 4.0) == 0.5  # 1/6 is within 20 %
    assert time_to_target(trace, 10.0, 0.01, 1.5) == math.inf  # not within the horizon
    assert time_to_target([[0.3, 9.95]], 10.0, 0.01, 4.0) == 0.3  # below the best known


def test_the_primal_gap_by_hand():
    assert primal_gap(12.0, 10.0) == pytest.approx(1 / 6, rel=1e-12)
    assert primal_gap(10.0, 12.0) == pytest.approx(1 / 6, rel=1e-12)
    assert primal_gap(-1.0, 1.0) == 2.0
    assert primal_gap(0.0, 0.0) == 0.0


def test_a_method_without_a_trace_is_one_point_at_its_runtime():
    curve = incumbent_curve({}, 0.02, 22.0)
    assert curve == [(0.02, 22.0)]
    # p = 1 until it returns at 0.02 s, then 4 / 22 until T = 2.
    assert primal_integral(curve, 18.0, 2.0) == pytest.approx(0.02 + 1.98 * 4 / 22, rel=1e-12)
    assert incumbent_curve({"trace": [[0.1, 5.0]]}, 1.0, 5.0) == [(0.1, 5.0)]


def test_the_primal_table_by_hand(run_dir):
    primal = primal_table(load(run_dir)).set_index("method")
    assert list(primal.index) == ["greedy", "hocf"]  # by mean integral
    assert (primal["scale"] == "2/4").all() and (primal["horizon"] == 2.0).all()
    # Best known: i1 10 (hocf at 2 s), i2 18 (hocf at 2 s), i3 J* = 25.
    i1 = 0.5 + 1.0 * 2 / 12
    i2 = 0.2 + 0.8 * 0.5 / 18.5
    i3 = 1.0 + 1.0 * 2 / 27
    hocf = primal.loc["hocf"]
    assert hocf["jobs"] == 3
    assert hocf["integral"] == pytest.approx((i1 + i2 + i3) / 3, rel=1e-12)
    assert hocf["integral_share"] == pytest.approx((i1 + i2 + i3) / 6, rel=1e-12)
    # Times to 1 %: 1.5, 1.0, never; to 5 %: 1.5, 0.2 (2.7 %), never.
    assert (hocf["time_1"], hocf["reached_1"]) == (1.5, 2)
    assert (hocf["time_5"], hocf["reached_5"]) == (1.5, 2)
    greedy = primal.loc["greedy"]
    assert greedy["use"] == "one-pass"
    assert greedy["integral"] == pytest.approx(
        (0.01 + 1.99 / 11 + 0.02 + 1.98 * 4 / 22 + 0.03 + 1.97 * 8 / 33) / 3, rel=1e-12)
    assert math.isnan(greedy["time_1"]) and greedy["reached_5"] == 0


# --- the table of cost against budget ----------------------------------------------------
def test_the_budget_table_by_hand(run_dir):
    table = budget_table(load(run_dir))
    static = table[table["mode"] == "static"]
    assert list(zip(static["budget"], static["method"], static["rank"], strict=True)) == [
        (0.5, "greedy", 1), (0.5, "hocf", 2), (2.0, "hocf", 1), (2.0, "greedy", 2)]
    rows = static.set_index(["budget", "method"])
    assert rows.at[(0.5, "hocf"), "J_mean"] == pytest.approx(70.5 / 3, rel=1e-12)
    assert rows.at[(0.5, "hocf"), "J_median"] == 24.0
    assert rows.at[(2.0, "hocf"), "J_mean"] == pytest.approx(55 / 3, rel=1e-12)
    assert rows.at[(2.0, "greedy"), "J_mean"] == 22.0
    assert rows.at[(0.5, "hocf"), "series"] == "hocf @ 0.5 s"
    assert rows["over_budget"].to_dict() == {(0.5, "greedy"): 0, (0.5, "hocf"): 1,
                                             (2.0, "hocf"): 0, (2.0, "greedy"): 0}
    assert (rows["plan_calls"] == 3).all() and (rows["instances"] == 3).all()
    assert rows.at[(2.0, "greedy"), "use"] == "one-pass"
    assert rows.at[(2.0, "greedy"), "seconds_per_call"] == pytest.approx(0.02, rel=1e-12)
    assert rows.at[(2.0, "hocf"), "use"] == "anytime"
    dynamic = table[table["mode"] == "dynamic"].iloc[0]
    assert (dynamic["plan_calls"], dynamic["over_budget"]) == (3, 2)
    assert dynamic["seconds_per_call"] == pytest.approx(0.5, rel=1e-12)


def test_the_best_two_at_each_budget_are_paired_by_instance(run_dir):
    frame = load(run_dir)
    tests = paired_tests(frame, budget_table(frame)).set_index(["mode", "budget"])
    assert list(tests.index) == [("static", 0.5), ("static", 2.0)]  # dynamic: one method
    low = tests.loc[("static", 0.5)]
    # hocf - greedy: 4, 2, -1.5; signed ranks 3, 2, -1: W+ = 5 of the 8 equally likely
    # sign patterns' sums 0, 1, 2, 3, 3, 4, 5, 6: two-sided p = 2 * 2/8.
    assert (low["best"], low["second"], low["instances"]) == ("greedy", "hocf", 3)
    assert low["diff_mean"] == pytest.approx(1.5, rel=1e-12)
    assert low["diff_half_width"] == pytest.approx(1.96 * math.sqrt(15.5 / 2) / math.sqrt(3),
                                                   rel=1e-12)
    assert low["p"] == pytest.approx(0.5)
    high = tests.loc[("static", 2.0)]
    # greedy - hocf: 1, 4, 6, all positive: p = 2 * 1/8.
    assert (high["best"], high["second"]) == ("hocf", "greedy")
    assert high["diff_mean"] == pytest.approx(11 / 3, rel=1e-12)
    assert high["diff_half_width"] == pytest.approx(1.96 * math.sqrt(19 / 3) / math.sqrt(3),
                                                    rel=1e-12)
    assert high["p"] == pytest.approx(0.25)


def test_the_budget_tables_in_markdown_and_latex(run_dir):
    frame = load(run_dir)
    calibration = load_meta(run_dir)["calibration"]
    table = budget_table(frame)
    tests = paired_tests(frame, table)
    markdown = budget_markdown(table, tests, "static", calibration)
    cells = [[c.strip() for c in line.split("|")[1:-1]] for line in markdown.splitlines()[:6]]
    assert cells[0] == ["scale", "budget", "method", "use", "n", "mean J", "median J", "rank",
                        "over budget"]
    assert cells[2:] == [
        ["2/4", "0.5 s (2 ref. units)", "greedy", "one pass, 0.0200 s", "3", "**22.00**",
         "**22.00**", "1", "0/3"],
        ["2/4", "0.5 s (2 ref. units)", "hocf", "anytime", "3", "23.50", "24.00", "2", "1/3"],
        ["2/4", "2 s (8 ref. units)", "hocf", "anytime", "3", "**18.33**", "**18.00**", "1",
         "0/3"],
        ["2/4", "2 s (8 ref. units)", "greedy", "one pass, 0.0200 s", "3", "22.00", "22.00",
         "2", "0/3"]]
    pairs = [[c.strip() for c in line.split("|")[1:-1]]
             for line in markdown.split("\n\n")[2].splitlines()]
    assert pairs[0] == ["scale", "budget", "best", "second", "n", "mean ΔJ (95 % CI)",
                        "Wilcoxon p"]
    # 1.96 sqrt(15.5 / 2) / sqrt(3) = 3.15; 1.96 sqrt(38 / 6) / sqrt(3) = 2.85.
    assert pairs[2:] == [["2/4", "0.5 s (2 ref. units)", "greedy", "hocf", "3", "1.50 ± 3.15",
                          "0.5000"],
                         ["2/4", "2 s (8 ref. units)", "hocf", "greedy", "3", "3.67 ± 2.85",
                          "0.2500"]]

    tex = budget_latex(table, tests, "static", calibration)
    spec, rows = tabular_rows(tex, "longtable")  # every row spans the seven columns
    assert spec == "lrrrrrl"
    assert [row[0] for row in rows if row[0] in ("greedy", "hocf")] == ["greedy", "hocf",
                                                                         "hocf", "greedy"]
    lines = tex.splitlines()
    for command in (r"\toprule", r"\midrule", r"\bottomrule", r"\endfirsthead",
                    r"\endlastfoot", r"\cmidrule(lr){3-4}"):
        assert command in lines, command
    assert lines.index(r"\begin{longtable}{lrrrrrl}") < lines.index(r"\bottomrule") < \
        lines.index(r"\end{longtable}")
    assert r"greedy & 3 & \textbf{22.00} & \textbf{22.00} & 1 & 0/3 & one pass, 0.0200 s \\" \
        in lines
    assert r"\multicolumn{7}{l}{$N/M$ = 2/4, budget 2 s (8 ref. units)} \\" in lines
    assert (r"\multicolumn{7}{p{0.9\linewidth}}{Best two: hocf, greedy; $\Delta J$ = 3.67 "
            r"$\pm$ 2.85, $p$ = 0.2500, $n$ = 3} \\") in lines
    assert "bench\\_host" in tex and "One pass (builds one plan and stops" in tex


@pytest.mark.skipif(shutil.which("pdflatex") is None, reason="pdflatex is not installed")
def test_the_budget_and_primal_tables_compile_in_a_one_column_article(run_dir, tmp_path):
    frame = load(run_dir)
    calibration = load_meta(run_dir)["calibration"]
    table = budget_table(frame)
    # The longest labels a report prints beside the hand-made ones.
    wide = table.assign(method=table["method"].str.replace("hocf", "exact-cpsat:threads=2"))
    tests = paired_tests(frame, table).assign(best="hocf:init=incumbent",
                                              second="exact-cpsat:threads=2")
    log, _ = pdflatex(tmp_path, budget_latex(wide, tests, "static", calibration), "budget")
    assert "Overfull \\hbox" not in log
    primal = primal_table(frame).assign(method="exact-cpsat:threads=2")
    log, _ = pdflatex(tmp_path, primal_latex(primal, calibration), "primal")
    assert "Overfull \\hbox" not in log


def test_j_against_budget_has_quartiles_per_method_and_budget(run_dir):
    curves = budget_curves(load(run_dir))
    static = curves[curves["mode"] == "static"].set_index(["method", "budget"])
    assert static.loc[("hocf", 0.5), ["q1", "median", "q3"]].tolist() == [
        pytest.approx(19.5), 24.0, pytest.approx(27.75)]
    assert static.loc[("greedy", 2.0), "median"] == 22.0
    assert len(static) == 4  # hocf without a budget is no point of the curves


# --- a method at a budget is its own series everywhere -----------------------------------
def test_every_table_keeps_budgets_apart(run_dir):
    frame = load(run_dir)
    table = method_table(frame)
    static = table[table["mode"] == "static"].set_index("method")
    assert sorted(static.index) == ["greedy @ 0.5 s", "greedy @ 2 s", "hocf", "hocf @ 0.5 s",
                                    "hocf @ 2 s"]
    assert static.at["hocf", "J_mean"] == pytest.approx(68 / 3, rel=1e-12)
    assert static.at["hocf @ 2 s", "J_mean"] == pytest.approx(55 / 3, rel=1e-12)
    assert static["jobs"].tolist() == [3] * 5
    assert set(summary(frame)["method"]) == {*static.index}
    assert method_label("hocf", float("nan")) == "hocf"


def test_a_store_without_budgets_gives_the_tables_of_old_stores(tmp_path):
    with ResultStore(tmp_path / "run") as store:
        for instance, cost in zip(INSTANCES, J[("hocf", None)], strict=True):
            record(store, instance, "hocf", None, cost)
            record(store, instance, "greedy", None, cost + 1, stats={"trace": [[0.1, 9.0]]})
    frame = load(tmp_path / "run")
    old = frame.drop(columns=["budget", "over_budget"])  # a store from before budgets
    pd.testing.assert_frame_equal(method_table(frame), method_table(old))
    pd.testing.assert_frame_equal(per_instance(frame), per_instance(old))
    assert budget_table(frame).empty and primal_table(frame).empty
    index = write_report(tmp_path / "run", tmp_path / "report").read_text()
    assert "Cost against budget" not in index and "budgets per plan call" not in index
    assert not list((tmp_path / "report").rglob("budget-*"))


def test_the_report_has_a_cost_against_budget_section(run_dir, tmp_path):
    pytest.importorskip("matplotlib")
    out = tmp_path / "report"
    index = write_report(run_dir, out).read_text()
    static = index[index.index("## Static mode"): index.index("## Dynamic mode")]
    assert "### Cost against budget" in static
    assert ("Budgets per plan call: 0.5 s (2 ref. units), 2 s (8 ref. units); a reference "
            "unit is 0.25 s") in static
    assert "committed prefixes" in static and "see docs/methods.md" in static
    assert "One pass (builds one plan and stops; the budget only caps it): greedy." in static
    assert "#### Primal integral and time to target (static mode)" in static
    # hocf also ran without a budget in static mode; every dynamic job had one.
    assert "A method named without `@` in the tables above ran by its own stopping" in static
    dynamic = index[index.index("## Dynamic mode"):]
    assert "### Cost against budget" in dynamic and "Primal integral" not in dynamic
    assert "own stopping rule" not in dynamic
    assert "none in static mode" in static and "none in static mode" not in dynamic
    assert ("except that DGA seeds half its population from the plan in force and a label "
            "with init=incumbent starts from it") in dynamic
    assert "- budgets per plan call: 0.5 s (2 ref. units), 2 s (8 ref. units)" in index
    for name in ("budget-static.md", "budget-static.tex", "budget-static.csv",
                 "budget-tests-static.csv", "budget-dynamic.tex", "primal-static.md",
                 "primal-static.tex", "primal-static.csv"):
        assert (out / "tables" / name).is_file(), name
    for mode in ("static", "dynamic"):
        assert (out / "figures" / f"budget-J-{mode}.png").stat().st_size > 0
        assert (out / "figures" / f"budget-J-{mode}.pdf").is_file()
        assert f"![Total cost J against the budget per plan call ({mode})]" \
               f"(figures/budget-J-{mode}.png)" in index
    assert pd.read_csv(out / "tables" / "budget-static.csv")["over_budget"].sum() == 1
    primal = (out / "tables" / "primal-static.md").read_text()
    cells = [[c.strip() for c in line.split("|")[1:-1]] for line in primal.splitlines()[:4]]
    assert cells[2:] == [["2/4", "2 s (8 ref. units)", "greedy", "3", "0.359", "0.180", "-- (0)",
                          "-- (0)"],
                         ["2/4", "2 s (8 ref. units)", "hocf", "3", "0.654", "0.327", "1.50 (2)",
                          "1.50 (2)"]]
