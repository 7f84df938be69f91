"""Route edits shared by the constructive and coalition methods: inserting a task visit
(with the largest feasible amount, optionally after a depot visit) and removing one.

Every candidate is priced by the evaluator's incremental path, so "best" always means the
lowest J of the whole plan, never a proxy.
"""

from __future__ import annotations

from collections.abc import Callable, Iterator, Sequence

from tsac_bench.model import Instance, Route, Visit
from tsac_bench.model.evaluator import PlanState, Proposal, RouteTrace


def insertion_routes(instance: Instance, n: int, route: Route, task: int, first_free: int = 0,
                     amount: int = 1) -> Iterator[tuple[Route, int]]:
    """Every way to put ``task`` into AAV n's ``route`` at or after ``first_free``, with and
    without a depot visit right before it. Yields ``(new_route, index of the task visit)``."""
    if any(v.node == task for v in route):
        return
    dist = instance.dist_rows
    to_task = dist[task]
    is_depot = instance.is_depot
    visit = Visit(task, amount)
    # A task may not end a route: an insertion after the last visit brings a depot home.
    home = (Visit(instance.nearest_depot(task)),)
    for i in range(first_free, len(route) + 1):
        prev = route[i - 1].node if i > 0 else instance.start_node(n)
        head, rest = route[:i], route[i:] or home
        yield (*head, visit, *rest), i
        if not is_depot(prev):
            from_prev = dist[prev]
            depot = min(instance.depot_nodes, key=lambda k: from_prev[k] + to_task[k])
            yield (*head, Visit(depot), visit, *rest), i + 1


def max_amount(instance: Instance, trace: RouteTrace, index: int) -> int:
    """Largest amount the task visit at ``index`` of a feasible route could carry, the other
    visits unchanged: the capacity slack over the stretch its goods are on board, and for a
    delivery from a depot the AAV has already left, what it loaded there and the trip does
    not use yet."""
    route, loads = trace.route, trace.loads
    is_depot = instance.is_depot
    capacity = instance.aavs[trace.aav].capacity
    if instance.tasks[route[index].node].is_delivery:
        # Loaded at the last depot visit before it, on board until it is delivered.
        start = index - 1
        while not is_depot(route[start].node):
            start -= 1
        room = capacity - max(loads[start:index])
        if route[start].load is not None:
            room = min(room, route[start].load - trace.delivery_load[start])
    else:
        # Picked up here, on board until the next depot visit unloads it.
        end = index
        while not is_depot(route[end].node):
            end += 1
        room = capacity - max(loads[index:end])
    return route[index].amount + room


def best_insertion(state: PlanState, n: int, task: int, first_free: int = 0,
                   residual: int | None = None,
                   admissible: Callable[[Proposal], bool] | None = None) -> Proposal | None:
    """The cheapest feasible insertion of ``task`` into AAV n's route, carrying as much of
    ``residual`` (default: the task's demand not yet covered on time by other AAVs) as fits.
    ``admissible`` vetoes candidates by a method's own rule (e.g. CNP's binding contracts).
    None when no insertion is feasible (and admissible) or the task needs nothing more."""
    evaluator = state.evaluator
    instance = evaluator.instance
    route = state.traces[n].route
    if residual is None:
        residual = instance.tasks[task].demand - state.covered(task, exclude=n)
    if residual < 1:
        return None
    best: Proposal | None = None
    for candidate, index in insertion_routes(instance, n, route, task, first_free):
        probe = evaluator.trace(n, candidate)
        if probe.errors:
            continue
        amount = min(residual, max_amount(instance, probe, index))
        if amount < 1:
            continue
        if amount != 1:
            candidate = (*candidate[:index], Visit(task, amount), *candidate[index + 1:])
        proposal = state.propose(n, candidate)
        if proposal is None or (admissible is not None and not admissible(proposal)):
            continue
        if best is None or proposal.delta < best.delta:
            best = proposal
    return best


def removal_route(instance: Instance, route: Route, task: int, first_free: int = 0) -> Route:
    """``route`` without its visit to ``task`` (which must lie at or after ``first_free``),
    dropping depot visits the removal made pointless."""
    index = next(i for i, v in enumerate(route) if v.node == task)
    if index < first_free:
        raise ValueError("cannot remove a committed visit")
    visits = list(route[:index] + route[index + 1:])
    is_depot = instance.is_depot
    # Two depot visits in a row: the first is never needed (the second reloads and unloads,
    # and by the triangle inequality skipping it is no longer and no later).
    i = max(first_free, 1)
    while i < len(visits):
        if is_depot(visits[i].node) and is_depot(visits[i - 1].node) and i - 1 >= first_free:
            del visits[i - 1]
        else:
            i += 1
    if not any(not is_depot(v.node) for v in visits[first_free:]):
        # Nothing left to do after the prefix: stop where the prefix stops (at a depot).
        visits = visits[:first_free]
        if visits and not is_depot(visits[-1].node):
            visits.append(Visit(instance.nearest_depot(visits[-1].node)))
    return tuple(visits)


def top_up(plan: PlanState, first_free: Sequence[int]) -> int:
    """Raise the amounts of on-time task visits (after each AAV's committed prefix) towards
    their task's residual demand, as far as capacity allows. Each raise lowers J: C_load falls
    and no time, distance or other load changes. Returns how many visits grew."""
    instance = plan.evaluator.instance
    tasks = instance.tasks
    grown = 0
    for n in range(instance.n_aavs):
        for k in range(first_free[n], len(plan.traces[n].route)):
            trace = plan.traces[n]
            node, amount = trace.route[k].node, trace.route[k].amount
            if node >= instance.n_tasks or \
                    not tasks[node].on_time(trace.arrivals[k]):
                continue
            extra = min(tasks[node].demand - plan.covered(node),
                        max_amount(instance, trace, k) - amount)
            if extra < 1:
                continue
            route = (*trace.route[:k], Visit(node, amount + extra), *trace.route[k + 1:])
            proposal = plan.propose(n, route)
            if proposal is not None and proposal.delta < 0:
                plan.apply(proposal)
                grown += 1
    return grown
