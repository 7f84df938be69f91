"""The exact MILP of Problem 1 (MODEL.md) in Pyomo, solved by HiGHS.

``build_milp`` returns a ``pyomo.ConcreteModel`` (nothing is solved there); ``solve_milp``
runs HiGHS on it; ``decode`` reads the routes back; ``warm_start`` loads a solution into the
variables (a MIP start, and the tests' check that every canonical solution is a point of the
model with objective J). docs/formulations.md states every constraint and big-M.

The model searches canonical solutions (formulations/network.py): per AAV a path from its
start through task visits, each arc direct or through one depot, closed by an uncharged
final depot visit. Its objective equals J of the decoded solution exactly: C_load, C_time and
C_op are linear in the variables at every integer point.
"""

from __future__ import annotations

import itertools
import math
import time
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

from tsac_bench.formulations.network import (
    DIRECT,
    START,
    AavNetwork,
    Prefix,
    aav_network,
    canonical_routes,
    coalition_cover_cuts,
    first_task,
    identical_groups,
    late_committed,
    parse_prefix,
    prefix_arrivals,
)
from tsac_bench.model import Instance, Route, Visit
from tsac_bench.model.evaluator import CostEvaluator


@dataclass
class MilpOptions:
    """Which strengthening the builder adds (each is exact; see docs/formulations.md)."""

    symmetry: bool = True  # order identical AAVs by their smallest task index
    capacity_cuts: bool = True  # sum of amounts <= B * number of trips
    range_time_link: bool = True  # Dcum <= v * t (no AAV flies faster than its speed)
    time_flow: bool = True  # arrival times carried on the arcs (a stronger LP than big-M)
    cover_cuts: bool = True  # a large task needs particular AAVs in full


@dataclass
class MilpData:
    """What decoding and warm-starting need besides the Pyomo variables."""

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


def build_milp(instance: Instance, tasks: Sequence[int] | None = None,
               committed: Sequence[Route] | None = None,
               options: MilpOptions | None = None, plan_time: float = 0.0) -> Any:
    """The MILP over ``tasks`` (default all; others stay unserved) with every AAV's route
    starting with its ``committed`` prefix and its free visits planned at ``plan_time`` (it
    leaves its anchor no earlier). Returns the model; ``model.data`` is a MilpData."""
    import pyomo.environ as pyo

    from tsac_bench.planning import PlanningState

    options = options or MilpOptions()
    n_aavs = instance.n_aavs
    committed = tuple(committed) if committed else tuple(() for _ in range(n_aavs))
    moment = PlanningState(instance, plan_time, frozenset(), committed)
    prefixes = [parse_prefix(instance, p) for p in committed]
    in_prefix = {m for p in prefixes for _, m, _, _ in p.steps}
    chosen = sorted(set(range(instance.n_tasks) if tasks is None else tasks) | in_prefix)
    late = late_committed(instance, committed)
    networks = []
    for n in range(n_aavs):
        prefix = prefixes[n]
        required = [(i, j, k) for i, j, k, _ in prefix.steps]
        trailing = None if prefix.trailing_depot is None else (prefix.last,
                                                                 prefix.trailing_depot)
        # Every AAV may join any chosen task, also one another AAV's prefix has committed to:
        # a partly served task's coalition can still grow.
        networks.append(aav_network(instance, n, chosen, prefix_arrivals(
            instance, n, committed[n]), required, trailing, prefix.last,
            moment.anchor(n).time))
    w1, w2, w3 = instance.weights
    horizon = instance.horizon
    e_base = instance.e_base
    data = MilpData(instance, chosen, networks, prefixes, late,
                    constant=instance.unserved_task_cost * (instance.n_tasks - len(chosen)),
                    committed=committed, plan_time=plan_time)

    model = pyo.ConcreteModel(name=f"tsac-milp[{instance.name}]")
    model.data = data
    visits = [(n, j) for n, net in enumerate(networks) for j in net.tasks]
    arcs = [(n, a.tail, a.head, a.mode) for n, net in enumerate(networks) for a in net.arcs]
    arc_of = {(n, a.tail, a.head, a.mode): a for n, net in enumerate(networks)
              for a in net.arcs}
    ends = [(n, i) for n, net in enumerate(networks) for i in [START, *net.tasks]]
    model.V = pyo.Set(initialize=visits, dimen=2, ordered=True)
    model.A = pyo.Set(initialize=arcs, dimen=4, ordered=True)
    model.E = pyo.Set(initialize=ends, dimen=2, ordered=True)
    model.T = pyo.Set(initialize=chosen, ordered=True)

    def cap(n: int) -> int:
        return instance.aavs[n].capacity

    committed_amount = {(n, j): a for n, p in enumerate(prefixes) for _, j, _, a in p.steps}

    def upper_amount(n: int, j: int) -> int:
        # A committed amount may exceed the demand (wasteful, legal); it is fixed as flown.
        return max(min(cap(n), instance.tasks[j].demand), committed_amount.get((n, j), 0))

    model.x = pyo.Var(model.A, domain=pyo.Binary)  # arc flown
    model.end = pyo.Var(model.E, domain=pyo.Binary)  # route closes after node (START: unused)
    model.y = pyo.Var(model.V, domain=pyo.Binary)  # AAV n visits task j
    model.a = pyo.Var(model.V, domain=pyo.NonNegativeIntegers,
                      bounds=lambda m, n, j: (0, upper_amount(n, j)))
    model.t = pyo.Var(model.V, bounds=lambda m, n, j: (networks[n].earliest[j],
                                                      networks[n].latest[j]))
    model.dl = pyo.Var(model.V, bounds=lambda m, n, j: (0, cap(n)))  # delivery goods after
    model.pl = pyo.Var(model.V, bounds=lambda m, n, j: (0, cap(n)))  # pickup goods after
    model.u = pyo.Var(model.T, bounds=(0, 1))  # task served
    model.Tm = pyo.Var(model.T, bounds=lambda m, j: (instance.tasks[j].t_start,
                                                     _task_latest(data, j)))

    arcs_in: dict[tuple[int, int], list] = {(n, j): [] for n, j in visits}
    arcs_out: dict[tuple[int, int], list] = {(n, i): [] for n, i in ends}
    for key in arcs:
        n, i, j, _ = key
        arcs_in[n, j].append(key)
        arcs_out[n, i].append(key)

    # --- routing: one path per AAV from its start, closed by the end arc -----------------
    model.leave_start = pyo.Constraint(range(n_aavs), rule=lambda m, n: sum(
        m.x[k] for k in arcs_out[n, START]) + m.end[n, START] == 1)
    model.flow_in = pyo.Constraint(model.V, rule=lambda m, n, j: sum(
        m.x[k] for k in arcs_in[n, j]) == m.y[n, j])
    model.flow_out = pyo.Constraint(model.V, rule=lambda m, n, j: sum(
        m.x[k] for k in arcs_out[n, j]) + m.end[n, j] == m.y[n, j])
    model.amount_min = pyo.Constraint(model.V, rule=lambda m, n, j: m.a[n, j] >= m.y[n, j])
    model.amount_max = pyo.Constraint(model.V, rule=lambda m, n, j: m.a[n, j]
                                      <= upper_amount(n, j) * m.y[n, j])

    def on_time_amount(m: Any, j: int) -> Any:
        return sum(m.a[n, j] for n, net in enumerate(networks) if j in net.earliest
                   and (n, j) not in late)

    # covered <= on-time goods and <= demand: C_load = 1 - covered / R (Eq. 5's max(0, .)).
    model.covered = pyo.Var(model.T, bounds=lambda m, j: (0, instance.tasks[j].demand))
    model.coverage = pyo.Constraint(model.T, rule=lambda m, j: m.covered[j]
                                    <= on_time_amount(m, j))

    # Canonical solutions bring no more than the demand (unless a committed visit did).
    def demand_rule(m: Any, j: int) -> Any:
        amount = on_time_amount(m, j)
        if isinstance(amount, int):
            return pyo.Constraint.Skip
        fixed = sum(a for (n, i), a in committed_amount.items() if i == j and (n, j) not in late)
        return amount <= max(instance.tasks[j].demand, fixed)

    model.demand = pyo.Constraint(model.T, rule=demand_rule)

    # --- time (Eq. 7): t_j >= t_i + travel on the arc flown; windows are the bounds --------
    pairs: dict[tuple[int, int, int], list] = {}
    for key in arcs:
        pairs.setdefault(key[:3], []).append(key)

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

    # A free arc out of the anchor leaves it no earlier than the plan (MODEL.md, "Time").
    def ready_rule(m: Any, n: int, i: int, j: int) -> Any:
        net = networks[n]
        if i != net.anchor or (net.ready <= 0 and net.committed_depot is None):
            return pyo.Constraint.Skip
        speed = instance.aavs[n].speed
        return m.t[n, j] >= sum(net.ready_arrival(arc_of[k], speed) * m.x[k]
                                for k in pairs[n, i, j])

    model.ready = pyo.Constraint(model.P, rule=ready_rule)
    # Arcs of zero travel time (coincident points) need an order to exclude cycles.
    zero = [p for p in pairs if p[1] != START and min(arc_of[k].travel for k in pairs[p]) == 0]
    if zero:
        model.rank = pyo.Var(model.V, bounds=(0, len(chosen)))
        model.order = pyo.Constraint(zero, rule=lambda m, n, i, j: m.rank[n, j] >= m.rank[
            n, i] + 1 - (len(chosen) + 1) * (1 - sum(m.x[k] for k in pairs[n, i, j])))

    if options.time_flow:
        _add_time_flow(model, data, arc_of, arcs_in, arcs_out)

    # --- loads (Eq. 10): d after a visit >= the deliveries still ahead in the trip --------
    def is_delivery(j: int) -> bool:
        return instance.tasks[j].is_delivery

    def delivered(m: Any, n: int, j: int) -> Any:
        return m.a[n, j] if is_delivery(j) else 0

    def picked(m: Any, n: int, j: int) -> Any:
        return 0 if is_delivery(j) else m.a[n, j]

    model.capacity = pyo.Constraint(model.V, rule=lambda m, n, j: m.dl[n, j] + m.pl[n, j]
                                <= cap(n))
    model.depot_load = pyo.Constraint(model.V, rule=lambda m, n, j: m.dl[n, j]
                                      + delivered(m, n, j) <= cap(n))
    model.own_pickup = pyo.Constraint(model.V, rule=lambda m, n, j: m.pl[n, j]
                                      >= picked(m, n, j))
    direct = [k for k in arcs if k[3] == DIRECT]

    def delivery_chain(m: Any, n: int, i: int, j: int, mode: int) -> Any:
        before = 0 if i == START else m.dl[n, i]
        return before >= m.dl[n, j] + delivered(m, n, j) - cap(n) * (1 - m.x[n, i, j, mode])

    def pickup_chain(m: Any, n: int, i: int, j: int, mode: int) -> Any:
        before = 0 if i == START else m.pl[n, i]
        return m.pl[n, j] >= before + picked(m, n, j) - cap(n) * (1 - m.x[n, i, j, mode])

    model.delivery_chain = pyo.Constraint(direct, rule=delivery_chain)
    # A committed depot visit the AAV has left loaded what it recorded, no more.
    model.recorded_load = pyo.Constraint(
        [(n, j) for n, p in enumerate(prefixes) for j in p.loads],
        rule=lambda m, n, j: m.dl[n, j] + delivered(m, n, j) <= prefixes[n].loads[j])
    model.pickup_chain = pyo.Constraint([k for k in direct if k[1] != START],
                                        rule=pickup_chain)

    if options.capacity_cuts:
        def trips(m: Any, n: int) -> Any:
            return sum(m.x[k] for k in arcs if k[0] == n and k[3] != DIRECT)

        def used(m: Any, n: int) -> Any:
            return 1 - m.end[n, START]

        def kind_rows(delivery: bool) -> list[int]:
            return [n for n in range(n_aavs)
                    if any(is_delivery(j) == delivery for j in networks[n].tasks)]

        model.delivery_trips = pyo.Constraint(kind_rows(True), rule=lambda m, n: sum(
            m.a[n, j] for j in networks[n].tasks if is_delivery(j)) <= cap(n) * trips(m, n))
        model.pickup_trips = pyo.Constraint(kind_rows(False), rule=lambda m, n: sum(
            m.a[n, j] for j in networks[n].tasks if not is_delivery(j))
            <= cap(n) * (trips(m, n) + used(m, n)))

    # --- range (Eq. 9): Dcum and the over-range indicator where it can matter -------------
    op_cost: dict[tuple[int, int], Any] = {}
    over_terms = []
    for n, net in enumerate(networks):
        aav = instance.aavs[n]
        per_metre = aav.alpha / 1000.0 / e_base
        full = aav.full_range_cost / e_base
        for j in net.tasks:
            leg_cost = sum(per_metre * arc_of[k].leg * model.x[k] for k in arcs_in[n, j])
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
                over_terms.append((n, j, leg_cost, full, per_metre))
    if over_terms:
        range_visits = [(n, j) for n, j in visits if n in data.range_aavs]
        model.RV = pyo.Set(initialize=range_visits, dimen=2, ordered=True)
        model.dc = pyo.Var(model.RV, bounds=lambda m, n, j: (
            networks[n].min_distance[j], instance.aavs[n].speed * networks[n].latest[j]))
        over = [(n, j) for n, j, *_ in over_terms]
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
        if options.range_time_link:
            model.range_time = pyo.Constraint(model.RV, rule=lambda m, n, j: m.dc[n, j]
                                              <= instance.aavs[n].speed * m.t[n, j])
        model.within_range = pyo.Constraint(over, rule=lambda m, n, j: m.dc[n, j]
                                            <= instance.aavs[n].max_range
                                            + (m.dc[n, j].ub - instance.aavs[n].max_range)
                                            * m.o[n, j])
        model.over_visit = pyo.Constraint(over, rule=lambda m, n, j: m.o[n, j] <= m.y[n, j])
        model.q_leg = pyo.ConstraintList()
        model.q_full = pyo.ConstraintList()
        for n, j, leg_cost, full, per_metre in over_terms:
            longest = max((per_metre * arc_of[k].leg for k in arcs_in[n, j]), default=0.0)
            model.q_leg.add(model.q[n, j] >= leg_cost - longest * model.o[n, j])
            model.q_full.add(model.q[n, j] >= full * model.o[n, j])
            op_cost[n, j] = model.q[n, j]

    # --- C_time: the latest on-time arrival of the coalition, 1 when nobody comes ---------
    late_tasks = {m for _, m in late}
    model.latest_arrival = pyo.Constraint(
        [(n, j) for n, j in visits if j not in late_tasks],
        rule=lambda m, n, j: m.Tm[j] >= m.t[n, j] - (networks[n].latest[j]
                                                     - instance.tasks[j].t_start)
        * (1 - m.y[n, j]))
    model.served = pyo.Constraint(model.T, rule=lambda m, j: m.u[j] <= sum(
        m.y[n, j] for n, net in enumerate(networks) if j in net.earliest))
    for j in late_tasks:  # a late committed visit makes C_time = 1 whatever else comes
        model.u[j].fix(0)
        model.Tm[j].fix(instance.tasks[j].t_start)

    if options.cover_cuts:
        model.cover = pyo.ConstraintList()
        for j in chosen:
            members = [n for n, net in enumerate(networks) if j in net.earliest
                       and (n, j) not in late]
            upper = {n: upper_amount(n, j) for n in members}
            for rest, coef in coalition_cover_cuts(upper, instance.tasks[j].demand):
                model.cover.add(model.covered[j] <= rest + sum(
                    c * model.y[n, j] for n, c in coef.items()))

    # --- committed prefixes: their arcs and amounts are fixed -----------------------------
    for n, prefix in enumerate(prefixes):
        for i, j, mode, amount in prefix.steps:
            model.x[n, i, j, mode].fix(1)
            model.a[n, j].fix(amount)
        if prefix.trailing_depot is not None:
            for key in arcs_out[n, prefix.last]:
                if key[3] != prefix.trailing_depot:
                    model.x[key].fix(0)

    # --- symmetry: identical AAVs ordered by their smallest task index --------------------
    if options.symmetry:
        sym = []
        for group in identical_groups(instance, committed):
            sym += list(itertools.pairwise(group))
        rows = [(n, n2, j) for n, n2 in sym for j in networks[n2].tasks]
        model.symmetry = pyo.Constraint(rows, rule=lambda m, n, n2, j: m.y[n2, j] <= sum(
            m.y[n, i] for i in networks[n].tasks if i <= j))

    # --- objective (Eqs. 1, 4-6, 8, 9) ----------------------------------------------------
    def task_cost(m: Any, j: int) -> Any:
        task = instance.tasks[j]
        load = 1 - m.covered[j] / task.demand
        tardiness = 1 - m.u[j] + (m.Tm[j] - task.t_start) / horizon
        op = sum(op_cost[n, j] for n, net in enumerate(networks) if j in net.earliest)
        return w1 * load + w2 * tardiness + w3 * op

    model.J = pyo.Objective(expr=data.constant + sum(task_cost(model, j) for j in chosen),
                            sense=pyo.minimize)
    return model


def _add_time_flow(model: Any, data: MilpData, arc_of: dict, arcs_in: dict,
                   arcs_out: dict) -> None:
    """Arrival times carried on the arcs: r_a is the arrival at a's head when a is flown, 0
    otherwise, so Z_nj = sum of r over the arcs into j is t_nj * y_nj. The big-M time rows
    let a fractional arc leave t_nj at its lower bound; here every fraction of flow carries
    its own arrival, which is what the coalition's C_time then pays for
    (T_j - t_start >= Z_nj - t_start * y_nj). Valid: at an integer point set each r to the
    arrival of its head; leaving i along b arrives no earlier than t_i + travel_b, and a route
    that ends at i has no outgoing r (the end term absorbs Z_ni <= t_end(i))."""
    import pyomo.environ as pyo

    instance = data.instance
    networks = data.networks

    def lowest(key: tuple) -> float:
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


def _task_latest(data: MilpData, j: int) -> float:
    return max([data.instance.tasks[j].t_end]
               + [net.latest[j] for net in data.networks if j in net.latest])


# --- decoding and warm starts --------------------------------------------------------------
def decode(model: Any) -> tuple[Route, ...]:
    """The routes of the model's current (integer) solution."""
    from pyomo.environ import value

    data: MilpData = model.data
    instance = data.instance
    routes = []
    for n, net in enumerate(data.networks):
        by_tail = {}
        for a in net.arcs:
            if value(model.x[n, a.tail, a.head, a.mode]) > 0.5:
                by_tail[a.tail] = a
        route: list[Visit] = []
        node, seen = START, set()
        while node in by_tail:
            arc = by_tail[node]
            if arc.head in seen:
                raise RuntimeError(f"AAV {n}: the solution's arcs form a cycle")
            seen.add(arc.head)
            if arc.mode != DIRECT:
                route.append(Visit(arc.mode))
            route.append(Visit(arc.head, round(value(model.a[n, arc.head]))))
            node = arc.head
        trailing = data.prefixes[n].trailing_depot
        if trailing is not None and node == data.prefixes[n].last:
            route.append(Visit(trailing))
        elif route:
            route.append(Visit(instance.nearest_depot(node)))
        # The arcs give the prefix's nodes and amounts; the prefix itself has its stamps.
        prefix = data.committed[n] if data.committed else ()
        assert [v[:2] for v in route[:len(prefix)]] == [v[:2] for v in prefix]
        routes.append((*prefix, *route[len(prefix):]))
    return tuple(routes)


def warm_start(model: Any, routes: Sequence[Route]) -> None:
    """Set every variable to the point of ``routes`` (which must be canonical, see
    ``canonical_routes``, and ordered for the symmetry constraints: ``order_identical``).
    Raises KeyError if a route uses an arc the model does not have."""
    data: MilpData = model.data
    instance = data.instance
    evaluator = CostEvaluator(instance, data.plan_time, [len(p) for p in data.committed]
                              if data.committed else None)
    for var in model.component_data_objects(ctype=_var_type()):
        if not var.fixed:
            var.set_value(max(0.0, var.lb if var.lb is not None else 0.0))
    for j in data.tasks:
        if not model.u[j].fixed:
            model.u[j].set_value(0)
        if not model.Tm[j].fixed:
            model.Tm[j].set_value(instance.tasks[j].t_start)
    for n, net in enumerate(data.networks):
        for j in net.tasks:
            model.t[n, j].set_value(net.earliest[j])
            if n in data.range_aavs:
                model.dc[n, j].set_value(net.min_distance[j])
        route = routes[n]
        if not route:
            model.end[n, START].set_value(1)
            continue
        trace = evaluator.trace(n, route)
        tail, mode, last = START, DIRECT, START
        for k, v in enumerate(route):
            if instance.is_depot(v.node):
                mode = v.node
                continue
            j = v.node
            key = (n, tail, j, mode)
            if key not in model.x:
                raise KeyError(f"AAV {n}: arc {key[1:]} is not in the model")
            model.x[key].set_value(1)
            if hasattr(model, "r"):
                model.r[key].set_value(trace.arrivals[k])
            model.y[n, j].set_value(1)
            model.a[n, j].set_value(v.amount)
            model.t[n, j].set_value(trace.arrivals[k])
            model.dl[n, j].set_value(trace.delivery_load[k])
            model.pl[n, j].set_value(trace.pickup_load[k])
            if n in data.range_aavs:
                model.dc[n, j].set_value(trace.distance_at_arrival[k])
            if data.over_range.get((n, j)) is None and (n, j) in model.o:
                over = trace.distance_at_arrival[k] > instance.aavs[n].max_range
                model.o[n, j].set_value(int(over))
                model.q[n, j].set_value(trace.op_costs[k])
            if not model.u[j].fixed:
                model.u[j].set_value(1)
                model.Tm[j].set_value(max(model.Tm[j].value, trace.arrivals[k]))
            if hasattr(model, "rank"):
                model.rank[n, j].set_value(sum(1 for w in route[:k]
                                               if not instance.is_depot(w.node)))
            tail, mode, last = j, DIRECT, j
        model.end[n, last].set_value(1)
    for j in data.tasks:
        on_time = sum(model.a[n, j].value for n, net in enumerate(data.networks)
                      if j in net.earliest and (n, j) not in data.late)
        model.covered[j].set_value(min(on_time, instance.tasks[j].demand))


def _var_type() -> Any:
    from pyomo.environ import Var

    return Var


def order_identical(instance: Instance, routes: Sequence[Route],
                    committed: Sequence[Route] | None = None) -> tuple[Route, ...]:
    """Permute the routes of identical AAVs so that the symmetry constraints hold."""
    routes = list(routes)
    for group in identical_groups(instance, committed or ()):
        ordered = sorted((routes[n] for n in group), key=lambda r: first_task(r, instance))
        for n, r in zip(group, ordered, strict=True):
            routes[n] = r
    return tuple(routes)


def violated_constraints(model: Any, tolerance: float = 1e-6) -> list[str]:
    """Names of the constraints (and bounds) the model's current values break."""
    from pyomo.environ import Constraint, Var, value

    broken = []
    for c in model.component_data_objects(Constraint, active=True):
        body = value(c.body)
        if c.has_lb() and body < value(c.lower) - tolerance:
            broken.append(f"{c.name}: {body} < {value(c.lower)}")
        if c.has_ub() and body > value(c.upper) + tolerance:
            broken.append(f"{c.name}: {body} > {value(c.upper)}")
    for var in model.component_data_objects(Var):
        if var.value is None:
            continue
        if (var.lb is not None and var.value < var.lb - tolerance) or (
                var.ub is not None and var.value > var.ub + tolerance):
            broken.append(f"{var.name}: {var.value} outside [{var.lb}, {var.ub}]")
    return broken


# --- solving ------------------------------------------------------------------------------
@dataclass(frozen=True)
class SolveReport:
    """What a backend run says about itself (MODEL.md's status vocabulary)."""

    status: str  # optimal | feasible | no-solution | error
    objective: float | None
    lower_bound: float | None
    mip_gap: float | None
    solver: str
    solver_version: str
    threads: int
    seed: int
    wall_time: float
    stop_reason: str
    has_solution: bool

    def as_stats(self) -> dict[str, Any]:
        return {k: getattr(self, k) for k in (
            "status", "objective", "lower_bound", "mip_gap", "solver", "solver_version",
            "threads", "seed", "wall_time", "stop_reason")}


def relative_gap(objective: float | None, bound: float | None) -> float | None:
    if objective is None or bound is None:
        return None
    return max(0.0, objective - bound) / max(abs(objective), 1e-10)


def solve_milp(model: Any, *, time_limit: float | None = None, threads: int = 1,
               mip_rel_gap: float = 1e-9, seed: int = 0, warm: bool = False,
               log: bool = False) -> SolveReport:
    """Solve with HiGHS (through Pyomo's appsi interface) and load the best solution found
    into the model. ``warm`` passes the variables' current values as a MIP start.

    HiGHS's default relative gap (1e-4) would stop short of the optimum: ``mip_rel_gap``
    defaults to 1e-9 (with a tiny absolute gap). HiGHS runs its tree search on several
    threads only with ``parallel=on``, which is set when ``threads > 1``."""
    import highspy
    from pyomo.contrib.appsi.base import TerminationCondition
    from pyomo.contrib.appsi.solvers import Highs

    opt = Highs()
    opt.config.load_solution = False
    opt.config.stream_solver = log
    opt.config.mip_gap = mip_rel_gap
    opt.config.warmstart = warm
    if time_limit is not None:
        opt.config.time_limit = max(0.01, float(time_limit))
    opt.highs_options = {
        "threads": int(threads),
        "parallel": "on" if threads > 1 else "off",
        "random_seed": int(seed),
        "mip_abs_gap": 1e-9,
        "output_flag": bool(log),
    }
    version = ".".join(str(p) for p in opt.version())
    began = time.perf_counter()
    try:
        highspy.Highs.resetGlobalScheduler(True)
        results = opt.solve(model)
    except Exception as exc:
        return SolveReport("error", None, None, None, "highs", version, threads, seed,
                           time.perf_counter() - began, f"{type(exc).__name__}: {exc}", False)
    wall = time.perf_counter() - began
    condition = results.termination_condition
    has_solution = results.best_feasible_objective is not None
    if has_solution:
        results.solution_loader.load_vars()
    objective = results.best_feasible_objective
    bound = results.best_objective_bound
    if condition == TerminationCondition.optimal:
        status = "optimal"
        bound = objective if bound is None else bound
    elif condition == TerminationCondition.infeasible:
        status = "error"  # the empty plan is always feasible: infeasible means a bug
    elif has_solution:
        status = "feasible"
    else:
        status = "no-solution"
    if bound is not None and not math.isfinite(bound):
        bound = None
    return SolveReport(status, objective, bound, relative_gap(objective, bound), "highs",
                       version, threads, seed, wall, condition.name, has_solution)


def canonical_warm_start(model: Any, routes: Sequence[Route],
                         committed: Sequence[Route] | None = None) -> tuple[Route, ...]:
    """Load ``routes`` (any feasible plan respecting the prefixes) as the MIP start; returns
    the canonical routes that were loaded."""
    data: MilpData = model.data
    instance = data.instance
    free = [len(p) for p in committed] if committed else None
    routes = canonical_routes(instance, routes, free, data.plan_time)
    allowed = set(data.tasks)
    # A plan that visits tasks outside the model cannot be a start: drop those visits.
    routes = tuple(tuple(v for v in r if instance.is_depot(v.node) or v.node in allowed)
                   for r in routes)
    routes = canonical_routes(instance, routes, free, data.plan_time)
    routes = order_identical(instance, routes, committed)
    warm_start(model, routes)
    return routes
