"""The one manifest reader: lenient for a batch run (problems listed, good entries kept),
strict for verify (the first problem is the one-line error)."""

import json

import pytest

from tsac_bench.batch.manifests import Reference, read_manifest
from tsac_bench.errors import InputError

GOOD = {"file": "a.json", "J_star": 1.5, "lower_bound": 1.5, "status": "optimal"}


def write(tmp_path, instances) -> None:
    (tmp_path / "manifest.json").write_text(
        json.dumps({"format": "tsac-bench/manifest@1", "instances": instances}))


@pytest.mark.parametrize("bad", [float("nan"), float("inf"), -float("inf"), "1.5", True])
def test_a_bound_that_is_not_a_finite_number_is_one_problem_and_the_rest_reads(tmp_path, bad):
    write(tmp_path, {"a": GOOD, "b": {**GOOD, "file": "b.json", "lower_bound": bad}})
    manifest = read_manifest(tmp_path)
    assert manifest.references() == {"a": Reference(1.5, 1.5, "manifest")}
    assert manifest.problem_lines() == [
        f"{tmp_path / 'manifest.json'}: instances.b.lower_bound: expected a finite number or "
        f"null, got {bad!r}"]
    with pytest.raises(InputError, match=r"instances\.b\.lower_bound"):
        manifest.require_valid()


def test_an_absent_manifest_has_no_references_and_is_an_error_only_when_required(tmp_path):
    manifest = read_manifest(tmp_path)
    assert manifest.references() == {}
    with pytest.raises(InputError, match="no manifest in this directory"):
        manifest.require_valid()
