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

from tsac_bench.allocator import PlanningState, PlanResult, Settings
from tsac_bench.evaluator import CostEvaluator
from tsac_bench.insertion import best_insertion


class GreedyAllocator(Settings):
    name = "greedy"

    def __init__(self) -> None:
        pass

    def plan(self, state: PlanningState, *, seed: int = 0,
             time_limit: float | None = None) -> PlanResult:
        del seed  # deterministic by construction
        deadline = None if time_limit is None else time.perf_counter() + time_limit
        instance = state.instance
        plan = CostEvaluator(instance).state(state.base_routes())
        order = sorted(state.visible, key=lambda m: (instance.tasks[m].t_end,
                                                     -instance.tasks[m].demand, m))
        insertions, stopped = 0, "done"
        for task in order:
            while True:
                if deadline is not None and time.perf_counter() > deadline:
                    stopped = "time-limit"
                    break
                best = None
                for n in range(instance.n_aavs):
                    proposal = best_insertion(plan, n, task, state.first_free(n))
                    if proposal is not None and (best is None or proposal.delta < best.delta):
                        best = proposal
                if best is None or best.delta >= 0:
                    break
                plan.apply(best)
                insertions += 1
            if stopped != "done":
                break
        return PlanResult(plan.routes, {"insertions": insertions, "stop": stopped})
