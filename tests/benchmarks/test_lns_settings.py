"""The table of reports/lns-settings.md (benchmarks/lns_settings.py) on one small validation
instance: every setting starts from the same plan, none ends above it, and each search ends
with the whole fleet's neighbourhood proved, so at the same J; the page names no machine
path."""

from __future__ import annotations

import sys
from pathlib import Path

import pytest

sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "benchmarks"))
pytest.importorskip("numba")
pytest.importorskip("highspy")
import lns_settings


def test_every_setting_starts_alike_and_ends_at_the_proved_fleet(tmp_path: Path) -> None:
    out = tmp_path / "lns.md"
    lns_settings.main(["--sizes", "3/6:1:30", "--settings", "1/1/5", "2/2/5", "1/1/5/excess",
                       "--time-limit", "60", "--start-seconds", "1", "--out", str(out)])
    text = out.read_text()
    rows = [[cell.strip() for cell in line.strip("|").split("|")]
            for line in text.splitlines() if line.startswith("| 3/6 seed ")]
    assert [row[1] for row in rows] == ["1/1/5", "2/2/5", "1/1/5/excess"]
    starts, ends = {row[2] for row in rows}, {row[3] for row in rows}
    assert len(starts) == 1 and len(ends) == 1
    assert float(ends.pop()) <= float(starts.pop())
    assert all(row[8] == "3" for row in rows)  # grown to the whole fleet of three
    assert "| 3/6 | 30 | 1/1/5 |" in text and "| 1 of 1 |" in text  # 30 s: the size's own
    assert "DGA's plan (after 1 s, seed 0)" in text
    assert str(tmp_path) not in text
