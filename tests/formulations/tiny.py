"""Random tiny instances for the cross-checks: a few AAVs and tasks in a 3 km square, small
capacities and demands (so that splits, multi-trip routes and capacity limits matter), windows
that some routes miss, and, when ``tight_range``, ranges short enough to be exceeded."""

from __future__ import annotations

import numpy as np

from tsac_bench.model import AAV, Depot, Instance, Task, TaskKind

#: Two AAV types: slow and roomy, fast and small (the paper's TABLE 1 in miniature).
TINY_TYPES = (
    {"speed": 10.0, "capacity": 4, "alpha": 20.0, "lam": 200.0},
    {"speed": 20.0, "capacity": 2, "alpha": 10.0, "lam": 50.0},
)


def tiny_instance(seed: int, n_aavs: int = 2, n_tasks: int = 3, n_depots: int | None = None,
                  tight_range: bool | None = None, max_demand: int = 4,
                  releases: bool = False) -> Instance:
    rng = np.random.default_rng(seed)
    k = int(n_depots if n_depots is not None else rng.integers(1, 3))
    tight = bool(rng.random() < 0.5) if tight_range is None else tight_range

    def point() -> tuple[float, float]:
        x, y = rng.integers(-1500, 1500, size=2, endpoint=True)
        return float(x), float(y)

    depots = tuple(Depot(f"D{i}", *point()) for i in range(k))
    aavs = []
    for i in range(n_aavs):
        kind = int(rng.integers(0, 2))
        reach = float(rng.integers(2000, 6000)) if tight else 100_000.0
        where = (depots[i % k].x, depots[i % k].y) if rng.random() < 0.8 else point()
        aavs.append(AAV(f"A{i}", kind + 1, *where, max_range=reach, **TINY_TYPES[kind]))
    tasks = []
    for j in range(n_tasks):
        kind = TaskKind.PICKUP if rng.random() < 0.5 else TaskKind.DELIVERY
        demand = int(rng.integers(1, max_demand, endpoint=True))
        t_start = float(rng.integers(0, 300))
        t_end = t_start + float(rng.integers(150, 700))
        release = float(rng.integers(0, int(t_start) + 1)) if releases and rng.random() < 0.5 \
            else 0.0
        tasks.append(Task(f"T{j}", *point(), kind, demand, t_start, t_end, release))
    return Instance(f"tiny-s{seed}", tuple(aavs), depots, tuple(tasks), horizon=1000.0,
                    seed=seed)
