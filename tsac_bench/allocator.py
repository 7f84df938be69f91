"""The ``Allocator`` protocol every method implements, the planning state it sees, and the
registry that finds methods by name (built-ins and ``tsac_bench.allocators`` plug-ins).

A method is a class whose constructor takes its settings as keywords (so that a run can be
rebuilt from its record) and whose ``plan`` turns a ``PlanningState`` into one route per AAV.
"""

from __future__ import annotations

import importlib
import inspect
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from importlib.metadata import entry_points
from typing import Any, ClassVar, Protocol, runtime_checkable

from tsac_bench.errors import TsacBenchError, UnknownMethodError
from tsac_bench.model import Instance, Route, Visit

ENTRY_POINT_GROUP = "tsac_bench.allocators"


@dataclass(frozen=True)
class PlanningState:
    """What an allocator may use at one planning moment.

    ``visible`` tasks are the released ones the allocator may visit; every AAV's new route
    must start with its ``committed`` prefix (MODEL.md, the dynamic run). ``incumbent`` is the
    plan in force before this moment, a warm start for methods that want one.
    """

    instance: Instance
    time: float = 0.0
    visible: frozenset[int] = frozenset()
    committed: tuple[Route, ...] = ()
    incumbent: tuple[Route, ...] | None = None

    def __post_init__(self) -> None:
        if not self.committed:
            object.__setattr__(self, "committed", tuple(() for _ in self.instance.aavs))

    @classmethod
    def static(cls, instance: Instance) -> PlanningState:
        """Every task known at t = 0, nothing committed."""
        return cls(instance, 0.0, frozenset(range(instance.n_tasks)))

    def first_free(self, n: int) -> int:
        """Index of AAV n's first visit that the plan may change."""
        return len(self.committed[n])

    def base_routes(self) -> tuple[Route, ...]:
        """The committed prefixes made into feasible routes: a prefix that stops at a task
        (the AAV is flying to it) is closed with the depot nearest to that task."""
        closed = []
        for prefix in self.committed:
            if prefix and not self.instance.is_depot(prefix[-1].node):
                prefix = (*prefix, Visit(self.instance.nearest_depot(prefix[-1].node)))
            closed.append(prefix)
        return tuple(closed)

    def warm_routes(self) -> tuple[Route, ...]:
        """The ``incumbent`` plan kept where this state allows it, a warm start: each AAV's
        incumbent route without its free visits to tasks no longer visible (depot visits made
        pointless dropped too); ``base_routes()`` for an AAV whose incumbent does not start
        with its committed prefix, and for every AAV when there is no incumbent."""
        from tsac_bench.insertion import removal_route

        if self.incumbent is None:
            return self.base_routes()
        instance, n_tasks = self.instance, self.instance.n_tasks
        warm = []
        for n, (route, base) in enumerate(zip(self.incumbent, self.base_routes(), strict=True)):
            first_free = self.first_free(n)
            if tuple(route[:first_free]) != self.committed[n]:
                warm.append(base)
                continue
            for v in route[first_free:]:
                if v.node < n_tasks and v.node not in self.visible:
                    route = removal_route(instance, route, v.node, first_free)
            warm.append(route if len(route) > first_free else base)
        return tuple(warm)

    def violations(self, routes: Sequence[Route]) -> list[str]:
        """What in ``routes`` this state forbids (changed prefix, invisible task)."""
        problems = []
        if len(routes) != self.instance.n_aavs:
            return [f"{len(routes)} routes for {self.instance.n_aavs} AAVs"]
        n_tasks = self.instance.n_tasks
        for n, (route, prefix) in enumerate(zip(routes, self.committed, strict=True)):
            aav = self.instance.aavs[n].id
            if tuple(route[: len(prefix)]) != prefix:
                problems.append(f"{aav}: the committed prefix was changed")
            for v in route[len(prefix):]:
                if v.node < n_tasks and v.node not in self.visible:
                    problems.append(f"{aav}: visits task {self.instance.tasks[v.node].id} "
                                    f"which is not visible at t={self.time:g}")
        return problems


@dataclass(frozen=True)
class PlanResult:
    """An allocator's answer: routes plus what it wants recorded (status, bounds, counters).

    ``cost`` is J as the method itself computes it, if it does (a solver's objective, an
    incremental total); ``solve`` records it next to the evaluator's J and the conformance
    suite requires the two to agree."""

    routes: tuple[Route, ...]
    stats: Mapping[str, Any] = field(default_factory=dict)
    cost: float | None = None


#: The planning modes of tsac_bench.solve; a method that declares ``modes`` plans only those.
ALL_MODES = ("static", "dynamic")


@runtime_checkable
class Allocator(Protocol):
    """``name`` is what users type. An allocator may also declare ``modes`` (a tuple of
    "static", "dynamic"; both when absent): the planning states it can handle. "static"
    states have nothing committed; "dynamic" ones have committed prefixes and hidden tasks."""

    name: ClassVar[str]

    def plan(self, state: PlanningState, *, seed: int = 0,
             time_limit: float | None = None) -> PlanResult: ...


def supported_modes(allocator: object) -> tuple[str, ...]:
    """The modes an allocator (class or instance) declares it can plan."""
    return tuple(getattr(allocator, "modes", ALL_MODES))


class Settings:
    """Mixin: ``settings()`` returns the constructor keywords, as scikit-learn's get_params."""

    def settings(self) -> dict[str, Any]:
        names = [p for p in inspect.signature(type(self).__init__).parameters if p != "self"]
        return {name: getattr(self, name) for name in names}


# --- registry ----------------------------------------------------------------------------
#: Built-in methods by name, as "module:Class" so that listing them imports nothing heavy.
BUILTIN_METHODS: dict[str, str] = {
    "greedy": "tsac_bench.solvers.greedy:GreedyAllocator",
    "hocf": "tsac_bench.solvers.hocf:HOCFAllocator",
    "rocf": "tsac_bench.solvers.rocf:ROCFAllocator",
    "dga": "tsac_bench.solvers.dga:DGAAllocator",
    "cnp": "tsac_bench.solvers.cnp:ContractNetAllocator",
    "exact": "tsac_bench.solvers.exact:ExactAllocator",
    "exact-cpsat": "tsac_bench.solvers.exact:CpSatAllocator",
    "exact-bp": "tsac_bench.solvers.exact:BranchPriceAllocator",
    "tsac-ocf": "tsac_bench.solvers.tsac_ocf:TSACOCFAllocator",
    "pyvrp": "tsac_bench.solvers.pyvrp_peer:PyVRPAllocator",
}

#: The pyproject extra that installs what a built-in method needs, where it needs one.
METHOD_EXTRAS: dict[str, str] = {"pyvrp": "peers"}

_registered: dict[str, Callable[..., Allocator]] = {}


def register(name: str) -> Callable[[type], type]:
    """Class decorator registering a method in this process (tests and notebooks)."""

    def decorate(cls: type) -> type:
        _registered[name] = cls
        return cls

    return decorate


def _plugin_methods() -> dict[str, Any]:
    return {ep.name: ep for ep in entry_points(group=ENTRY_POINT_GROUP)}


def available_methods() -> list[str]:
    return sorted({*BUILTIN_METHODS, *_registered, *_plugin_methods()})


def method_source(name: str) -> str:
    if name in _registered:
        return "registered"
    if name in BUILTIN_METHODS:
        return "built-in"
    return "plug-in"


class MethodUnavailable(TsacBenchError):
    """A known method whose optional dependencies are not installed."""


def allocator_class(name: str) -> Callable[..., Allocator]:
    if name in _registered:
        return _registered[name]
    plugins = _plugin_methods()
    if name in BUILTIN_METHODS:
        module_name, _, attr = BUILTIN_METHODS[name].partition(":")
        try:
            return getattr(importlib.import_module(module_name), attr)
        except ImportError as exc:
            extra = METHOD_EXTRAS.get(name, "all")
            raise MethodUnavailable(f"method {name!r} needs {exc.name!r}: "
                                    f"pip install -e '.[{extra}]'") from None
    if name in plugins:
        try:
            return plugins[name].load()
        except ImportError as exc:
            raise MethodUnavailable(f"plug-in method {name!r} needs {exc.name!r}") from None
    raise UnknownMethodError(name, available_methods())


def make_allocator(name: str, **settings: Any) -> Allocator:
    """The method ``name`` built with ``settings`` (its constructor keywords); a name the
    constructor does not take is a one-line error listing the ones it does."""
    cls = allocator_class(name)
    parameters = inspect.signature(cls).parameters.values()
    accepted = [p.name for p in parameters if p.kind in (p.POSITIONAL_OR_KEYWORD,
                                                         p.KEYWORD_ONLY)]
    takes_any = any(p.kind == p.VAR_KEYWORD for p in parameters)
    unknown = sorted(set(settings) - set(accepted))
    if unknown and not takes_any:
        raise TsacBenchError(f"method {name!r} has no setting {unknown[0]!r}; its settings: "
                             f"{', '.join(accepted) or 'none'}")
    return cls(**settings)
