"""The reproduction script's own tables (benchmarks/paper_reproduction.py), on hand-made data."""

from __future__ import annotations

import sys
from pathlib import Path

import pytest

pd = pytest.importorskip("pandas")
sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "benchmarks"))
import paper_reproduction  # noqa: E402


def rows(values: dict[tuple[str, str], list[float]]) -> pd.DataFrame:
    return pd.DataFrame([{"mode": "dynamic", "scale": scale, "instance": f"i{k}",
                          "method": method, "J": J}
                         for (scale, method), costs in values.items()
                         for k, J in enumerate(costs)])


def test_before_and_after_means_changes_and_ranks(tmp_path: Path) -> None:
    before = tmp_path / "before.csv"
    rows({("4/10", "a"): [10.0, 20.0], ("4/10", "b"): [12.0, 12.0]}).to_csv(before, index=False)
    # "b" has a third instance that "before" lacks: only instances both ran count.
    after = rows({("4/10", "a"): [11.0, 22.0], ("4/10", "b"): [9.0, 10.0, 100.0]})
    lines = paper_reproduction.before_and_after(before, after)
    assert "| 4/10 | b | 12.00 | 9.50 | -20.83% | 1 | 1 |" in lines
    assert "| 4/10 | a | 15.00 | 16.50 | 10.00% | 2 | 2 |" in lines


def test_a_missing_bound_prints_as_no_bound() -> None:
    assert paper_reproduction.percent(float("nan")) == "no bound"
    assert paper_reproduction.percent(0.1234) == "12.3%"
