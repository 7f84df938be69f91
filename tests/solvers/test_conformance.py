"""Every registered method obeys the allocator contract (docs/plugins.md), through the checks
the package ships (tsac_bench.testing), as a plug-in's own suite runs them.

Parametrized over ``available_methods()``, so a method registered later (built-in or
plug-in) is checked without touching this file. Plans are checked on the paper's small
scenario as well as on a generated instance with releases.
"""

import pytest
from solver_cases import paper_x20, quick

from tsac_bench.planning import available_methods
from tsac_bench.testing import allocator_checks

INSTANCES = {"quick-3-6-s3": quick("quick-3-6-s3"), "paper-small-x20": paper_x20()}
CHECKS = [check for method in available_methods()
          for check in allocator_checks(method, instances=INSTANCES)]


@pytest.mark.parametrize("check", CHECKS, ids=str)
def test_conformance(check):
    check()


def test_a_failed_check_names_the_method_and_the_check():
    from tsac_bench.planning import PlanResult, Settings
    from tsac_bench.testing import check_allocator

    class Wanderer(Settings):
        """Claims a J of its own that the evaluator does not confirm."""

        name = "wanderer"

        def __init__(self) -> None:
            pass

        def plan(self, state, *, seed=0, time_limit=None):
            return PlanResult(state.base_routes(), cost=-1.0)

    with pytest.raises(AssertionError, match=r"wanderer:feasible-and-scored\[quick-3-6-s3-static"
                                             r"\]: the method claims J = -1.0"):
        check_allocator(Wanderer(), instances={"quick-3-6-s3": INSTANCES["quick-3-6-s3"]})
