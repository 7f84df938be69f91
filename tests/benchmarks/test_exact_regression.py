"""The regression-set tool (benchmarks/exact_regression.py): ``make`` writes the committed
instances, and ``prove`` records an optimum that the committed manifest agrees with."""

from __future__ import annotations

import json
import shutil
import sys
from pathlib import Path

import pytest

sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "benchmarks"))
import exact_regression

REGRESSION = Path(__file__).resolve().parents[2] / "instances" / "regression"


def without_generator_name(file: Path) -> dict:
    # The committed files name the generator by its module path before the package's
    # layers (tsac_bench.generator); the instance itself must be the same.
    data = json.loads(file.read_text())
    data["meta"].pop("generator")
    return data


def test_make_writes_the_committed_instances(tmp_path: Path) -> None:
    exact_regression.main(["make", "--out", str(tmp_path)])
    made = sorted(p.name for p in tmp_path.glob("*.json"))
    committed = sorted(p.name for p in REGRESSION.glob("*.json") if p.name != "manifest.json")
    assert made == committed
    for name in made:
        assert without_generator_name(tmp_path / name) == without_generator_name(
            REGRESSION / name), name


def test_prove_records_the_committed_optimum_of_a_small_instance(tmp_path: Path) -> None:
    pytest.importorskip("pyomo")
    name = "reg-static-2-4-s1"
    shutil.copy(REGRESSION / f"{name}.json", tmp_path)
    exact_regression.main(["prove", str(tmp_path), "--time-limit", "60", "--methods", "exact"])
    entry = json.loads((tmp_path / "manifest.json").read_text())["instances"][name]
    committed = json.loads((REGRESSION / "manifest.json").read_text())["instances"][name]
    assert entry["status"] == "optimal"
    assert entry["J_star"] == pytest.approx(committed["J_star"], rel=1e-6)
