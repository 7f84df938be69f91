"""Immutable problem data: AAVs, depots, tasks and the instance that binds them.

Every node of the instance has an integer index so that routes and the evaluator work on
plain ints: tasks are ``0 .. M-1``, depots ``M .. M+K-1`` and the AAVs' start positions
``M+K .. M+K+N-1``. ``Instance.dist`` holds the Euclidean distance between every pair.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, field
from enum import StrEnum
from functools import cached_property
from types import MappingProxyType

import numpy as np

from tsac_bench.errors import ModelError

#: Arrival times are sums of float legs; a visit counts as on time up to this slack (s)
#: so that an exact solver's arrival exactly at t_end is not lost to rounding.
TIME_TOLERANCE = 1e-6


class TaskKind(StrEnum):
    PICKUP = "P"
    DELIVERY = "D"


@dataclass(frozen=True, slots=True)
class AAV:
    id: str
    type: int
    x: float
    y: float
    speed: float  # m/s
    capacity: int  # kg
    max_range: float  # m
    alpha: float  # cost per km flown
    lam: float  # intrinsic value, charged once when the range is exceeded

    @property
    def full_range_cost(self) -> float:
        """alpha * D[km] + lam: the cost of a task visit made beyond the range (Eq. 9)."""
        return self.alpha * self.max_range / 1000.0 + self.lam


@dataclass(frozen=True, slots=True)
class Depot:
    id: str
    x: float
    y: float


@dataclass(frozen=True, slots=True)
class Task:
    id: str
    x: float
    y: float
    kind: TaskKind
    demand: int  # kg
    t_start: float  # s
    t_end: float  # s
    release: float = 0.0  # s, when the task becomes known

    @property
    def is_delivery(self) -> bool:
        return self.kind is TaskKind.DELIVERY

    @property
    def latest_on_time(self) -> float:
        """The latest arrival that counts as on time (t_end up to TIME_TOLERANCE): the one
        statement of the on-time rule, which every method and model reads from here."""
        return self.t_end + TIME_TOLERANCE

    def on_time(self, arrival: float) -> bool:
        return arrival <= self.latest_on_time


DEFAULT_HORIZON = 3600.0
DEFAULT_WEIGHTS = (100.0, 10.0, 1.0)


@dataclass(frozen=True)
class Instance:
    name: str
    aavs: tuple[AAV, ...]
    depots: tuple[Depot, ...]
    tasks: tuple[Task, ...]
    horizon: float = DEFAULT_HORIZON
    weights: tuple[float, float, float] = DEFAULT_WEIGHTS
    seed: int | None = None
    meta: Mapping[str, object] = field(default_factory=dict)

    def __post_init__(self) -> None:
        object.__setattr__(self, "aavs", tuple(self.aavs))
        object.__setattr__(self, "depots", tuple(self.depots))
        object.__setattr__(self, "tasks", tuple(self.tasks))
        object.__setattr__(self, "weights", tuple(float(w) for w in self.weights))
        object.__setattr__(self, "meta", MappingProxyType(dict(self.meta)))
        validate_instance(self)

    def __reduce__(self) -> tuple:
        # mappingproxy does not pickle; worker processes and Dask need instances to.
        return (type(self), (self.name, self.aavs, self.depots, self.tasks, self.horizon,
                             self.weights, self.seed, dict(self.meta)))

    # --- sizes and indices -------------------------------------------------------------
    @property
    def n_aavs(self) -> int:
        return len(self.aavs)

    @property
    def n_tasks(self) -> int:
        return len(self.tasks)

    @property
    def n_depots(self) -> int:
        return len(self.depots)

    @property
    def scale(self) -> str:
        """``N/M``, the paper's name for an instance size."""
        return f"{self.n_aavs}/{self.n_tasks}"

    def is_depot(self, node: int) -> bool:
        return self.n_tasks <= node < self.n_tasks + self.n_depots

    def depot_node(self, k: int) -> int:
        return self.n_tasks + k

    def start_node(self, n: int) -> int:
        return self.n_tasks + self.n_depots + n

    @property
    def depot_nodes(self) -> range:
        return range(self.n_tasks, self.n_tasks + self.n_depots)

    @cached_property
    def node_ids(self) -> tuple[str, ...]:
        """Ids of the routable nodes (tasks then depots), indexed by node number."""
        return tuple(t.id for t in self.tasks) + tuple(d.id for d in self.depots)

    @cached_property
    def node_index(self) -> Mapping[str, int]:
        return MappingProxyType({node_id: i for i, node_id in enumerate(self.node_ids)})

    @cached_property
    def aav_index(self) -> Mapping[str, int]:
        return MappingProxyType({a.id: n for n, a in enumerate(self.aavs)})

    # --- geometry --------------------------------------------------------------------
    @cached_property
    def positions(self) -> np.ndarray:
        """(M+K+N, 2) array of node positions in metres, in node-index order."""
        points = [(t.x, t.y) for t in self.tasks]
        points += [(d.x, d.y) for d in self.depots]
        points += [(a.x, a.y) for a in self.aavs]
        return np.asarray(points, dtype=float).reshape(-1, 2)

    @cached_property
    def dist(self) -> np.ndarray:
        """Euclidean distance matrix in metres over all nodes (tasks, depots, starts)."""
        p = self.positions
        return np.hypot(p[:, None, 0] - p[None, :, 0], p[:, None, 1] - p[None, :, 1])

    @cached_property
    def dist_rows(self) -> tuple[tuple[float, ...], ...]:
        """``dist`` as nested tuples: element access from Python is ~10x faster than numpy's."""
        return tuple(tuple(row) for row in self.dist.tolist())

    @cached_property
    def e_base(self) -> float:
        """E_base = max over the AAVs of alpha_i * D_i[km] + lam_i (Eq. 9's normaliser)."""
        return max((a.full_range_cost for a in self.aavs), default=1.0)

    def nearest_depot(self, node: int) -> int:
        """The depot node closest to ``node`` (ties: lowest index)."""
        row = self.dist_rows[node]
        return min(self.depot_nodes, key=row.__getitem__)

    def released_by(self, time: float) -> frozenset[int]:
        return frozenset(m for m, t in enumerate(self.tasks) if t.release <= time)

    @property
    def unserved_task_cost(self) -> float:
        """What a task with no visit costs: w1 * 1 + w2 * 1."""
        return self.weights[0] + self.weights[1]


def is_int(value: object) -> bool:
    """True for a real int: ``2.0`` and ``True`` are not amounts of kilograms."""
    return type(value) is int or (isinstance(value, np.integer))


def validate_instance(instance: Instance) -> None:
    """Raise ModelError (with the offending field's path) if the instance breaks docs/model.md."""
    if not instance.name:
        raise ModelError("name", "must be a non-empty string")
    if not (math.isfinite(instance.horizon) and instance.horizon > 0):
        raise ModelError("horizon", f"must be a positive number of seconds, got {instance.horizon}")
    if len(instance.weights) != 3 or any(not math.isfinite(w) or w < 0 for w in instance.weights):
        raise ModelError("weights", f"must be three non-negative numbers, got {instance.weights}")
    seen: dict[str, str] = {}
    for group, items in (("aavs", instance.aavs), ("depots", instance.depots),
                         ("tasks", instance.tasks)):
        for i, item in enumerate(items):
            if not item.id:
                raise ModelError(f"{group}[{i}].id", "must be a non-empty string")
            if item.id in seen:
                raise ModelError(f"{group}[{i}].id",
                                 f"duplicate id {item.id!r} (already used in {seen[item.id]})")
            seen[item.id] = group
            for coord in ("x", "y"):
                if not math.isfinite(getattr(item, coord)):
                    raise ModelError(f"{group}[{i}].{coord}", "must be a finite number of metres")
    for i, a in enumerate(instance.aavs):
        for attr in ("speed", "max_range"):
            value = getattr(a, attr)
            if not (math.isfinite(value) and value > 0):
                raise ModelError(f"aavs[{i}].{attr}", f"must be positive, got {value}")
        if not is_int(a.capacity) or a.capacity < 1:
            raise ModelError(f"aavs[{i}].capacity", f"must be an integer >= 1 kg, got {a.capacity}")
        for attr in ("alpha", "lam"):
            value = getattr(a, attr)
            if not (math.isfinite(value) and value >= 0):
                raise ModelError(f"aavs[{i}].{attr}", f"must be non-negative, got {value}")
    if instance.tasks and not instance.depots:
        raise ModelError("depots", "an instance with tasks needs at least one depot")
    if instance.aavs and instance.e_base <= 0:
        raise ModelError("aavs", "alpha * max_range + lam must be positive for some AAV")
    for i, t in enumerate(instance.tasks):
        if not is_int(t.demand) or t.demand < 1:
            raise ModelError(f"tasks[{i}].demand", f"must be an integer >= 1 kg, got {t.demand}")
        if t.kind not in (TaskKind.PICKUP, TaskKind.DELIVERY):
            raise ModelError(f"tasks[{i}].kind", f"must be 'P' or 'D', got {t.kind!r}")
        if not (math.isfinite(t.t_start) and t.t_start >= 0):
            raise ModelError(f"tasks[{i}].t_start", f"must be >= 0, got {t.t_start}")
        if t.t_end < t.t_start:
            raise ModelError(f"tasks[{i}].t_end",
                             f"window ends before it starts ({t.t_end} < t_start {t.t_start})")
        if t.t_end - t.t_start > instance.horizon:
            raise ModelError(f"tasks[{i}].t_end",
                             f"window [{t.t_start}, {t.t_end}] is longer than the horizon "
                             f"{instance.horizon}")
        if not (0 <= t.release <= t.t_start):
            raise ModelError(f"tasks[{i}].release",
                             f"must lie in [0, t_start={t.t_start}], got {t.release}")
