"""The exact MILP of Problem 1 (docs/model.md) in Pyomo, solved by HiGHS.

``build_milp`` returns a ``pyomo.ConcreteModel`` (nothing is solved there); ``solve_milp``
runs HiGHS on it; ``decode`` reads the routes back; ``warm_start`` loads a solution into the
variables (a MIP start, and the tests' check that every canonical solution is a point of the
model with objective J). docs/formulations.md states every constraint and big-M.

The model searches canonical solutions (formulations/network.py): per AAV a path from its
start through task visits, each arc direct or through one depot, closed by an uncharged
final depot visit. Its objective equals J of the decoded solution exactly: C_load, C_time and
C_op are linear in the variables at every integer point. ``build_milp`` only composes the
blocks of formulations/milp_blocks.py, one per constraint family.
"""

from __future__ import annotations

import math
import time
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

from tsac_bench.formulations import milp_blocks as blocks
from tsac_bench.formulations.milp_blocks import MilpData
from tsac_bench.formulations.network import (
    DIRECT,
    START,
    aav_network,
    canonical_routes,
    first_task,
    identical_groups,
    late_committed,
    parse_prefix,
    prefix_arrivals,
)
from tsac_bench.model import Instance, Route, Visit
from tsac_bench.model.evaluator import CostEvaluator
from tsac_bench.planning import mip_gap


@dataclass
class MilpOptions:
    """Which strengthening the builder adds (each is exact; see docs/formulations.md)."""

    symmetry: bool = True  # order identical AAVs by their smallest task index
    capacity_cuts: bool = True  # sum of amounts <= B * number of trips
    range_time_link: bool = True  # Dcum <= v * t (no AAV flies faster than its speed)
    time_flow: bool = True  # arrival times carried on the arcs (a stronger LP than big-M)
    cover_cuts: bool = True  # a large task needs particular AAVs in full


def build_milp(instance: Instance, tasks: Sequence[int] | None = None,
               committed: Sequence[Route] | None = None,
               options: MilpOptions | None = None, plan_time: float = 0.0) -> Any:
    """The MILP over ``tasks`` (default all; others stay unserved) with every AAV's route
    starting with its ``committed`` prefix and its free visits planned at ``plan_time`` (it
    leaves its anchor no earlier). Returns the model; ``model.data`` is a MilpData."""
    import pyomo.environ as pyo

    options = options or MilpOptions()
    data = milp_data(instance, tasks, committed, plan_time)
    index = blocks.MilpIndex.of(data)
    model = pyo.ConcreteModel(name=f"tsac-milp[{instance.name}]")
    model.data = data
    blocks.add_variables(model, data, index)
    blocks.add_flow_conservation(model, data, index)
    blocks.add_amounts(model, data, index)
    blocks.add_time_windows(model, data, index)
    if options.time_flow:
        blocks.add_time_flow(model, data, index)
    blocks.add_loads(model, data, index)
    if options.capacity_cuts:
        blocks.add_capacity_cuts(model, data, index)
    op_cost = blocks.add_range(model, data, index, options.range_time_link)
    blocks.add_coalition_time(model, data, index)
    if options.cover_cuts:
        blocks.add_cover_cuts(model, data, index)
    blocks.fix_prefixes(model, data, index)
    if options.symmetry:
        blocks.add_symmetry(model, data)
    blocks.add_objective(model, data, op_cost)
    return model


def milp_data(instance: Instance, tasks: Sequence[int] | None,
              committed: Sequence[Route] | None, plan_time: float) -> MilpData:
    """The tasks of the model (``tasks`` and every committed one), the prefixes and each
    AAV's network: the arcs that time windows, reachability and depot dominance leave."""
    from tsac_bench.planning import PlanningState

    committed = tuple(committed) if committed else tuple(() for _ in range(instance.n_aavs))
    moment = PlanningState(instance, plan_time, frozenset(), committed)
    prefixes = [parse_prefix(instance, p) for p in committed]
    in_prefix = {m for p in prefixes for _, m, _, _ in p.steps}
    chosen = sorted(set(range(instance.n_tasks) if tasks is None else tasks) | in_prefix)
    networks = []
    for n, prefix in enumerate(prefixes):
        required = [(i, j, k) for i, j, k, _ in prefix.steps]
        trailing = None if prefix.trailing_depot is None else (prefix.last,
                                                                 prefix.trailing_depot)
        # Every AAV may join any chosen task, also one another AAV's prefix has committed to:
        # a partly served task's coalition can still grow.
        networks.append(aav_network(instance, n, chosen, prefix_arrivals(
            instance, n, committed[n]), required, trailing, prefix.last,
            moment.anchor(n).time))
    return MilpData(instance, chosen, networks, prefixes, late_committed(instance, committed),
                    constant=instance.unserved_task_cost * (instance.n_tasks - len(chosen)),
                    committed=committed, plan_time=plan_time)


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
    """What a backend run says about itself (its status as docs/plugins.md, "What
    `PlanResult` carries", defines them)."""

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
    gap = None if objective is None or bound is None else mip_gap(objective, bound)
    return SolveReport(status, objective, bound, gap, "highs", version, threads, seed, wall,
                       condition.name, has_solution)


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
