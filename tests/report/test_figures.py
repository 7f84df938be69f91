"""Figures from a store whose solutions are real files on tests/data/hand.json."""

from dataclasses import replace
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from tsac_bench.batch.store import ResultStore, job_key
from tsac_bench.model import Solution
from tsac_bench.model.evaluator import CostEvaluator
from tsac_bench.model.io import read_instance, read_solution, write_solution
from tsac_bench.reporting.data import SolutionLoader, coalition_sizes, replan_costs
from tsac_bench.reporting.report import write_report

pytest.importorskip("matplotlib")

HAND = Path(__file__).parent.parent / "data" / "hand.json"
HAND_SOLUTION = HAND.parent / "hand-solution.json"


@pytest.fixture
def run_dir(tmp_path) -> Path:
    """Method "a" is hand-solution.json (one AAV per task); method "b" sends both AAVs to
    T1 (20 kg delivery, 10 kg each). Both in both modes; the dynamic runs carry re-plans."""
    instance = read_instance(HAND)
    solutions = {
        "a": read_solution(HAND_SOLUTION, instance),
        "b": Solution.from_ids(instance, {"A0": ["D0", ("T1", 10), "D0"],
                                          "A1": ["D0", ("T1", 10), "D0"]}),
    }
    run = tmp_path / "run"
    with ResultStore(run) as store:
        for method, solution in solutions.items():
            evaluation = CostEvaluator(instance).evaluate(solution)
            for mode in ("static", "dynamic"):
                relative = store.solution_path("data", "hand", method, mode, 0)
                write_solution(solution, instance, run / relative)
                replans = [{"time": 0.0, "J": 300.0, "J_known": 100.0, "J_known_before": None},
                           {"time": 250.0, "J": evaluation.J, "J_known": evaluation.J,
                            "J_known_before": 290.0}]
                store.record({
                    "key": job_key("hand", method, mode, 0), "instance": "hand",
                    "instance_set": "data", "instance_file": str(HAND), "scale": "2/4",
                    "method": method, "mode": mode, "seed": 0, "status": "ok",
                    "J": evaluation.J, "J_load": evaluation.terms["load"],
                    "J_time": evaluation.terms["time"], "J_op": evaluation.terms["op"],
                    "solution_file": str(relative), "host": "test", "versions": {},
                    "stats": {"replans": replans} if mode == "dynamic" else {}})
    return run


def test_coalition_sizes_come_from_the_stored_solutions(run_dir):
    with ResultStore(run_dir) as store:
        data = coalition_sizes(store.frame(), run_dir)
    static = data[data["mode"] == "static"].sort_values(["method", "task"])
    assert list(static[["method", "task", "demand", "coalition_size"]].itertuples(
        index=False, name=None)) == [("a", "T0", 10, 1), ("a", "T1", 20, 1),
                                     ("a", "T3", 10, 1), ("b", "T1", 20, 2)]


def test_the_report_draws_every_figure_as_png_and_pdf(run_dir, tmp_path):
    out = tmp_path / "report"
    index = write_report(run_dir, out).read_text()
    names = ["boxplot-J-static", "boxplot-J-dynamic", "profile-static", "profile-dynamic",
             "coalitions-static", "coalitions-dynamic", "gantt-hand-a", "gantt-hand-b",
             "routes-hand"]
    for name in names:
        for suffix in (".png", ".pdf"):
            path = out / "figures" / (name + suffix)
            assert path.stat().st_size > 1000, path
        assert f"figures/{name}.png" in index
    assert "only the visits are drawn" not in index  # the re-plans were used
    assert "## Static mode" in index and "## Dynamic mode" in index
    per_instance = pd.read_csv(out / "tables" / "per_instance.csv")
    assert sorted(per_instance["J"].round(6)) == sorted(
        [212.821528, 212.821528, *[np.round(_b_cost(), 6)] * 2])


def test_gantt_without_replans_is_drawn_with_a_note(run_dir, tmp_path):
    with ResultStore(run_dir) as store:
        for row in store.rows():
            if row["mode"] == "dynamic":
                store.record({**row, "stats": {}})
    from tsac_bench.reporting.figures import dynamic_gantt

    with ResultStore(run_dir) as store:
        frame = store.frame()
    _, paths, note = dynamic_gantt(frame, SolutionLoader(run_dir), tmp_path / "figures")
    assert "only the visits are drawn" in note
    assert [p.name for p in paths] == ["gantt-hand-a.png", "gantt-hand-b.png"]
    assert (tmp_path / "figures" / "gantt-hand-a.pdf").exists()


def _b_cost() -> float:
    instance = read_instance(HAND)
    return CostEvaluator(instance).cost(Solution.from_ids(
        instance, {"A0": ["D0", ("T1", 10), "D0"], "A1": ["D0", ("T1", 10), "D0"]}))


def released_later(release: float):
    """hand.json with T3 (window [0, 3600]) released at ``release``, its window opening then."""
    instance = read_instance(HAND)
    tasks = tuple(replace(t, release=release, t_start=release) if t.id == "T3" else t
                  for t in instance.tasks)
    return replace(instance, tasks=tasks)


def test_the_cost_curve_is_the_plan_in_force_after_each_replan_never_the_release_spike():
    from tsac_bench.planning.simulator import simulate
    from tsac_bench.solvers.greedy import GreedyAllocator

    instance = released_later(250.0)
    run = simulate(instance, GreedyAllocator())
    records = [r.to_dict() for r in run.replans]
    times, costs = replan_costs({"replans": records}, instance)
    assert times == [0.0, 250.0]
    assert costs == [run.replans[0].J_known, run.replans[1].J_known]
    assert costs[1] == pytest.approx(run.evaluation.J, rel=1e-12)  # the executed plan
    # The cost the simulator records just before the re-plan holds T3 unserved (110): the
    # curve never shows it.
    assert run.replans[1].J_known_before == pytest.approx(costs[0] + 110, rel=1e-12)
    # Early stores kept only J (over every task): T3, unreleased at t = 0, costs w1 + w2.
    plain = [{"time": r["time"], "J": r["J"]} for r in records]
    plain_times, plain_costs = replan_costs({"replans": plain}, instance)
    assert plain_times == times and plain_costs == pytest.approx(costs, rel=1e-12)
    assert records[0]["J"] - 110 == pytest.approx(costs[0], rel=1e-12)


def test_replan_costs_by_hand():
    instance = released_later(90.0)
    stats = {"replans": [{"time": 0.0, "J": 300.0}, {"time": 90.0, "J": 150.0}]}
    assert replan_costs(stats, instance) == ([0.0, 90.0], [190.0, 150.0])
    known = {"replans": [{"time": 0.0, "J": 300.0, "J_known": 20.0, "J_known_before": None},
                         {"time": 90.0, "J": 150.0, "J_known": 40.0, "J_known_before": 130.0}]}
    assert replan_costs(known, instance) == ([0.0, 90.0], [20.0, 40.0])
    assert replan_costs({}, instance) == ([], [])
    assert replan_costs({"replans": [{"J": 1.0}]}, instance) == ([], [])


def test_gantt_lanes_and_cost_panel():
    from tsac_bench.reporting.figures import COST_AXIS_LABEL, gantt_figure

    instance = read_instance(HAND)
    solution = read_solution(HAND_SOLUTION, instance)
    fig = gantt_figure(instance, solution, ([0.0, 90.0], [20.0, 40.0]), "hand")
    gantt, cost = fig.axes
    assert cost.get_ylabel() == COST_AXIS_LABEL
    assert "plan in force" in COST_AXIS_LABEL and "after each re-plan" in COST_AXIS_LABEL
    # A0 flies 2 legs, A1 5; A1 waits for T1's window (hatched): 8 bars in all.
    assert len(gantt.patches) == 2 + 5 + 1
    labels = sorted(t.get_text() for t in gantt.texts)
    # Four depot visits, but A1 starts at D0: its first leg is a sliver, left unlabelled.
    assert labels == ["D0", "D0", "D0", "T0:5", "T1:10", "T3:10"]
    times, costs = cost.lines[0].get_data()
    # The last plan's cost holds to the end of the last route.
    end = max(t.arrivals[-1] for t in (CostEvaluator(instance).trace(n, r)
                                       for n, r in enumerate(solution.routes)) if t.arrivals)
    assert list(costs) == [20.0, 40.0, 40.0] and list(times) == [0.0, 90.0, end]
