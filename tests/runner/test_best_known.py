"""Best-known plans and bounds kept in a set's manifest (tsac_bench/batch/best_known.py)."""

import json
import shutil

import pytest

from tsac_bench.batch import best_known
from tsac_bench.batch.manifests import iter_instance_files, read_manifest
from tsac_bench.batch.runner import RunConfig, run_batch
from tsac_bench.errors import InputError
from tsac_bench.formulations.task_bound import task_lower_bound
from tsac_bench.model import Solution, Visit
from tsac_bench.model.evaluator import evaluate
from tsac_bench.model.io import read_instance, read_solution
from tsac_bench.planning import PlanningState, make_allocator

from .conftest import QUICK

SMALL = ["quick-2-4-s1", "quick-2-5-s2", "quick-4-10-s5"]


@pytest.fixture
def small_set(tmp_path):
    """Three quick instances (two proved, one not) and their manifest, without budgets."""
    directory = tmp_path / "set"
    directory.mkdir()
    manifest = json.loads((QUICK / "manifest.json").read_text())
    # As `prove` writes them: J* and the best J of the exact backends, no plan kept.
    manifest["instances"] = {k: {f: v[f] for f in ("file", "J_star", "lower_bound", "status",
                                                   "best_J")}
                             for k, v in manifest["instances"].items() if k in SMALL}
    del manifest["budgets"]  # one job per method and mode is enough here
    # The 4/10 instance as `prove` left it before exact-bp proved it: a bound, no best J.
    manifest["instances"]["quick-4-10-s5"] = {"file": "quick-4-10-s5.json", "J_star": None,
                                              "lower_bound": 1.38, "status": "feasible"}
    # One proved instance as if nothing were known of it yet.
    manifest["instances"]["quick-2-5-s2"] = {"file": "quick-2-5-s2.json", "J_star": None,
                                             "lower_bound": None, "status": "feasible"}
    (directory / "manifest.json").write_text(json.dumps(manifest))
    for name in SMALL:
        shutil.copy(QUICK / f"{name}.json", directory)
    return directory


def test_a_run_brings_its_best_offline_plan_and_bounds_into_the_manifest(small_set, tmp_path):
    run = tmp_path / "run"
    run_batch(RunConfig([small_set], run, methods=["greedy", "hocf"], mode="both", jobs=1),
              progress=False)
    run_batch(RunConfig([small_set / "quick-2-4-s1.json", small_set / "quick-2-5-s2.json"],
                        run, methods=["exact"], mode="static", jobs=1), progress=False)
    before = read_manifest(small_set).entries
    changes = best_known.update(run, [small_set], note=lambda line: None)

    entries = read_manifest(small_set).entries
    # Proved before, without a plan: the first job's plan that reaches J* is stored.
    entry = entries["quick-2-4-s1"]
    assert entry["J_star"] == before["quick-2-4-s1"]["J_star"] and entry["status"] == "optimal"
    assert entry["best_J"] == pytest.approx(entry["J_star"], rel=1e-9)
    assert entry["found_by"]["method"] in {"greedy", "hocf", "exact"}
    # Unknown before: exact's proof (its own stats' bound, not the row's reference column)
    # settles it at the J* of quick's manifest.
    entry = entries["quick-2-5-s2"]
    J_star = json.loads((QUICK / "manifest.json").read_text())["instances"]["quick-2-5-s2"][
        "J_star"]
    assert entry["status"] == "optimal" and entry["bound_by"]["method"] == "exact"
    assert entry["J_star"] == entry["best_J"] == pytest.approx(J_star, rel=1e-9)
    assert entry["lower_bound"] == pytest.approx(J_star, rel=1e-6)
    # The unproved 4/10 instance: the lowest J of greedy and hocf in either mode, each
    # dynamic plan counted with its stamps removed.
    instance = read_instance(small_set / "quick-4-10-s5.json")
    costs = {}
    for path in (run / "solutions").rglob("quick-4-10-s5/*.json"):
        plan = best_known.offline_plan(read_solution(path, instance), instance)
        costs[path.name] = evaluate(instance, plan).J
    entry = entries["quick-4-10-s5"]
    assert len(costs) == 4 and entry["best_J"] == pytest.approx(min(costs.values()), rel=1e-12)
    assert entry["lower_bound"] == before["quick-4-10-s5"]["lower_bound"]
    assert entry["status"] == "feasible" and entry["J_star"] is None
    assert {c.instance for c in changes if c.what == "plan"} == set(SMALL)
    assert all(check.passed for check in best_known.check(small_set))
    # The plans beside the instances are not instances to a later run.
    assert [p.name for p in iter_instance_files([small_set])] == [f"{n}.json" for n in SMALL]
    # Taking the same run again changes nothing.
    assert best_known.update(run, [small_set], note=lambda line: None) == []


def test_check_finds_a_best_J_that_its_plan_does_not_evaluate_to(small_set, tmp_path):
    run = tmp_path / "run"
    run_batch(RunConfig([small_set / "quick-4-10-s5.json"], run, methods=["greedy"],
                        mode="static", jobs=1), progress=False)
    best_known.update(run, [small_set], note=lambda line: None)
    path = small_set / "manifest.json"
    data = json.loads(path.read_text())
    data["instances"]["quick-4-10-s5"]["best_J"] -= 0.01
    path.write_text(json.dumps(data))
    (failed,) = [c for c in best_known.check(small_set) if not c.passed]
    assert failed.instance == "quick-4-10-s5" and "best_J says" in failed.problem


def test_a_bound_above_the_best_J_and_a_plan_below_J_star_are_refused():
    entry = {"best_J": 10.0, "lower_bound": 2.0, "J_star": None, "status": "feasible"}
    with pytest.raises(InputError, match=r"above the best-known J 10\.0"):
        best_known.take_bound(entry, 10.5, {"method": "exact"}, "run job x")
    assert best_known.take_bound(entry, 10.0, {"method": "exact", "time_limit": 60}, "x")
    assert entry["status"] == "optimal" and entry["J_star"] == 10.0
    assert not best_known.take_bound(entry, 9.0, {"method": "exact-bp"}, "x")


def test_a_plan_is_kept_in_canonical_form(tmp_path):
    # hocf's plan of quick-3-6-s3 (seed 0) has J 20.506584; the same plan with its late
    # visits dropped and goods above a demand cut has 18.573178, and that is what is kept.
    instance = read_instance(QUICK / "quick-3-6-s3.json")
    plan = Solution(instance.name, make_allocator("hocf").plan(
        PlanningState.static(instance), seed=0).routes)
    assert pytest.approx(20.506584, abs=1e-6) == evaluate(instance, plan).J
    entry = {"J_star": None, "lower_bound": None, "status": "feasible"}
    assert best_known.take_plan(entry, tmp_path, instance, plan, {"method": "hocf"}, "x")
    stored = read_solution(tmp_path / entry["best_plan"], instance)
    assert entry["best_J"] == evaluate(instance, stored).J == pytest.approx(18.573178, abs=1e-6)
    # A plan over a task's demand and the AAV's capacity is not cut into a feasible one.
    overloaded = Solution(instance.name, ((Visit(0, 1e6),),) + ((),) * (instance.n_aavs - 1))
    assert best_known.offline_plan(overloaded, instance) == overloaded


def test_task_bounds_fill_an_empty_set(small_set):
    (small_set / "manifest.json").unlink()
    assert best_known.add_task_bounds(small_set) == 3
    entries = read_manifest(small_set).require_valid().entries
    for name in SMALL:
        state = PlanningState.static(read_instance(small_set / f"{name}.json"))
        assert entries[name]["lower_bound"] == task_lower_bound(state)
        assert entries[name]["bound_by"] == {"method": "tasks-on-their-own"}
    assert best_known.add_task_bounds(small_set) == 0


def test_a_plan_below_a_proved_J_star_is_refused(tmp_path):
    instance = read_instance(QUICK / "quick-2-4-s1.json")
    entry = {"J_star": 1e9, "best_J": 1e9, "lower_bound": 1e9, "status": "optimal"}
    with pytest.raises(InputError, match=r"below the proved J\* 1000000000\.0"):
        best_known.take_plan(entry, tmp_path, instance, Solution.empty(instance),
                             {"method": "greedy"}, "run job y")
    assert not (tmp_path / "best-known").exists()


def test_the_command_line_updates_shows_and_verifies_the_plans(small_set, tmp_path):
    from typer.testing import CliRunner

    from tsac_bench.cli import app

    def invoke(*args):
        return CliRunner().invoke(app, [str(a) for a in args])

    run = tmp_path / "run"
    run_batch(RunConfig([small_set / "quick-4-10-s5.json"], run, methods=["greedy"],
                        mode="static", jobs=1), progress=False)
    updated = invoke("bks", "update", run, "--set", small_set)
    assert updated.exit_code == 0 and "quick-4-10-s5: plan none -> " in updated.output
    shown = invoke("bks", "show", small_set)
    assert shown.exit_code == 0 and "greedy" in shown.output
    checked = invoke("verify", small_set, "--plans-only")
    assert checked.exit_code == 0 and "1/1 best-known plans passed" in checked.output
    (small_set / "best-known" / "quick-4-10-s5.json").write_text("{}")
    assert invoke("verify", small_set, "--plans-only").exit_code == 1
    missing = invoke("bks", "update", tmp_path / "nowhere")
    assert missing.exit_code == 2 and len(missing.output.strip().splitlines()) == 1


def test_a_fresh_proof_keeps_the_plan_and_bound_it_did_not_beat():
    old = {"file": "x.json", "J_star": None, "lower_bound": 8.0, "status": "feasible",
           "best_J": 10.0, "best_plan": "best-known/x.json", "found_by": {"method": "dga"},
           "bound_by": {"method": "exact-bp"}}
    # prove's own entry: its backends found 11 over a bound of 7.
    fresh = {"file": "x.json", "J_star": None, "lower_bound": 7.0, "status": "feasible",
             "best_J": 11.0, "mip_gap": 4 / 11}
    kept = best_known.carried_over(old, fresh)
    assert (kept["best_J"], kept["best_plan"], kept["found_by"]) == (10.0, "best-known/x.json",
                                                                     {"method": "dga"})
    assert (kept["lower_bound"], kept["bound_by"]) == (8.0, {"method": "exact-bp"})
    assert kept["mip_gap"] == pytest.approx(0.2) and kept["status"] == "feasible"
    # A proof that reaches the stored plan's J settles it.
    proved = best_known.carried_over(old, {**fresh, "lower_bound": 10.0, "best_J": 10.5})
    assert proved["status"] == "optimal" and proved["J_star"] == 10.0


def test_recombining_a_runs_plans_lowers_the_best_known_plan(tmp_path):
    from typer.testing import CliRunner

    from tsac_bench.cli import app

    def invoke(*args):
        return CliRunner().invoke(app, [str(a) for a in args])

    # paper-mc 4/10 seed 4: the best of greedy and three short DGA runs is 12.811767; routes
    # taken from different plans give 12.338687 (the least over every choice of their
    # canonical routes, by brute force, 12.338725: tests/formulations/test_recombine.py).
    directory = tmp_path / "set"
    directory.mkdir()
    shutil.copy(QUICK.parent / "paper-mc" / "4-10" / "gen-4-10-s4.json", directory)
    run = tmp_path / "run"
    run_batch(RunConfig([directory], run, methods=["greedy", "dga:generations=5"],
                        mode="static", seeds=3, jobs=1), progress=False)
    assert invoke("bks", "update", run).exit_code == 0
    assert read_manifest(directory).entries["gen-4-10-s4"]["best_J"] == pytest.approx(
        12.811767, abs=1e-6)
    result = invoke("bks", "recombine", directory, run, "--time-limit", 60)
    assert result.exit_code == 0, result.output
    assert "gen-4-10-s4: plan 12.811767 -> 12.338687 (recombined)" in result.output
    entry = read_manifest(directory).entries["gen-4-10-s4"]
    assert entry["found_by"] == {"method": "recombine", "runs": ["run"], "time_limit": 60.0,
                                 "plans": 7}
    assert all(check.passed for check in best_known.check(directory))
    assert "0 improvement(s)" in invoke("bks", "recombine", directory, run).output
    unknown = invoke("bks", "recombine", directory, run, "--only", "nope")
    assert unknown.exit_code == 2 and unknown.output.strip().splitlines() == [
        f"error: {directory}: --only: no instance named 'nope' here"]
    # The same plans as solution files (say, a set's earlier best-known plans) do as well.
    fresh = tmp_path / "fresh"
    fresh.mkdir()
    shutil.copy(directory / "gen-4-10-s4.json", fresh)
    plans = sorted((run / "solutions").rglob("*.json"))
    assert len(plans) == 6  # greedy and DGA, three seeds each
    result = invoke("bks", "recombine", fresh, *plans)
    assert "gen-4-10-s4: plan none -> 12.338687 (recombined)" in result.output, result.output
    not_a_plan = invoke("bks", "recombine", fresh, fresh / "gen-4-10-s4.json")
    assert not_a_plan.exit_code == 2 and not_a_plan.output.strip().splitlines() == [
        f"error: {fresh / 'gen-4-10-s4.json'}: format: expected 'tsac-bench/solution@1'"]


def _invoke(*args):
    from typer.testing import CliRunner

    from tsac_bench.cli import app

    return CliRunner().invoke(app, [str(a) for a in args])


def test_improving_searches_an_instance_and_takes_its_plan_and_bound_in(small_set):
    # Nothing known of quick-2-5-s2 here: exact-bp proves its J* (0.224634) from scratch.
    result = _invoke("bks", "improve", small_set, "--only", "quick-2-5-s2", "--time-limit", 60)
    assert result.exit_code == 0, result.output
    for what in ("plan", "bound"):
        assert (f"quick-2-5-s2: {what} none -> 0.224634 (exact-bp static (bks improve))"
                in result.output)
    entry = read_manifest(small_set).entries["quick-2-5-s2"]
    assert entry["status"] == "optimal" and entry["J_star"] == pytest.approx(0.2246342466,
                                                                             abs=1e-9)
    assert entry["found_by"]["improved_from"] == {"sources": [], "plans": 0}
    assert entry["bound_by"]["time_limit"] == 60.0
    settings = entry["found_by"]["settings"]  # as a run's job records them
    assert list(settings) == sorted(settings) and settings["time_limit"] is None
    assert all(check.passed for check in best_known.check(small_set))
    again = _invoke("bks", "improve", small_set, "--only", "quick-2-5-s2", "--time-limit", 5)
    assert "0 improvement(s)" in again.output, again.output
    unknown = _invoke("bks", "improve", small_set, "--only", "nope")
    assert unknown.exit_code == 2 and unknown.output.strip().splitlines() == [
        f"error: {small_set}: --only: no instance named 'nope' here"]


def test_improving_starts_from_the_sources_plans(tmp_path):
    # paper-mc 4/10 seed 4: the library's plan is optimal (J* 10.339542, proved by exact-bp
    # in 240 s); in one second exact-bp from its own starts ends at 13.53 (measured), so the
    # plan kept is the source's, and the bound stays below it.
    directory = tmp_path / "set"
    directory.mkdir()
    paper_mc = QUICK.parent / "paper-mc" / "4-10"
    shutil.copy(paper_mc / "gen-4-10-s4.json", directory)
    source = paper_mc / "best-known" / "gen-4-10-s4.json"
    result = _invoke("bks", "improve", directory, source, "--time-limit", 1)
    assert result.exit_code == 0, result.output
    assert "gen-4-10-s4: plan none -> 10.339542 (exact-bp static (bks improve))" in result.output
    entry = read_manifest(directory).entries["gen-4-10-s4"]
    assert entry["found_by"]["improved_from"] == {"sources": ["gen-4-10-s4.json"], "plans": 1}
    assert entry["lower_bound"] < 10.339542 and entry["status"] == "feasible"


def _another_search_raises_a_bound(directory, name, bound):
    """What a second search on the same set does while the first one runs: it writes the
    manifest with a higher bound of another instance."""
    data = json.loads((directory / "manifest.json").read_text())
    data["instances"][name]["lower_bound"] = bound
    (directory / "manifest.json").write_text(json.dumps(data))


def test_two_searches_on_one_set_keep_each_others_results(small_set, monkeypatch):
    # `bks improve` and `prove` read the manifest at their start and search for hours; what
    # another search wrote meanwhile (quick-4-10-s5's bound 1.38 -> 1.39) must survive
    # their own write.
    from tsac_bench.batch import verify
    from tsac_bench.solvers.exact import BranchPriceAllocator

    search = BranchPriceAllocator.plan_from

    def searched_beside_another(self, *args, **kwargs):
        _another_search_raises_a_bound(small_set, "quick-4-10-s5", 1.39)
        return search(self, *args, **kwargs)

    monkeypatch.setattr(BranchPriceAllocator, "plan_from", searched_beside_another)
    best_known.improve(small_set, [], 60, only=["quick-2-5-s2"], note=lambda _: None)
    entries = read_manifest(small_set).entries
    assert entries["quick-4-10-s5"]["lower_bound"] == 1.39
    assert entries["quick-2-5-s2"]["J_star"] == pytest.approx(0.2246342466, abs=1e-9)

    monkeypatch.undo()  # exact-bp's own search, not the 1.39 again
    solve = verify.solve_exact

    def solved_beside_another(*args, **kwargs):
        _another_search_raises_a_bound(small_set, "quick-4-10-s5", 1.4)
        return solve(*args, **kwargs)

    monkeypatch.setattr(verify, "solve_exact", solved_beside_another)
    verify.prove(small_set, 60, "test", names=["quick-2-4-s1"], methods=["exact-bp"],
                 log=lambda _: None)
    entries = read_manifest(small_set).entries
    assert entries["quick-4-10-s5"]["lower_bound"] == 1.4
    assert entries["quick-2-4-s1"]["solvers"]["exact-bp"]["status"] == "optimal"
    assert entries["quick-2-5-s2"]["J_star"] == pytest.approx(0.2246342466, abs=1e-9)


def test_the_manifest_lock_makes_a_second_writer_wait(tmp_path):
    import threading
    import time

    from tsac_bench.batch.manifests import manifest_lock

    order = []

    def second():
        with manifest_lock(tmp_path):
            order.append("second")

    with manifest_lock(tmp_path):
        waiting = threading.Thread(target=second)
        waiting.start()
        time.sleep(0.2)  # the thread has long reached the lock: it waits there
        order.append("first")
    waiting.join(10)
    assert order == ["first", "second"]


def test_a_neighbourhood_search_lowers_a_best_known_plan(tmp_path):
    # reg-static-3-6-s2 (J* 5.069236) from a random plan: repairs of two AAVs and one more
    # task, then of all three, reach J* (tests/formulations/test_neighbourhoods.py checks
    # the repairs against brute force); the plan is taken in, not proved.
    from tests.formulations.plans import random_plan
    from tsac_bench.formulations.network import canonical_routes
    from tsac_bench.model.io import write_solution

    directory = tmp_path / "set"
    directory.mkdir()
    regression = QUICK.parent / "regression"
    shutil.copy(regression / "reg-static-3-6-s2.json", directory)
    instance = read_instance(directory / "reg-static-3-6-s2.json")
    start = tmp_path / "start.json"
    write_solution(Solution(instance.name, canonical_routes(instance, random_plan(instance, 0))),
                   instance, start)
    assert "plan none -> 156.963886" in _invoke("bks", "recombine", directory, start).output
    result = _invoke("bks", "lns", directory, "--aavs", 2, "--extra", 1, "--repair-limit", 60,
                     "--time-limit", 600)
    assert result.exit_code == 0, result.output
    assert "reg-static-3-6-s2: plan 156.963886 -> 5.069236 (lns static)" in result.output
    entry = read_manifest(directory).entries["reg-static-3-6-s2"]
    assert entry["found_by"]["method"] == "lns" and entry["status"] == "feasible"
    assert entry["found_by"]["settings"] == {"aavs": 2, "extra": 1, "repair_limit": 60.0,
                                             "order": "shuffled"}
    assert all(check.passed for check in best_known.check(directory))
    for option, value in (("--aavs", 0), ("--order", "cheapest")):
        bad = _invoke("bks", "lns", directory, option, value)
        assert bad.exit_code == 2 and option in bad.output
