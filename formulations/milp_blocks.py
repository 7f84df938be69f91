"""The MILP's blocks (formulations/milp.py composes them in ``build_milp``), Egret's
``model_library`` style: each ``add_*`` adds one constraint family of docs/formulations.md,
"The MILP", with its variables, and names the equation of docs/model.md it states. They share
the index sets of ``MilpIndex``. ``build_milp`` calls them in a fixed order, which is the
order of HiGHS's columns and rows and so of its search path.
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass, field
from typing import Any

from tsac_bench.formulations.network import (
    DIRECT,
    START,
    AavNetwork,
    Arc,
    Prefix,
    coalition_cover_cuts,
    identical_groups,
)
from tsac_bench.model import Instance, Route

ArcKey = tuple[int, int, int, int]  # (AAV, tail, head, mode)


@dataclass
class MilpData:
    """What the blocks read, and what decoding and warm-starting need besides the Pyomo
    variables."""

    instance: Instance
    tasks: list[int]
    networks: list[AavNetwork]
    prefixes: list[Prefix]
    late: set[tuple[int, int]]
    constant: float  # cost of tasks outside the model (not visible): w1 + w2 each
    committed: tuple[Route, ...] = ()  # the prefixes, stamps included
    plan_time: float = 0.0  # when the free visits are planned (a dynamic re-plan's t_e)
    range_aavs: set[int] = field(default_factory=set)  # AAVs whose Dcum the model tracks
    over_range: dict[tuple[int, int], int | None] = field(default_factory=dict)  # fixed o


@dataclass(frozen=True)
class MilpIndex:
    """The index sets the blocks share, read once off the AAVs' networks."""

    visits: list[tuple[int, int]]  # V: (n, j), task j reachable on time by AAV n
    arcs: list[ArcKey]  # A
    ends: list[tuple[int, int]]  # E: (n, i), the route of n ends after i (START: unused)
    arc_of: dict[ArcKey, Arc]
    arcs_in: dict[tuple[int, int], list[ArcKey]]
    arcs_out: dict[tuple[int, int], list[ArcKey]]
    pairs: dict[tuple[int, int, int], list[ArcKey]]  # (n, i, j): its arcs, one per mode
    upper: dict[tuple[int, int], int]  # the largest amount of each visit

    @classmethod
    def of(cls, data: MilpData) -> MilpIndex:
        instance, networks = data.instance, data.networks
        arc_of = {(n, a.tail, a.head, a.mode): a for n, net in enumerate(networks)
                  for a in net.arcs}
        arcs = list(arc_of)
        visits = [(n, j) for n, net in enumerate(networks) for j in net.tasks]
        ends = [(n, i) for n, net in enumerate(networks) for i in [START, *net.tasks]]
        arcs_in: dict[tuple[int, int], list[ArcKey]] = {v: [] for v in visits}
        arcs_out: dict[tuple[int, int], list[ArcKey]] = {e: [] for e in ends}
        pairs: dict[tuple[int, int, int], list[ArcKey]] = {}
        for key in arcs:
            n, i, j, _ = key
            arcs_in[n, j].append(key)
            arcs_out[n, i].append(key)
            pairs.setdefault(key[:3], []).append(key)
        # A committed amount may exceed the demand (wasteful, legal); it is fixed as flown.
        committed = _committed_amounts(data)
        upper = {(n, j): max(min(instance.aavs[n].capacity, instance.tasks[j].demand),
                             committed.get((n, j), 0)) for n, j in visits}
        return cls(visits, arcs, ends, arc_of, arcs_in, arcs_out, pairs, upper)


def add_variables(model: Any, data: MilpData, index: MilpIndex) -> None:
    """The sets V, A, E, T and the variables every block uses: arcs x, route ends, visits y,
    amounts a (Eqs. 2-3), arrivals t (Eq. 7; the upper bound t_end forbids late visits), the
    goods on board after a visit dl, pl (Eq. 10), tasks served u and the coalition's latest
    arrival Tm (Eq. 6)."""
    import pyomo.environ as pyo

    instance, networks = data.instance, data.networks
    model.V = pyo.Set(initialize=index.visits, dimen=2, ordered=True)
    model.A = pyo.Set(initialize=index.arcs, dimen=4, ordered=True)
    model.E = pyo.Set(initialize=index.ends, dimen=2, ordered=True)
    model.T = pyo.Set(initialize=data.tasks, ordered=True)

    def cap(m: Any, n: int, j: int) -> tuple[int, int]:
        return 0, instance.aavs[n].capacity

    model.x = pyo.Var(model.A, domain=pyo.Binary)
    model.end = pyo.Var(model.E, domain=pyo.Binary)
    model.y = pyo.Var(model.V, domain=pyo.Binary)
    model.a = pyo.Var(model.V, domain=pyo.NonNegativeIntegers,
                      bounds=lambda m, n, j: (0, index.upper[n, j]))
    model.t = pyo.Var(model.V, bounds=lambda m, n, j: (networks[n].earliest[j],
                                                      networks[n].latest[j]))
    model.dl = pyo.Var(model.V, bounds=cap)
    model.pl = pyo.Var(model.V, bounds=cap)
    model.u = pyo.Var(model.T, bounds=(0, 1))
    model.Tm = pyo.Var(model.T, bounds=lambda m, j: (instance.tasks[j].t_start,
                                                     _task_latest(data, j)))


def add_flow_conservation(model: Any, data: MilpData, index: MilpIndex) -> None:
    """Routing (Eq. 11 and the route structure): one path per AAV from its start, each task
    visited entered once and left once or closed by the end arc."""
    import pyomo.environ as pyo

    arcs_in, arcs_out = index.arcs_in, index.arcs_out
    model.leave_start = pyo.Constraint(range(data.instance.n_aavs), rule=lambda m, n: sum(
        m.x[k] for k in arcs_out[n, START]) + m.end[n, START] == 1)
    model.flow_in = pyo.Constraint(model.V, rule=lambda m, n, j: sum(
        m.x[k] for k in arcs_in[n, j]) == m.y[n, j])
    model.flow_out = pyo.Constraint(model.V, rule=lambda m, n, j: sum(
        m.x[k] for k in arcs_out[n, j]) + m.end[n, j] == m.y[n, j])


def add_amounts(model: Any, data: MilpData, index: MilpIndex) -> None:
    """Amounts (Eqs. 2-3) and C_load's covered goods (Eq. 5): a visit brings 1..min(B, R)
    kg; covered <= the on-time goods and <= the demand, so C_load = 1 - covered / R; the
    coalition brings no more than the demand (canonical point 4)."""
    import pyomo.environ as pyo

    instance = data.instance
    model.amount_min = pyo.Constraint(model.V, rule=lambda m, n, j: m.a[n, j] >= m.y[n, j])
    model.amount_max = pyo.Constraint(model.V, rule=lambda m, n, j: m.a[n, j]
                                      <= index.upper[n, j] * m.y[n, j])
    model.covered = pyo.Var(model.T, bounds=lambda m, j: (0, instance.tasks[j].demand))
    model.coverage = pyo.Constraint(model.T, rule=lambda m, j: m.covered[j]
                                    <= _on_time_amount(m, data, j))
    committed = _committed_amounts(data)

    def demand_rule(m: Any, j: int) -> Any:
        amount = _on_time_amount(m, data, j)
        if isinstance(amount, int):
            return pyo.Constraint.Skip
        # A committed visit may have brought more than the demand: that total stays legal.
        fixed = sum(a for (n, i), a in committed.items() if i == j and (n, j) not in data.late)
        return amount <= max(instance.tasks[j].demand, fixed)

    model.demand = pyo.Constraint(model.T, rule=demand_rule)


def add_time_windows(model: Any, data: MilpData, index: MilpIndex) -> None:
    """Time (Eq. 7, with waiting): t_j >= t_i + travel on the arc flown (per-pair big-M),
    from the anchor no earlier than the plan (``ready``); the windows are t's bounds. Arcs of
    zero travel time get an order (``rank``) so that they form no cycle."""
    import pyomo.environ as pyo

    instance, networks = data.instance, data.networks
    pairs, arc_of = index.pairs, index.arc_of

    def time_rule(m: Any, n: int, i: int, j: int) -> Any:
        keys = pairs[n, i, j]
        travel = sum(arc_of[k].travel * m.x[k] for k in keys)
        if i == START:
            return m.t[n, j] >= travel
        net = networks[n]
        big_m = max(0.0, net.latest[i] + max(arc_of[k].travel for k in keys) - net.earliest[j])
        used = sum(m.x[k] for k in keys)
        return m.t[n, j] >= m.t[n, i] + travel - big_m * (1 - used)

    model.P = pyo.Set(initialize=list(pairs), dimen=3, ordered=True)
    model.time = pyo.Constraint(model.P, rule=time_rule)

    def ready_rule(m: Any, n: int, i: int, j: int) -> Any:
        net = networks[n]
        if i != net.anchor or (net.ready <= 0 and net.committed_depot is None):
            return pyo.Constraint.Skip
        speed = instance.aavs[n].speed
        return m.t[n, j] >= sum(net.ready_arrival(arc_of[k], speed) * m.x[k]
                                for k in pairs[n, i, j])

    model.ready = pyo.Constraint(model.P, rule=ready_rule)
    zero = [p for p in pairs if p[1] != START and min(arc_of[k].travel for k in pairs[p]) == 0]
    if zero:
        size = len(data.tasks)
        model.rank = pyo.Var(model.V, bounds=(0, size))
        model.order = pyo.Constraint(zero, rule=lambda m, n, i, j: m.rank[n, j] >= m.rank[
            n, i] + 1 - (size + 1) * (1 - sum(m.x[k] for k in pairs[n, i, j])))


def add_time_flow(model: Any, data: MilpData, index: MilpIndex) -> None:
    """Arrival times carried on the arcs (strengthening of Eq. 7 and C_time): r_a is the
    arrival at a's head when a is flown, 0 otherwise, so Z_nj = sum of r over the arcs into j
    is t_nj * y_nj. The big-M time rows let a fractional arc leave t_nj at its lower bound;
    here every fraction of flow carries its own arrival, which is what the coalition's C_time
    then pays for (T_j - t_start >= Z_nj - t_start * y_nj). Valid: at an integer point set
    each r to the arrival of its head; leaving i along b arrives no earlier than t_i +
    travel_b, and a route that ends at i has no outgoing r (the end term absorbs Z_ni <=
    t_end(i))."""
    import pyomo.environ as pyo

    instance, networks = data.instance, data.networks
    arc_of, arcs_in, arcs_out = index.arc_of, index.arcs_in, index.arcs_out

    def lowest(key: ArcKey) -> float:
        n, i, j, _ = key
        net = networks[n]
        leave = 0.0 if i == START else net.earliest[i]
        low = max(net.earliest[j], leave + arc_of[key].travel)
        if i == net.anchor:
            low = max(low, net.ready_arrival(arc_of[key], instance.aavs[n].speed))
        return low

    model.r = pyo.Var(model.A, domain=pyo.NonNegativeReals)
    model.r_low = pyo.Constraint(model.A, rule=lambda m, *k: m.r[k] >= lowest(k) * m.x[k])
    model.r_high = pyo.Constraint(model.A, rule=lambda m, *k: m.r[k]
                                  <= networks[k[0]].latest[k[2]] * m.x[k])

    def arrival_flow(m: Any, n: int, j: int) -> Any:
        return sum(m.r[k] for k in arcs_in[n, j])

    model.r_leave = pyo.Constraint(model.V, rule=lambda m, n, i: sum(
        m.r[k] - arc_of[k].travel * m.x[k] for k in arcs_out[n, i])
        >= arrival_flow(m, n, i) - networks[n].latest[i] * m.end[n, i])
    model.r_arrival = pyo.Constraint(model.V, rule=lambda m, n, j: m.t[n, j]
                                     >= arrival_flow(m, n, j))
    late_tasks = {j for _, j in data.late}
    model.r_coalition = pyo.Constraint(
        [(n, j) for n, j in model.V if j not in late_tasks],
        rule=lambda m, n, j: m.Tm[j] - instance.tasks[j].t_start
        >= arrival_flow(m, n, j) - instance.tasks[j].t_start * m.y[n, j])


def add_loads(model: Any, data: MilpData, index: MilpIndex) -> None:
    """Loads (Eq. 10): dl after a visit >= the deliveries still ahead in the trip, pl >= the
    pickups so far, dl + pl <= B; a direct arc chains them (big-M = B), a depot arc resets
    the chain, a trip from the start carries no delivery goods; a committed depot visit the
    AAV has left loaded what it recorded, no more."""
    import pyomo.environ as pyo

    instance, prefixes = data.instance, data.prefixes

    def cap(n: int) -> int:
        return instance.aavs[n].capacity

    def delivered(m: Any, n: int, j: int) -> Any:
        return m.a[n, j] if instance.tasks[j].is_delivery else 0

    def picked(m: Any, n: int, j: int) -> Any:
        return 0 if instance.tasks[j].is_delivery else m.a[n, j]

    model.capacity = pyo.Constraint(model.V, rule=lambda m, n, j: m.dl[n, j] + m.pl[n, j]
                                    <= cap(n))
    model.depot_load = pyo.Constraint(model.V, rule=lambda m, n, j: m.dl[n, j]
                                      + delivered(m, n, j) <= cap(n))
    model.own_pickup = pyo.Constraint(model.V, rule=lambda m, n, j: m.pl[n, j]
                                      >= picked(m, n, j))
    direct = [k for k in index.arcs if k[3] == DIRECT]

    def delivery_chain(m: Any, n: int, i: int, j: int, mode: int) -> Any:
        before = 0 if i == START else m.dl[n, i]
        return before >= m.dl[n, j] + delivered(m, n, j) - cap(n) * (1 - m.x[n, i, j, mode])

    def pickup_chain(m: Any, n: int, i: int, j: int, mode: int) -> Any:
        before = 0 if i == START else m.pl[n, i]
        return m.pl[n, j] >= before + picked(m, n, j) - cap(n) * (1 - m.x[n, i, j, mode])

    model.delivery_chain = pyo.Constraint(direct, rule=delivery_chain)
    model.recorded_load = pyo.Constraint(
        [(n, j) for n, p in enumerate(prefixes) for j in p.loads],
        rule=lambda m, n, j: m.dl[n, j] + delivered(m, n, j) <= prefixes[n].loads[j])
    model.pickup_chain = pyo.Constraint([k for k in direct if k[1] != START],
                                        rule=pickup_chain)


def add_capacity_cuts(model: Any, data: MilpData, index: MilpIndex) -> None:
    """Capacity cuts (strengthening of Eq. 10): each trip loads or unloads at most B, so an
    AAV's delivery amounts are at most B x its depot arcs, its pickup amounts at most B x
    (its depot arcs + 1 if used)."""
    import pyomo.environ as pyo

    instance, networks = data.instance, data.networks

    def trips(m: Any, n: int) -> Any:
        return sum(m.x[k] for k in index.arcs if k[0] == n and k[3] != DIRECT)

    def amounts(m: Any, n: int, delivery: bool) -> Any:
        return sum(m.a[n, j] for j in networks[n].tasks
                   if instance.tasks[j].is_delivery == delivery)

    def kind_rows(delivery: bool) -> list[int]:
        return [n for n in range(instance.n_aavs) if any(
            instance.tasks[j].is_delivery == delivery for j in networks[n].tasks)]

    model.delivery_trips = pyo.Constraint(kind_rows(True), rule=lambda m, n: amounts(
        m, n, True) <= instance.aavs[n].capacity * trips(m, n))
    def used(m: Any, n: int) -> Any:
        return 1 - m.end[n, START]

    model.pickup_trips = pyo.Constraint(kind_rows(False), rule=lambda m, n: amounts(
        m, n, False) <= instance.aavs[n].capacity * (trips(m, n) + used(m, n)))


def add_range(model: Any, data: MilpData, index: MilpIndex, link: bool) -> dict:
    """Range and operating cost (Eq. 9): the cost q_nj of each visit, as the leg expression
    where the range cannot be passed, the full-range cost where even the shortest way there
    passes it, and through Dcum and the over-range indicator o where it can matter (``link``:
    Dcum <= v t). Returns q per visit, for the objective."""
    instance, networks = data.instance, data.networks
    op_cost: dict[tuple[int, int], Any] = {}
    open_visits = []  # (n, j, leg cost, full-range cost, cost per metre)
    for n, net in enumerate(networks):
        aav = instance.aavs[n]
        per_metre = aav.alpha / 1000.0 / instance.e_base
        full = aav.full_range_cost / instance.e_base
        for j in net.tasks:
            leg_cost = sum(per_metre * index.arc_of[k].leg * model.x[k]
                           for k in index.arcs_in[n, j])
            reach = aav.speed * net.latest[j]  # Dcum <= v * t <= v * t_end
            if net.min_distance[j] > aav.max_range:
                data.over_range[n, j] = 1
                op_cost[n, j] = full * model.y[n, j]
            elif reach <= aav.max_range:
                data.over_range[n, j] = 0
                op_cost[n, j] = leg_cost
            else:
                data.over_range[n, j] = None
                data.range_aavs.add(n)
                open_visits.append((n, j, leg_cost, full, per_metre))
    if open_visits:
        _add_distance(model, data, index, [(n, j) for n, j, *_ in open_visits], link)
        _add_over_range_cost(model, data, index, open_visits, op_cost)
    return op_cost


def _add_distance(model: Any, data: MilpData, index: MilpIndex, over: list[tuple[int, int]],
                  link: bool) -> None:
    """Dcum (Eq. 9) of the AAVs that can pass their range: dc_j >= dc_i + distance on the arc
    flown (per-pair big-M), dc <= v t (``link``), and the variables o, q of the visits
    ``over`` where the range can be passed."""
    import pyomo.environ as pyo

    instance, networks = data.instance, data.networks
    pairs, arc_of = index.pairs, index.arc_of
    range_visits = [(n, j) for n, j in index.visits if n in data.range_aavs]
    model.RV = pyo.Set(initialize=range_visits, dimen=2, ordered=True)
    model.dc = pyo.Var(model.RV, bounds=lambda m, n, j: (
        networks[n].min_distance[j], instance.aavs[n].speed * networks[n].latest[j]))
    model.o = pyo.Var(over, domain=pyo.Binary)
    model.q = pyo.Var(over, domain=pyo.NonNegativeReals)

    def distance_rule(m: Any, n: int, i: int, j: int) -> Any:
        keys = pairs[n, i, j]
        flown = sum(arc_of[k].distance * m.x[k] for k in keys)
        if i == START:
            return m.dc[n, j] >= flown
        big_m = max(0.0, m.dc[n, i].ub + max(arc_of[k].distance for k in keys)
                    - m.dc[n, j].lb)
        return m.dc[n, j] >= m.dc[n, i] + flown - big_m * (1 - sum(m.x[k] for k in keys))

    model.distance = pyo.Constraint([p for p in pairs if p[0] in data.range_aavs],
                                    rule=distance_rule)
    if link:
        model.range_time = pyo.Constraint(model.RV, rule=lambda m, n, j: m.dc[n, j]
                                          <= instance.aavs[n].speed * m.t[n, j])


def _add_over_range_cost(model: Any, data: MilpData, index: MilpIndex, open_visits: list,
                         op_cost: dict) -> None:
    """Eq. 9's two cases where the range can be passed: o = 0 forces Dcum <= D; q >= the leg
    cost unless o = 1, q >= the full-range cost F if o = 1 (exact: F >= any leg within the
    range, so o = 1 never helps a visit within it). Sets op_cost of those visits to q."""
    import pyomo.environ as pyo

    instance = data.instance
    over = [(n, j) for n, j, *_ in open_visits]
    model.within_range = pyo.Constraint(over, rule=lambda m, n, j: m.dc[n, j]
                                        <= instance.aavs[n].max_range
                                        + (m.dc[n, j].ub - instance.aavs[n].max_range)
                                        * m.o[n, j])
    model.over_visit = pyo.Constraint(over, rule=lambda m, n, j: m.o[n, j] <= m.y[n, j])
    model.q_leg = pyo.ConstraintList()
    model.q_full = pyo.ConstraintList()
    for n, j, leg_cost, full, per_metre in open_visits:
        longest = max((per_metre * index.arc_of[k].leg for k in index.arcs_in[n, j]),
                      default=0.0)
        model.q_leg.add(model.q[n, j] >= leg_cost - longest * model.o[n, j])
        model.q_full.add(model.q[n, j] >= full * model.o[n, j])
        op_cost[n, j] = model.q[n, j]


def add_coalition_time(model: Any, data: MilpData, index: MilpIndex) -> None:
    """C_time (Eq. 6): Tm_j >= every on-time member's arrival (big-M = the widest possible
    difference), u_j <= the number of visitors, so C_time = 1 - u + (Tm - t_start) / T_hor;
    a task with a late committed visit has C_time = 1 whatever else comes."""
    import pyomo.environ as pyo

    instance, networks = data.instance, data.networks
    late_tasks = {m for _, m in data.late}
    model.latest_arrival = pyo.Constraint(
        [(n, j) for n, j in index.visits if j not in late_tasks],
        rule=lambda m, n, j: m.Tm[j] >= m.t[n, j] - (networks[n].latest[j]
                                                     - instance.tasks[j].t_start)
        * (1 - m.y[n, j]))
    model.served = pyo.Constraint(model.T, rule=lambda m, j: m.u[j] <= sum(
        m.y[n, j] for n, net in enumerate(networks) if j in net.earliest))
    for j in late_tasks:
        model.u[j].fix(0)
        model.Tm[j].fix(instance.tasks[j].t_start)


def add_cover_cuts(model: Any, data: MilpData, index: MilpIndex) -> None:
    """Coalition cover cuts (strengthening of C_load, Eq. 5; network.coalition_cover_cuts):
    a large task needs particular AAVs in full, covered_j <= rest + sum of their shares."""
    import pyomo.environ as pyo

    model.cover = pyo.ConstraintList()
    for j in data.tasks:
        members = [n for n, net in enumerate(data.networks) if j in net.earliest
                   and (n, j) not in data.late]
        upper = {n: index.upper[n, j] for n in members}
        for rest, coef in coalition_cover_cuts(upper, data.instance.tasks[j].demand):
            model.cover.add(model.covered[j] <= rest + sum(
                c * model.y[n, j] for n, c in coef.items()))


def fix_prefixes(model: Any, data: MilpData, index: MilpIndex) -> None:
    """The dynamic run's committed prefixes (docs/model.md, "The dynamic run"): their arcs
    and amounts are fixed as flown; a trailing committed depot is the only way on."""
    for n, prefix in enumerate(data.prefixes):
        for i, j, mode, amount in prefix.steps:
            model.x[n, i, j, mode].fix(1)
            model.a[n, j].fix(amount)
        if prefix.trailing_depot is not None:
            for key in index.arcs_out[n, prefix.last]:
                if key[3] != prefix.trailing_depot:
                    model.x[key].fix(0)


def add_symmetry(model: Any, data: MilpData) -> None:
    """Symmetry breaking (exact): identical AAVs ordered by their smallest task index,
    y_{n',j} <= sum_{i <= j} y_{n,i} for consecutive n < n' of a group."""
    import pyomo.environ as pyo

    networks = data.networks
    pairs = [p for group in identical_groups(data.instance, data.committed)
             for p in itertools.pairwise(group)]
    rows = [(n, n2, j) for n, n2 in pairs for j in networks[n2].tasks]
    model.symmetry = pyo.Constraint(rows, rule=lambda m, n, n2, j: m.y[n2, j] <= sum(
        m.y[n, i] for i in networks[n].tasks if i <= j))


def add_objective(model: Any, data: MilpData, op_cost: dict) -> None:
    """J (Eqs. 1, 4-6, 8, 9): per task w1 C_load + w2 C_time + w3 C_op, plus w1 + w2 for
    every task outside the model."""
    import pyomo.environ as pyo

    instance = data.instance
    w1, w2, w3 = instance.weights

    def task_cost(m: Any, j: int) -> Any:
        task = instance.tasks[j]
        load = 1 - m.covered[j] / task.demand
        tardiness = 1 - m.u[j] + (m.Tm[j] - task.t_start) / instance.horizon
        op = sum(op_cost[n, j] for n, net in enumerate(data.networks) if j in net.earliest)
        return w1 * load + w2 * tardiness + w3 * op

    model.J = pyo.Objective(expr=data.constant + sum(task_cost(model, j) for j in data.tasks),
                            sense=pyo.minimize)


def _committed_amounts(data: MilpData) -> dict[tuple[int, int], int]:
    return {(n, j): a for n, p in enumerate(data.prefixes) for _, j, _, a in p.steps}


def _on_time_amount(m: Any, data: MilpData, j: int) -> Any:
    """The amounts of j's on-time visits (late committed visits earn nothing)."""
    return sum(m.a[n, j] for n, net in enumerate(data.networks) if j in net.earliest
               and (n, j) not in data.late)


def _task_latest(data: MilpData, j: int) -> float:
    return max([data.instance.tasks[j].t_end]
               + [net.latest[j] for net in data.networks if j in net.latest])


