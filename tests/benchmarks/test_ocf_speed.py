"""The OCF speed page (benchmarks/ocf_speed.py) on one small instance: every variant has its
J and wall time, and greedy's J is the one `solve` gives."""

from __future__ import annotations

import os
import sys
from pathlib import Path

import pytest

sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "benchmarks"))
pytest.importorskip("torch")  # tsac-ocf is one of the variants
import ocf_speed

from tsac_bench.model.generator import generate
from tsac_bench.planning.solve import solve


def test_the_page_has_every_variant_of_one_instance(tmp_path: Path,
                                                    monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(ocf_speed, "SCALES", ("4/10",))
    # The tool pins its process to one core; the test process stays as it was.
    monkeypatch.setattr(os, "sched_setaffinity", lambda pid, cpus: None, raising=False)
    out = tmp_path / "ocf.md"
    monkeypatch.setattr(sys, "argv", ["ocf_speed.py", "--instances", "1", "--first-seed", "7",
                                      "--out", str(out)])
    ocf_speed.main()
    text = out.read_text()
    row = next(line for line in text.splitlines() if line.startswith("| 7 |"))
    cells = [cell.strip() for cell in row.strip("|").split("|")][1:]
    assert len(cells) == len(ocf_speed.VARIANTS)
    greedy = solve(generate("4/10", 7), "greedy", seed=0).cost
    assert cells[0].startswith(f"{greedy:.2f} (")
    summary = [line for line in text.splitlines() if line.startswith("| 4/10 | ")]
    assert [line.split("|")[2].strip() for line in summary] == [v[0] for v in ocf_speed.VARIANTS]
