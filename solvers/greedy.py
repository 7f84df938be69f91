"""``greedy``: earliest-deadline-first cheapest insertion with payload splitting.

Tasks are taken by deadline (then larger demand first, then id). For each task, the AAV and
position whose insertion lowers J the most receive as much of the residual demand as fits
(the evaluator prices every candidate, depot detours included); this repeats while the task
still has residual demand and an insertion still lowers J, which splits a heavy task across
several AAVs. Deterministic: ties go to the lowest AAV index and earliest position.

It is the warm start of the exact solvers and the floor every other method must beat.
"""

from __future__ import annotations

import time
from collections.abc import Iterable
from typing import ClassVar

from tsac_bench.model.evaluator import PlanState
from tsac_bench.planning import PlanningState, PlanResult, Settings, declare
from tsac_bench.planning.budget import ONE_PASS
from tsac_bench.planning.insertion import best_insertion


def insert_cheapest(plan: PlanState, state: PlanningState, tasks: Iterable[int],
                    deadline: float | None = None) -> tuple[int, str]:
    """For each task in turn, apply the cheapest insertion of its residual demand while one
    lowers J. Returns the number of insertions and why it stopped ("done" or "time-limit")."""
    n_aavs = state.instance.n_aavs
    insertions = 0
    for task in tasks:
        while True:
            if deadline is not None and time.perf_counter() > deadline:
                return insertions, "time-limit"
            best = None
            for n in range(n_aavs):
                proposal = best_insertion(plan, n, task, state.first_free(n))
                if proposal is not None and (best is None or proposal.delta < best.delta):
                    best = proposal
            if best is None or best.delta >= 0:
                break
            plan.apply(best)
            insertions += 1
    return insertions, "done"


def deadline_order(state: PlanningState) -> list[int]:
    """Visible tasks by deadline, then larger demand first, then index."""
    tasks = state.instance.tasks
    return sorted(state.visible, key=lambda m: (tasks[m].t_end, -tasks[m].demand, m))


class GreedyAllocator(Settings):
    name = "greedy"
    budget_use: ClassVar[str] = ONE_PASS
    setting_constraints = declare()

    def __init__(self) -> None:
        pass

    def plan(self, state: PlanningState, *, seed: int = 0,
             time_limit: float | None = None) -> PlanResult:
        del seed  # deterministic by construction
        deadline = None if time_limit is None else time.perf_counter() + time_limit
        plan = state.evaluator().state(state.base_routes())
        insertions, stopped = insert_cheapest(plan, state, deadline_order(state), deadline)
        return PlanResult(plan.routes, {"insertions": insertions, "stop": stopped})
