"""The manifest rule of tsac_bench/batch/verify.py: J* needs a prover and no disagreement."""

from __future__ import annotations

from tsac_bench.batch.verify import entry_from


def record(status: str, J: float, bound: float | None) -> dict:
    return {"status": status, "J": J, "lower_bound": bound}


def test_one_prover_is_enough_when_the_others_agree() -> None:
    entry = entry_from({"exact-bp": record("optimal", 10.0, 10.0),
                        "exact": record("feasible", 12.0, 6.0),
                        "exact-cpsat": record("feasible", 10.0, None)}, "a.json", "cmd")
    assert entry["status"] == "optimal"
    assert entry["J_star"] == 10.0 and entry["lower_bound"] == 10.0
    assert entry["proved_by"] == ["exact-bp"]
    assert entry["mip_gap"] == 0.0


def test_a_backend_below_the_claimed_optimum_is_a_conflict() -> None:
    # exact found a plan cheaper than exact-bp's "optimum": one of them is wrong.
    entry = entry_from({"exact-bp": record("optimal", 10.0, 10.0),
                        "exact": record("feasible", 9.5, 6.0)}, "a.json", "cmd")
    assert entry["status"] == "conflict"
    assert entry["J_star"] is None and entry["proved_by"] == []
    assert entry["lower_bound"] == 9.5  # min(best J, best bound)


def test_a_bound_above_the_claimed_optimum_is_a_conflict() -> None:
    entry = entry_from({"exact-bp": record("optimal", 10.0, 10.0),
                        "exact": record("feasible", 11.0, 10.5)}, "a.json", "cmd")
    assert entry["status"] == "conflict"


def test_two_provers_that_differ_are_a_conflict_and_none_leaves_a_bound() -> None:
    assert entry_from({"exact": record("optimal", 10.0, 10.0),
                       "exact-cpsat": record("optimal", 10.5, 10.5)}, "a.json",
                      "cmd")["status"] == "conflict"
    open_entry = entry_from({"exact": record("feasible", 12.0, 9.0),
                             "exact-cpsat": record("feasible", 11.0, 8.0)}, "a.json", "cmd")
    assert open_entry["status"] == "feasible" and open_entry["J_star"] is None
    assert open_entry["lower_bound"] == 9.0 and open_entry["best_J"] == 11.0
    assert abs(open_entry["mip_gap"] - 2.0 / 11.0) < 1e-12
