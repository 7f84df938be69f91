"""Small instances for the solver tests, edge cases included, built from the paper's types."""

from pathlib import Path

from tsac_bench.model import AAV, Depot, Instance, Task, TaskKind
from tsac_bench.model.generator import AAV_TYPES
from tsac_bench.model.io import read_instance

ROOT = Path(__file__).parents[2]


def aav(name: str, kind: int, x: float = 0.0, y: float = 0.0) -> AAV:
    return AAV(name, kind, x, y, **AAV_TYPES[kind])  # type: ignore[arg-type]


def task(name: str, x: float, y: float, demand: int = 10, window=(0.0, 3000.0),
         release: float = 0.0, kind: str = "D") -> Task:
    return Task(name, x, y, TaskKind(kind), demand, window[0], window[1], release)


DEPOTS = (Depot("D0", 0.0, 0.0), Depot("D1", 3000.0, 0.0))
FLEET = (aav("A0", 1), aav("A1", 2, 3000.0, 0.0))


def edge_cases() -> dict[str, Instance]:
    """name -> instance; each stresses one corner of the model."""
    return {
        "no-tasks": Instance("no-tasks", FLEET, DEPOTS, ()),
        "one-aav": Instance("one-aav", FLEET[:1], DEPOTS, (
            task("T0", 1000, 1000, 10), task("T1", -1000, 2000, 20, kind="P"),
            task("T2", 2000, -1500, 5, window=(300, 2000)))),
        # T1 lies 7 km from every depot but closes 10 s after t = 0.
        "unreachable": Instance("unreachable", FLEET, DEPOTS, (
            task("T0", 1500, 1000, 10), task("T1", 5000, 5000, 5, window=(0, 10)))),
        # 500 kg against a fleet of 30 + 10 kg, and a task visited at most once per AAV.
        "over-demand": Instance("over-demand", FLEET, DEPOTS, (
            task("T0", 1500, 1500, 500, kind="P"), task("T1", -500, 800, 10))),
        "all-late": Instance("all-late", FLEET, DEPOTS, (
            task("T0", 1000, 1000, 10, window=(200, 2000), release=200),
            task("T1", 2000, -1000, 10, window=(400, 2400), release=400, kind="P"),
            task("T2", -1500, 500, 20, window=(400, 3000), release=400))),
    }


def quick(name: str) -> Instance:
    """One of instances/quick (e.g. "quick-2-4-s1")."""
    return read_instance(ROOT / "instances" / "quick" / f"{name}.json")


def paper_x20() -> Instance:
    return read_instance(ROOT / "instances" / "paper" / "paper-small-x20.json")
