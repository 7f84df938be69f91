import json

import pytest

from tsac_bench.batch.runner import RunConfig, run_batch
from tsac_bench.batch.store import ResultStore

pytest.importorskip("distributed")

SAME = ["key", "instance", "method", "mode", "seed", "status", "J", "J_load", "J_time", "J_op",
        "solution_file", "settings"]


def test_dask_local_cluster_gives_the_local_executor_s_results(tmp_path, two_instances):
    runs = {}
    for executor in ("local", "dask"):
        out = tmp_path / executor
        outcome = run_batch(RunConfig([two_instances], out, methods=["greedy"], mode="static",
                                      seeds=2, jobs=2, executor=executor),
                            note=lambda line: None, progress=False)
        assert (outcome.ran, outcome.failed) == (4, 0)
        with ResultStore(out) as store:
            runs[executor] = store.rows()
    assert [{c: r[c] for c in SAME} for r in runs["dask"]] == \
        [{c: r[c] for c in SAME} for r in runs["local"]]
    for row in runs["dask"]:
        assert row["J"] > 0
        dask_solution = json.loads((tmp_path / "dask" / row["solution_file"]).read_text())
        local_solution = json.loads((tmp_path / "local" / row["solution_file"]).read_text())
        assert dask_solution == local_solution


def test_dask_resumes_like_the_local_executor(tmp_path, two_instances):
    out = tmp_path / "run"
    config = RunConfig([two_instances], out, methods=["greedy"], mode="static", jobs=1)
    run_batch(config, note=lambda line: None, progress=False)
    config.executor, config.seeds = "dask", 2
    outcome = run_batch(config, note=lambda line: None, progress=False)
    assert (outcome.total, outcome.skipped, outcome.ran) == (4, 2, 2)


def test_on_dask_a_hung_or_crashing_job_is_recorded_too(tmp_path, two_instances, plugin_path,
                                                        cli):
    (two_instances / "quick-2-5-s2.json").unlink()
    out = tmp_path / "run"
    result = cli("run", two_instances, "--methods", "greedy,boom,abort,hang", "--mode", "static",
                 "--jobs", "2",
                 "--executor", "dask", "--time-limit", "0.2", "--grace", "1", "--no-report",
                 "--no-progress", "--out", out, plugins=plugin_path)
    assert result.returncode == 0, result.stderr
    with ResultStore(out) as store:
        status = {row["method"]: (row["status"], row["message"]) for row in store.rows()}
    assert status["greedy"] == ("ok", "")
    assert status["boom"] == ("error", "RuntimeError: boom on purpose")
    assert status["abort"] == ("crash", "worker process exited with code 3")
    assert status["hang"][0] == "timeout"
