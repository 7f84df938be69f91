"""The TSAC evaluation's paired table (benchmarks/tsac_eval.py), on hand-made costs."""

from __future__ import annotations

import sys
from pathlib import Path

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
