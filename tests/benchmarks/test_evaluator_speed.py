"""The evaluator-speed page (benchmarks/evaluator_speed.py), with each timing made of one
call: the page has a row per instance with the plan's visits."""

from __future__ import annotations

import sys
from pathlib import Path

import pytest

sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "benchmarks"))
import evaluator_speed

from tsac_bench.model.generator import generate
from tsac_bench.planning.solve import solve


def test_the_page_has_one_row_per_instance(tmp_path: Path,
                                           monkeypatch: pytest.MonkeyPatch) -> None:
    calls = []

    def once(call, repeat: int = 7, number: int = 200) -> float:
        calls.append(call())
        return 1e-4

    monkeypatch.setattr(evaluator_speed, "median_seconds", once)
    out = tmp_path / "speed.md"
    monkeypatch.setattr(sys, "argv", ["evaluator_speed.py", "--instances", "1",
                                      "--out", str(out)])
    evaluator_speed.main()
    routes = solve(generate("32/80", 0), "greedy").solution.routes
    rows = [line for line in out.read_text().splitlines() if line.startswith("| 0 |")]
    assert len(rows) == 1
    assert rows[0].split("|")[2].strip() == str(sum(len(r) for r in routes))
    assert len(calls) == 3
    assert "Median: full 100 us" in out.read_text()
