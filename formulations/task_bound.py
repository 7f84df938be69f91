"""A lower bound on a planning state's J that needs no search: each task on its own.

``J = sum_m C_m`` and C_m depends only on the visits to m (docs/model.md). Relax everything
that links the tasks (an AAV flies to one place at a time, shares its load and its range
along a trip) and each task keeps only this: AAV n can arrive no earlier than its straight
flight from its anchor allows (by way of a depot for a delivery when it carries no goods),
brings at most its capacity, and pays for the leg into m at least ``alpha_n`` times the
shortest leg any node offers into m (capped at its range: a visit beyond it pays the full
range cost, which is more). The least C_m over every set of AAVs that could visit m so is
a lower bound on C_m in any plan: a late visitor only sets ``C_time = 1``, which no on-time
coalition's term exceeds, and the partial service term falls linearly in the amount.

Every task no plan of the state may visit costs ``w1 + w2`` exactly (docs/model.md). A task
that a committed prefix already visits is bounded by 0 (its coalition is partly fixed; the
bound stays valid, only weaker).

The bound is cheap (one small knapsack per task, 0.06 s at 32/80) and weak where the
linking matters, which is the paper's scales: its median over the 100 instances per scale
of instances/paper-mc/ is 23 % of the best static J known at 4/10, 15 % at 8/20, 11 % at
16/40 and 7 % at 32/80 (docs/formulations.md). The exact methods report it where it beats
their own bound, so a run stopped before its solver has a bound still has one.
"""

from __future__ import annotations

import math

import numpy as np

from tsac_bench.planning import PlanningState

#: Arrivals of the straight flights are shortened by this relative amount, so that float
#: sums of real legs that are longer but round lower never fall before the bound's arrival.
ARRIVAL_SLACK = 1e-9


def task_lower_bound(state: PlanningState) -> float:
    """The sum over the instance's tasks of each task's least cost on its own (above)."""
    return math.fsum(task_lower_bounds(state))


def task_lower_bounds(state: PlanningState) -> list[float]:
    """Each task's least cost on its own (above), by task index: ``w1 + w2`` where no plan
    of the state may visit it, 0 where a committed prefix does."""
    instance = state.instance
    n_tasks = instance.n_tasks
    w1, w2, w3 = instance.weights
    dist = instance.dist
    depots = list(instance.depot_nodes)
    touched = {v.node for prefix in state.committed for v in prefix if v.node < n_tasks}
    anchors = [state.anchor(n) for n in range(instance.n_aavs)]
    least = [0.0 if m in touched else instance.unserved_task_cost for m in range(n_tasks)]
    for m in sorted(state.visible - touched):
        task = instance.tasks[m]
        # The shortest leg into m from any node but m itself (AAV starts join per AAV).
        others = [j for j in range(n_tasks) if j != m] + depots
        shortest_in = float(dist[others, m].min())
        members = []  # (theta, op term, kg) of each AAV that can be on time at m
        for n, aav in enumerate(instance.aavs):
            anchor = anchors[n]
            # Legs summed in the evaluator's order; "via" the anchor itself adds 0 exactly.
            via = [anchor.node] if not task.is_delivery or anchor.on_board != 0 else depots
            arrival = min(anchor.time + dist[anchor.node, k] / aav.speed + dist[k, m] / aav.speed
                          for k in via)
            arrival = max(task.t_start, arrival * (1.0 - ARRIVAL_SLACK))
            if not task.on_time(arrival):
                continue
            leg = min(shortest_in, float(dist[anchor.node, m]), aav.max_range)
            members.append(((arrival - task.t_start) / instance.horizon,
                            w3 * aav.alpha / 1000.0 / instance.e_base * leg,
                            min(aav.capacity, task.demand)))
        least[m] = _least_task_cost(members, task.demand, w1, w2, instance.unserved_task_cost)
    return least


def _least_task_cost(members: list[tuple[float, float, int]], demand: int, w1: float,
                     w2: float, unserved: float) -> float:
    """min(unserved, w1 (1 - kg / demand) + w2 * latest theta + sum of op terms) over the
    non-empty sets of ``members``: taken in order of arrival, the latest member of a set
    is the one just added, and ``cheapest[c]`` is the least op sum of a set so far that
    brings c kg (capped at the demand)."""
    best = unserved
    cheapest = np.full(demand + 1, np.inf)
    cheapest[0] = 0.0
    served = np.arange(demand + 1) / demand
    for theta, op, kg in sorted(members):
        grown = cheapest.copy()
        grown[kg:] = np.minimum(grown[kg:], cheapest[:demand + 1 - kg] + op)
        grown[demand] = min(grown[demand], cheapest[demand - kg:].min() + op)
        cheapest = grown
        best = min(best, float((w1 * (1.0 - served[1:]) + w2 * theta + cheapest[1:]).min()))
    return best
