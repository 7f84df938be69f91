import json
import os
import shutil
import signal
import sqlite3
import time
from pathlib import Path

import pandas as pd
import pytest

from tsac_bench.batch.runner import RunConfig, run_batch
from tsac_bench.batch.store import ResultStore, export
from tsac_bench.batch.worker import execute_job
from tsac_bench.errors import UnknownMethodError
from tsac_bench.model.io import read_instance, read_solution
from tsac_bench.planning.solve import solve
from tsac_bench.reporting.data import per_instance, references

COMPARED = ["key", "instance", "scale", "method", "mode", "seed", "status", "J", "J_load",
            "J_time", "J_op", "solution_file"]


def rows_by_key(run_dir: Path) -> dict[str, dict]:
    with ResultStore(run_dir, create=False) as store:
        return {row["key"]: row for row in store.rows()}


def count_rows(db: Path) -> int:
    if not db.exists():
        return 0
    try:
        with sqlite3.connect(db, timeout=5) as conn:
            return conn.execute("SELECT count(*) FROM jobs").fetchone()[0]
    except sqlite3.OperationalError:  # the table is not created yet
        return 0


def summary_lines(stdout: str) -> list[str]:
    """The summary table printed at the end of a run (without the counts line after it)."""
    return [line for line in stdout.splitlines() if "│" in line or "┃" in line]


def test_a_killed_run_resumes_and_ends_like_an_uninterrupted_one(tmp_path, two_instances,
                                                                 plugin_path, cli):
    args = ["run", two_instances, "--methods", "greedy,slow", "--mode", "static", "--seeds", "3",
            "--jobs", "1",
            "--no-report", "--no-progress"]
    killed = tmp_path / "killed"
    process = cli(*args, "--out", killed, plugins=plugin_path, background=True)
    deadline = time.monotonic() + 60
    while count_rows(killed / "results.sqlite") < 3 and time.monotonic() < deadline:
        time.sleep(0.02)
    os.kill(process.pid, signal.SIGKILL)
    process.wait()
    partial = rows_by_key(killed)
    assert 3 <= len(partial) < 12, "the kill must land in the middle of the run"

    resumed = cli(*args, "--out", killed, plugins=plugin_path)
    assert resumed.returncode == 0, resumed.stderr
    assert f"{len(partial)} of 12 jobs already recorded" in resumed.stderr
    assert f"{12 - len(partial)} job(s) run, {len(partial)} already recorded" in resumed.stdout
    after = rows_by_key(killed)
    assert len(after) == 12
    for key, row in partial.items():  # finished jobs were skipped, not run again
        assert after[key]["finished_at"] == row["finished_at"]
        assert after[key]["J"] == row["J"]

    full = cli(*args, "--out", tmp_path / "full", plugins=plugin_path)
    assert full.returncode == 0, full.stderr
    uninterrupted = rows_by_key(tmp_path / "full")
    assert [{c: r[c] for c in COMPARED} for r in after.values()] == \
        [{c: r[c] for c in COMPARED} for r in uninterrupted.values()]
    assert summary_lines(resumed.stdout) == summary_lines(full.stdout)
    assert len(summary_lines(full.stdout)) == 3 + 2  # header lines + one row per scale
    for row in after.values():
        assert row["status"] == "ok"
        stored = json.loads((killed / row["solution_file"]).read_text())
        assert stored == json.loads((tmp_path / "full" / row["solution_file"]).read_text())


def test_raising_crashing_and_hanging_plugins_are_recorded_and_the_batch_goes_on(
        tmp_path, two_instances, plugin_path, cli):
    out = tmp_path / "run"
    result = cli("run", two_instances, "--methods", "greedy,boom,abort,hang", "--mode", "static",
                 "--jobs", "2",
                 "--time-limit", "0.2", "--grace", "1", "--no-report", "--no-progress",
                 "--out", out, plugins=plugin_path)
    assert result.returncode == 0, result.stderr
    rows = rows_by_key(out)
    assert len(rows) == 8
    by_method: dict[str, list[dict]] = {}
    for row in rows.values():
        by_method.setdefault(row["method"], []).append(row)
    assert {r["status"] for r in by_method["boom"]} == {"error"}
    assert all(r["message"] == "RuntimeError: boom on purpose" for r in by_method["boom"])
    assert all("Traceback" in r["detail"] for r in by_method["boom"])
    assert {r["status"] for r in by_method["abort"]} == {"crash"}
    assert all("exited with code 3" in r["message"] for r in by_method["abort"])
    assert {r["status"] for r in by_method["hang"]} == {"timeout"}
    assert all(r["J"] is None and r["solution_file"] is None
               for m in ("boom", "abort", "hang") for r in by_method[m])
    for row in by_method["greedy"]:
        assert row["status"] == "ok"
        instance = read_instance(row["instance_file"])
        assert row["J"] == solve(instance, "greedy", time_limit=0.2).cost
        assert row["J"] == pytest.approx(row["J_load"] + row["J_time"] + row["J_op"], rel=1e-12)
        assert read_solution(out / row["solution_file"], instance).cost == row["J"]
    assert "boom on purpose" in result.stderr
    assert "8 job(s) run, 0 already recorded, 6 failed" in result.stdout


def test_a_malformed_instance_is_reported_and_the_others_run(tmp_path, two_instances, cli):
    bad = Path(__file__).parent.parent / "data" / "bad" / "missing-field.json"
    shutil.copy(bad, two_instances / "broken.json")
    out = tmp_path / "run"
    result = cli("run", two_instances, "--methods", "greedy", "--mode", "static", "--no-report",
                 "--no-progress",
                 "--out", out)
    assert result.returncode == 2
    problems = [line for line in result.stderr.splitlines() if "broken.json" in line]
    assert problems == [f"{two_instances / 'broken.json'}: tasks[3].t_end: Field required"]
    assert sorted(r["instance"] for r in rows_by_key(out).values()) == ["quick-2-4-s1",
                                                                        "quick-2-5-s2"]


def test_an_unknown_method_is_one_line_and_runs_nothing(tmp_path, two_instances, cli):
    result = cli("run", two_instances, "--methods", "greedy,nope", "--out", tmp_path / "run")
    assert result.returncode == 2
    assert result.stderr.strip().splitlines()[-1].startswith("error: unknown method 'nope'")
    assert not (tmp_path / "run" / "results.sqlite").exists()
    with pytest.raises(UnknownMethodError):
        run_batch(RunConfig([two_instances], tmp_path / "x", methods=["nope"]))


def test_a_seed_range_adds_seeds_to_a_run_without_running_its_seeds_again(tmp_path,
                                                                           two_instances, cli):
    out = tmp_path / "run"
    run_batch(RunConfig([two_instances], out, methods=["greedy"], mode="static", seeds=2,
                        jobs=1), note=lambda line: None, progress=False)
    result = cli("run", two_instances, "--methods", "greedy", "--mode", "static",
                 "--seeds", "1-3", "--no-report", "--no-progress", "--out", out)
    assert result.returncode == 0, result.stderr
    assert "4 job(s) run, 2 already recorded, 0 failed" in result.stdout.replace("\n", " ")
    seeds = sorted((r["instance"], r["seed"]) for r in rows_by_key(out).values())
    assert seeds == [(name, seed) for name in ("quick-2-4-s1", "quick-2-5-s2")
                     for seed in range(4)]


@pytest.mark.parametrize(("seeds", "message"), [
    ("3-1", "error: --seeds: '3-1' names no seed"),
    ("0", "error: --seeds: '0' names no seed"),
    ("two", "error: --seeds: 'two' is neither a count nor a range FIRST-LAST"),
])
def test_a_bad_seed_count_or_range_is_one_line_and_runs_nothing(tmp_path, two_instances, cli,
                                                                seeds, message):
    result = cli("run", two_instances, "--methods", "greedy", "--seeds", seeds,
                 "--out", tmp_path / "run")
    assert result.returncode == 2
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith(message), result.stderr
    assert not (tmp_path / "run").exists()


def test_an_unknown_mode_is_a_recorded_error(two_instances):
    instance = read_instance(two_instances / "quick-2-4-s1.json")
    from tsac_bench.model.io import instance_to_dict

    result = execute_job({"instance": instance_to_dict(instance), "method": "greedy",
                          "mode": "sideways", "seed": 0, "time_limit": 1})
    assert result["status"] == "error" and "unknown mode 'sideways'" in result["message"]


def test_manifest_references_give_gaps(tmp_path, two_instances):
    greedy = {p.stem: solve(read_instance(p), "greedy").cost
              for p in sorted(two_instances.glob("*.json"))}
    manifest = {"format": "tsac-bench/manifest@1", "instances": {
        "quick-2-4-s1": {"file": "quick-2-4-s1.json", "J_star": greedy["quick-2-4-s1"] / 1.25,
                         "lower_bound": 1.0, "status": "optimal"},
        "quick-2-5-s2": {"file": "quick-2-5-s2.json", "J_star": None,
                         "lower_bound": greedy["quick-2-5-s2"] / 2, "status": "feasible"}}}
    (two_instances / "manifest.json").write_text(json.dumps(manifest))
    out = tmp_path / "run"
    outcome = run_batch(RunConfig([two_instances], out, methods=["greedy"], mode="static",
                                  seeds=2, jobs=2), note=lambda line: None, progress=False)
    assert (outcome.total, outcome.ran, outcome.failed, outcome.problems) == (4, 4, 0, [])
    with ResultStore(out) as store:
        frame = store.frame()
    assert set(frame["reference"]) == {"manifest"}
    table = per_instance(frame).set_index("instance")
    assert table.at["quick-2-4-s1", "gap"] == pytest.approx(0.25, rel=1e-12)
    assert pd.isna(table.at["quick-2-5-s2", "gap"])
    assert table.at["quick-2-5-s2", "gap_lb"] == pytest.approx(1.0, rel=1e-12)
    assert table.at["quick-2-4-s1", "seeds"] == 2


def test_an_exact_jobs_status_and_bound_reach_the_store_and_the_references(tmp_path,
                                                                           two_instances):
    # No manifest here: J* comes from the run. instances/quick's manifest has quick-2-4-s1's
    # J* = 35.456039935500684 and quick-2-5-s2's 0.2246342465841162.
    out = tmp_path / "run"
    outcome = run_batch(RunConfig([two_instances], out, methods=["exact"], mode="static",
                                  jobs=1), note=lambda line: None, progress=False)
    assert (outcome.ran, outcome.failed) == (2, 0)
    stored = rows_by_key(out)["quick-2-4-s1|exact|static|0"]["stats"]
    assert stored["status"] == "optimal"
    assert stored["lower_bound"] == pytest.approx(35.456039935500684, rel=1e-6)
    with ResultStore(out) as store:
        refs = references(store.frame())
    assert list(refs["J_star_source"]) == ["exact run", "exact run"]
    assert list(refs["J_star"]) == pytest.approx([35.456039935500684, 0.2246342465841162],
                                                 rel=1e-6)
    assert (refs["lower_bound"] <= refs["J_star"] * (1 + 1e-6)).all()


def test_a_jobs_spec_and_row_share_its_identity_and_the_row_is_the_stores_columns(
        two_instances):
    from tsac_bench.batch.records import JobIdentity, JobRow
    from tsac_bench.batch.runner import load_instances, plan_jobs, resolve_methods
    from tsac_bench.batch.store import COLUMNS

    assert JobRow.__required_keys__ | JobRow.__optional_keys__ == set(COLUMNS)
    loaded, _ = load_instances([two_instances / "quick-2-4-s1.json"])
    methods, _ = resolve_methods(["hocf:k_max=3"])
    job = plan_jobs(loaded, methods, ["static"], [0], None, budgets=[0.5])[0]
    identity = JobIdentity.__required_keys__ | JobIdentity.__optional_keys__
    assert {key: job.spec[key] for key in identity} == {key: job.row[key] for key in identity}
    assert {key: job.row[key] for key in identity} == {
        "key": "quick-2-4-s1|hocf:k_max=3|static|0|budget=0.5",
        "instance_file": str(two_instances / "quick-2-4-s1.json"), "mode": "static",
        "seed": 0, "settings": {"k_max": 3}, "time_limit": 0.5, "budget": 0.5}
    assert (job.spec["method"], job.row["method"]) == ("hocf", "hocf:k_max=3")


def test_a_malformed_manifest_is_reported_and_the_run_goes_on(tmp_path, two_instances):
    (two_instances / "manifest.json").write_text(json.dumps(
        {"format": "tsac-bench/manifest@1",
         "instances": {"quick-2-4-s1": {"file": "quick-2-4-s1.json", "J_star": "12",
                                        "lower_bound": None, "status": "optimal"},
                       "quick-2-5-s2": {"J_star": 1.0}}}))
    notes: list[str] = []
    outcome = run_batch(RunConfig([two_instances], tmp_path / "run", methods=["greedy"],
                                  mode="static", jobs=1), note=notes.append, progress=False)
    assert outcome.problems == [f"{two_instances / 'manifest.json'}: "
                                "instances.quick-2-4-s1.J_star: expected a finite number or "
                                "null, got '12'",
                                f"{two_instances / 'manifest.json'}: "
                                "instances.quick-2-5-s2.file: missing"]
    assert outcome.ran == 2 and outcome.failed == 0


def test_export_csv_and_parquet_hold_every_row(tmp_path, two_instances):
    out = tmp_path / "run"
    run_batch(RunConfig([two_instances], out, methods=["greedy"], mode="static", seeds=2,
                        jobs=1), note=lambda line: None, progress=False)
    assert export(out, "csv", tmp_path / "r.csv") == 4
    assert export(out, "parquet", tmp_path / "r.parquet") == 4
    csv = pd.read_csv(tmp_path / "r.csv").sort_values("key").reset_index(drop=True)
    parquet = pd.read_parquet(tmp_path / "r.parquet").sort_values("key").reset_index(drop=True)
    stored = rows_by_key(out)
    assert list(csv["key"]) == sorted(stored)
    assert list(parquet["J"]) == [stored[k]["J"] for k in sorted(stored)]
    assert list(csv["J"]) == pytest.approx(list(parquet["J"]), rel=1e-15)
    assert json.loads(parquet["versions"][0])["tsac-bench"]


def test_default_time_limits_grow_with_the_task_count():
    from tsac_bench.batch.runner import default_time_limit

    assert default_time_limit("greedy", 4) == 2.0
    assert default_time_limit("greedy", 80) == 16.0
    assert default_time_limit("exact", 10) == 5.0
    assert default_time_limit("exact-cpsat", 40) == 20.0


def test_method_specs_are_jobs_of_their_own_and_a_store_of_plain_names_resumes(
        tmp_path, two_instances, cli):
    out = tmp_path / "run"
    common = ["--mode", "dynamic", "--jobs", "2", "--no-progress", "--out", out]
    first = cli("run", two_instances, "--methods", "hocf", "--no-report", *common)
    assert first.returncode == 0, first.stderr
    before = rows_by_key(out)
    # The keys of a store written before method specs existed: the name alone.
    assert sorted(before) == ["quick-2-4-s1|hocf|dynamic|0", "quick-2-5-s2|hocf|dynamic|0"]

    both = cli("run", two_instances, "--methods", "hocf,hocf:init=incumbent,hocf",
               "--report-out", tmp_path / "report", *common)
    assert both.returncode == 0, both.stderr
    assert "2 job(s) run, 2 already recorded, 0 failed" in both.stdout
    after = rows_by_key(out)
    for key, row in before.items():
        assert after[key]["finished_at"] == row["finished_at"]
    assert sorted(after) == sorted([*before, "quick-2-4-s1|hocf:init=incumbent|dynamic|0",
                                    "quick-2-5-s2|hocf:init=incumbent|dynamic|0"])
    for row in after.values():
        assert row["status"] == "ok"
        init = "incumbent" if row["method"] == "hocf:init=incumbent" else "empty"
        assert row["settings"]["init"] == init
        solution = json.loads((out / row["solution_file"]).read_text())
        assert solution["meta"]["settings"]["init"] == init
        assert solution["cost"] == row["J"]
    assert {Path(r["solution_file"]).name for r in after.values()} == {
        "hocf-dynamic-s0.json", "hocf+init=incumbent-dynamic-s0.json"}

    tables = tmp_path / "report" / "tables"
    summary = pd.read_csv(tables / "summary.csv")
    assert set(summary["method"]) == {"hocf", "hocf:init=incumbent"}
    markdown = (tables / "summary-dynamic.md").read_text()
    latex = (tables / "summary-dynamic.tex").read_text()
    for label in ("hocf", "hocf:init=incumbent"):
        assert f"| {label} " in markdown
        assert any(line.startswith(f"{label} & ") for line in latex.splitlines())
    # One instance per scale and one seed: each cell's mean J is that job's J.
    cells = summary.set_index(["scale", "method"])["J_mean"].to_dict()
    assert cells == {(r["scale"], r["method"]): pytest.approx(r["J"], rel=1e-12)
                     for r in after.values()}


@pytest.mark.parametrize(("methods", "message"), [
    ("greedy,hocf:init=foo", "error: method 'hocf' setting 'init': got 'foo'; allowed: one of "
                             "'empty', 'incumbent', 'greedy'"),
    ("exact-cpsat:threads=zero", "error: method 'exact-cpsat' setting 'threads': got 'zero'; "
                                 "allowed: an integer >= 1"),
    ("hocf:k_max", "error: method spec 'hocf:k_max': 'k_max': expected KEY=VALUE"),
    ("dga:size=3", "error: method 'dga' has no setting 'size'; its settings: islands, "),
])
def test_a_bad_spec_is_one_line_and_runs_nothing(tmp_path, two_instances, cli, methods,
                                                 message):
    result = cli("run", two_instances, "--methods", methods, "--out", tmp_path / "run")
    assert result.returncode == 2
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith(message), result.stderr
    assert not (tmp_path / "run").exists()


def test_jobs_of_a_spec_take_the_modes_and_time_limits_of_its_method(two_instances):
    from tsac_bench.batch.runner import load_instances, plan_jobs, resolve_methods

    loaded, _ = load_instances([two_instances])
    methods, _ = resolve_methods(["exact-cpsat:threads=2", "hocf:k_max=3", "hocf:k_max=03"])
    jobs = plan_jobs(loaded, methods, ["static", "dynamic"], [0], None)
    cells = sorted((j.row["instance"], j.row["method"], j.row["mode"], j.row["time_limit"])
                   for j in jobs)
    assert cells == sorted((instance, label, mode, limit)
                           for instance in ("quick-2-4-s1", "quick-2-5-s2")
                           for label, mode, limit in (
                               ("exact-cpsat:threads=2", "static", 5.0),
                               ("hocf:k_max=3", "static", 2.0),
                               ("hocf:k_max=3", "dynamic", 2.0)))
    for job in jobs:  # the worker builds the method from its name and converted settings
        assert (job.spec["method"], job.spec["settings"]) in (("exact-cpsat", {"threads": 2}),
                                                             ("hocf", {"k_max": 3}))


def test_resuming_jobs_recorded_with_other_settings_says_so_and_keeps_them(tmp_path,
                                                                            two_instances):
    out = tmp_path / "run"
    config = RunConfig([two_instances], out, methods=["hocf", "greedy"], mode="static", jobs=1)
    notes: list[str] = []
    run_batch(config, note=notes.append, progress=False)
    again = run_batch(config, note=notes.append, progress=False)
    assert again.ran == 0 and not any("other settings" in line for line in notes)
    # Budgeted jobs record the work caps their budget lifts (hocf's samples=None): resuming
    # them compares with those, not with the unbudgeted defaults.
    budgeted = RunConfig([two_instances], tmp_path / "budgeted", methods=["hocf"],
                         mode="static", jobs=1, budgets=[0.05])
    run_batch(budgeted, note=notes.append, progress=False)
    assert run_batch(budgeted, note=notes.append, progress=False).ran == 0
    assert not any("other settings" in line for line in notes)
    # A store from before a default changed: one hocf job recorded another c_max and a
    # setting hocf no longer has.
    with sqlite3.connect(out / "results.sqlite") as db:
        key, settings = db.execute("SELECT key, settings FROM jobs WHERE method = 'hocf' "
                                   "ORDER BY key LIMIT 1").fetchone()
        older = {**json.loads(settings), "c_max": 10, "retired": True}
        db.execute("UPDATE jobs SET settings = ? WHERE key = ?", (json.dumps(older), key))
        before = db.execute("SELECT J, finished_at FROM jobs WHERE key = ?", (key,)).fetchone()
    notes.clear()
    resumed = run_batch(config, note=notes.append, progress=False)
    assert resumed.ran == 0
    assert notes[-1] == ("1 recorded hocf job(s) ran with other settings than hocf takes now "
                         "(c_max, retired); they are kept: delete them from the store to run "
                         "them again")
    with sqlite3.connect(out / "results.sqlite") as db:
        assert db.execute("SELECT J, finished_at FROM jobs WHERE key = ?",
                          (key,)).fetchone() == before
