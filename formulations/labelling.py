"""The compiled labelling of exact-bp's pricing (numba): the kernel that ``pricing.Pricer``
feeds with the AAV's network, the task prices and the amount tables, and the label
operations it is made of (growing the label arrays, visit tables, dominance). Kept in one
module, apart from the Python side of pricing, because numba compiles it as one unit; the
rules it implements (resources, dominance, the ng memory) are stated in ``pricing``.

Labels live in arrays that double when full; a label is an index. Buckets hold the live
labels of each node for the dominance tests.
"""

import time

import numpy as np
from numba import njit, objmode


@njit(cache=True)
def _grown1(a, size):
    out = np.empty(size, a.dtype)
    out[:a.shape[0]] = a
    return out


@njit(cache=True)
def _grown2(a, size):
    out = np.empty((size, a.shape[1]), a.dtype)
    out[:a.shape[0]] = a
    return out


@njit(cache=True)
def _grown3(a, size):
    out = np.empty((size, a.shape[1], a.shape[2]), a.dtype)
    out[:a.shape[0]] = a
    return out


@njit(cache=True)
def _wider(a, columns):
    out = np.empty((a.shape[0], columns), a.dtype)
    out[:, :a.shape[1]] = a
    return out


@njit(cache=True)
def _visit_table(src, dst, delivery, price, low, high, scratch_i, scratch_v, row):
    """dst = src after a visit with amounts low..high at ``price`` per kg:
    min over a of src(c - a) - price * a, as a sliding-window minimum (monotone queue) of
    src(z) + price * z over z in c - high .. c - low, less price * c; along the peak axis
    for a delivery, along the pickup axis for a pickup, whose cell used is min(x, y) (its
    goods also raise the peak)."""
    size = src.shape[0]
    for outer in range(size):
        head = tail = 0
        for c in range(size):
            z = c - low
            if z >= 0:
                v = (src[z, outer] if delivery else src[outer, z]) + price * z
                while tail > head and scratch_v[tail - 1] >= v:
                    tail -= 1
                scratch_i[tail] = z
                scratch_v[tail] = v
                tail += 1
            while tail > head and scratch_i[head] < c - high:
                head += 1
            best = scratch_v[head] - price * c if tail > head else np.inf
            if delivery:
                dst[c, outer] = best
            else:
                row[c] = best
        if not delivery:
            for y in range(size):
                dst[outer, y] = row[min(outer, y)]


@njit(cache=True)
def _first_visit_table(dst, least, delivery, price, low, high):
    """The visit's table when the trip starts at a depot right before it (every cell of the
    old table is ``least``): the largest amount the cell allows, up to ``high``."""
    size = dst.shape[0]
    for x in range(size):
        for y in range(size):
            room = x if delivery else min(x, y)
            dst[x, y] = least - price * min(room, high) if room >= low else np.inf


@njit(cache=True)
def _early_cost(early_theta, early_penalty, j, theta):
    """The penalty a visit to j at arrival term theta pays (its thresholds at or above
    theta)."""
    total = 0.0
    for q in range(early_theta.shape[1]):
        if theta <= early_theta[j, q]:
            total += early_penalty[j, q]
    return total


@njit(cache=True)
def arrival_cut_terms_kernel(pieces, j, theta):
    """``arrival_cut_terms`` of task j's pieces (rows lo, hi, aav, closer, goods)."""
    aav = closer = goods = 0.0
    for q in range(pieces.shape[2]):
        if theta > pieces[0, j, q]:
            g = min(theta, pieces[1, j, q]) - pieces[0, j, q]
            aav += pieces[2, j, q] * g
            closer += pieces[3, j, q] * g
            goods += pieces[4, j, q] * g
    return aav, closer, goods


@njit(cache=True)
def _timed_price(c, p, j, theta, aav_time, closer, closer_time, goods_time, pieces):
    """A visit to a timed task j at arrival term theta: its cost ``c`` with the time rows',
    arrival cuts' and closing terms added, and its price per kg ``p`` less the goods-time
    and goods cut terms (the labelling's order of float operations)."""
    c += aav_time[j] * theta
    cut_aav, cut_closer, cut_goods = arrival_cut_terms_kernel(pieces, j, theta)
    c += cut_aav
    c += min(0.0, closer_time[j] * theta + cut_closer - closer[j])
    p -= goods_time[j] * theta
    p -= cut_goods
    return c, p


@njit(cache=True)
def _least_early_cost(early_theta, early_penalty, j, latest):
    """A lower bound on the penalty a visit to j pays at any arrival term up to ``latest``:
    each positive penalty that even the latest arrival pays, each negative one in full
    (the penalties fall with the arrival, so the earliest arrival bounds nothing)."""
    total = 0.0
    for q in range(early_theta.shape[1]):
        penalty = early_penalty[j, q]
        if penalty < 0.0 or latest <= early_theta[j, q]:
            total += penalty
    return total


@njit(cache=True)
def _goods_gain(p, c, unit, a_low, a_high):
    """The least goods term of a visit whose amount is c units (floor(amount / unit) = c)
    within a_low..a_high at price p per kg: the largest such amount when goods have value,
    else the least amount."""
    if p > 0.0:
        return -p * min(a_high, (c + 1) * unit - 1)
    return -p * a_low


@njit(cache=True)
def _visit_value(here, d, q, delivery, c_low, c_high, p, unit, a_low, a_high):
    """The least goods term of a visit plus the completion bound after it (``here``, by
    room), from room (d, q), over the amounts in units c_low..c_high that the room takes."""
    value = np.inf
    for cu in range(c_low, min(c_high, d if delivery else q) + 1):
        rest = here[d - cu, q] if delivery else here[d, q - cu]
        value = min(value, _goods_gain(p, cu, unit, a_low, a_high) + rest)
    return value


@njit(cache=True)
def completion_bounds(out_first, arc_head, arc_leg1, arc_leg2, arc_depot, t_start, t_end,
                      demand, is_delivery, timed, speed, capacity, per_metre, full, horizon,
                      cover, aav_time, closer, closer_time, goods_time, visit_bonus,
                      cut_bonus, arc_bonus, forbidden_task, forbidden_arc, amount_low,
                      amount_high, theta_high, early_theta, early_penalty, pieces, step,
                      n_steps, unit):
    """bound[b, i, d, q]: a lower bound on the reduced cost that any completion adds to a
    label at node i whose clock is at least b * step and whose trip has room for d more
    units of deliveries and q more units of pickups (a unit is ``unit`` kg, room rounded
    up; docs/formulations.md, "Completion bounds"). A backward recursion over the time grid
    that relaxes the rest: tasks may be visited again, each leg pays its least operating
    cost, each price term is taken at the earliest arrival the grid allows (every term but
    the arrival windows' penalties is non-decreasing in the arrival; those are bounded by
    ``_least_early_cost``), and an amount of a kg takes floor(a / unit) units of the room
    (Eq. 10 keeps a trip's deliveries and its pickups each within B; a depot visit
    renews both). Stopping adds nothing, so every entry is <= 0. A bucket whose moves
    within it do not settle in as many passes as there are nodes (a cycle of legs
    shorter than the step) bounds nothing (-inf). Only the steps a label at node i can be
    in are computed, those of i's window: a label's clock there (and a move's arrival, the
    recursion's only read) lies within it. The others stay -inf, a bound never read."""
    n_nodes = out_first.shape[0] - 1
    units = -(-capacity // unit)
    bound = np.full((n_steps, n_nodes, units + 1, units + 1), -np.inf)
    first_step = np.zeros(n_nodes, np.int64)
    last_step = np.full(n_nodes, n_steps - 1, np.int64)
    for i in range(t_start.shape[0]):  # the tasks; the nodes after them are anchors
        if np.isfinite(t_start[i]):
            first_step[i] = min(int(t_start[i] / step), n_steps - 1)
        if np.isfinite(t_end[i]):
            last_step[i] = min(int(t_end[i] / step), n_steps - 1)
    for i in range(n_nodes):
        bound[first_step[i]:last_step[i] + 1, i] = 0.0
    for b in range(n_steps - 1, -1, -1):
        leave = b * step
        settled = False
        for _ in range(n_nodes + 1):
            changed = False
            for i in range(n_nodes):
                if b < first_step[i] or b > last_step[i]:
                    continue
                for a in range(out_first[i], out_first[i + 1]):
                    j = arc_head[a]
                    if forbidden_task[j] or forbidden_arc[a]:
                        continue
                    last = arc_leg2[a] if arc_depot[a] else arc_leg1[a]
                    # Shortened by a relative 1e-9: below the float sum of the real legs.
                    t = leave + (arc_leg1[a] + arc_leg2[a]) / speed * (1.0 - 1e-9)
                    if t < t_start[j]:
                        t = t_start[j]
                    if t > t_end[j]:
                        continue
                    c = min(per_metre * last, full) - visit_bonus[j] - arc_bonus[a] \
                        - cut_bonus[j]
                    p = cover[j]
                    if timed[j]:
                        theta = (t - t_start[j]) / horizon
                        if theta > theta_high[j]:
                            continue
                        latest = min(theta_high[j], (t_end[j] - t_start[j]) / horizon)
                        c += _least_early_cost(early_theta, early_penalty, j, latest)
                        c, p = _timed_price(c, p, j, theta, aav_time, closer, closer_time,
                                            goods_time, pieces)
                    a_low = amount_low[j]
                    a_high = min(demand[j], capacity, amount_high[j])
                    if a_high < a_low:
                        continue
                    c_low = a_low // unit
                    c_high = a_high // unit if p > 0.0 else c_low
                    later = min(int(t / step), n_steps - 1)
                    here = bound[later, j]
                    # A depot before j starts a fresh trip: the same value from every room.
                    fresh = _visit_value(here, units, units, is_delivery[j], c_low, c_high, p,
                                         unit, a_low, a_high) if arc_depot[a] else 0.0
                    for d in range(units + 1):
                        for q in range(units + 1):
                            value = c + (fresh if arc_depot[a] else _visit_value(
                                here, d, q, is_delivery[j], c_low, c_high, p, unit, a_low,
                                a_high))
                            if value < bound[b, i, d, q]:
                                bound[b, i, d, q] = value
                                changed = changed or later == b
            if not changed:
                settled = True
                break
        if not settled:
            bound[b] = -np.inf
    return bound


@njit(cache=True)
def _prices_out(table, bound, unit, capacity):
    """Whether a label with this table may still lead to a schedule of negative reduced
    cost by ``bound`` (its node's and clock's completion bounds by room): some cell
    (peak x, pickup goods y <= x) plus the bound of the room it leaves (B - x for
    deliveries, B - y for pickups, rounded up to units) is negative. An amount choice
    with peak p and pickup goods q is in cell (p, q), so no completion of it is missed."""
    units = bound.shape[0] - 1
    if table[capacity, capacity] + bound[units, units] >= 0.0:
        return False  # the most room bounds lowest
    for x in range(capacity + 1):
        d = -(-(capacity - x) // unit)
        for y in range(x + 1):
            if table[x, y] + bound[d, -(-(capacity - y) // unit)] < 0.0:
                return True
    return False


@njit(cache=True)
def _dominates(a, b, clock, cost, loaded, visited, flown, tables, max_range, dcum_monotone,
               penalised, early_theta, early_penalty, t_start, t_end, horizon, reach,
               elementary):
    """The rule of the module docstring; the cheap scalar tests go first (the table test
    needs cost_a <= cost_b, its cell (B, B)). Without ``elementary`` (the ng relaxation)
    a task in b's memory is not out of b's reach: b may come back once it forgets it."""
    if clock[a] > clock[b] or cost[a] > cost[b] or (loaded[b] and not loaded[a]):
        return False
    for w in range(visited.shape[1]):
        if visited[a, w] & ~visited[b, w]:
            return False
    # A penalised task (early visits pay): on b's completion a may arrive early enough to
    # pay where b does not, at most the penalty of a's earliest arrival, unless b cannot
    # visit it any more (visited, or out of reach before its window closes). reach[m] is
    # the straight leg's time from a's and b's task.
    charge = 0.0
    if clock[a] < clock[b]:
        for m in penalised:
            if (elementary and (visited[b, m >> 6] >> (m & 63)) & 1) or \
                    clock[b] + reach[m] > t_end[m]:
                continue
            earliest = max(t_start[m], clock[a] + reach[m])
            charge += _early_cost(early_theta, early_penalty, m,
                                  (earliest - t_start[m]) / horizon)
        if cost[a] + charge > cost[b]:
            return False
    if not (flown[a] > max_range and flown[b] > max_range):
        if dcum_monotone:
            if flown[a] > flown[b]:
                return False
        elif flown[a] != flown[b]:
            return False
    # Cells with y > x repeat (x, x): a trip's pickup goods never exceed its peak, so
    # pickup <= y adds nothing to peak <= x there.
    ta, tb = tables[a], tables[b]
    for x in range(ta.shape[0]):
        for y in range(x + 1):
            if ta[x, y] + charge > tb[x, y]:
                return False
    return True


@njit(cache=True)
def label_schedules(out_first, arc_head, arc_leg1, arc_leg2, arc_depot,
               t_start, t_end, demand, is_delivery, timed,
               speed, capacity, max_range, per_metre, full, dcum_monotone, horizon,
               anchor_node, anchor_clock, anchor_flown, anchor_visited, anchor_loaded, root,
               cover, aav_time, closer, closer_time, goods_time, visit_bonus, cut_bonus,
               arc_bonus,
               forbidden_task, forbidden_arc, amount_low, amount_high, theta_high,
               early_theta, early_penalty, penalised, pieces, reach, ng_memory, elementary,
               label_cap, deadline, completion, step, unit):
    """Every undominated label from the anchor, extended path length by path length (with
    ``label_cap`` > 0 only the cheapest that many per node and length go on).

    A label that cannot lead to a schedule that prices out by ``completion[b, node]``
    (``completion_bounds``, b its clock's step; ``_prices_out``) is not kept (an empty
    ``completion`` bounds nothing).

    Returns (cost, alive, node, parent, arc, price, low, high, tables), one entry per
    label, the root first (parent -1). Arrival and Dcum are accumulated leg by leg in the
    evaluator's order of float operations, so a label's clock is the evaluator's arrival."""
    size = capacity + 1
    n_nodes = out_first.shape[0] - 1
    n_steps = completion.shape[0]
    words = anchor_visited.shape[0]
    room = 1024
    node = np.empty(room, np.int64)
    parent = np.empty(room, np.int64)
    arc_of = np.empty(room, np.int64)
    price_of = np.empty(room)
    low_of = np.empty(room, np.int64)
    high_of = np.empty(room, np.int64)
    clock = np.empty(room)
    flown = np.empty(room)
    cost = np.empty(room)
    alive = np.empty(room, np.bool_)
    loaded = np.empty(room, np.bool_)
    visited = np.empty((room, words), np.int64)
    tables = np.empty((room, size, size))
    node[0], parent[0], arc_of[0], price_of[0], low_of[0], high_of[0] = anchor_node, -1, -1, \
        0.0, 0, 0
    clock[0], flown[0], alive[0], loaded[0] = anchor_clock, anchor_flown, True, anchor_loaded
    visited[0] = anchor_visited
    tables[0] = root
    cost[0] = root[size - 1, size - 1]
    count = 1
    bucket = np.empty((n_nodes, 64), np.int64)
    bucket_clock = np.empty((n_nodes, 64))
    bucket_cost = np.empty((n_nodes, 64))
    bucket_tasks = np.empty((n_nodes, 64), np.int64)  # the first word of the visited set
    bucket_len = np.zeros(n_nodes, np.int64)
    frontier = np.zeros(1, np.int64)
    scratch_i = np.empty(size, np.int64)
    scratch_v = np.empty(size)
    row = np.empty(size)
    finished = True
    extended = 0
    while frontier.shape[0] > 0 and finished:
        produced = np.empty(16, np.int64)
        n_produced = 0
        for lab in frontier:
            if not alive[lab]:
                continue
            # A search's time limit must hold inside one call too: one exact pricing
            # call can take minutes where the labels explode.
            extended += 1
            if extended % 256 == 0:
                with objmode(now="float64"):
                    now = time.perf_counter()
                if now > deadline:
                    finished = False
                    break
            here = node[lab]
            for a in range(out_first[here], out_first[here + 1]):
                j = arc_head[a]
                if (visited[lab, j >> 6] >> (j & 63)) & 1 or forbidden_task[j] \
                        or forbidden_arc[a]:
                    continue
                t, f = clock[lab], flown[lab]
                leg = arc_leg1[a]
                f += leg
                t += leg / speed
                new_trip, has_goods = arc_depot[a], loaded[lab]
                if new_trip:
                    leg = arc_leg2[a]
                    f += leg
                    t += leg / speed
                    has_goods = True
                if t < t_start[j]:
                    t = t_start[j]
                if t > t_end[j]:
                    continue
                if is_delivery[j] and not has_goods:
                    continue
                c = per_metre * leg if f <= max_range else full
                c -= visit_bonus[j] + arc_bonus[a]
                c -= cut_bonus[j]
                p = cover[j]
                if timed[j]:
                    theta = (t - t_start[j]) / horizon
                    if theta > theta_high[j]:
                        continue
                    c += _early_cost(early_theta, early_penalty, j, theta)
                    c, p = _timed_price(c, p, j, theta, aav_time, closer, closer_time,
                                        goods_time, pieces)
                a_low = amount_low[j]
                a_high = min(demand[j], capacity, amount_high[j])
                # With no value on goods, more than the least amount only uses capacity.
                if p <= 0.0:
                    a_high = min(a_high, a_low)
                if a_high < a_low:
                    continue
                if count == node.shape[0]:
                    room = 2 * count
                    node, parent, arc_of = (_grown1(node, room), _grown1(parent, room),
                                            _grown1(arc_of, room))
                    price_of, low_of, high_of = (_grown1(price_of, room),
                                                 _grown1(low_of, room), _grown1(high_of, room))
                    clock, flown, cost = (_grown1(clock, room), _grown1(flown, room),
                                          _grown1(cost, room))
                    alive, loaded = _grown1(alive, room), _grown1(loaded, room)
                    visited, tables = _grown2(visited, room), _grown3(tables, room)
                k = count
                if new_trip:
                    _first_visit_table(tables[k], cost[lab], is_delivery[j], p, a_low, a_high)
                else:
                    _visit_table(tables[lab], tables[k], is_delivery[j], p, a_low, a_high,
                                 scratch_i, scratch_v, row)
                if not np.isfinite(tables[k, size - 1, size - 1]):
                    continue
                tables[k] += c
                if n_steps and not _prices_out(
                        tables[k], completion[min(int(t / step), n_steps - 1), j], unit,
                        capacity):
                    continue
                node[k], parent[k], arc_of[k], price_of[k] = j, lab, a, p
                low_of[k], high_of[k] = a_low, a_high
                clock[k], flown[k], cost[k] = t, f, tables[k, size - 1, size - 1]
                alive[k], loaded[k] = True, has_goods
                visited[k] = visited[lab] & ng_memory[j]
                visited[k, j >> 6] |= np.int64(1) << (j & 63)
                # Dominance within the bucket of node j; its labels' clocks, costs and
                # (first words of) visited sets are kept side by side so that the scan
                # reads contiguous memory and tests the rest only where those allow it.
                members = bucket_len[j]
                rejected = False
                tasks = visited[k, 0]
                for i in range(members):
                    if bucket_clock[j, i] <= t and bucket_cost[j, i] <= cost[k] and \
                            bucket_tasks[j, i] & ~tasks == 0:
                        other = bucket[j, i]
                        if alive[other] and _dominates(other, k, clock, cost, loaded, visited,
                                                       flown, tables, max_range,
                                                       dcum_monotone, penalised,
                                                       early_theta, early_penalty,
                                                       t_start, t_end, horizon, reach[j],
                                                       elementary):
                            rejected = True
                            break
                if rejected:
                    continue
                kept = 0
                for i in range(members):
                    other = bucket[j, i]
                    if not alive[other]:
                        continue
                    if bucket_clock[j, i] >= t and bucket_cost[j, i] >= cost[k] and \
                            tasks & ~bucket_tasks[j, i] == 0 and \
                            _dominates(k, other, clock, cost, loaded, visited, flown, tables,
                                       max_range, dcum_monotone, penalised,
                                       early_theta, early_penalty,
                                       t_start, t_end, horizon, reach[j], elementary):
                        alive[other] = False
                        continue
                    bucket[j, kept] = other
                    bucket_clock[j, kept] = bucket_clock[j, i]
                    bucket_cost[j, kept] = bucket_cost[j, i]
                    bucket_tasks[j, kept] = bucket_tasks[j, i]
                    kept += 1
                if kept == bucket.shape[1]:
                    bucket = _wider(bucket, 2 * kept)
                    bucket_clock = _wider(bucket_clock, 2 * kept)
                    bucket_cost = _wider(bucket_cost, 2 * kept)
                    bucket_tasks = _wider(bucket_tasks, 2 * kept)
                bucket[j, kept] = k
                bucket_clock[j, kept] = t
                bucket_cost[j, kept] = cost[k]
                bucket_tasks[j, kept] = tasks
                bucket_len[j] = kept + 1
                count += 1
                if n_produced == produced.shape[0]:
                    produced = _grown1(produced, 2 * n_produced)
                produced[n_produced] = k
                n_produced += 1
        frontier = produced[:n_produced].copy()
        if label_cap > 0:
            frontier = _cheapest_per_node(frontier, node, cost, alive, label_cap, n_nodes)
    return (cost[:count], alive[:count], node[:count], parent[:count], arc_of[:count],
            price_of[:count], low_of[:count], high_of[:count], tables[:count], finished)


@njit(cache=True)
def _cheapest_per_node(labels, node, cost, alive, cap, n_nodes):
    """The live ``labels`` that are among the ``cap`` cheapest of their node (ties: the
    earlier label); the others are marked dead (the heuristic label budget)."""
    order = np.argsort(cost[labels], kind="mergesort")
    taken = np.zeros(n_nodes, np.int64)
    keep = np.zeros(labels.shape[0], np.bool_)
    for i in order:
        lab = labels[i]
        if not alive[lab]:
            continue
        if taken[node[lab]] < cap:
            taken[node[lab]] += 1
            keep[i] = True
        else:
            alive[lab] = False
    return labels[keep]


