"""Exact pricing of the branch-and-price master (formulations/branch_price/): for one AAV,
the schedule (visits, depot reloads, amounts) of least reduced cost, by labelling.

A label is a partial schedule from the AAV's anchor (its start, or the end of its committed
prefix) that ends at a task. Its resources are the clock, the distance flown (Dcum), the set
of tasks visited, whether the current trip began at a depot (``loaded``: a delivery needs
goods from a depot), and the load state of the current trip, kept for every amount choice at
once in a table (``Pricer``): ``peak``, the least capacity the trip needs so far (Eq. 10 asks
d + p <= B after every visit, and d after visit i is the delivery goods still to come in the
trip, so the trip is feasible iff (goods delivered in the trip) + max_i (p_i - delivered_i)
<= B; peak is that left-hand side so far: a delivery of a adds a to it, a pickup raises it to
at least the pickup goods on board), and ``pickup``, the pickup goods on board. A depot visit
starts a new trip (peak = pickup = 0, loaded).

The reduced cost adds, per task visit, terms that depend only on that visit's arrival, amount
and leg (``TaskPrices``), so it is a sum along the path. Label L1 dominates L2 at the same
node when every completion of L2 is a completion of L1 at no higher reduced cost:
  table1 <= table2 in every cell (so cost1 <= cost2), clock1 <= clock2 (every later arrival is
  no later; every price term is non-decreasing in the arrival since the time-row duals are
  >= 0), visited1 subset of visited2 (elementarity), loaded1 >= loaded2, and
  Dcum: both beyond the range (every later visit pays the full-range cost), or Dcum1 <= Dcum2
  when the full-range cost is at least the cost of any leg (q is then non-decreasing in Dcum),
  or Dcum1 == Dcum2 otherwise;
  and, where a branching decision asks a task's arrival to be later than a floor (the
  master's row that keeps early visits out, whose dual is a penalty on them,
  ``TaskPrices.early_penalty``; the only price term that falls with the arrival): L1
  pays in advance the penalty its earliest possible arrival there would pay, unless L2
  has visited that task or can no longer reach it on time, or the clocks are equal.
  Every completion of L2 is then one of L1 at no higher reduced cost: L1 arrives no later
  anywhere, so it pays at most that penalty more. "Reach" and L1's earliest arrival use
  the straight leg from the label's task, which no path beats (distances obey the
  triangle inequality, and waiting for a window only adds time), shortened by a relative
  1e-9 so that the test stays on the safe side of the float sums of the real legs.
  (A hard floor in the labelling instead breaks the clock rule outright: an exact call
  under one ran for a minute on 4/10 seed 1, where the penalty is small.)
The ng relaxation (``Pricer.price(relaxed=True)``) keeps, in place of the visited set, the
label's memory: of the tasks visited, those in the neighbourhood of the label's task (and the
committed ones); a task out of memory may be visited again. Its least reduced cost is over a
superset of the schedules, so a lower bound on the exact least.
Arrival and Dcum are accumulated leg by leg in the evaluator's order of float operations, so
a schedule's arrivals (hence its time-window feasibility and price) are the evaluator's to
the last bit. The labelling runs compiled (numba): pricing is nearly all of the search's
time otherwise.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np

from tsac_bench.formulations.labelling import (
    arrival_cut_terms_kernel,
    completion_bounds,
    label_schedules,
)
from tsac_bench.formulations.network import DIRECT, START, AavNetwork
from tsac_bench.model import Instance, Route, Visit
from tsac_bench.planning import Anchor


@dataclass
class TaskPrices:
    """The duals one AAV's pricing sees. A visit to task m at arrival t with amount a adds
    op_cost - (cover[m] - goods_time[m] * theta) * a + aav_time[m] * theta
    + min(0, closer_time[m] * theta - closer[m]) - visit_bonus[m] - cut_bonus[m] to the
    reduced cost, theta = (t - t_start) / horizon (time terms only for tasks in ``timed``);
    each arc adds -arc_bonus[(tail, head, mode)]. goods_time[m] >= 0, so the price per kg
    falls with the arrival: an earlier clock is never worse, except for ``early_penalty``
    (arrival-window branching's "later than" side): a visit to m whose theta is <= a
    threshold pays that threshold's penalty (>= 0), summed over m's thresholds.
    ``arrival_cuts[m]`` lists pieces (lo, hi, aav, closer, goods) of the arrival cuts' duals
    (>= 0): with g = min(max(theta - lo, 0), hi - lo), a piece adds aav * g to the visit's
    cost, closer * g inside the closing term's min, and takes goods * g off the price per
    kg; all three are non-decreasing in the arrival, so they leave the dominance as it is."""

    base: float  # reduced cost of the empty schedule (prefix only): -convexity dual + prefix
    cover: dict[int, float]
    aav_time: dict[int, float]
    closer: dict[int, float]
    closer_time: dict[int, float]
    visit_bonus: dict[int, float] = field(default_factory=dict)  # branching rows
    cut_bonus: dict[int, float] = field(default_factory=dict)  # coalition cover cuts
    arc_bonus: dict[tuple[int, int, int], float] = field(default_factory=dict)
    goods_time: dict[int, float] = field(default_factory=dict)  # goods-weighted arrival rows
    early_penalty: dict[int, list[tuple[float, float]]] = field(default_factory=dict)
    arrival_cuts: dict[int, list[tuple[float, float, float, float, float]]] = field(
        default_factory=dict)


def arrival_cut_terms(pieces: Sequence[tuple[float, float, float, float, float]],
                      theta: float) -> tuple[float, float, float]:
    """The (aav, closer, goods per kg) price terms of ``TaskPrices.arrival_cuts`` pieces at
    arrival term ``theta``: the labelling's own function, so the same float operations."""
    if not pieces:
        return 0.0, 0.0, 0.0
    rows = np.array(pieces, float).T[:, None, :]  # (lo, hi, aav, closer, goods) x 1 task
    return arrival_cut_terms_kernel(np.ascontiguousarray(rows), 0, theta)


@dataclass
class Restrictions:
    """What the branching decisions of a node forbid in this AAV's schedules."""

    forbidden_tasks: frozenset[int] = frozenset()
    forbidden_arcs: frozenset[tuple[int, int, int]] = frozenset()
    amount_low: dict[int, int] = field(default_factory=dict)
    amount_high: dict[int, int] = field(default_factory=dict)
    #: Arrival-window branching on a timed task m: a visit to m must have its arrival term
    #: theta = (t - t_start) / horizon <= arrival_high[m] (the other side, "later than", is
    #: a master row: TaskPrices.early_penalty).
    arrival_high: dict[int, float] = field(default_factory=dict)


@dataclass(frozen=True)
class PricingAnchor:
    """Where the free part of an AAV's schedule starts: after its committed prefix."""

    node: int  # START or the last committed task
    clock: float  # when the AAV can leave for its first free visit (docs/model.md, "Time")
    flown: float  # Dcum when it leaves
    visited: int  # bit mask of committed tasks
    peak: int
    pickup: int
    loaded: bool
    #: The prefix ends with a depot visit the AAV has not left: it leaves from that depot,
    #: and its first free arc (through that depot) has only the leg from it to fly.
    skip_depot_visit: bool


#: A trip's room in the completion bounds, in at most this many units per kind of goods:
#: finer units bound closer and cost the recursion (units + 1) ** 2 states per node.
COMPLETION_UNITS = 6


@dataclass
class Schedule:
    """A priced schedule: the free visits after the prefix (depot visits included, the
    closing depot not) and its reduced cost by the labelling's arithmetic."""

    tail: tuple[Visit, ...]
    reduced_cost: float


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

    The labelling itself is compiled (``label_schedules``, numba); this class turns the network,
    the duals and the branching restrictions into its arrays and the labels it returns into
    schedules.
    """

    def __init__(self, instance: Instance, n: int, network: AavNetwork, anchor: PricingAnchor,
                 timed: frozenset[int], ng_size: int, completion_steps: int) -> None:
        self.instance = instance
        self.completion_steps = completion_steps
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
            if a.mode == DIRECT:
                legs = (dist[p][a.head], None)
            elif a.tail == anchor.node and anchor.skip_depot_visit:
                # The AAV waits at this depot: the leg from it is left, in the fresh trip
                # the anchor's load state already describes.
                legs = (dist[a.mode][a.head], None)
            else:
                legs = (dist[p][a.mode], dist[a.mode][a.head])
            self.out.setdefault(a.tail, []).append((a.tail, a.head, a.mode, *legs))
        self.t_start = {j: float(instance.tasks[j].t_start) for j in network.tasks}
        self.t_end = {j: instance.tasks[j].latest_on_time for j in network.tasks}
        self.demand = {j: instance.tasks[j].demand for j in network.tasks}
        self.delivery = {j: instance.tasks[j].is_delivery for j in network.tasks}
        self.horizon = float(instance.horizon)
        self.last_label_count = 0  # diagnostics: the labels the last call created
        # The compiled labelling's view: node n_tasks is START; arcs grouped by tail (CSR).
        n_tasks = instance.n_tasks
        self._start_node = n_tasks
        self.arcs = [arc for tail in sorted(self.out, key=self._node) for arc in self.out[tail]]
        self.arc_index = {arc[:3]: i for i, arc in enumerate(self.arcs)}
        first = np.zeros(n_tasks + 2, np.int64)
        for arc in self.arcs:
            first[self._node(arc[0]) + 1] += 1
        self._out_first = np.cumsum(first)
        self._arc_head = np.array([a[1] for a in self.arcs], np.int64)
        self._arc_leg1 = np.array([a[3] for a in self.arcs], float)
        self._arc_leg2 = np.array([0.0 if a[4] is None else a[4] for a in self.arcs], float)
        self._arc_depot = np.array([a[4] is not None for a in self.arcs], np.bool_)
        t_start = np.zeros(n_tasks)
        t_end = np.full(n_tasks, -np.inf)  # tasks off the network: never reached
        demand = np.zeros(n_tasks, np.int64)
        delivery = np.zeros(n_tasks, np.bool_)
        for j in network.tasks:
            t_start[j], t_end[j] = self.t_start[j], self.t_end[j]
            demand[j], delivery[j] = self.demand[j], self.delivery[j]
        self._t_start, self._t_end, self._demand, self._is_delivery = (t_start, t_end, demand,
                                                                       delivery)
        self._timed = np.array([j in timed for j in range(n_tasks)], np.bool_)
        # Straight-leg flying time from each task (a label's node) to each task, shortened
        # by a relative 1e-9 so that it stays below the float sums of any real path's legs.
        self._reach = np.ascontiguousarray(
            instance.dist[:n_tasks, :n_tasks] / self.speed * (1.0 - 1e-9))
        words = max(1, (n_tasks + 63) // 64)
        self._anchor_visited = _bit_words(anchor.visited, words)
        # What a label remembers of its visited tasks on arriving at j: everything (exact), or
        # the ng relaxation's neighbourhood of j, the ng_size tasks nearest to j (j itself
        # first), and the committed tasks, which no schedule may visit again.
        self._full_memory = np.full((n_tasks, words), -1, np.int64)
        self._ng_memory = self._full_memory.copy()
        on_network = sorted(network.tasks)
        for j in on_network:
            nearest = sorted(on_network, key=lambda i: (i != j, instance.dist[j, i], i))
            neighbourhood = anchor.visited
            for i in nearest[:ng_size]:
                neighbourhood |= 1 << i
            self._ng_memory[j] = _bit_words(neighbourhood, words)

    def _node(self, node: int) -> int:
        return self._start_node if node == START else node

    def price(self, prices: TaskPrices, restrictions: Restrictions, *, limit: int = 50,
              label_cap: int | None = None, relaxed: bool = False,
              growth_rounds: int = 0,
              deadline: float = math.inf) -> tuple[float, list[Schedule]]:
        """(least reduced cost, up to ``limit`` schedules of negative reduced cost, least
        first). With ``label_cap`` only the cheapest labels per node and length are kept: a
        heuristic whose least reduced cost is then not a bound. ``relaxed``: the ng
        relaxation, which may also visit a task again once it has left the task's
        neighbourhood; its least is over more paths, so a lower bound on the exact least,
        and only its elementary schedules are returned. When its negative paths are all
        non-elementary, the neighbourhoods grow by their cycles (``grow_memory``) and the
        relaxation runs again, up to ``growth_rounds`` times: each run's least is a lower
        bound, the largest is returned, and once the best path is elementary it is the
        exact least without the exact labelling. Past ``deadline`` (time.perf_counter) the
        labelling stops: the schedules found so far are returned and the least reduced
        cost is -inf (nothing is known of it), or in a later relaxed run the earlier
        run's least. With completion bounds (``completion_steps``; not in heuristic calls)
        the labels that cannot price out are dropped, and a least >= 0 is reported as 0."""
        n_tasks, size = self.instance.n_tasks, self.capacity + 1

        def per_task(values: dict[int, float], fill: float = 0.0, dtype=float) -> np.ndarray:
            out = np.full(n_tasks, fill, dtype)
            for m, v in values.items():
                out[m] = v
            return out

        arc_bonus = np.zeros(len(self.arcs))
        for key, v in prices.arc_bonus.items():
            if key in self.arc_index:
                arc_bonus[self.arc_index[key]] = v
        forbidden_arc = np.zeros(len(self.arcs), np.bool_)
        for key in restrictions.forbidden_arcs:
            if key in self.arc_index:
                forbidden_arc[self.arc_index[key]] = True
        forbidden_task = np.zeros(n_tasks, np.bool_)
        forbidden_task[list(restrictions.forbidden_tasks)] = True
        low = per_task(restrictions.amount_low, 1, np.int64)
        high = per_task(restrictions.amount_high, self.capacity, np.int64)
        slots = max((len(v) for v in prices.early_penalty.values()), default=0)
        early_theta = np.full((n_tasks, max(slots, 1)), -np.inf)
        early_penalty = np.zeros((n_tasks, max(slots, 1)))
        for m, steps in prices.early_penalty.items():
            for q, (threshold, penalty) in enumerate(steps):
                early_theta[m, q], early_penalty[m, q] = threshold, penalty
        penalised = sorted(prices.early_penalty)
        slots = max((len(v) for v in prices.arrival_cuts.values()), default=0)
        pieces = np.zeros((5, n_tasks, max(slots, 1)))
        pieces[0] = np.inf  # an unused slot starts past every arrival
        for m, steps in prices.arrival_cuts.items():
            for q, piece in enumerate(steps):
                pieces[:, m, q] = piece
        theta_high = per_task(restrictions.arrival_high, np.inf)
        root = np.full((size, size), np.inf)
        root[self.anchor.peak:, self.anchor.pickup:] = prices.base
        arrays = (
            per_task(prices.cover), per_task(prices.aav_time), per_task(prices.closer),
            per_task(prices.closer_time), per_task(prices.goods_time),
            per_task(prices.visit_bonus),
            per_task(prices.cut_bonus), arc_bonus, forbidden_task, forbidden_arc, low, high,
            theta_high, early_theta, early_penalty, np.array(penalised, np.int64), pieces)
        # A heuristic call keeps a few labels per node anyway: the bounds cost it more than
        # they save (8/20 validation root: 11 s for its heuristic calls' bounds, 4 s saved).
        completion = self._completion_bounds(arrays, heuristic=bool(label_cap))
        best = -math.inf
        chosen: list[Schedule] = []
        for _ in range(1 + (growth_rounds if relaxed else 0)):
            least, found, cycles = self._run(root, arrays, limit, label_cap, relaxed,
                                             deadline, completion)
            if least == -math.inf:  # cut short: the earlier run's least stands
                return best, chosen or found
            best, chosen = max(best, least), found
            if found or least >= -1e-9 or not self.grow_memory(cycles):
                break
        return best, chosen

    def _completion_bounds(self, arrays: tuple, heuristic: bool
                           ) -> tuple[np.ndarray, float, int]:
        """``labelling.completion_bounds`` on a grid of ``completion_steps`` steps up to the
        last window's end, the step and the unit of room (COMPLETION_UNITS per trip); an
        empty grid when they are off or for a ``heuristic`` call. The same for every run
        of one call (the ng memory does not enter it)."""
        n_nodes = len(self._out_first) - 1
        unit = -(-self.capacity // COMPLETION_UNITS)
        ends = self._t_end[np.isfinite(self._t_end)]
        if heuristic or not self.completion_steps or not len(ends) or ends.max() <= 0.0:
            return np.zeros((0, n_nodes, 1, 1)), 1.0, unit
        step = float(ends.max()) / self.completion_steps
        (cover, aav_time, closer, closer_time, goods_time, visit_bonus, cut_bonus, arc_bonus,
         forbidden_task, forbidden_arc, low, high, theta_high, early_theta, early_penalty,
         _, pieces) = arrays
        bound = completion_bounds(
            self._out_first, self._arc_head, self._arc_leg1, self._arc_leg2, self._arc_depot,
            self._t_start, self._t_end, self._demand, self._is_delivery, self._timed,
            self.speed, self.capacity, self.per_metre, self.full, self.horizon, cover,
            aav_time, closer, closer_time, goods_time, visit_bonus, cut_bonus, arc_bonus,
            forbidden_task, forbidden_arc, low, high, theta_high, early_theta, early_penalty,
            pieces, step, self.completion_steps, unit)
        return bound, step, unit

    def _run(self, root: np.ndarray, arrays: tuple, limit: int, label_cap: int | None,
             relaxed: bool, deadline: float, completion: tuple[np.ndarray, float, int]
             ) -> tuple[float, list[Schedule], list[tuple[Visit, ...]]]:
        """One labelling: (least reduced cost, schedules, and in the relaxation the
        non-elementary paths of negative reduced cost among the first ``limit``). With
        completion bounds the labels that cannot price out are dropped, so only a negative
        least is exact: the least is reported as min(least, 0), what the Lagrangian bound
        and the convergence test use."""
        anchor = self.anchor
        labels = label_schedules(
            self._out_first, self._arc_head, self._arc_leg1, self._arc_leg2, self._arc_depot,
            self._t_start, self._t_end, self._demand, self._is_delivery, self._timed,
            self.speed, self.capacity, self.max_range, self.per_metre, self.full,
            self.dcum_monotone, self.horizon,
            self._node(anchor.node), anchor.clock, anchor.flown, self._anchor_visited,
            anchor.loaded, root, *arrays, self._reach,
            self._ng_memory if relaxed else self._full_memory, not relaxed,
            0 if label_cap is None else label_cap, deadline, *completion)
        cost, alive, finished = labels[0], labels[1], labels[9]
        self.last_label_count = len(cost)
        least = float(cost.min()) if finished else -math.inf
        if len(completion[0]):
            least = min(least, 0.0)
        chosen, seen, cycles = [], set(), []
        for k in np.flatnonzero(alive)[np.argsort(cost[alive], kind="stable")]:
            if cost[k] >= -1e-9 or len(chosen) >= limit:
                break
            tail = self._tail(int(k), labels)
            if relaxed and not self._elementary(tail):
                if len(cycles) < limit:
                    cycles.append(tail)
                continue
            if tail not in seen:
                seen.add(tail)
                chosen.append(Schedule(tail, float(cost[k])))
        return least, chosen, cycles

    def grow_memory(self, paths: Sequence[Sequence[Visit]]) -> bool:
        """Forbid the cycles of ``paths`` in the ng relaxation (Roberti and Mingozzi's
        dynamic ng-path relaxation): where task i is visited twice, i joins the
        neighbourhood of every task visited in between, so that a label remembers i until
        it could come back. Neighbourhoods only grow, so every later relaxation is still
        one (of a smaller superset of the schedules). Whether anything was added."""
        grown = False
        for path in paths:
            tasks = [v.node for v in path if not self.instance.is_depot(v.node)]
            last_seen: dict[int, int] = {}
            for q, i in enumerate(tasks):
                p = last_seen.get(i)
                last_seen[i] = q
                if p is None:
                    continue
                word, bit = i >> 6, np.int64(1) << (i & 63)
                for v in tasks[p + 1:q]:
                    if not self._ng_memory[v, word] & bit:
                        self._ng_memory[v, word] |= bit
                        grown = True
        return grown

    def _elementary(self, tail: Sequence[Visit]) -> bool:
        """No task twice (depots may repeat)."""
        tasks = [v.node for v in tail if not self.instance.is_depot(v.node)]
        return len(tasks) == len(set(tasks))

    def _tail(self, label: int, labels: tuple) -> tuple[Visit, ...]:
        """The free visits of a finished label, amounts read back from the cell (B, B): at
        each visit the amount that attains the cell's minimum in the parent's table."""
        cost, _, node, parent, arc, price, low, high, tables, _ = labels
        steps = []
        while parent[label] >= 0:
            steps.append(label)
            label = parent[label]
        x = y = self.capacity
        amounts = []
        for lab in steps:  # last visit first
            before = tables[parent[lab]]
            new_trip = self._arc_depot[arc[lab]]
            if new_trip:  # through a depot: the parent's trip is closed
                before = np.full_like(before, cost[parent[lab]])
            amount_range = range(low[lab], high[lab] + 1)
            if self.delivery[node[lab]]:
                a = min((before[x - a, y] - price[lab] * a, a) for a in amount_range
                        if x - a >= 0)[1]
                x -= a
            else:
                z = min(x, y)
                a = min((before[x, z - a] - price[lab] * a, a) for a in amount_range
                        if z - a >= 0)[1]
                y = z - a
            amounts.append(a)
            if new_trip:
                x = y = self.capacity
        steps.reverse()
        amounts.reverse()
        visits: list[Visit] = []
        for k, (lab, a) in enumerate(zip(steps, amounts, strict=True)):
            mode = self.arcs[arc[lab]][2]
            if mode != DIRECT and not (k == 0 and self.anchor.skip_depot_visit):
                visits.append(Visit(mode))
            visits.append(Visit(int(node[lab]), a))
        return tuple(visits)


def _bit_words(bits: int, words: int) -> np.ndarray:
    """A set of tasks (bit i = task i) as the kernel's int64 words, 64 tasks each."""
    out = [(bits >> (64 * w)) & (2**64 - 1) for w in range(words)]
    return np.array([w - 2**64 if w >= 2**63 else w for w in out], np.int64)


def anchor_of(instance: Instance, n: int, prefix: Route, trailing_depot: int | None,
              last: int, leaves: Anchor) -> PricingAnchor:
    """The anchor after AAV n's committed ``prefix`` (walked for its current trip's load),
    leaving as the planning state's anchor says (``PlanningState.anchor``: its time and Dcum
    there, and the goods on board from a depot whose load was recorded).

    A recorded load L caps the trip's deliveries: delivered <= L, i.e. delivered + (B - L)
    <= B, which is the peak's test with B - L in the place of the term max_i (p_i -
    delivered_i) from before the first free visit; so the trip's peak starts at
    delivered so far + B - L = B - on_board, if that is more than its walk gives."""
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
    if leaves.on_board is not None:
        peak = max(peak, instance.aavs[n].capacity - leaves.on_board)
    return PricingAnchor(last, leaves.time, leaves.flown, visited, peak, pickup, loaded,
                  trailing_depot is not None)


def schedule_route(instance: Instance, prefix: Route, tail: Sequence[Visit]) -> Route:
    """The whole route of a schedule: prefix, free visits, closing depot."""
    route = list(prefix) + list(tail)
    if route and not instance.is_depot(route[-1].node):
        route.append(Visit(instance.nearest_depot(route[-1].node)))
    return tuple(route)


def schedule_tail(instance: Instance, route: Route, first_free: int = 0) -> tuple[Visit, ...]:
    """The free visits of a whole route (``schedule_route``'s ``tail``): the visits from
    ``first_free`` on, without the closing depot."""
    tail = tuple(route[first_free:])
    return tail[:-1] if tail and instance.is_depot(tail[-1].node) else tail


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

