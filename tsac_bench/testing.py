"""Conformance checks for allocators, shipped in the package so that a plug-in's own test
suite runs the same checks as tsac-bench's (as scikit-learn's ``check_estimator``).

Run them all at once, or as one pytest test per check::

    from tsac_bench.testing import allocator_checks, check_allocator

    check_allocator("my-method")   # AssertionError naming the first failed check

    @pytest.mark.parametrize("check", allocator_checks("my-method"), ids=str)
    def test_my_method_conforms(check):
        check()

``method`` is a registered name (built-in, plug-in entry point or ``register``) or an
allocator object. A check that does not apply (a mode the method does not declare, a method
whose dependencies are missing) raises ``CheckSkipped``, a ``unittest.SkipTest`` that pytest
reports as skipped. Every instance is built here or by the generator, so no checkout of
tsac-bench is needed.
"""

from __future__ import annotations

import itertools
import tempfile
import unittest
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from pathlib import Path

from tsac_bench.errors import TsacBenchError
from tsac_bench.model import AAV, Depot, Instance, Task, TaskKind
from tsac_bench.model.evaluator import CostEvaluator, cost_at_least
from tsac_bench.model.generator import AAV_TYPES, generate
from tsac_bench.model.io import read_solution, write_solution
from tsac_bench.planning import ALL_MODES, Allocator, MethodUnavailable, supported_modes
from tsac_bench.planning.budget import ANYTIME, ONE_PASS, budget_use
from tsac_bench.planning.registry import allocator_class, make_allocator
from tsac_bench.planning.settings import check_settings, constructor_keywords
from tsac_bench.planning.solve import SolveOutcome, solve

__all__ = ["DEPOTS", "FLEET", "Check", "CheckSkipped", "aav", "allocator_checks",
           "check_allocator", "check_declared_settings", "edge_cases", "small_instances", "task"]

#: Seconds per plan call: small enough for a suite, large enough for the exact methods.
TIME_LIMIT = 2.0
#: A plan call may overrun its budget by this factor plus this many seconds (imports, setup).
BUDGET_FACTOR, BUDGET_SLACK = 2.0, 3.0
#: The budget of the anytime checks: a few games or generations on a 4/10 instance.
ANYTIME_BUDGET = 0.3


class CheckSkipped(unittest.SkipTest):
    """The check does not apply to this method."""


def aav(name: str, kind: int, x: float = 0.0, y: float = 0.0) -> AAV:
    """An AAV of the paper's type ``kind`` (1 or 2) at (x, y)."""
    return AAV(name, kind, x, y, **AAV_TYPES[kind])  # type: ignore[arg-type]


def task(name: str, x: float, y: float, demand: int = 10, window=(0.0, 3000.0),
         release: float = 0.0, kind: str = "D") -> Task:
    """A task; ``kind`` "D" (delivery) or "P" (pickup)."""
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


def small_instances() -> dict[str, Instance]:
    """Generated instances of the paper's family (the same as instances/quick)."""
    return {f"gen-{scale.replace('/', '-')}-s{seed}": generate(scale, seed)
            for scale, seed in (("2/5", 2), ("3/6", 3), ("4/10", 5))}


@dataclass(frozen=True)
class Check:
    """One named check of one method; call it to run it."""

    name: str
    method: str | Allocator
    run: Callable[[], None]

    def __call__(self) -> None:
        self.run()

    def __str__(self) -> str:
        return f"{_method_name(self.method)}:{self.name}"


def _method_name(method: str | Allocator) -> str:
    return method if isinstance(method, str) else type(method).name


def _allocator_type(method: str | Allocator) -> type:
    if not isinstance(method, str):
        return type(method)
    try:
        return allocator_class(method)
    except MethodUnavailable as exc:
        raise CheckSkipped(str(exc)) from None


def check_declared_settings(cls: type) -> None:
    """A method that declares ``setting_constraints`` declares one per constructor keyword
    (no catch-all ``**kwargs``), and each default converts to itself and is admitted."""
    names, defaults, takes_any = constructor_keywords(cls)
    assert not takes_any, f"{cls.__name__} takes **kwargs: its settings cannot be checked"
    declared = cls.setting_constraints
    assert sorted(declared) == sorted(names), (
        f"declared {sorted(declared)}, constructor keywords {sorted(names)}")
    for setting, constraint in declared.items():
        assert constraint.convert(defaults[setting]) == defaults[setting], setting
        assert constraint.admits(defaults[setting], defaults), (
            f"the default {setting}={defaults[setting]!r} breaks its own constraint")


def _declared_modes(method: str | Allocator) -> tuple[str, ...]:
    return supported_modes(_allocator_type(method))


def _run(method: str | Allocator, instance: Instance, mode: str, *, seed: int = 0,
         time_limit: float | None = TIME_LIMIT, budget: float | None = None,
         settings: Mapping[str, object] | None = None) -> SolveOutcome:
    """``solve`` plus what any reader of the solution would check again from the routes."""
    if mode not in _declared_modes(method):
        raise CheckSkipped(f"{_method_name(method)} declares modes {_declared_modes(method)}")
    if budget is not None:
        time_limit = None
    outcome = solve(instance, method, seed=seed, time_limit=time_limit, mode=mode,
                    budget=budget, settings=settings)
    fresh = CostEvaluator(instance).evaluate(outcome.solution.routes)
    assert fresh.feasible, fresh.errors
    assert outcome.cost == fresh.J == outcome.solution.cost
    assert outcome.claim_matches, (f"the method claims J = {outcome.claimed_cost}, the "
                                   f"evaluator computes {outcome.cost}")
    if outcome.lower_bound is not None:
        assert cost_at_least(outcome.cost, outcome.lower_bound), (
            f"the method claims a lower bound {outcome.lower_bound} above J = {outcome.cost}")
    return outcome


def _load_share(outcome: SolveOutcome, task_id: str) -> float:
    return next(b.cost.load for b in outcome.evaluation.per_task if b.task == task_id)


def allocator_checks(method: str | Allocator, *,
                     instances: Mapping[str, Instance] | None = None) -> list[Check]:
    """Every conformance check of ``method``; ``instances`` (name -> instance) replaces the
    generated ones that plans are checked on."""
    name = _method_name(method)
    generated = small_instances()
    instances = dict(generated if instances is None else instances)
    edge = edge_cases()
    timed, seeded = generated["gen-4-10-s5"], generated["gen-2-5-s2"]
    checks: list[Check] = []

    def add(check_name: str, body: Callable[[], None]) -> None:
        checks.append(Check(check_name, method, body))

    def undeclared_mode_refused() -> None:
        unsupported = [m for m in ALL_MODES if m not in _declared_modes(method)]
        if not unsupported:
            raise CheckSkipped(f"{name} plans every mode")
        try:
            solve(edge["one-aav"], method, mode=unsupported[0])
        except TsacBenchError as exc:
            assert f"not '{unsupported[0]}'" in str(exc), str(exc)
        else:
            raise AssertionError(f"a {unsupported[0]} run of {name} was not refused")

    add("undeclared-mode-refused", undeclared_mode_refused)

    def settings_declared_and_rebuilt() -> None:
        cls = _allocator_type(method)
        if not getattr(cls, "setting_constraints", None) and constructor_keywords(cls)[0]:
            raise CheckSkipped(f"{name} declares no setting_constraints")
        check_declared_settings(cls)
        built = make_allocator(name) if isinstance(method, str) else method
        rebuilt = cls(**check_settings(name, cls, built.settings()))
        assert rebuilt.settings() == built.settings()

    add("settings-declared-and-rebuilt", settings_declared_and_rebuilt)

    def feasible_and_scored(instance: Instance, mode: str) -> None:
        outcome = _run(method, instance, mode)
        assert outcome.solution.meta["method"] == name
        assert outcome.solution.meta["mode"] == mode
        with tempfile.TemporaryDirectory() as folder:
            path = Path(folder) / "solution.json"
            write_solution(outcome.solution, instance, path)
            again = read_solution(path, instance)
        assert CostEvaluator(instance).cost(again) == outcome.cost == again.cost
        assert (again.meta.get("status"), again.meta.get("lower_bound")) == (
            outcome.status, outcome.lower_bound), "the solution file keeps status and bound"

    for mode in ALL_MODES:
        for label, instance in instances.items():
            add(f"feasible-and-scored[{label}-{mode}]",
                lambda i=instance, m=mode: feasible_and_scored(i, m))

    def records_every_planning_moment() -> None:
        instance = generated["gen-3-6-s3"]
        outcome = _run(method, instance, "dynamic")
        replans = outcome.stats["replans"]
        events = sorted({t.release for t in instance.tasks if t.release > 0})
        assert [r["time"] for r in replans] == [0.0, *events]
        assert abs(replans[-1]["J"] - outcome.cost) <= 1e-12 * max(1.0, outcome.cost)

    add("dynamic-run-records-every-planning-moment", records_every_planning_moment)

    def respects_its_time_budget() -> None:
        outcome = _run(method, timed, "static", time_limit=1.0)
        assert outcome.wall_time <= BUDGET_FACTOR * 1.0 + BUDGET_SLACK, outcome.wall_time

    add("respects-its-time-budget", respects_its_time_budget)

    def declares_its_budget_use() -> None:
        cls = _allocator_type(method)
        use = budget_use(cls)
        if use != ANYTIME:
            return
        names = constructor_keywords(cls)[0]
        for setting in (cls.work_setting, *cls.unbounded_settings):
            assert setting in names, f"{setting!r} is not a constructor keyword of {name}"
        assert isinstance(getattr(cls, "work_unit", None), str), "an anytime method names " \
            "its work_unit"

    add("declares-its-budget-use", declares_its_budget_use)

    def anytime_under_a_budget() -> None:
        cls = _allocator_type(method)
        if budget_use(cls) != ANYTIME:
            raise CheckSkipped(f"{name} is not an anytime method")
        if not isinstance(method, str):
            raise CheckSkipped("a budget lifts the work caps of a method named, not built")
        outcome = _run(method, timed, "static", seed=3, budget=ANYTIME_BUDGET)
        assert outcome.wall_time <= BUDGET_FACTOR * ANYTIME_BUDGET + BUDGET_SLACK
        stats = outcome.stats
        trace, work = stats.get("trace"), stats.get("work")
        assert isinstance(work, int) and work >= 1, f"work count {work!r}"
        assert trace, "a budgeted call records its incumbent trace"
        times, costs = [p[0] for p in trace], [p[1] for p in trace]
        assert times == sorted(times) and all(b < a for a, b in itertools.pairwise(costs))
        assert abs(costs[-1] - outcome.cost) <= 1e-9 * max(1.0, outcome.cost)
        # The work count reproduces the plan without the budget; half of it is a prefix of
        # the same search, never better.
        unbounded = dict(cls.unbounded_settings)
        again = _run(method, timed, "static", seed=3, time_limit=None,
                     settings={**unbounded, cls.work_setting: work})
        assert again.solution.routes == outcome.solution.routes
        half = _run(method, timed, "static", seed=3, time_limit=None,
                    settings={**unbounded, cls.work_setting: max(1, work // 2)})
        assert outcome.cost <= half.cost

    add("anytime-under-a-budget", anytime_under_a_budget)

    def one_pass_under_a_budget() -> None:
        if budget_use(_allocator_type(method)) != ONE_PASS:
            raise CheckSkipped(f"{name} is not a one-pass method")
        plain = _run(method, seeded, "static", time_limit=None)
        budgeted = _run(method, seeded, "static", budget=ANYTIME_BUDGET * 10)
        assert budgeted.solution.routes == plain.solution.routes

    add("one-pass-under-a-budget", one_pass_under_a_budget)

    def same_seed_same_result(mode: str) -> None:
        first, second = (_run(method, seeded, mode, seed=7), _run(method, seeded, mode, seed=7))
        assert first.solution.routes == second.solution.routes
        assert first.cost == second.cost

    def no_tasks(mode: str) -> None:
        outcome = _run(method, edge["no-tasks"], mode)
        assert outcome.cost == 0.0
        assert all(route == () for route in outcome.solution.routes)

    def one_aav(mode: str) -> None:
        instance = edge["one-aav"]
        # A 30 kg AAV with 35 kg of reachable, unhurried work serves some of it.
        assert _run(method, instance, mode).cost < instance.unserved_task_cost * instance.n_tasks

    def unreachable_task(mode: str) -> None:
        instance = edge["unreachable"]
        breakdown = {b.task: b for b in _run(method, instance, mode).evaluation.per_task}
        assert breakdown["T1"].cost.load == 1.0
        assert breakdown["T1"].cost.total >= instance.unserved_task_cost
        assert breakdown["T0"].cost.load < 1.0  # the reachable task is still served

    def demand_beyond_the_fleet(mode: str) -> None:
        instance = edge["over-demand"]
        load = _load_share(_run(method, instance, mode), "T0")
        capacity = sum(a.capacity for a in instance.aavs)
        # Each AAV visits T0 at most once, so at most 40 of the 500 kg are ever covered; a
        # method still sends what it can.
        assert 1 - capacity / 500 - 1e-12 <= load < 1.0

    for mode in ALL_MODES:
        add(f"same-seed-same-result[{mode}]", lambda m=mode: same_seed_same_result(m))
        add(f"no-tasks[{mode}]", lambda m=mode: no_tasks(m))
        add(f"one-aav[{mode}]", lambda m=mode: one_aav(m))
        add(f"unreachable-task[{mode}]", lambda m=mode: unreachable_task(m))
        add(f"demand-beyond-the-fleet[{mode}]", lambda m=mode: demand_beyond_the_fleet(m))

    def all_tasks_released_late() -> None:
        instance = edge["all-late"]
        outcome = _run(method, instance, "dynamic")
        first = outcome.stats["replans"][0]
        assert first["time"] == 0.0 and first["visible"] == 0
        assert first["J"] == instance.unserved_task_cost * instance.n_tasks
        assert [r["time"] for r in outcome.stats["replans"]] == [0.0, 200.0, 400.0]
        assert outcome.cost < instance.unserved_task_cost * instance.n_tasks

    add("all-tasks-released-late", all_tasks_released_late)
    return checks


def check_allocator(method: str | Allocator, *,
                    instances: Mapping[str, Instance] | None = None) -> dict[str, str]:
    """Run every check; returns check name -> "passed" or "skipped: why". The first failure
    raises ``AssertionError`` naming the check."""
    results = {}
    for check in allocator_checks(method, instances=instances):
        try:
            check()
        except CheckSkipped as exc:
            results[check.name] = f"skipped: {exc}"
        except AssertionError as exc:
            raise AssertionError(f"{check}: {exc}") from exc
        else:
            results[check.name] = "passed"
    return results
