"""The ``Allocator`` protocol every method implements and the planning state it sees
(the registry that finds methods by name is ``tsac_bench.planning.registry``).

A method is a class whose constructor takes its settings as keywords (so that a run can be
rebuilt from its record) and whose ``plan`` turns a ``PlanningState`` into one route per AAV.
"""

from __future__ import annotations

import inspect
import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from enum import StrEnum
from typing import TYPE_CHECKING, Any, ClassVar, NamedTuple, Protocol, runtime_checkable

from tsac_bench.errors import TsacBenchError
from tsac_bench.model import Instance, Route, Visit
from tsac_bench.planning.settings import Constraint

if TYPE_CHECKING:
    from tsac_bench.model.evaluator import CostEvaluator


class Anchor(NamedTuple):
    """Where AAV n's free route begins at a planning moment: the node it last committed to
    (its start position when nothing is committed), the earliest time it can leave it for a
    visit planned now, the distance flown to get there, and the delivery goods it will have
    on board there from the last depot it left (None when the anchor is a depot, where it
    loads what the new plan needs, or when that depot's load was not recorded)."""

    node: int
    time: float
    flown: float
    on_board: int | None


@dataclass(frozen=True)
class PlanningState:
    """What an allocator may use at one planning moment.

    ``visible`` tasks are the released ones the allocator may visit; every AAV's new route
    must start with its ``committed`` prefix (docs/model.md, "The dynamic run"), stamps included.
    Every visit a plan places after the prefix counts as planned at ``time``: the AAV leaves
    its anchor no earlier (``anchor``), and ``evaluator()`` prices routes so. A depot visit
    the AAV has left carries the goods it loaded, which later deliveries of that trip may not
    exceed. ``incumbent`` is the plan in force before this moment, a warm start for methods
    that want one.
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

    @property
    def at_start(self) -> bool:
        """Nothing committed and nothing planned after t = 0: the run has not begun."""
        return self.time == 0 and not any(self.committed)

    def first_free(self, n: int) -> int:
        """Index of AAV n's first visit that the plan may change."""
        return len(self.committed[n])

    def evaluator(self) -> CostEvaluator:
        """The evaluator that prices this moment's plans as they will be executed: every
        visit after a committed prefix planned at ``time``."""
        from tsac_bench.model.evaluator import CostEvaluator

        return CostEvaluator(self.instance, self.time,
                             [self.first_free(n) for n in range(self.instance.n_aavs)])

    def anchor(self, n: int) -> Anchor:
        """AAV n's anchor: where, from when and with which goods its free route begins."""
        from tsac_bench.model.evaluator import CostEvaluator, departure

        prefix = self.committed[n]
        if not prefix:
            # The start position is no depot: deliveries need one first.
            return Anchor(self.instance.start_node(n), departure(0.0, self.time), 0.0, 0)
        trace = CostEvaluator(self.instance).trace(n, prefix)
        ready = departure(trace.arrivals[-1], self.time)
        if self.instance.is_depot(prefix[-1].node):
            return Anchor(prefix[-1].node, ready, trace.distance_at_arrival[-1], None)
        n_tasks, tasks = self.instance.n_tasks, self.instance.tasks
        on_board = 0
        for v in reversed(prefix):
            if v.node >= n_tasks:
                if v.load is None:
                    on_board = None
                else:
                    on_board += v.load
                break
            if tasks[v.node].is_delivery:
                on_board -= v.amount
        return Anchor(prefix[-1].node, ready, trace.distance_at_arrival[-1], on_board)

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
        from tsac_bench.planning.insertion import removal_route

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
        """What in ``routes`` this state forbids (changed prefix, invisible task, a stamp on
        a visit after the prefix: only the simulator writes ``planned_at`` and ``load``)."""
        problems = []
        if len(routes) != self.instance.n_aavs:
            return [f"{len(routes)} routes for {self.instance.n_aavs} AAVs"]
        n_tasks = self.instance.n_tasks
        for n, (route, prefix) in enumerate(zip(routes, self.committed, strict=True)):
            aav = self.instance.aavs[n].id
            if tuple(route[: len(prefix)]) != prefix:
                problems.append(f"{aav}: the committed prefix was changed")
            for v in route[len(prefix):]:
                if v.load is not None or v.planned_at is not None:
                    problems.append(f"{aav}: a planned visit carries a stamp (planned_at, "
                                    "load): the simulator writes them")
                if v.node < n_tasks and v.node not in self.visible:
                    problems.append(f"{aav}: visits task {self.instance.tasks[v.node].id} "
                                    f"which is not visible at t={self.time:g}")
        return problems


class PlanStatus(StrEnum):
    """What a method proves about its plan (docs/formulations.md). There is no "infeasible":
    the plan without visits is always feasible, so a model found infeasible is an error."""

    OPTIMAL = "optimal"  # no plan of the planning state costs less (to the solver's tolerance)
    FEASIBLE = "feasible"  # stopped (by its time limit) before a proof
    NO_SOLUTION = "no-solution"  # found no plan in time: the routes are its start
    ERROR = "error"  # the model failed or disagrees with the evaluator: the routes are its start


#: The keys under which a record (a results store's stats, a dynamic run's re-plans, a
#: manifest, an exact solver's report) keeps ``PlanResult.status`` and ``lower_bound``.
CLAIM_KEYS = ("status", "lower_bound")


@dataclass(frozen=True)
class PlanResult:
    """An allocator's answer: routes, what it proves about them and what else it wants
    recorded (counters, solver details).

    ``status`` and ``lower_bound`` are a method's claims, None where it makes none (every
    heuristic): ``lower_bound`` is no more than the J of any plan of the planning state. A
    status may be given as its text (``"optimal"``). ``cost`` is J as the method itself
    computes it, if it does (a solver's objective, an incremental total); ``solve`` records
    it next to the evaluator's J and the conformance suite requires the two to agree."""

    routes: tuple[Route, ...]
    stats: Mapping[str, Any] = field(default_factory=dict)
    cost: float | None = None
    status: PlanStatus | None = None
    lower_bound: float | None = None

    def __post_init__(self) -> None:
        # Records keep the claims under these keys (recorded_stats): stats holding them
        # too would make two answers to one question.
        taken = [key for key in CLAIM_KEYS if key in self.stats]
        if taken:
            raise TsacBenchError(f"PlanResult.stats holds {', '.join(taken)}: pass "
                                 "PlanResult(..., status=, lower_bound=) instead")
        if self.status is not None:
            try:
                object.__setattr__(self, "status", PlanStatus(self.status))
            except ValueError:
                raise TsacBenchError(f"PlanResult.status {self.status!r}: expected one of "
                                     f"{', '.join(PlanStatus)}") from None
        if self.lower_bound is not None:
            bound = float(self.lower_bound)
            if not math.isfinite(bound):
                raise TsacBenchError(f"PlanResult.lower_bound {bound}: expected a finite "
                                     "number, or None for no bound")
            object.__setattr__(self, "lower_bound", bound)

    @classmethod
    def from_solver(cls, routes: Sequence[Route], report: Mapping[str, Any]) -> PlanResult:
        """A PlanResult from a solver's report, whose ``status`` and ``lower_bound`` are
        among its stats (as formulations/ report them)."""
        return cls(tuple(routes), {k: v for k, v in report.items() if k not in CLAIM_KEYS},
                   status=report.get("status"), lower_bound=report.get("lower_bound"))

    def recorded_stats(self) -> dict[str, Any]:
        """``stats`` as records keep them, with the claims (``claim_entries``)."""
        return {**self.stats, **claim_entries(self.status, self.lower_bound)}


def claim_entries(status: PlanStatus | None, lower_bound: float | None) -> dict[str, Any]:
    """The claims made, under ``CLAIM_KEYS``, as records keep them (``recorded_claim`` reads
    them back)."""
    claims = zip(CLAIM_KEYS, (status, lower_bound), strict=True)
    return {key: value for key, value in claims if value is not None}


def recorded_claim(stats: Any) -> tuple[PlanStatus | None, float | None]:
    """The status and lower bound a record keeps (``PlanResult.recorded_stats``); None for
    either where it has none, or an older plug-in's stats hold something else there."""
    if not isinstance(stats, Mapping):
        return None, None
    status, bound = (stats.get(key) for key in CLAIM_KEYS)
    known = status in tuple(PlanStatus)
    is_number = isinstance(bound, int | float) and not isinstance(bound, bool)
    return (PlanStatus(status) if known else None), (float(bound) if is_number else None)


def mip_gap(J: float, lower_bound: float) -> float:
    """How far a bound leaves J from proven: (J - LB) / J, as MIP solvers state it."""
    return max(0.0, J - lower_bound) / max(abs(J), 1e-10)


#: The planning modes. "static": every task known at t = 0, one plan call. "dynamic": the
#: simulator's run, one plan call per release. A method that declares ``modes`` plans only those.
ALL_MODES = ("static", "dynamic")


@runtime_checkable
class Allocator(Protocol):
    """``name`` is what users type. An allocator may also declare ``modes`` (a tuple of
    "static", "dynamic"; both when absent): the planning states it can handle. "static"
    states have nothing committed; "dynamic" ones have committed prefixes and hidden tasks.
    A method that returns ``status=PlanStatus.OPTIMAL`` only for proven optima declares
    ``proves_optimality = True``: its static runs may then supply J* to reports and
    ``tsac-bench verify`` uses it as a backend."""

    name: ClassVar[str]

    def plan(self, state: PlanningState, *, seed: int = 0,
             time_limit: float | None = None) -> PlanResult: ...


def supported_modes(allocator: object) -> tuple[str, ...]:
    """The modes an allocator (class or instance) declares it can plan."""
    return tuple(getattr(allocator, "modes", ALL_MODES))


def proves_optimality(allocator: object) -> bool:
    """Whether an allocator (class or instance) declares that it proves optimality."""
    return bool(getattr(allocator, "proves_optimality", False))


class Settings:
    """Mixin: ``settings()`` returns the constructor keywords, as scikit-learn's get_params.

    ``setting_constraints`` declares what each keyword admits (``tsac_bench.planning.settings``);
    ``make_allocator`` checks and converts settings by it before the constructor runs."""

    setting_constraints: ClassVar[Mapping[str, Constraint]] = {}

    def settings(self) -> dict[str, Any]:
        names = [p for p in inspect.signature(type(self).__init__).parameters if p != "self"]
        return {name: getattr(self, name) for name in names}
