"""PlanResult's typed claims (status, lower bound) and the one form records keep them in."""

import pytest

from tsac_bench.errors import TsacBenchError
from tsac_bench.planning import PlanResult, PlanStatus, mip_gap, recorded_claim

ROUTES = ((), ())


def test_a_status_given_as_text_is_typed_and_recorded_under_the_stores_keys():
    result = PlanResult(ROUTES, {"nodes": 3}, status="feasible", lower_bound=8)
    assert result.status is PlanStatus.FEASIBLE and result.lower_bound == 8.0
    recorded = result.recorded_stats()
    assert recorded == {"nodes": 3, "status": "feasible", "lower_bound": 8.0}
    assert recorded_claim(recorded) == (PlanStatus.FEASIBLE, 8.0)


def test_a_heuristic_claims_nothing_and_records_its_stats_as_they_are():
    result = PlanResult(ROUTES, {"stop": "stable"})
    assert (result.status, result.lower_bound) == (None, None)
    assert result.recorded_stats() == {"stop": "stable"}
    assert recorded_claim(result.recorded_stats()) == (None, None)


def test_a_solvers_report_gives_the_typed_fields():
    report = {"status": "optimal", "lower_bound": 4.5, "mip_gap": 0.0, "solver": "highs"}
    result = PlanResult.from_solver([(), ()], report)
    assert result.routes == ROUTES
    assert (result.status, result.lower_bound) == (PlanStatus.OPTIMAL, 4.5)
    assert result.stats == {"mip_gap": 0.0, "solver": "highs"}
    assert result.recorded_stats() == report


@pytest.mark.parametrize(("kwargs", "message"), [
    ({"status": "proven"}, "PlanResult.status 'proven': expected one of optimal, feasible, "
                           "no-solution, error"),
    ({"stats": {"status": "optimal"}}, "PlanResult.stats holds status: pass PlanResult(..., "
                                       "status=, lower_bound=) instead"),
    ({"lower_bound": float("-inf")}, "PlanResult.lower_bound -inf: expected a finite number, "
                                     "or None for no bound"),
])
def test_a_claim_outside_the_contract_is_one_line(kwargs, message):
    with pytest.raises(TsacBenchError) as error:
        PlanResult(ROUTES, **kwargs)
    assert str(error.value) == message


def test_a_record_read_back_keeps_only_what_is_a_claim():
    # Stores written by an older plug-in may hold anything under these keys.
    assert recorded_claim({"status": "stable", "lower_bound": "n/a"}) == (None, None)
    assert recorded_claim({"status": "no-solution", "lower_bound": True}) == (
        PlanStatus.NO_SOLUTION, None)
    assert recorded_claim(None) == (None, None)


def test_the_gap_is_relative_to_J():
    assert mip_gap(10.0, 8.0) == pytest.approx(0.2, rel=1e-15)
    assert mip_gap(10.0, 12.0) == 0.0
