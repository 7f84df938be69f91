"""The table of reports/exact-bp-completion.md (benchmarks/exact_bp_completion.py), on one
small validation instance: every setting converges to the same root LP, whose column
count is the same (the completion bounds drop no column), and the page names no machine
path."""

from __future__ import annotations

import sys
from pathlib import Path

import pytest

sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "benchmarks"))
pytest.importorskip("numba")
pytest.importorskip("highspy")
import exact_bp_completion


def test_each_setting_gives_the_same_converged_root(tmp_path: Path) -> None:
    out = tmp_path / "completion.md"
    exact_bp_completion.main(["--sizes", "2/4:2", "--steps", "0", "64", "--out", str(out)])
    text = out.read_text()
    rows = [[cell.strip() for cell in line.strip("|").split("|")]
            for line in text.splitlines() if line.startswith("| 2/4 seed ")]
    assert [row[1] for row in rows] == ["off", "64", "off", "64"]
    for off, on in (rows[0:2], rows[2:4]):
        assert off[0] == on[0]
        assert on[4] == off[4] == "yes"
        assert float(on[2]) == pytest.approx(float(off[2]), rel=1e-9)
        assert on[5] == off[5]  # the same columns
    assert str(tmp_path) not in text
