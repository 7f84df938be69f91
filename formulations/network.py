"""What the exact models share: the canonical form of a solution and the routing network of
each AAV (which task visits and which arcs can occur in an optimal solution).

Canonical form (docs/model.md, "Cost", says why late visits never help): every feasible
solution can be turned, without raising J, into one in which
* no visit is late (dropping a late visit never raises J),
* at most one depot visit lies between two task visits and before the first one (of two depot
  visits in a row the first is useless: by the triangle inequality skipping it is no longer and
  no later, and the second one loads and unloads the same goods),
* no task receives more than its demand in total (an amount above the residual earns nothing;
  lowering it keeps every load feasible; a visit left with nothing to bring is dropped, which
  by the triangle inequality shortens the next leg at least as much as the dropped leg costs),
* a route ends right after its last task visit with one depot visit (legs into depots are not
  charged and nothing after the last task is timed or charged).
So an exact model may search canonical solutions only. ``canonical_routes`` performs these
steps and never raises J (it is checked by the evaluator in the tests).

Arc pruning (``aav_network``): a task visit of AAV n is possible only if its earliest arrival
(straight from the start, through a depot for a delivery) is not after t_end; an arc i -> j
(direct or through depot k) only if leaving i at its earliest arrival reaches j by t_end(j); a
delivery cannot follow the start directly (no goods before a depot visit); a depot k between
i and j is dominated by a depot k' that is no farther in total and no farther from j (same
load effect, no later, no costlier leg into j).
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Sequence
from dataclasses import dataclass, field

from tsac_bench.model import Instance, Route, Visit
from tsac_bench.model.evaluator import TIME_TOLERANCE, CostEvaluator

#: The start node of an AAV in the networks below (tasks are 0..M-1).
START = -1
#: The mode of an arc that goes straight to the next task (otherwise the mode is a depot node).
DIRECT = -1


def canonical_routes(instance: Instance, routes: Sequence[Route],
                     first_free: Sequence[int] | None = None,
                     plan_time: float = 0.0) -> tuple[Route, ...]:
    """``routes`` (feasible) in canonical form, J not raised; visits before ``first_free[n]``
    (a committed prefix) are left as they are, the others are timed as planned at
    ``plan_time``."""
    free = list(first_free) if first_free is not None else [0] * len(routes)
    evaluator = CostEvaluator(instance, plan_time, free)
    routes = [tuple(r) for r in routes]
    is_depot = instance.is_depot
    # Late visits first: they carry no on-time goods, so nothing else depends on them.
    for n, route in enumerate(routes):
        trace = evaluator.trace(n, route)
        keep = [v for k, v in enumerate(route)
                if k < free[n] or is_depot(v.node)
                or instance.tasks[v.node].on_time(trace.arrivals[k])]
        routes[n] = tuple(keep)
    # Amounts above the demand: cut the latest-indexed AAVs' shares first (deterministic).
    for m, task in enumerate(instance.tasks):
        holders = [(n, k) for n, route in enumerate(routes) for k, v in enumerate(route)
                   if v.node == m]
        excess = sum(routes[n][k].amount for n, k in holders) - task.demand
        for n, k in reversed(holders):
            if excess <= 0:
                break
            if k < free[n]:
                continue
            amount = routes[n][k].amount
            cut = min(excess, amount)
            excess -= cut
            route = list(routes[n])
            route[k] = route[k]._replace(amount=amount - cut)
            routes[n] = tuple(route)
    for n, route in enumerate(routes):
        head = list(route[:free[n]])
        tail = [v for v in route[free[n]:] if is_depot(v.node) or v.amount > 0]
        merged: list[Visit] = []
        for v in tail:
            # Of two depot visits in a row keep the second (it is the one that loads).
            if merged and is_depot(v.node) and is_depot(merged[-1].node):
                merged[-1] = v
            elif not merged and head and is_depot(v.node) and is_depot(head[-1].node):
                continue  # a committed depot visit already precedes it
            else:
                merged.append(v)
        for i, v in enumerate(merged):
            if is_depot(v.node) and i + 1 < len(merged):
                prev = merged[i - 1].node if i > 0 else (
                    head[-1].node if head else instance.start_node(n))
                merged[i] = Visit(best_depot(instance, prev, v.node, merged[i + 1].node))
        # Drop trailing depot visits; one is added back after the last task.
        while merged and is_depot(merged[-1].node):
            merged.pop()
        full = head + merged
        if merged:
            full.append(Visit(instance.nearest_depot(merged[-1].node)))
        elif head and not is_depot(head[-1].node):
            full.append(Visit(instance.nearest_depot(head[-1].node)))
        routes[n] = tuple(full)
    return tuple(routes)


@dataclass(frozen=True)
class Arc:
    """AAV n flies from ``tail`` (a task or START) to task ``head``, through depot ``mode``
    unless mode is DIRECT."""

    tail: int
    head: int
    mode: int
    distance: float  # metres flown from tail to head
    leg: float  # metres of the leg into head (from tail, or from the depot)
    travel: float  # seconds


@dataclass
class AavNetwork:
    """The task visits and arcs one AAV may use in a canonical solution.

    ``anchor`` is the tail of the arcs a plan may choose first (the last committed task, or
    START); the AAV leaves the node it last committed to (that task, its start position or a
    committed depot visit after them) no earlier than ``ready``."""

    n: int
    tasks: list[int]
    earliest: dict[int, float]  # earliest arrival at each task (Eq. 7 lower bound)
    latest: dict[int, float]  # t_end (late visits are excluded)
    min_distance: dict[int, float]  # least Dcum on arrival
    arcs: list[Arc] = field(default_factory=list)
    anchor: int = START
    ready: float = 0.0
    committed_depot: int | None = None

    def ready_arrival(self, arc: Arc, speed: float) -> float:
        """The earliest arrival at the head of a free arc out of the anchor: from ``ready``
        at the committed depot (only its leg into the head is left) or at the anchor."""
        return self.ready + (arc.leg if self.committed_depot is not None else arc.distance) \
            / speed

    def arcs_into(self, j: int) -> list[Arc]:
        return [a for a in self.arcs if a.head == j]

    def arcs_out_of(self, i: int) -> list[Arc]:
        return [a for a in self.arcs if a.tail == i]


def aav_network(instance: Instance, n: int, tasks: Sequence[int],
                fixed_arrival: dict[int, float] | None = None,
                required: Sequence[tuple[int, int, int]] = (),
                committed_depot: tuple[int, int] | None = None,
                anchor: int = START, ready: float = 0.0) -> AavNetwork:
    """AAV n's network over ``tasks``. ``fixed_arrival`` gives the known arrival of committed
    visits (kept even when late); ``required`` lists (tail, head, mode) arcs that must exist
    (a committed prefix); ``committed_depot`` = (tail, depot) when the prefix ends with a depot
    visit after ``tail``: every way on from ``tail`` then goes through that depot, dominated
    or not, since it has been flown already. ``anchor`` and ``ready``: the tail of the free
    arcs and when the AAV can leave for them (see AavNetwork)."""
    fixed_arrival = fixed_arrival or {}
    aav = instance.aavs[n]
    dist = instance.dist_rows
    start = instance.start_node(n)
    depots = list(instance.depot_nodes)
    v = aav.speed

    def position(i: int) -> int:
        return start if i == START else i

    def modes(i: int, j: int) -> list[tuple[int, float, float]]:
        """(mode, distance, leg) of every undominated way from i to j."""
        p = position(i)
        if committed_depot is not None and i == committed_depot[0]:
            k = committed_depot[1]
            return [(k, *depot_leg(instance, p, k, j))]
        options = sorted({(k, *depot_leg(instance, p, k, j))
                          for k in (best_depot(instance, p, k, j) for k in depots)})
        if not (i == START and instance.tasks[j].is_delivery):
            options.insert(0, (DIRECT, dist[p][j], dist[p][j]))
        return options

    earliest, latest, min_distance = {}, {}, {}
    kept = []
    for j in tasks:
        task = instance.tasks[j]
        first = modes(START, j)
        # Bounds are widened by float noise so that a route's own walk always fits them.
        shortest = min(m[1] for m in first) * (1 - 1e-12)
        if j in fixed_arrival:
            early = late = fixed_arrival[j]
        else:
            early, late = max(task.t_start, shortest / v), task.latest_on_time
            if early > late:
                continue
        earliest[j], latest[j], min_distance[j] = early, late, shortest
        kept.append(j)
    network = AavNetwork(n, kept, earliest, latest, min_distance, anchor=anchor, ready=ready,
                         committed_depot=None if committed_depot is None else committed_depot[1])
    must = set(required)
    for i in [START, *kept]:
        leave = 0.0 if i == START else earliest[i]
        for j in kept:
            if j == i:
                continue
            for mode, distance, leg in modes(i, j):
                travel = distance / v
                arrival = leave + travel
                if i == anchor:
                    arrival = max(arrival, network.ready_arrival(
                        Arc(i, j, mode, distance, leg, travel), v))
                if arrival <= latest[j] + TIME_TOLERANCE or (i, j, mode) in must:
                    network.arcs.append(Arc(i, j, mode, distance, leg, travel))
    present = {(a.tail, a.head, a.mode) for a in network.arcs}
    for i, j, mode in must - present:
        # A committed arc through a dominated depot: add it back as it was flown.
        p = position(i)
        distance = dist[p][j] if mode == DIRECT else dist[p][mode] + dist[mode][j]
        leg = dist[p][j] if mode == DIRECT else dist[mode][j]
        network.arcs.append(Arc(i, j, mode, distance, leg, distance / v))
    return network


def depot_leg(instance: Instance, p: int, k: int, j: int) -> tuple[float, float]:
    """(distance, leg into j) of flying p -> depot k -> task j."""
    dist = instance.dist_rows
    return dist[p][k] + dist[k][j], dist[k][j]


def best_depot(instance: Instance, p: int, k: int, j: int) -> int:
    """The depot that replaces k between p and task j: among the depots no farther in total
    and no farther from j (same loads, no later, no costlier leg into j) the first by
    (distance, leg, index). It is undominated, so the exact models keep only these."""
    distance, leg = depot_leg(instance, p, k, j)
    candidates = [(*depot_leg(instance, p, o, j), o) for o in instance.depot_nodes]
    return min(c for c in candidates if c[0] <= distance and c[1] <= leg)[2]


@dataclass(frozen=True)
class Prefix:
    """A committed prefix as arcs of the network: ``steps`` are (tail, head, mode, amount) in
    order; ``trailing_depot`` is a depot visit after the last committed task (or None)."""

    steps: tuple[tuple[int, int, int, int], ...]
    trailing_depot: int | None
    #: The delivery goods recorded on the committed depot visit before a task (by task).
    loads: dict[int, int] = field(default_factory=dict)

    @property
    def last(self) -> int:
        return self.steps[-1][1] if self.steps else START


class UnsupportedPrefix(ValueError):
    """A committed prefix that no canonical solution has (two depot visits in a row)."""


def parse_prefix(instance: Instance, prefix: Route) -> Prefix:
    steps, pending, tail, loads = [], None, START, {}
    for v in prefix:
        if instance.is_depot(v.node):
            if pending is not None:
                raise UnsupportedPrefix("a committed prefix with two depot visits in a row")
            pending = v
        else:
            steps.append((tail, v.node, DIRECT if pending is None else pending.node, v.amount))
            if pending is not None and pending.load is not None:
                loads[v.node] = pending.load
            tail, pending = v.node, None
    return Prefix(tuple(steps), None if pending is None else pending.node, loads)


def prefix_arrivals(instance: Instance, n: int, prefix: Route) -> dict[int, float]:
    """Arrival (Eq. 7) of each committed task visit of AAV n."""
    if not prefix:
        return {}
    trace = CostEvaluator(instance).trace(n, prefix)
    return {v.node: t for v, t in zip(prefix, trace.arrivals, strict=True)
            if not instance.is_depot(v.node)}


def late_committed(instance: Instance, committed: Sequence[Route]) -> set[tuple[int, int]]:
    """(AAV, task) pairs of committed visits that are late (they earn nothing, C_time = 1)."""
    late = set()
    for n, prefix in enumerate(committed):
        for m, t in prefix_arrivals(instance, n, prefix).items():
            if not instance.tasks[m].on_time(t):
                late.add((n, m))
    return late


def identical_groups(instance: Instance, committed: Sequence[Route],
                     reach: Sequence[frozenset[int] | None] | None = None) -> list[list[int]]:
    """Groups (size >= 2) of interchangeable AAVs: same parameters, same start, no prefix
    and, where ``reach`` limits each AAV's tasks, the same tasks in reach."""
    groups: dict[tuple, list[int]] = {}
    for n, a in enumerate(instance.aavs):
        if committed and committed[n]:
            continue
        key = (a.x, a.y, a.speed, a.capacity, a.max_range, a.alpha, a.lam,
               None if reach is None else reach[n])
        groups.setdefault(key, []).append(n)
    return [g for g in groups.values() if len(g) > 1]


def first_task(route: Route, instance: Instance) -> float:
    """The smallest task index in a route (inf when it has none): the symmetry-breaking key."""
    return min((v.node for v in route if not instance.is_depot(v.node)), default=math.inf)


#: Cover cuts are generated for tasks that at most this many AAVs can reach: the family has
#: 2^N members, and the exact models do not prove instances with larger fleets anyway.
MAX_COVER_CUT_AAVS = 8


def coalition_cover_cuts(upper: dict[int, int], demand: int
                         ) -> list[tuple[int, dict[int, int]]]:
    """Valid inequalities covered_j <= rest + sum_{n in S} coef_n * visit_nj, one for each
    group S of the AAVs that may visit task j, returned as (rest, {n: coef_n}).

    ``upper[n]`` is the most AAV n can bring (min(B_n, R_j)). rest is what the AAVs outside S
    can bring together; where rest < R_j the coalition needs a member of S to cover more, and
    each member adds at most min(upper[n], R_j - rest) beyond rest before the demand caps
    the coverage. The LP relaxation cannot otherwise see that a large task needs a particular
    AAV in full: with a_nj <= upper[n] * y_nj alone, a fractional y buys part of the goods."""
    cuts: list[tuple[int, dict[int, int]]] = []
    aavs = sorted(upper)
    if len(aavs) > MAX_COVER_CUT_AAVS:
        return cuts
    for size in range(1, len(aavs) + 1):
        for group in itertools.combinations(aavs, size):
            rest = sum(upper[n] for n in aavs if n not in group)
            if rest < demand:
                cuts.append((rest, {n: min(upper[n], demand - rest) for n in group}))
    return cuts
