"""Small builders shared by the tests (imported by module name: tests/ is on sys.path)."""

from tsac_bench.model import Instance, Solution


def plan(instance: Instance, **routes: list) -> Solution:
    """``plan(hand, A0=[("T0", 5), "D0"])``: a solution from ids, other AAVs idle."""
    return Solution.from_ids(instance, routes)
