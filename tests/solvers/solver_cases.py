"""Instances of the project's files for the solver tests; the built ones (edge cases, the
paper's AAV types) come from the package's conformance kit."""

from pathlib import Path

from tsac_bench.model import Instance
from tsac_bench.model.io import read_instance
from tsac_bench.testing import DEPOTS, FLEET, aav, edge_cases, task

__all__ = ["DEPOTS", "FLEET", "aav", "edge_cases", "paper_x20", "quick", "task"]

ROOT = Path(__file__).parents[2]


def quick(name: str) -> Instance:
    """One of instances/quick (e.g. "quick-2-4-s1")."""
    return read_instance(ROOT / "instances" / "quick" / f"{name}.json")


def paper_x20() -> Instance:
    return read_instance(ROOT / "instances" / "paper" / "paper-small-x20.json")
