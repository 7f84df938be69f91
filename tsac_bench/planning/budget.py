"""Budgets per plan call: how a method uses one, when an anytime call stops, its incumbent
trace, and the rule that flags a call as over its budget.

A *budget* is wall-clock seconds per plan call, the same for every method compared: the
footing of the EURO Meets NeurIPS 2022 vehicle routing competition (one time limit per
instance and epoch on the same hardware). Every method gets it as its ``time_limit``; a method
declares what more it does with it (``budget_use``, a class attribute):

* ``"anytime"``: it improves its plan until the budget is spent and returns its best. It
  declares ``unbounded_settings`` (the settings that lift its own stopping rule, e.g. OCF's
  ``samples=None``: a budgeted call gets them) and ``work_setting`` (the setting that caps its
  work count, e.g. ``decisions``). A budgeted call records ``stats["work"]`` (the work it did,
  in the unit ``work_unit``) and ``stats["trace"]`` (``[seconds, J]`` at each improvement of
  its best plan); the method re-run with ``work_setting=work`` and no budget returns the same
  plan, which is what makes a budgeted result reproducible on another machine (the
  deterministic work limits of MIP solvers).
* ``"one-pass"``: it builds one plan and stops (greedy, cnp); the budget only caps it.
* ``"time-limit"``: it searches until its time limit and returns its incumbent (and, for an
  exact method, its bound). What a method that declares nothing is taken to do.
"""

from __future__ import annotations

import time
from collections.abc import Mapping
from typing import Any

from tsac_bench.errors import InvalidSetting, TsacBenchError

__all__ = [
    "ANYTIME",
    "BUDGET_USES",
    "ONE_PASS",
    "TIME_LIMIT",
    "IncumbentTrace",
    "WorkStop",
    "budget_use",
    "budgeted_settings",
    "check_budget",
    "is_over_budget",
    "over_budget_limit",
    "reference_units",
    "require_a_stop",
]

ANYTIME, ONE_PASS, TIME_LIMIT = "anytime", "one-pass", "time-limit"
BUDGET_USES = (ANYTIME, ONE_PASS, TIME_LIMIT)

#: A plan call is over its budget when it returns later than budget * (1 + share) + seconds:
#: the share absorbs a method's last unit of work, the seconds the fixed cost of a call
#: (checks, copies) that no method can spend less than.
OVER_BUDGET_SHARE, OVER_BUDGET_SECONDS = 0.10, 0.05


def budget_use(allocator: object) -> str:
    """How an allocator (class or instance) uses a budget (module docstring)."""
    use = getattr(allocator, "budget_use", TIME_LIMIT)
    if use not in BUDGET_USES:
        name = getattr(allocator, "name", type(allocator).__name__)
        raise TsacBenchError(f"method {name!r}: budget_use: expected one of "
                             f"{', '.join(BUDGET_USES)}, got {use!r}")
    return use


def check_budget(budget: float, where: str = "--budget") -> float:
    """``budget`` if it is a positive finite number of seconds; one line naming ``where``
    otherwise."""
    if isinstance(budget, bool) or not isinstance(budget, int | float) or not (
            0 < budget < float("inf")):
        raise TsacBenchError(f"{where}: expected seconds > 0, got {budget!r}")
    return float(budget)


def budgeted_settings(method: str, cls: object, settings: Mapping[str, Any]) -> dict[str, Any]:
    """``settings`` for a budgeted plan call of ``method``: an anytime method's
    ``unbounded_settings`` added, so that only the budget stops it. Giving one of them as
    well is an error: a budget and a work cap would be two stopping rules, and which one
    ended a call would depend on the machine."""
    if budget_use(cls) != ANYTIME:
        return dict(settings)
    unbounded: Mapping[str, Any] = getattr(cls, "unbounded_settings", {})
    given = sorted(set(unbounded) & set(settings))
    if given:
        raise InvalidSetting(f"method {method!r} setting {given[0]!r}: not with a budget (a "
                             "budgeted call lifts it; the budget alone stops the method)")
    return {**settings, **unbounded}


def require_a_stop(method: str, setting: str, time_limit: float | None,
                   *limits: object) -> None:
    """Refuse an anytime call that nothing would stop: no time limit and every one of
    ``limits`` (its work caps) None; ``setting`` names the first of them."""
    if time_limit is None and all(limit is None for limit in limits):
        raise InvalidSetting(f"method {method!r} setting {setting!r}: none needs a budget "
                             "or a time limit (nothing else would stop the method)")


def over_budget_limit(budget: float) -> float:
    """The latest a plan call with ``budget`` seconds may return."""
    return budget * (1 + OVER_BUDGET_SHARE) + OVER_BUDGET_SECONDS


def is_over_budget(seconds: float, budget: float | None) -> bool:
    return budget is not None and seconds > over_budget_limit(budget)


def reference_units(budget: float, calibration: Mapping[str, Any] | None) -> float | None:
    """A budget in reference units: seconds divided by the reference workload's seconds on
    the machine (``tsac_bench.batch.calibrate``); None without a calibration."""
    return None if not calibration else budget / calibration["seconds"]


class WorkStop:
    """When an anytime plan call stops: at ``time_limit`` seconds after it began, or once
    ``work_limit`` units of work are done, whichever comes first (None: no such limit).

    The method asks ``reached()`` before each unit of work (a game decision, an evaluated
    individual) and calls ``done()`` after it, at the same points whichever limit applies, so
    that a call stopped by time and one stopped by the work count it recorded end on the
    same unit.

    With ``look_ahead`` a unit does not start when the mean unit so far (the call's elapsed
    time over its units, setup included, so an overestimate) would end past the deadline:
    for units long enough to overrun a budget on their own (a DGA individual at 32/80 takes
    up to 0.2 s), where a game decision takes microseconds and needs no such care."""

    def __init__(self, time_limit: float | None, work_limit: int | None,
                 began: float | None = None, look_ahead: bool = False) -> None:
        self.began = time.perf_counter() if began is None else began
        self.deadline = None if time_limit is None else self.began + time_limit
        self.work_limit = work_limit
        self.look_ahead = look_ahead
        self.work = 0

    def reached(self) -> str | None:
        """Why no more work may start ("work" or "time-limit"), or None."""
        if self.work_limit is not None and self.work >= self.work_limit:
            return "work"
        if self.deadline is not None:
            now = time.perf_counter()
            mean_unit = (now - self.began) / self.work if self.look_ahead and self.work else 0.0
            if now + mean_unit > self.deadline:
                return "time-limit"
        return None

    def done(self, units: int = 1) -> None:
        self.work += units

    def elapsed(self) -> float:
        return time.perf_counter() - self.began


class IncumbentTrace:
    """``[seconds since the call began, J]`` each time the call's best plan improves: the
    curve that primal integrals and times to target are computed from."""

    def __init__(self, began: float) -> None:
        self.began = began
        self.points: list[list[float]] = []

    @property
    def best(self) -> float:
        return self.points[-1][1] if self.points else float("inf")

    def offer(self, cost: float, at: float | None = None) -> bool:
        """Record ``cost`` (a plan's J, found at perf_counter time ``at``, default now) if it
        improves the best; returns whether it did."""
        if cost >= self.best:
            return False
        when = time.perf_counter() if at is None else at
        self.points.append([max(0.0, when - self.began), float(cost)])
        return True
