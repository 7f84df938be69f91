"""The TSAC evaluation's paired table (benchmarks/tsac_eval.py), on hand-made costs."""

from __future__ import annotations

import os
import sys
from pathlib import Path

import pytest

sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "benchmarks"))
import tsac_eval


def test_paired_rows_give_the_mean_difference_its_interval_and_the_counts() -> None:
    costs = {"ref": [10.0, 20.0, 30.0], "b": [12.0, 18.0, 33.0], "c": [10.0, 20.0, 30.0]}
    # b - ref = (2, -2, 3): mean 1, sample sd sqrt(7), half-width 1.96 sqrt(7) / sqrt(3)
    # = 2.994; 1 / mean J(ref) 20 = 5 %; one instance lower, two higher.
    # c equals the reference: an interval of width 0 and no instance either way.
    assert tsac_eval.paired_rows("8/20", costs, "ref") == [
        "| 8/20 | b | +1.00 | [-1.99, +3.99] | +5.0 % | 1 / 2 |",
        "| 8/20 | c | +0.00 | [+0.00, +0.00] | +0.0 % | 0 / 0 |",
    ]



def test_the_noise_control_is_hocf_at_share_0_and_deviates_in_its_share_of_decisions():
    import numpy as np

    from tsac_bench.model.generator import generate
    from tsac_bench.planning.solve import solve

    instance = generate("8/20", 2)
    assert tsac_eval.footing(tsac_eval.NoiseControl(0.1), {}) == "empty, 1"
    assert (solve(instance, tsac_eval.NoiseControl(0.0), mode="dynamic").cost
            == solve(instance, "hocf", mode="dynamic").cost)

    class Hocf:  # stands in for HOCF's rule: always the first candidate, calls counted
        calls = 0

        def select(self, view, rng):
            self.calls += 1
            return view.candidates[0]

    class View:
        candidates = (3, 5, 8)

    hocf, rng = Hocf(), np.random.default_rng(0)
    rule = tsac_eval.RandomDeviation(hocf, 0.25)
    chosen = [rule.select(View(), rng) for _ in range(2000)]
    deviations = 2000 - hocf.calls
    assert 2000 * 0.25 - 60 < deviations < 2000 * 0.25 + 60  # 3 standard deviations
    # A deviation draws uniformly, HOCF's own choice included.
    assert abs(chosen.count(5) - deviations / 3) < 45 and set(chosen) == {3, 5, 8}


def test_ablation_and_temperature_rows_sample_an_actor_and_row_specs_run_as_given():
    rows = tsac_eval.variants(None, ["old=old.pt"], incumbent=False, temperatures=True,
                              baselines=("hocf",), specs=("margin 1=tsac-ocf:margin=1",))
    assert rows == [
        ("hocf", "hocf", {}),
        ("tsac-ocf", "tsac-ocf", {}),
        ("tsac-ocf T=0.5", "tsac-ocf", {"decode": "sample", "temperature": 0.5}),
        ("tsac-ocf T=0 (argmax)", "tsac-ocf", {"decode": "sample", "temperature": 0.0}),
        ("old", "tsac-ocf", {"policy": "old.pt", "decode": "sample"}),
        ("margin 1", "tsac-ocf:margin=1", {}),
    ]


@pytest.mark.skipif(not hasattr(os, "sched_getaffinity") or len(os.sched_getaffinity(0)) < 2,
                    reason="worker processes are pinned to a core each")
def test_worker_processes_give_the_runs_of_one_process_in_order() -> None:
    from tsac_bench.model.generator import generate
    from tsac_bench.planning.solve import solve

    instances = [generate("4/10", seed) for seed in (3, 4)]
    calls = list(zip(*[("hocf", instance, "hocf", {}) for instance in instances] + [
        ("noise", instance, tsac_eval.NoiseControl(0.5), {}) for instance in instances],
        strict=True))
    in_process, _ = tsac_eval.runner(1)
    in_workers, close = tsac_eval.runner(2)
    try:
        here = list(in_process(tsac_eval.dynamic_run, *calls))
        there = list(in_workers(tsac_eval.dynamic_run, *calls))
    finally:
        close()
    assert [cost for cost, *_ in there] == [cost for cost, *_ in here]
    assert here[0][0] == solve(instances[0], "hocf", mode="dynamic").cost
    assert here[0][0] != here[1][0]  # the order of the calls is kept
    assert all(0 < longest <= wall for _, wall, longest, _ in here + there)
    assert all(stops == 0 for *_, stops in here)
