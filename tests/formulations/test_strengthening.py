"""The strengthening of the MILP (docs/formulations.md): valid for every plan, and it raises
the LP relaxation's bound where the issue says the plain model is weak."""

from __future__ import annotations

import itertools

import pytest

from tsac_bench.formulations.network import coalition_cover_cuts
from tsac_bench.model.generator import generate

pyo = pytest.importorskip("pyomo.environ")


def test_cover_cuts_of_a_task_that_needs_the_large_aav() -> None:
    # 40 kg; one AAV brings up to 30, three bring 10 each: without AAV 0 at most 30 kg come,
    # and with it each of its kilograms beyond those 30 is one of the last 10.
    cuts = coalition_cover_cuts({0: 30, 1: 10, 2: 10, 3: 10}, 40)
    assert (30, {0: 10}) in cuts
    assert (10, {0: 30, 1: 10, 2: 10}) in cuts
    assert all(rest < 40 for rest, _ in cuts)
    assert not any(coef == {1: 10} for _, coef in cuts)  # 50 kg come without AAV 1


@pytest.mark.parametrize(("upper", "demand"), [({0: 3, 1: 2, 2: 2}, 5), ({0: 4, 1: 4}, 6),
                                               ({0: 1, 1: 3, 2: 2, 3: 2}, 7)])
def test_cover_cuts_hold_for_every_coalition(upper: dict[int, int], demand: int) -> None:
    cuts = coalition_cover_cuts(upper, demand)
    assert cuts
    for amounts in itertools.product(*(range(upper[n] + 1) for n in sorted(upper))):
        covered = min(sum(amounts), demand)
        for rest, coef in cuts:
            assert covered <= rest + sum(c * (amounts[n] > 0) for n, c in coef.items())


def _lp_bound(instance, **options) -> float:
    from tsac_bench.formulations.milp import MilpOptions, build_milp, solve_milp

    model = build_milp(instance, options=MilpOptions(**options))
    pyo.TransformationFactory("core.relax_integer_vars").apply_to(model)
    report = solve_milp(model)
    assert report.status == "optimal"
    return report.objective


def test_time_flow_and_cover_cuts_raise_the_lp_bound() -> None:
    # Measured: plain 1.679, time flow 3.224, both 4.904 (J* = 9.8012, exact-scaling.md).
    instance = generate("3/8", 3)
    plain = _lp_bound(instance, time_flow=False, cover_cuts=False)
    flow = _lp_bound(instance, cover_cuts=False)
    both = _lp_bound(instance)
    assert plain == pytest.approx(1.679, abs=1e-3)
    assert flow == pytest.approx(3.224, abs=1e-3)
    assert both == pytest.approx(4.904, abs=1e-3)
    assert both <= 9.8012
