"""Split polishing: the best payload amounts for fixed visit sequences (cvxpy + HiGHS).

With every AAV's sequence of visits fixed, arrival times, distances and so C_time and C_op
do not depend on the amounts; only C_load (Eq. 5) and the load limits (Eq. 10) do. The
amounts that minimise J therefore solve a small integer program: maximise the covered share
sum_m w1 * min(R_m, on-time goods of m) / R_m subject to, on every trip, d + p <= B after
each visit (d: deliveries still ahead in the trip, p: pickups since its start), every visit
keeping an amount >= 1 (the sequence stays as it is). A late visit keeps amount 1 (its goods
earn nothing and take room).

``polish`` never returns a worse solution: the polished routes are re-scored by the
evaluator and kept only if their J is lower. Comparing J before and after tells how much of
a method's gap is splitting rather than routing.
"""

from __future__ import annotations

from collections.abc import Sequence

from tsac_bench.model import Instance, Route, Solution
from tsac_bench.model.evaluator import CostEvaluator


def polish_routes(instance: Instance, routes: Sequence[Route]) -> tuple[Route, ...]:
    """The routes with their amounts re-optimised (feasible; J not raised)."""
    import cvxpy as cp

    evaluator = CostEvaluator(instance)
    routes = tuple(tuple(r) for r in routes)
    before = evaluator.cost(routes)
    visits = [(n, k) for n, r in enumerate(routes) for k, v in enumerate(r)
              if not instance.is_depot(v.node)]
    if not visits:
        return routes
    index = {key: i for i, key in enumerate(visits)}
    a = cp.Variable(len(visits), integer=True)
    constraints = [a >= 1]
    covered_by: dict[int, list[int]] = {}
    for n, route in enumerate(routes):
        trace = evaluator.trace(n, route)
        capacity = instance.aavs[n].capacity
        for k, v in enumerate(route):
            if instance.is_depot(v.node):
                continue
            if not instance.tasks[v.node].on_time(trace.arrivals[k]):
                constraints.append(a[index[n, k]] == 1)
            else:
                covered_by.setdefault(v.node, []).append(index[n, k])
        # Trips: the stretches between depot visits (the first one starts at the start).
        bounds = [-1, *(k for k, v in enumerate(route) if instance.is_depot(v.node))]
        for first, last in zip(bounds, [*bounds[1:], len(route)], strict=True):
            trip = list(range(first + 1, last))
            deliveries = [k for k in trip if instance.tasks[route[k].node].is_delivery]
            pickups = [k for k in trip if not instance.tasks[route[k].node].is_delivery]
            if first == -1 and deliveries:
                raise ValueError(f"route of {instance.aavs[n].id} delivers before a depot")
            if first >= 0 and deliveries:  # the depot loads every delivery of the trip
                loaded = route[first].load  # a dynamic run's record of what it loaded
                limit = capacity if loaded is None else min(capacity, loaded)
                constraints.append(sum(a[index[n, k]] for k in deliveries) <= limit)
            for k in trip:
                ahead = [a[index[n, i]] for i in deliveries if i > k]
                behind = [a[index[n, i]] for i in pickups if i <= k]
                if ahead or behind:
                    constraints.append(sum(ahead + behind) <= capacity)
    w1 = instance.weights[0]
    tasks = sorted(covered_by)
    share = cp.Variable(len(tasks))
    gain = 0
    for i, m in enumerate(tasks):
        demand = instance.tasks[m].demand
        constraints += [share[i] <= demand, share[i] <= sum(a[j] for j in covered_by[m])]
        gain += w1 * share[i] / demand
    problem = cp.Problem(cp.Maximize(gain), constraints)
    problem.solve(solver=cp.HIGHS)
    if problem.status not in ("optimal", "optimal_inaccurate") or a.value is None:
        return routes
    amounts = [round(float(x)) for x in a.value]
    polished = tuple(
        tuple(v if instance.is_depot(v.node) else v._replace(amount=amounts[index[n, k]])
              for k, v in enumerate(route))
        for n, route in enumerate(routes))
    result = evaluator.evaluate(polished)
    if not result.feasible or result.J is None or before <= result.J:
        return routes
    return polished


def polish(instance: Instance, solution: Solution) -> Solution:
    """``solution`` with re-optimised amounts, its cost recomputed by the evaluator."""
    routes = polish_routes(instance, solution.routes)
    cost = CostEvaluator(instance).cost(routes)
    meta = {**solution.meta, "polished": routes != tuple(solution.routes)}
    return Solution(solution.instance, routes, cost, meta)
