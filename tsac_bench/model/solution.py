"""Solutions: one route per AAV, each an ordered tuple of visits.

In memory a visit names its node by index (see ``Instance``) so that allocators and the
evaluator never hash strings on the hot path; ids appear only at the file boundary.
A depot visit has ``amount == 0``. ``planned_at`` and ``load`` are the dynamic run's stamps
(docs/model.md, "The dynamic run"): None where absent, as in every offline solution.
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass, field
from types import MappingProxyType
from typing import NamedTuple

from tsac_bench.model.instance import Instance


class Visit(NamedTuple):
    node: int
    amount: int = 0
    #: The time of the plan that sent the AAV here: it leaves the previous node no earlier.
    planned_at: float | None = None
    #: On a depot visit the AAV has left: the delivery goods it loaded there (kg).
    load: int | None = None


Route = tuple[Visit, ...]


def as_route(visits: Iterable[Sequence[int] | Visit]) -> Route:
    return tuple(v if isinstance(v, Visit) else Visit(*v) for v in visits)


@dataclass(frozen=True)
class Solution:
    """Routes aligned with ``instance.aavs``; ``cost`` is what the producer claims."""

    instance: str
    routes: tuple[Route, ...]
    cost: float | None = None
    meta: Mapping[str, object] = field(default_factory=dict)

    def __post_init__(self) -> None:
        object.__setattr__(self, "routes", tuple(as_route(r) for r in self.routes))
        object.__setattr__(self, "meta", MappingProxyType(dict(self.meta)))

    def __reduce__(self) -> tuple:
        # mappingproxy does not pickle; worker processes and Dask need solutions to.
        return (type(self), (self.instance, self.routes, self.cost, dict(self.meta)))

    @classmethod
    def empty(cls, instance: Instance, **kwargs: object) -> Solution:
        return cls(instance.name, tuple(() for _ in instance.aavs), **kwargs)

    @classmethod
    def from_ids(
        cls,
        instance: Instance,
        routes: Mapping[str, Iterable[tuple[str, int] | str]],
        **kwargs: object,
    ) -> Solution:
        """Build from ``{aav_id: [(task_id, amount) | depot_id, ...]}``; missing AAVs are idle."""
        unknown = set(routes) - set(instance.aav_index)
        if unknown:
            raise KeyError(f"unknown AAV id(s): {sorted(unknown)}")
        resolved = []
        for aav in instance.aavs:
            visits = []
            for item in routes.get(aav.id, ()):
                node_id, amount = (item, 0) if isinstance(item, str) else item
                visits.append(Visit(instance.node_index[node_id], amount))
            resolved.append(tuple(visits))
        return cls(instance.name, tuple(resolved), **kwargs)

    def to_ids(self, instance: Instance) -> dict[str, list[tuple[str, int]]]:
        ids = instance.node_ids
        return {
            aav.id: [(ids[v.node], v.amount) for v in route]
            for aav, route in zip(instance.aavs, self.routes, strict=True)
        }

    def with_meta(self, **meta: object) -> Solution:
        return Solution(self.instance, self.routes, self.cost, {**self.meta, **meta})

    def with_cost(self, cost: float | None) -> Solution:
        return Solution(self.instance, self.routes, cost, self.meta)
