"""Budgets per plan call (tsac_bench/planning/budget.py): the over-budget rule, budgeted
settings, a budget through solve, the runner, the store, the CLI and the calibration."""

import sqlite3
import time
from pathlib import Path

import pytest
from typer.testing import CliRunner

from tsac_bench.batch.runner import RunConfig, run_batch
from tsac_bench.batch.store import ResultStore, job_key
from tsac_bench.cli import app
from tsac_bench.errors import InvalidSetting, TsacBenchError
from tsac_bench.model.generator import generate
from tsac_bench.model.io import read_instance, read_solution
from tsac_bench.planning import PlanResult, allocator_class
from tsac_bench.planning.budget import (
    IncumbentTrace,
    WorkStop,
    budgeted_settings,
    is_over_budget,
    over_budget_limit,
)
from tsac_bench.planning.solve import solve

QUICK = Path(__file__).parent.parent / "instances" / "quick"


def test_over_budget_is_ten_per_cent_and_fifty_milliseconds_late():
    assert over_budget_limit(1.0) == pytest.approx(1.15)
    assert over_budget_limit(0.1) == pytest.approx(0.16)
    assert not is_over_budget(0.159, 0.1) and is_over_budget(0.161, 0.1)
    assert not is_over_budget(100.0, None)


def test_budgeted_settings_lift_the_work_caps_of_anytime_methods_only():
    assert budgeted_settings("hocf", allocator_class("hocf"), {"init": "incumbent"}) == {
        "init": "incumbent", "samples": None}
    assert budgeted_settings("dga", allocator_class("dga"), {}) == {"generations": None}
    assert budgeted_settings("greedy", allocator_class("greedy"), {}) == {}
    with pytest.raises(InvalidSetting, match="method 'dga' setting 'generations': not with a "
                                             "budget"):
        budgeted_settings("dga", allocator_class("dga"), {"generations": 5})


def test_work_stop_counts_units_and_reads_the_clock():
    stop = WorkStop(None, 3)
    for _ in range(3):
        assert stop.reached() is None
        stop.done()
    assert stop.reached() == "work"
    assert WorkStop(0.0, None).reached() == "time-limit"
    assert WorkStop(None, None).reached() is None


def test_work_stop_with_look_ahead_starts_no_unit_the_mean_unit_would_overrun(monkeypatch):
    clock = iter([0.0, 0.7, 0.7, 0.7])
    monkeypatch.setattr(time, "perf_counter", lambda: next(clock))
    careful, plain = WorkStop(1.0, None, look_ahead=True), WorkStop(1.0, None, began=0.0)
    careful.done()
    plain.done()
    # 0.7 s for the first unit: the second would end at 1.4 s, past the 1 s deadline.
    assert careful.reached() == "time-limit" and plain.reached() is None


def test_incumbent_trace_keeps_strict_improvements_only():
    trace = IncumbentTrace(began=10.0)
    assert trace.offer(5.0, at=10.5) and not trace.offer(5.0, at=11.0)
    assert trace.offer(4.0, at=12.0) and not trace.offer(4.5, at=12.5)
    assert trace.points == [[0.5, 5.0], [2.0, 4.0]] and trace.best == 4.0


class Sleeper:
    """Sleeps 0.3 s whatever its budget: the runner must flag it."""

    name = "sleeper"

    def plan(self, state, *, seed=0, time_limit=None):
        time.sleep(0.3)
        return PlanResult(state.base_routes())


def test_solve_with_a_budget_counts_the_plan_calls_over_it():
    instance = generate("3/6", seed=3)
    outcome = solve(instance, Sleeper(), budget=0.1, mode="dynamic")
    calls = len(outcome.stats["replans"])
    assert calls >= 2 and outcome.over_budget == calls
    assert outcome.solution.meta["budget"] == 0.1
    assert solve(instance, Sleeper(), budget=1.0).over_budget == 0
    with pytest.raises(TsacBenchError, match="a budget and a time limit"):
        solve(instance, "greedy", budget=1.0, time_limit=1.0)
    with pytest.raises(TsacBenchError, match="--budget: expected seconds > 0"):
        solve(instance, "greedy", budget=0.0)


def test_a_budgeted_run_records_budget_over_budget_and_calibration(tmp_path):
    files = [QUICK / "quick-3-6-s3.json"]
    out = tmp_path / "run"
    outcome = run_batch(RunConfig(files, out, methods=["greedy", "hocf"], mode="both",
                                  budgets=[0.05, 0.2], jobs=1), progress=False,
                        note=lambda line: None)
    assert outcome.total == 2 * 2 * 2 and outcome.failed == 0
    with ResultStore(out, create=False) as store:
        rows = {row["key"]: row for row in store.rows()}
        meta = store.meta()
    key = job_key("quick-3-6-s3", "hocf", "static", 0, 0.2)
    assert key == "quick-3-6-s3|hocf|static|0|budget=0.2"
    row = rows[key]
    assert row["budget"] == 0.2 == row["time_limit"] and row["over_budget"] in (0, 1)
    assert row["stats"]["work"] >= 1 and row["stats"]["trace"][-1][1] == pytest.approx(row["J"])
    solution = read_solution(out / row["solution_file"], read_instance(files[0]))
    assert solution.meta["budget"] == 0.2 and solution.meta["settings"]["samples"] is None
    assert {r["budget"] for r in rows.values()} == {0.05, 0.2}
    assert meta["calibration"]["seconds"] > 0 and len(meta["calibrations"]) == 1
    # The same command again resumes: nothing left to run, a second calibration kept.
    again = run_batch(RunConfig(files, out, methods=["greedy", "hocf"], mode="both",
                                budgets=[0.05, 0.2], jobs=1), progress=False,
                      note=lambda line: None)
    assert again.ran == 0 and again.skipped == 8


def test_a_store_from_before_budgets_gains_the_columns(tmp_path):
    with sqlite3.connect(tmp_path / "results.sqlite") as conn:
        conn.execute('CREATE TABLE jobs ("key" TEXT PRIMARY KEY, "instance" TEXT NOT NULL, '
                     '"method" TEXT NOT NULL, "mode" TEXT NOT NULL, "seed" INTEGER NOT NULL, '
                     '"status" TEXT NOT NULL)')
        conn.execute("INSERT INTO jobs VALUES ('a|greedy|static|0', 'a', 'greedy', 'static', "
                     "0, 'ok')")
    with ResultStore(tmp_path, create=False) as store:
        row = store.rows()[0]
    assert row["key"] == "a|greedy|static|0" and row["budget"] is None
    assert row["over_budget"] is None


runner = CliRunner()


@pytest.mark.parametrize(("args", "message"), [
    (["--budget", "1,x"], "--budget: 'x' is not a number of seconds"),
    (["--budget", "0"], "--budget: expected seconds > 0, got 0.0"),
    (["--budget", "1", "--time-limit", "1"], "--budget: not with --time-limit"),
    (["--budget", "1", "--methods", "hocf:samples=4"], "method 'hocf' setting 'samples': "
                                                       "not with a budget"),
])
def test_bad_budgets_are_one_line_and_exit_2(tmp_path, args, message):
    result = runner.invoke(app, ["run", str(QUICK / "quick-2-4-s1.json"), "--out",
                                 str(tmp_path / "r"), "--no-report", "--no-progress", *args])
    assert result.exit_code == 2, result.output
    assert message in result.output and "Traceback" not in result.output


def test_solve_prints_the_budget_use_and_calibrate_stores_its_reference(tmp_path):
    result = runner.invoke(app, ["solve", str(QUICK / "quick-3-6-s3.json"), "--method", "hocf",
                                 "--budget", "0.1"])
    assert result.exit_code == 0, result.output
    assert "budget 0.1 s per plan call: 0 of 1 plan call(s) over it; work " in result.output
    result = runner.invoke(app, ["calibrate", "--out", str(tmp_path)])
    assert result.exit_code == 0, result.output
    with ResultStore(tmp_path, create=False) as store:
        assert store.meta()["calibration"]["workload"].startswith("one hocf plan call")


def test_a_worker_warms_a_method_up_once_before_its_first_budgeted_job(monkeypatch):
    from tsac_bench.batch import worker
    from tsac_bench.model.io import instance_to_dict

    calls = []
    monkeypatch.setattr(worker, "_warmed", set())
    monkeypatch.setattr("tsac_bench.planning.solve.solve",
                        lambda *args, **kwargs: calls.append(kwargs.get("budget")))
    worker.warm_up("hocf", {})
    worker.warm_up("hocf", {})
    worker.warm_up("hocf", {"init": "incumbent"})
    assert calls == [worker.WARM_UP_BUDGET] * 2
    monkeypatch.undo()
    spec = {"instance": instance_to_dict(generate("3/6", seed=3)), "method": "greedy",
            "mode": "static", "seed": 0, "budget": 0.5, "settings": {}}
    assert worker.execute_job(spec)["status"] == "ok"


def test_a_sets_manifest_budgets_add_budgeted_jobs_of_its_heuristics(tmp_path):
    """instances/quick declares budgets: a run that names none runs its heuristic and
    learned methods at them too (the main job's small sweep), its exact methods not."""
    import json
    import shutil

    from tsac_bench.batch.manifests import read_manifest

    assert read_manifest(QUICK).budgets == [0.1, 0.3]
    folder = tmp_path / "set"
    folder.mkdir()
    shutil.copy(QUICK / "quick-2-4-s1.json", folder)
    manifest = json.loads((QUICK / "manifest.json").read_text())
    manifest["instances"] = {"quick-2-4-s1": manifest["instances"]["quick-2-4-s1"]}
    (folder / "manifest.json").write_text(json.dumps(manifest))
    run_batch(RunConfig([folder], tmp_path / "run", methods=["greedy", "exact", "hocf:samples=2"],
                        mode="static", jobs=1), progress=False, note=lambda line: None)
    with ResultStore(tmp_path / "run", create=False) as store:
        budgets = sorted((row["method"], row["budget"] or 0.0) for row in store.rows())
    assert budgets == [("exact", 0.0), ("greedy", 0.0), ("greedy", 0.1), ("greedy", 0.3),
                       ("hocf:samples=2", 0.0)]
    manifest["budgets"] = [0, "1"]
    (folder / "manifest.json").write_text(json.dumps(manifest))
    assert read_manifest(folder).problem_lines() == [
        f"{folder / 'manifest.json'}: budgets: expected a list of seconds > 0, got [0, '1']"]
