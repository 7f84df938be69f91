"""The root-bound table of reports/exact-bp-root.md (benchmarks/exact_bp_root.py), on one
regression instance: every LP bound is at most J*, and each row family of the route master
(and each strengthening of the MILP) raises the bound or leaves it."""

from __future__ import annotations

import json
import shutil
import sys
from itertools import pairwise
from pathlib import Path

import pytest

sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "benchmarks"))
pytest.importorskip("pyomo")
pytest.importorskip("numba")
import exact_bp_root

NAME = "reg-static-2-4-s2"


def test_one_instance_row_is_ordered_and_below_the_optimum(tmp_path: Path,
                                                           monkeypatch: pytest.MonkeyPatch
                                                           ) -> None:
    regression = Path(__file__).resolve().parents[2] / "instances" / "regression"
    entry = json.loads((regression / "manifest.json").read_text())["instances"][NAME]
    shutil.copy(regression / entry["file"], tmp_path)
    (tmp_path / "manifest.json").write_text(json.dumps({"instances": {NAME: entry}}))
    monkeypatch.setattr(exact_bp_root, "REGRESSION", tmp_path)
    out = tmp_path / "root.md"
    exact_bp_root.main(["--sizes", "2-4", "--out", str(out)])
    rows = [line for line in out.read_text().splitlines() if line.startswith(f"| {NAME} ")]
    assert len(rows) == 1
    cells = [cell.strip() for cell in rows[0].strip("|").split("|")]
    assert float(cells[1]) == pytest.approx(entry["J_star"], abs=5e-5)
    milp, master = [float(c) for c in cells[2:5]], [float(c) for c in cells[5:10]]
    tolerance = 0.05  # the table's shares are rounded to 0.1 %
    assert all(share <= 100.0 + tolerance for share in milp + master)
    for lower, higher in (*pairwise(milp), *pairwise(master)):
        assert lower <= higher + tolerance, (milp, master)
