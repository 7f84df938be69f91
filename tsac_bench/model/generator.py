"""The paper's scenario family (Sec. IV-A): random instances, deterministic per seed.

Every distribution is a keyword of ``ScenarioGenerator`` and is written down in
docs/model.md ("Generated instances"). Defaults reproduce the paper's setting: TABLE 1 AAV
types, a 10 km x 10 km area centred at 0, horizon 3600 s, weights (100, 10, 1).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from tsac_bench.model import AAV, Depot, Instance, Task, TaskKind

#: TABLE 1 of the paper: type -> speed (m/s), capacity (kg), range (m), alpha, lam.
AAV_TYPES: dict[int, dict[str, float | int]] = {
    1: {"speed": 10.0, "capacity": 30, "max_range": 60_000.0, "alpha": 20.0, "lam": 2000.0},
    2: {"speed": 20.0, "capacity": 10, "max_range": 30_000.0, "alpha": 10.0, "lam": 500.0},
}

#: The paper's four Monte Carlo scales, AAVs/tasks.
PAPER_SCALES = ("4/10", "8/20", "16/40", "32/80")


def parse_scale(text: str) -> tuple[int, int]:
    """``"16/40"`` -> (16, 40)."""
    try:
        n, m = (int(part) for part in text.split("/"))
    except ValueError:
        raise ValueError(f"scale must look like N/M (AAVs/tasks), got {text!r}") from None
    if n < 1 or m < 0:
        raise ValueError(f"scale needs at least one AAV and no negative task count: {text!r}")
    return n, m


@dataclass(frozen=True)
class ScenarioGenerator:
    """Random instances of the paper's family.

    * Depots: ``n_depots`` (default ``max(2, N // 4)``), uniform in the area.
    * AAVs: ``ceil(N * heavy_share)`` of type 1, the rest type 2 (TABLE 2 has 1 of 4);
      AAV i starts at depot ``i mod K`` (Eq. 11: routes start at a depot).
    * Tasks: uniform in the area, pickup with probability ``pickup_share``; demand drawn
      from ``demand_levels`` with ``demand_weights``.
    * Releases: ``dynamic_share`` of the tasks are released at one of ``n_events`` event times,
      uniform in ``event_window`` (fractions of the horizon); the rest at 0.
    * Windows: t_start = release + U{0..start_delay} s; length U[window_min, window_max] s,
      stretched where needed so that the fastest AAV type can reach the task from its nearest
      depot after the release with ``reach_slack`` seconds to spare, capped at the horizon.
    Coordinates and times are integers (metres, seconds).
    """

    area: float = 10_000.0
    horizon: float = 3600.0
    weights: tuple[float, float, float] = (100.0, 10.0, 1.0)
    n_depots: int | None = None
    heavy_share: float = 0.25
    pickup_share: float = 0.5
    demand_levels: tuple[int, ...] = (5, 10, 20, 30, 40, 60)
    demand_weights: tuple[float, ...] = (0.2, 0.3, 0.2, 0.1, 0.1, 0.1)
    dynamic_share: float = 0.5
    n_events: int = 2
    event_window: tuple[float, float] = (0.05, 0.5)
    start_delay: int = 300
    window_min: float = 900.0
    window_max: float = 2400.0
    reach_slack: float = 60.0

    def generate(self, n_aavs: int, n_tasks: int, seed: int, name: str | None = None) -> Instance:
        rng = np.random.default_rng(seed)
        half = self.area / 2

        def point() -> tuple[float, float]:
            x, y = rng.integers(-int(half), int(half), size=2, endpoint=True)
            return float(x), float(y)

        k = self.n_depots if self.n_depots is not None else max(2, n_aavs // 4)
        depots = tuple(Depot(f"D{i}", *point()) for i in range(k))
        n_heavy = math.ceil(n_aavs * self.heavy_share)
        aavs = tuple(
            AAV(f"A{i}", kind, depots[i % k].x, depots[i % k].y, **AAV_TYPES[kind])  # type: ignore[arg-type]
            for i, kind in enumerate([1] * n_heavy + [2] * (n_aavs - n_heavy))
        )
        events = np.sort(rng.uniform(*self.event_window, size=self.n_events) * self.horizon)
        events = np.round(events)
        fastest = max(t["speed"] for t in AAV_TYPES.values())
        probabilities = np.asarray(self.demand_weights) / sum(self.demand_weights)
        tasks = []
        for i in range(n_tasks):
            x, y = point()
            kind = TaskKind.PICKUP if rng.random() < self.pickup_share else TaskKind.DELIVERY
            demand = int(rng.choice(self.demand_levels, p=probabilities))
            dynamic = self.n_events > 0 and rng.random() < self.dynamic_share
            release = float(rng.choice(events)) if dynamic else 0.0
            t_start = release + float(rng.integers(0, self.start_delay, endpoint=True))
            reach = min(math.hypot(x - d.x, y - d.y) for d in depots) / fastest
            length = max(float(np.round(rng.uniform(self.window_min, self.window_max))),
                         math.ceil(release + reach + self.reach_slack - t_start))
            t_end = t_start + min(length, self.horizon)
            tasks.append(Task(f"T{i}", x, y, kind, demand, t_start, t_end, release))
        return Instance(
            name=name or f"gen-{n_aavs}-{n_tasks}-s{seed}",
            aavs=aavs, depots=depots, tasks=tuple(tasks),
            horizon=self.horizon, weights=self.weights, seed=seed,
            meta={"generator": "tsac_bench.model.generator.ScenarioGenerator", "scale":
                  f"{n_aavs}/{n_tasks}", "depots": k},
        )


def generate(scale: str, seed: int, **settings: object) -> Instance:
    n, m = parse_scale(scale)
    return ScenarioGenerator(**settings).generate(n, m, seed)  # type: ignore[arg-type]
