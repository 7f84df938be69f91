"""Exact pricing of the branch-and-price master (formulations/branch_price.py): for one AAV,
the schedule (visits, depot reloads, amounts) of least reduced cost, by labelling.

A label is a partial schedule from the AAV's anchor (its start, or the end of its committed
prefix) that ends at a task. Its resources are the clock, the distance flown (Dcum), the set
of tasks visited, and the load state of the current trip:
* ``peak``: the least capacity the trip needs so far. Eq. 10 asks d + p <= B after every
  visit, and d after visit i is the delivery goods still to come in the trip, so the trip is
  feasible iff (goods delivered in the trip) + max_i (p_i - delivered_i) <= B; peak is that
  left-hand side so far: a delivery of a adds a to it, a pickup raises it to at least the
  pickup goods on board;
* ``pickup``: the pickup goods on board (what later pickups add to);
* ``loaded``: whether the trip began at a depot (a delivery needs goods from a depot).
A depot visit starts a new trip (peak = pickup = 0, loaded). Amounts are chosen when a task is
added: every integer in the allowed range is a separate label, since the reduced cost is
linear in the amount but the load it uses limits what comes later.

The reduced cost adds, per task visit, terms that depend only on that visit's arrival, amount
and leg (``TaskPrices``), so it is a sum along the path. Label L1 dominates L2 at the same
node when every completion of L2 is a completion of L1 at no higher reduced cost:
  cost1 <= cost2, clock1 <= clock2 (every later arrival is no later; every price term is
  non-decreasing in the arrival since the time-row duals are >= 0), visited1 subset of
  visited2 (elementarity), peak1 <= peak2, pickup1 <= pickup2, loaded1 >= loaded2, and
  Dcum: both beyond the range (every later visit pays the full-range cost), or Dcum1 <= Dcum2
  when the full-range cost is at least the cost of any leg (q is then non-decreasing in Dcum),
  or Dcum1 == Dcum2 otherwise.
Arrival and Dcum are accumulated leg by leg in the evaluator's order of float operations.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np

from tsac_bench.formulations.network import DIRECT, START, AavNetwork
from tsac_bench.model import Instance, Route, Visit


@dataclass
class TaskPrices:
    """The duals one AAV's pricing sees. A visit to task m at arrival t with amount a adds
    op_cost - cover[m] * a + aav_time[m] * theta + min(0, closer_time[m] * theta - closer[m])
    - visit_bonus[m] - cut_bonus[m] to the reduced cost, theta = (t - t_start) / horizon
    (time terms only for tasks in ``timed``); each arc adds -arc_bonus[(tail, head, mode)]."""

    base: float  # reduced cost of the empty schedule (prefix only): -convexity dual + prefix
    cover: dict[int, float]
    aav_time: dict[int, float]
    closer: dict[int, float]
    closer_time: dict[int, float]
    visit_bonus: dict[int, float] = field(default_factory=dict)  # branching rows
    cut_bonus: dict[int, float] = field(default_factory=dict)  # coalition cover cuts
    arc_bonus: dict[tuple[int, int, int], float] = field(default_factory=dict)


@dataclass
class Restrictions:
    """What the branching decisions of a node forbid in this AAV's schedules."""

    forbidden_tasks: frozenset[int] = frozenset()
    forbidden_arcs: frozenset[tuple[int, int, int]] = frozenset()
    amount_low: dict[int, int] = field(default_factory=dict)
    amount_high: dict[int, int] = field(default_factory=dict)


@dataclass(frozen=True)
class Anchor:
    """Where the free part of an AAV's schedule starts: after its committed prefix."""

    node: int  # START or the last committed task
    clock: float
    flown: float
    visited: int  # bit mask of committed tasks
    peak: int
    pickup: int
    loaded: bool
    skip_depot_visit: bool  # the first free arc's depot is the prefix's trailing depot


@dataclass
class Schedule:
    """A priced schedule: the free visits after the prefix (depot visits included, the
    closing depot not) and its reduced cost by the labelling's arithmetic."""

    tail: tuple[Visit, ...]
    reduced_cost: float


class _Label:
    __slots__ = ("alive", "amounts", "arc", "clock", "cost", "flown", "loaded", "node", "parent",
                 "price", "table", "visited")

    def __init__(self, node, clock, flown, visited, loaded, table, parent, arc, price, amounts):
        self.node, self.clock, self.flown, self.visited = node, clock, flown, visited
        self.loaded, self.table = loaded, table
        self.parent, self.arc, self.price, self.amounts = parent, arc, price, amounts
        self.alive = True
        self.cost = float(table[-1, -1])  # the reduced cost of the finished schedule


class Pricer:
    """Labelling for one AAV over its network (formulations/network.py).

    The amounts are not fixed in a label: its ``table[x, y]`` is the least reduced cost of
    its path over all amount choices whose current trip needs peak <= x and carries pickup
    goods <= y (x, y in 0..B). A visit with price ``cover`` per kg and amounts lo..hi maps it
    by min over the amount (a delivery needs peak - a before it, a pickup needs pickup
    min(x, y) - a: its goods count in the peak too); a depot visit collapses it to its
    least value (a new trip needs nothing of the old one). So one label stands for every
    amount vector of its path, and label L1 dominates L2 only if table1 <= table2 everywhere
    (with the other resources as above); the reduced cost of a finished schedule is
    table[B, B]; the amounts are read back cell by cell from the parents' tables.
    """

    def __init__(self, instance: Instance, n: int, network: AavNetwork, anchor: Anchor,
                 timed: frozenset[int]) -> None:
        self.instance = instance
        self.n = n
        self.network = network
        self.anchor = anchor
        self.timed = timed
        aav = instance.aavs[n]
        w3 = instance.weights[2]
        self.speed = float(aav.speed)
        self.capacity = aav.capacity
        self.max_range = float(aav.max_range)
        self.per_metre = w3 * aav.alpha / 1000.0 / instance.e_base
        self.full = w3 * aav.full_range_cost / instance.e_base
        longest = max((a.leg for a in network.arcs), default=0.0)
        self.dcum_monotone = self.full >= self.per_metre * longest
        dist = instance.dist_rows
        start = instance.start_node(n)
        # (tail, head, mode, first leg, second leg or None) per arc, legs as the evaluator
        # walks them.
        self.out: dict[int, list] = {}
        for a in network.arcs:
            p = start if a.tail == START else a.tail
            legs = (dist[p][a.head], None) if a.mode == DIRECT else (dist[p][a.mode],
                                                                      dist[a.mode][a.head])
            self.out.setdefault(a.tail, []).append((a.tail, a.head, a.mode, *legs))
        self.t_start = {j: float(instance.tasks[j].t_start) for j in network.tasks}
        self.t_end = {j: instance.tasks[j].latest_on_time for j in network.tasks}
        self.demand = {j: instance.tasks[j].demand for j in network.tasks}
        self.delivery = {j: instance.tasks[j].is_delivery for j in network.tasks}
        self.horizon = float(instance.horizon)
        cells = np.arange(self.capacity + 1)
        self._rows = cells[:, None].repeat(self.capacity + 1, axis=1)
        self._smaller = np.minimum.outer(cells, cells)

    def _root_table(self, base: float) -> np.ndarray:
        table = np.full((self.capacity + 1, self.capacity + 1), np.inf)
        table[self.anchor.peak:, self.anchor.pickup:] = base
        return table

    def _visit(self, table: np.ndarray, delivery: bool, price: float, low: int, high: int
               ) -> np.ndarray:
        """The table after a visit with amounts low..high at ``price`` per kg.

        min over a of T(c - a) - price * a is a sliding-window minimum of T(z) + price * z
        (window c - high .. c - low) less price * c, taken along the peak axis for a delivery
        and along the pickup axis for a pickup (whose goods also raise the peak: the pickup
        cell used is min(x, y))."""
        size = self.capacity + 1
        axis = 0 if delivery else 1
        cells = np.arange(size, dtype=float)
        ramp = price * (cells[:, None] if delivery else cells[None, :])
        shifted = table + ramp
        pad_shape = (high, size) if delivery else (size, high)
        window = np.concatenate([np.full(pad_shape, np.inf), shifted], axis=axis)
        length, span = high - low + 1, 1
        while 2 * span <= length:
            window = np.minimum(_take(window, 0, -span, axis), _take(window, span, None, axis))
            span *= 2
        out = np.minimum(_take(window, 0, size, axis),
                         _take(window, length - span, length - span + size, axis)) - ramp
        if not delivery:
            out = out[self._rows, self._smaller]
        return out

    def _first_visit(self, least: float, delivery: bool, price: float, low: int, high: int
                     ) -> np.ndarray:
        """``_visit`` of a table that is ``least`` everywhere (the first visit of a trip):
        the largest amount the cell allows, up to ``high``, at least ``low``."""
        room = self._rows if delivery else self._smaller
        return np.where(room >= low, least - price * np.minimum(room, high), np.inf)

    def price(self, prices: TaskPrices, restrictions: Restrictions, *, limit: int = 50,
              label_cap: int | None = None) -> tuple[float, list[Schedule]]:
        """(least reduced cost, up to ``limit`` schedules of negative reduced cost, least
        first). With ``label_cap`` only the cheapest labels per node and length are kept: a
        heuristic whose least reduced cost is then not a bound."""
        anchor = self.anchor
        root = _Label(anchor.node, anchor.clock, anchor.flown, anchor.visited, anchor.loaded,
                      self._root_table(prices.base), None, None, 0.0, (0, 0))
        best = [root]
        buckets: dict[int, list[_Label]] = {}
        frontier = [root]
        forbidden_tasks = restrictions.forbidden_tasks
        forbidden_arcs = restrictions.forbidden_arcs
        low, high = restrictions.amount_low, restrictions.amount_high
        speed, capacity, max_range = self.speed, self.capacity, self.max_range
        per_metre, full = self.per_metre, self.full
        t_start, t_end, horizon = self.t_start, self.t_end, self.horizon
        timed = self.timed
        cover, aav_time = prices.cover, prices.aav_time
        closer, closer_time = prices.closer, prices.closer_time
        visit_bonus, arc_bonus = prices.visit_bonus, prices.arc_bonus
        cut_bonus = prices.cut_bonus
        while frontier:
            produced: list[_Label] = []
            for label in frontier:
                if not label.alive:
                    continue
                for arc in self.out.get(label.node, ()):
                    _, j, _, leg1, leg2 = arc
                    bit = 1 << j
                    if label.visited & bit or j in forbidden_tasks or arc[:3] in forbidden_arcs:
                        continue
                    clock, flown = label.clock, label.flown
                    flown += leg1
                    clock += leg1 / speed
                    table, loaded, leg = label.table, label.loaded, leg1
                    if leg2 is not None:
                        flown += leg2
                        clock += leg2 / speed
                        table = None  # a new trip: the old table collapses to its least value
                        loaded, leg = True, leg2
                    if clock < t_start[j]:
                        clock = t_start[j]
                    if clock > t_end[j]:
                        continue
                    is_delivery = self.delivery[j]
                    if is_delivery and not loaded:
                        continue
                    cost = per_metre * leg if flown <= max_range else full
                    cost -= visit_bonus.get(j, 0.0) + arc_bonus.get(arc[:3], 0.0)
                    cost -= cut_bonus.get(j, 0.0)
                    if j in timed:
                        theta = (clock - t_start[j]) / horizon
                        cost += aav_time.get(j, 0.0) * theta
                        cost += min(0.0, closer_time.get(j, 0.0) * theta - closer.get(j, 0.0))
                    a_low = low.get(j, 1)
                    a_high = min(self.demand[j], capacity, high.get(j, capacity))
                    price = cover.get(j, 0.0)
                    # With no value on goods, more than the least amount only uses capacity.
                    if price <= 0.0:
                        a_high = min(a_high, a_low)
                    if a_high < a_low:
                        continue
                    if table is None:
                        new_table = self._first_visit(label.cost, is_delivery, price, a_low,
                                                      a_high)
                    else:
                        new_table = self._visit(table, is_delivery, price, a_low, a_high)
                    if not np.isfinite(new_table[-1, -1]):
                        continue
                    new_table += cost
                    child = _Label(j, clock, flown, label.visited | bit, loaded, new_table,
                                   label, arc, price, (a_low, a_high))
                    if self._insert(buckets.setdefault(j, []), child):
                        produced.append(child)
            if label_cap is not None:
                produced = self._cap(produced, label_cap)
            frontier = produced
            best.extend(produced)
        least = min(lab.cost for lab in best)
        alive = sorted((lab for lab in best if lab.alive), key=lambda lab: lab.cost)
        chosen, seen = [], set()
        for lab in alive:
            if lab.cost >= -1e-9 or len(chosen) >= limit:
                break
            tail = self._tail(lab)
            if tail not in seen:
                seen.add(tail)
                chosen.append(Schedule(tail, lab.cost))
        return least, chosen

    @staticmethod
    def _cap(labels: list[_Label], cap: int) -> list[_Label]:
        by_node: dict[int, list[_Label]] = {}
        for lab in labels:
            if lab.alive:
                by_node.setdefault(lab.node, []).append(lab)
        kept = []
        for group in by_node.values():
            group.sort(key=lambda lab: lab.cost)
            for lab in group[cap:]:
                lab.alive = False
            kept += group[:cap]
        return kept

    def _dominates(self, a: _Label, b: _Label) -> bool:
        """The rule of the class docstring; the cheap scalar tests go first (the table test
        needs cost_a <= cost_b, its cell (B, B))."""
        if a.clock > b.clock or a.cost > b.cost or (b.loaded and not a.loaded) or (
                a.visited & ~b.visited):
            return False
        if not (a.flown > self.max_range and b.flown > self.max_range) and not (
                a.flown <= b.flown if self.dcum_monotone else a.flown == b.flown):
            return False
        return bool((a.table <= b.table).all())

    def _insert(self, bucket: list[_Label], child: _Label) -> bool:
        dominates = self._dominates
        for other in bucket:
            if other.alive and dominates(other, child):
                return False
        dropped = False
        for other in bucket:
            if other.alive and dominates(child, other):
                other.alive = False
                dropped = True
        if dropped:
            bucket[:] = [lab for lab in bucket if lab.alive]
        bucket.append(child)
        return True

    def _tail(self, label: _Label) -> tuple[Visit, ...]:
        """The free visits of a finished label, amounts read back from the cell (B, B): at
        each visit the amount that attains the cell's minimum in the parent's table."""
        steps = []
        while label.parent is not None:
            steps.append(label)
            label = label.parent
        x = y = self.capacity
        amounts = []
        for lab in steps:  # last visit first
            before = lab.parent.table
            if lab.arc[4] is not None:  # through a depot: the parent's trip is closed
                before = np.full_like(before, before[-1, -1])
            low, high = lab.amounts
            if self.delivery[lab.node]:
                options = [(before[x - a, y] - lab.price * a, a) for a in range(low, high + 1)
                           if x - a >= 0]
                a = min(options)[1]
                x -= a
            else:
                z = min(x, y)
                options = [(before[x, z - a] - lab.price * a, a) for a in range(low, high + 1)
                           if z - a >= 0]
                a = min(options)[1]
                y = z - a
            amounts.append(a)
            if lab.arc[4] is not None:
                x = y = self.capacity
        steps.reverse()
        amounts.reverse()
        visits: list[Visit] = []
        for k, (lab, a) in enumerate(zip(steps, amounts, strict=True)):
            mode = lab.arc[2]
            if mode != DIRECT and not (k == 0 and self.anchor.skip_depot_visit):
                visits.append(Visit(mode))
            visits.append(Visit(lab.node, a))
        return tuple(visits)


def _take(array: np.ndarray, start: int, stop: int | None, axis: int) -> np.ndarray:
    return array[start:stop] if axis == 0 else array[:, start:stop]


def anchor_of(instance: Instance, n: int, prefix: Route, trailing_depot: int | None,
              last: int, arrival: float | None, flown: float | None) -> Anchor:
    """The anchor after AAV n's committed ``prefix`` (walked for its current trip's load)."""
    peak = pickup = 0
    loaded = False
    visited = 0
    for v in prefix:
        if instance.is_depot(v.node):
            peak = pickup = 0
            loaded = True
        else:
            visited |= 1 << v.node
            if instance.tasks[v.node].is_delivery:
                peak += v.amount
            else:
                pickup += v.amount
                peak = max(peak, pickup)
    return Anchor(last, 0.0 if arrival is None else arrival, 0.0 if flown is None else flown,
                  visited, peak, pickup, loaded, trailing_depot is not None)


def schedule_route(instance: Instance, prefix: Route, tail: Sequence[Visit]) -> Route:
    """The whole route of a schedule: prefix, free visits, closing depot."""
    route = list(prefix) + list(tail)
    if route and not instance.is_depot(route[-1].node):
        route.append(Visit(instance.nearest_depot(route[-1].node)))
    return tuple(route)


def all_schedules(pricer: Pricer, restrictions: Restrictions | None = None
                  ) -> list[tuple[Visit, ...]]:
    """Every schedule the labelling could build, without dominance (for the tests' check
    that the labelling's least reduced cost is the least over all schedules)."""
    restrictions = restrictions or Restrictions()
    anchor = pricer.anchor
    out: list[tuple[Visit, ...]] = [()]

    def grow(node, clock, flown, visited, peak, pickup, loaded, tail, first):
        for arc in pricer.out.get(node, ()):
            _, j, mode, leg1, leg2 = arc
            if visited & (1 << j) or j in restrictions.forbidden_tasks:
                continue
            c, f = clock + leg1 / pricer.speed, flown + leg1
            pk, pu, ld = peak, pickup, loaded
            if leg2 is not None:
                c, f = c + leg2 / pricer.speed, f + leg2
                pk, pu, ld = 0, 0, True
            c = max(c, pricer.t_start[j])
            if c > pricer.t_end[j] or (pricer.delivery[j] and not ld):
                continue
            head = [] if mode == DIRECT or (first and anchor.skip_depot_visit) else [
                Visit(mode)]
            hi = min(pricer.demand[j], pricer.capacity)
            for amount in range(1, hi + 1):
                if pricer.delivery[j]:
                    npk, npu = pk + amount, pu
                else:
                    npu = pu + amount
                    npk = max(pk, npu)
                if npk > pricer.capacity:
                    break
                new_tail = (*tail, *head, Visit(j, amount))
                out.append(new_tail)
                grow(j, c, f, visited | (1 << j), npk, npu, ld, new_tail, False)

    grow(anchor.node, anchor.clock, anchor.flown, anchor.visited, anchor.peak, anchor.pickup,
         anchor.loaded, (), True)
    return out

