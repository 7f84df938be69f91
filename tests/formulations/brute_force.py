"""Exhaustive search for tiny instances: the third, independent check of the exact models.

Every route of every AAV is enumerated: each ordered subset of the tasks, each task visit
preceded by no depot or by any one depot, closed by a depot (which depot is irrelevant: legs
into depots are not charged and nothing after the last task is timed). Late visits are kept
(so the search does not rely on "late visits never help"). For each route every integer
amount vector with amounts in 1..min(B, R_m) is scored by the evaluator's route walk; of the
feasible ones only those whose on-time amounts are not dominated are kept (more on-time goods
never raise C_load, and C_time and C_op do not depend on amounts). Then every pair of routes
(two AAVs) is priced with numpy: C_time and C_op from the two routes, C_load maximised over
their amount vectors. The best plan is re-scored by the evaluator, which is its J.
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass

import numpy as np

from tsac_bench.model import Instance, Route, Visit
from tsac_bench.model.evaluator import TIME_TOLERANCE, CostEvaluator


@dataclass
class _Routes:
    """All routes of one AAV with what pricing needs, one row per route."""

    routes: list[Route]  # amounts 1 everywhere (placeholder)
    visited: np.ndarray  # (S, M) bool
    late: np.ndarray  # (S, M) bool
    arrival: np.ndarray  # (S, M), -inf where not visited or late
    op: np.ndarray  # (S, M), q_n(m) where visited
    vectors: list[np.ndarray]  # per route: (k, M) undominated amount vectors (all amounts)
    on_time: list[np.ndarray]  # per route: the same with late components zeroed


def _enumerate(instance: Instance, n: int) -> _Routes:
    evaluator = CostEvaluator(instance)
    n_tasks = instance.n_tasks
    capacity = instance.aavs[n].capacity
    t_end = np.array([t.t_end for t in instance.tasks])
    choices = [None, *instance.depot_nodes]
    out = _Routes([], [], [], [], [], [], [])  # type: ignore[arg-type]
    for length in range(n_tasks + 1):
        for order in itertools.permutations(range(n_tasks), length):
            for depots in itertools.product(choices, repeat=length):
                visits: list[Visit] = []
                for task, depot in zip(order, depots, strict=True):
                    if depot is not None:
                        visits.append(Visit(depot))
                    visits.append(Visit(task, 1))
                if visits:
                    visits.append(Visit(instance.nearest_depot(order[-1])))
                route = tuple(visits)
                if not evaluator.trace(n, route).feasible:
                    continue  # amounts of 1 already overload it: larger ones do too
                positions = [k for k, v in enumerate(route) if not instance.is_depot(v.node)]
                ranges = [range(1, min(capacity, instance.tasks[order[i]].demand) + 1)
                          for i in range(length)]
                rows = []
                trace = None
                for amounts in itertools.product(*ranges):
                    candidate = list(route)
                    for k, a in zip(positions, amounts, strict=True):
                        candidate[k] = Visit(route[k].node, a)
                    probe = evaluator.trace(n, candidate)
                    if probe.feasible:
                        trace = trace or probe
                        row = np.zeros(n_tasks, dtype=int)
                        row[list(order)] = amounts
                        rows.append(row)
                visited = np.zeros(n_tasks, bool)
                late = np.zeros(n_tasks, bool)
                arrival = np.full(n_tasks, -np.inf)
                op = np.zeros(n_tasks)
                if trace is not None:
                    for m, c in trace.contributions:
                        visited[m] = True
                        op[m] = c.op_cost
                        if c.arrival > t_end[m] + TIME_TOLERANCE:
                            late[m] = True
                        else:
                            arrival[m] = c.arrival
                matrix = np.array(rows).reshape(-1, n_tasks) if rows else np.zeros((1, n_tasks),
                                                                                 int)
                on_time = np.where(late, 0, matrix)
                # Keep one amount vector per undominated on-time vector.
                _, first = np.unique(on_time, axis=0, return_index=True)
                matrix, on_time = matrix[first], on_time[first]
                keep = [i for i, r in enumerate(on_time) if not np.any(
                    np.all(on_time >= r, axis=1) & np.any(on_time > r, axis=1))]
                out.routes.append(route)
                out.visited.append(visited)
                out.late.append(late)
                out.arrival.append(arrival)
                out.op.append(op)
                out.vectors.append(matrix[keep])
                out.on_time.append(on_time[keep])
    out.visited = np.array(out.visited)
    out.late = np.array(out.late)
    out.arrival = np.array(out.arrival)
    out.op = np.array(out.op)
    return out


def _with_amounts(instance: Instance, route: Route, amounts: np.ndarray) -> Route:
    return tuple(v if instance.is_depot(v.node) else Visit(v.node, int(amounts[v.node]))
                 for v in route)


def brute_force(instance: Instance) -> tuple[float, tuple[Route, ...]]:
    """The optimal J of a two-AAV instance and a plan that reaches it."""
    if instance.n_aavs != 2:
        raise ValueError("brute force handles exactly two AAVs")
    w1, w2, w3 = instance.weights
    demand = np.array([t.demand for t in instance.tasks], dtype=float)
    t_start = np.array([t.t_start for t in instance.tasks])
    first, second = _enumerate(instance, 0), _enumerate(instance, 1)
    # All amount vectors of the second AAV stacked, with the route each belongs to.
    stacked = np.vstack(second.on_time)
    owner = np.concatenate([np.full(len(v), s) for s, v in enumerate(second.on_time)])
    starts = np.searchsorted(owner, np.arange(len(second.routes)))
    best = (np.inf, None)
    for s1 in range(len(first.routes)):
        visited = first.visited[s1] | second.visited
        late = first.late[s1] | second.late
        latest = np.maximum(first.arrival[s1], second.arrival)
        c_time = np.where(visited & ~late, (latest - t_start) / instance.horizon, 1.0)
        c_op = first.op[s1] + second.op
        fixed = (w2 * c_time + w3 * c_op).sum(axis=1)
        share = np.minimum(1.0, (first.on_time[s1][:, None, :] + stacked[None, :, :]) / demand)
        per_row = share.sum(axis=2).max(axis=0)
        served = np.maximum.reduceat(per_row, starts)
        total = fixed + w1 * (instance.n_tasks - served)
        s2 = int(np.argmin(total))
        if total[s2] < best[0] - 1e-12:
            best = (float(total[s2]), (s1, s2))
    assert best[1] is not None
    s1, s2 = best[1]
    # Recover the amount vectors that reach the optimum.
    rows1, rows2 = first.on_time[s1], second.on_time[s2]
    share = np.minimum(1.0, (rows1[:, None, :] + rows2[None, :, :]) / demand).sum(axis=2)
    i1, i2 = np.unravel_index(int(np.argmax(share)), share.shape)
    plan = (_with_amounts(instance, first.routes[s1], first.vectors[s1][i1]),
            _with_amounts(instance, second.routes[s2], second.vectors[s2][i2]))
    J = CostEvaluator(instance).cost(plan)
    assert abs(J - best[0]) <= 1e-7 * max(1.0, J), (J, best[0])
    return J, plan
