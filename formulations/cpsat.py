"""An independent exact model of Problem 1 in OR-Tools CP-SAT (integer-scaled).

Per AAV one ``AddCircuit`` over node 0 (its start, which is also where the route "ends":
the closing depot visit is free) and one node per task; a task's self-loop means "not
visited". Each arc into a task is flown directly or through one depot (one Boolean per mode,
their sum is the arc). Times, distances and loads propagate along the chosen mode with
equalities where the model fixes them (distances, loads) and ``>=`` for times (waiting).

Integer scaling (explicit; ``Scale``):
* time in ticks of 1/``time_scale`` s, each travel time rounded UP, windows rounded inward
  (t_start up, t_end down): every solution of the scaled model is feasible and on time in
  the real model; a real solution is lost only if it is on time by less than a tick per leg;
* distances in 1/``distance_scale`` m, each leg rounded up (Dcum, Eq. 9's range test);
* the objective in units of 1/``objective_scale`` of J, with objective_scale = round(horizon
  * time_scale) * 1000 so that the C_time term is exact in ticks; every other coefficient
  is rounded to the nearest unit (error < 1e-9 J per term).
The routes are decoded and their J recomputed by the evaluator (the only J reported). The
bound CP-SAT proves is for the scaled model; ``lower_bound`` subtracts the largest amount by
which scaling can raise a plan's cost (see ``Scale.slack``).

CP-SAT is deterministic only with one worker and no time limit (with a time limit the point
where the search stops depends on the machine's speed).

``build_cpsat`` only composes the blocks below, one per constraint family (each ``add_*``
names the family and the equation of docs/model.md it states).
"""

from __future__ import annotations

import math
import time
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

from tsac_bench.model import Instance, Route, Visit
from tsac_bench.model.evaluator import CostEvaluator
from tsac_bench.planning import mip_gap


@dataclass(frozen=True)
class Scale:
    # Ticks per second: 1 ms, so that rounding each leg up loses at most 1 ms per leg.
    time_scale: int = 1000
    # Units per metre: 1 mm, so that rounding each leg up moves Dcum by at most 1 mm.
    distance_scale: int = 1000

    def objective_scale(self, instance: Instance) -> int:
        return max(1, round(instance.horizon * self.time_scale)) * 1000

    def slack(self, instance: Instance) -> float:
        """Most by which rounding can raise a plan's scaled cost above its J: every arrival
        is at most one tick late per leg before it (C_time) and each objective coefficient
        is off by half a unit."""
        legs = 2 * instance.n_tasks + 1
        per_task = instance.weights[1] * legs / (instance.horizon * self.time_scale)
        units = 2 * instance.n_tasks * (instance.n_aavs + 2) + instance.n_aavs * 4 * (
            instance.n_tasks + 1) ** 2
        return instance.n_tasks * per_task + units * 0.5 / self.objective_scale(instance)


@dataclass
class CpsatData:
    instance: Instance
    tasks: list[int]
    scale: Scale
    objective_scale: int
    constant: float  # J of the tasks outside the model, plus the objective's constant
    # (n, tail, head, mode) -> literal; tail/head are task nodes or -1 (the start/end).
    modes: dict[tuple[int, int, int, int], Any] = field(default_factory=dict)
    ends: dict[tuple[int, int], Any] = field(default_factory=dict)
    amount: dict[tuple[int, int], Any] = field(default_factory=dict)
    visit: dict[tuple[int, int], Any] = field(default_factory=dict)
    arrival: dict[tuple[int, int], Any] = field(default_factory=dict)


START = -1
DIRECT = -1


@dataclass
class AavVars:
    """One AAV's part of the model, shared by its blocks (keys: task nodes)."""

    n: int
    track_range: bool  # Dcum is modelled: the AAV could pass its range before a window closes
    arrival: dict[int, Any] = field(default_factory=dict)  # t, in ticks
    delivery: dict[int, Any] = field(default_factory=dict)  # dl: delivery goods after the visit
    pickup: dict[int, Any] = field(default_factory=dict)  # pl: pickup goods after the visit
    distance: dict[int, Any] = field(default_factory=dict)  # Dcum on arrival, scaled
    circuit: list[tuple[int, int, Any]] = field(default_factory=list)  # AddCircuit's arcs
    # Per task: (mode literal, its leg's operating cost in objective units).
    legs_into: dict[int, list[tuple[Any, int]]] = field(default_factory=dict)


def build_cpsat(instance: Instance, tasks: Sequence[int] | None = None,
                scale: Scale | None = None) -> tuple[Any, CpsatData]:
    """The CP-SAT model over ``tasks`` (default all; the others stay unserved), composed of
    one block per constraint family; they add their variables and constraints in a fixed
    order, the order of the model CP-SAT is given."""
    from ortools.sat.python import cp_model

    scale = scale or Scale()
    chosen = sorted(set(range(instance.n_tasks) if tasks is None else tasks))
    model = cp_model.CpModel()
    data = CpsatData(instance, chosen, scale, scale.objective_scale(instance),
                     instance.unserved_task_cost * (instance.n_tasks - len(chosen)))
    opens = {j: _ticks_up(instance.tasks[j].t_start, scale) for j in chosen}
    closes = {j: math.floor(instance.tasks[j].t_end * scale.time_scale + 1e-9) for j in chosen}
    objective: list[Any] = []
    for n, aav in enumerate(instance.aavs):
        track = any(aav.speed * instance.tasks[j].t_end > aav.max_range for j in chosen)
        aav_vars = AavVars(n, track)
        add_visits(model, data, aav_vars, opens, closes)
        add_arcs(model, data, aav_vars)
        model.AddCircuit(aav_vars.circuit)
        add_operating_cost(model, data, aav_vars, objective)
    constant_units = add_coalitions(model, data, opens, closes, objective)
    model.Minimize(sum(objective) + constant_units)
    return model, data


def add_visits(model: Any, data: CpsatData, aav_vars: AavVars, opens: dict[int, int],
               closes: dict[int, int]) -> None:
    """The visits of one AAV: amounts (Eqs. 2-3: 1..min(B, R) kg when visited), arrivals
    in the window (Eq. 7; late visits are excluded), the goods on board after each visit
    (Eq. 10: dl + pl <= B, dl + delivered <= B, a trip ends with no delivery goods left),
    Dcum where tracked, and the circuit's arcs that skip a task (its self-loop), close the
    route after it, or leave the AAV unused (node 0's self-loop)."""
    instance, n = data.instance, aav_vars.n
    aav = instance.aavs[n]
    cap = aav.capacity
    index = _circuit_nodes(data.tasks)
    for j in data.tasks:
        task = instance.tasks[j]
        visit = model.NewBoolVar(f"v{n}_{j}")
        a = model.NewIntVar(0, min(cap, task.demand), f"a{n}_{j}")
        model.Add(a >= 1).OnlyEnforceIf(visit)
        model.Add(a == 0).OnlyEnforceIf(visit.Not())
        t = model.NewIntVar(opens[j], max(opens[j], closes[j]), f"t{n}_{j}")
        if opens[j] > closes[j]:
            model.Add(visit == 0)
        dl = model.NewIntVar(0, cap, f"dl{n}_{j}")
        pl = model.NewIntVar(0, cap, f"pl{n}_{j}")
        model.Add(dl + pl <= cap)
        model.Add(dl + (a if task.is_delivery else 0) <= cap)
        model.Add(dl == 0).OnlyEnforceIf(visit.Not())
        model.Add(pl == 0).OnlyEnforceIf(visit.Not())
        if aav_vars.track_range:
            # v * t_end bounds Dcum; each leg rounded up adds at most one unit.
            aav_vars.distance[j] = model.NewIntVar(0, math.ceil(
                aav.speed * task.t_end * data.scale.distance_scale) + 2 * len(data.tasks) + 2,
                f"dc{n}_{j}")
        data.visit[n, j], data.amount[n, j], data.arrival[n, j] = visit, a, t
        aav_vars.arrival[j], aav_vars.delivery[j], aav_vars.pickup[j] = t, dl, pl
        aav_vars.circuit.append((index[j], index[j], visit.Not()))
        end = model.NewBoolVar(f"end{n}_{j}")
        aav_vars.circuit.append((index[j], 0, end))
        model.Add(dl == 0).OnlyEnforceIf(end)
        data.ends[n, j] = end
    unused = model.NewBoolVar(f"unused{n}")
    aav_vars.circuit.append((0, 0, unused))
    data.ends[n, START] = unused


def add_arcs(model: Any, data: CpsatData, aav_vars: AavVars) -> None:
    """The arcs of one AAV (the route structure, Eq. 11): arc i -> j is flown directly or
    through one depot (one literal per mode, their sum is the arc; no direct arc from the
    start to a delivery, which would carry no goods); each mode states its leg."""
    instance, n = data.instance, aav_vars.n
    dist = instance.dist_rows
    start = instance.start_node(n)
    index = _circuit_nodes(data.tasks)
    aav_vars.legs_into = {j: [] for j in data.tasks}
    for i in [START, *data.tasks]:
        p = start if i == START else i
        for j in data.tasks:
            if i == j:
                continue
            options = [(k, dist[p][k] + dist[k][j], dist[k][j]) for k in instance.depot_nodes]
            if not (i == START and instance.tasks[j].is_delivery):
                options.insert(0, (DIRECT, dist[p][j], dist[p][j]))
            arc = model.NewBoolVar(f"x{n}_{i}_{j}")
            aav_vars.circuit.append((0 if i == START else index[i], index[j], arc))
            lits = [add_leg(model, data, aav_vars, i, j, *option) for option in options]
            model.Add(sum(lits) == arc)


def add_leg(model: Any, data: CpsatData, aav_vars: AavVars, i: int, j: int, mode: int,
            flown: float, leg: float) -> Any:
    """One mode of arc i -> j, under its literal: time (Eq. 7, t_j >= t_i + travel in ticks
    rounded up: waiting allowed), Dcum (Eq. 9's distance, rounded up) and the load chain
    (Eq. 10: direct, the delivery goods before j cover j's and the pickup goods grow; through
    a depot, nothing is left to deliver before it and j's pickup starts the goods). Returns
    the literal; its leg's operating cost goes to ``legs_into``."""
    instance, n = data.instance, aav_vars.n
    aav = instance.aavs[n]
    task = instance.tasks[j]
    delivered = data.amount[n, j] if task.is_delivery else 0
    picked = 0 if task.is_delivery else data.amount[n, j]
    lit = model.NewBoolVar(f"m{n}_{i}_{j}_{mode}")
    data.modes[n, i, j, mode] = lit
    t, dl, pl, dc = aav_vars.arrival, aav_vars.delivery, aav_vars.pickup, aav_vars.distance
    travel = _ticks_up(flown / aav.speed, data.scale)
    if i == START:
        model.Add(t[j] >= travel).OnlyEnforceIf(lit)
    else:
        model.Add(t[j] >= t[i] + travel).OnlyEnforceIf(lit)
    if aav_vars.track_range:
        before = 0 if i == START else dc[i]
        model.Add(dc[j] == before + math.ceil(flown * data.scale.distance_scale - 1e-9)) \
            .OnlyEnforceIf(lit)
    before_d = 0 if i == START else dl[i]
    before_p = 0 if i == START else pl[i]
    if mode == DIRECT:
        model.Add(before_d == dl[j] + delivered).OnlyEnforceIf(lit)
        model.Add(pl[j] == before_p + picked).OnlyEnforceIf(lit)
    else:
        model.Add(before_d == 0).OnlyEnforceIf(lit)
        model.Add(pl[j] == picked).OnlyEnforceIf(lit)
    per_metre = instance.weights[2] * aav.alpha / 1000.0 / instance.e_base \
        * data.objective_scale
    aav_vars.legs_into[j].append((lit, round(per_metre * leg)))
    return lit


def add_operating_cost(model: Any, data: CpsatData, aav_vars: AavVars,
                       objective: list[Any]) -> None:
    """C_op of one AAV (Eq. 9) into ``objective``: each visit's leg cost, or where Dcum is
    tracked q_j, with o_j <=> Dcum_j > D: the full-range cost if o_j, the leg cost of the
    mode flown otherwise."""
    instance, n = data.instance, aav_vars.n
    aav = instance.aavs[n]
    if not aav_vars.track_range:
        for j in data.tasks:
            objective.extend(cost * lit for lit, cost in aav_vars.legs_into[j])
        return
    range_units = math.floor(aav.max_range * data.scale.distance_scale + 1e-9)
    full_units = round(instance.weights[2] * aav.full_range_cost / instance.e_base
                       * data.objective_scale)
    for j in data.tasks:
        visit, dc, legs = data.visit[n, j], aav_vars.distance[j], aav_vars.legs_into[j]
        q = model.NewIntVar(0, max([full_units] + [cost for _, cost in legs]), f"q{n}_{j}")
        over = model.NewBoolVar(f"o{n}_{j}")
        model.Add(dc >= range_units + 1).OnlyEnforceIf([over, visit])
        model.Add(dc <= range_units).OnlyEnforceIf(over.Not())
        model.Add(over == 0).OnlyEnforceIf(visit.Not())
        model.Add(q == full_units).OnlyEnforceIf(over)
        for lit, cost in legs:
            model.Add(q == cost).OnlyEnforceIf([lit, over.Not()])
        model.Add(q == 0).OnlyEnforceIf(visit.Not())
        objective.append(q)


def add_coalitions(model: Any, data: CpsatData, opens: dict[int, int],
                   closes: dict[int, int], objective: list[Any]) -> int:
    """The coalition of each task: its amounts within the demand (canonical point 4), C_load
    (Eq. 5) and C_time (Eq. 6: served = OR of the visits, T >= every visitor's arrival,
    T = t_start if nobody comes) into ``objective``. Returns the objective's constant
    (units)."""
    instance = data.instance
    w1, w2, _ = instance.weights
    obj_scale = data.objective_scale
    constant_units = 0
    for j in data.tasks:
        task = instance.tasks[j]
        visits = [data.visit[n, j] for n in range(instance.n_aavs)]
        amounts = [data.amount[n, j] for n in range(instance.n_aavs)]
        model.Add(sum(amounts) <= task.demand)
        served = model.NewBoolVar(f"served{j}")
        model.AddBoolOr(visits).OnlyEnforceIf(served)
        for v in visits:
            model.AddImplication(v, served)
        latest = model.NewIntVar(opens[j], max(opens[j], closes[j]), f"T{j}")
        for n in range(instance.n_aavs):
            model.Add(latest >= data.arrival[n, j]).OnlyEnforceIf(data.visit[n, j])
        model.Add(latest == opens[j]).OnlyEnforceIf(served.Not())
        # w1 (1 - sum a / R) + w2 (1 - served + (T - t_start) / H), in objective units.
        per_kg = round(w1 * obj_scale / task.demand)
        objective.extend(-per_kg * a for a in amounts)
        per_tick = round(w2 * obj_scale / (instance.horizon * data.scale.time_scale))
        objective.append(per_tick * latest)
        objective.append(-round(w2 * obj_scale) * served)
        constant_units += round((w1 + w2) * obj_scale) - round(
            per_tick * task.t_start * data.scale.time_scale)
    return constant_units


def _ticks_up(seconds: float, scale: Scale) -> int:
    return math.ceil(seconds * scale.time_scale - 1e-9)


def _circuit_nodes(tasks: list[int]) -> dict[int, int]:
    """The circuit node of each task (node 0 is the AAV's start and end)."""
    return {j: i + 1 for i, j in enumerate(tasks)}


def hint(model: Any, data: CpsatData, routes: Sequence[Route]) -> None:
    """Hint a plan (canonical: no late visits, one depot at most between tasks)."""
    instance = data.instance
    model.ClearHints()
    chosen = set(data.tasks)
    for n, route in enumerate(routes):
        tail, mode = START, DIRECT
        used = set()
        for v in route:
            if instance.is_depot(v.node):
                mode = v.node
                continue
            if v.node not in chosen:
                continue
            key = (n, tail, v.node, mode)
            if key in data.modes:
                used.add(key)
                model.AddHint(data.amount[n, v.node], v.amount)
            tail, mode = v.node, DIRECT
        for key, lit in data.modes.items():
            if key[0] == n:
                model.AddHint(lit, int(key in used))


def decode(solver: Any, data: CpsatData) -> tuple[Route, ...]:
    instance = data.instance
    routes = []
    for n in range(instance.n_aavs):
        by_tail = {}
        for (m, i, j, mode), lit in data.modes.items():
            if m == n and solver.BooleanValue(lit):
                by_tail[i] = (j, mode)
        route: list[Visit] = []
        node = START
        while node in by_tail:
            j, mode = by_tail[node]
            if mode != DIRECT:
                route.append(Visit(mode))
            route.append(Visit(j, int(solver.Value(data.amount[n, j]))))
            node = j
        if route:
            route.append(Visit(instance.nearest_depot(node)))
        routes.append(tuple(route))
    return tuple(routes)


@dataclass(frozen=True)
class CpsatOutcome:
    routes: tuple[Route, ...] | None
    stats: dict[str, Any]


def solve_cpsat(instance: Instance, tasks: Sequence[int] | None = None, *,
                time_limit: float | None = None, threads: int = 1, seed: int = 0,
                hint_routes: Sequence[Route] | None = None, rel_gap: float = 0.0,
                scale: Scale | None = None, log: bool = False) -> CpsatOutcome:
    """Build, solve and decode; stats follow the MILP backend's vocabulary."""
    import ortools
    from ortools.sat.python import cp_model

    began = time.perf_counter()
    model, data = build_cpsat(instance, tasks, scale)
    if hint_routes is not None:
        hint(model, data, hint_routes)
    solver = cp_model.CpSolver()
    solver.parameters.num_workers = int(threads)
    solver.parameters.random_seed = int(seed)
    solver.parameters.relative_gap_limit = float(rel_gap)
    solver.parameters.log_search_progress = log
    if time_limit is not None:
        solver.parameters.max_time_in_seconds = float(time_limit)
    code = solver.Solve(model)
    wall = time.perf_counter() - began
    name = solver.StatusName(code)
    scale_units = data.objective_scale
    has_solution = code in (cp_model.OPTIMAL, cp_model.FEASIBLE)
    routes = decode(solver, data) if has_solution else None
    objective = J = bound = None
    if has_solution:
        objective = data.constant + solver.ObjectiveValue() / scale_units
        J = CostEvaluator(instance).cost(routes)
    if code in (cp_model.OPTIMAL, cp_model.FEASIBLE):
        bound = data.constant + solver.BestObjectiveBound() / scale_units \
            - data.scale.slack(instance)
    status = {cp_model.OPTIMAL: "optimal", cp_model.FEASIBLE: "feasible",
              cp_model.UNKNOWN: "no-solution"}.get(code, "error")
    gap = None if J is None or bound is None else mip_gap(J, bound)
    stats = {
        "status": status, "objective": J, "scaled_objective": objective,
        "lower_bound": bound, "mip_gap": gap, "solver": "cp-sat",
        "solver_version": ortools.__version__, "threads": int(threads), "seed": int(seed),
        "wall_time": wall, "stop_reason": name,
        "deterministic": threads == 1 and time_limit is None,
        "time_scale": data.scale.time_scale, "distance_scale": data.scale.distance_scale,
        "objective_scale": scale_units,
    }
    return CpsatOutcome(routes, stats)


# --- process isolation -----------------------------------------------------------------------
# The ortools and highspy wheels each bundle their own libhighs.so.1 (same soname, different
# versions): whichever of the two a process imports second fails to load. CP-SAT therefore
# always runs in a spawned worker process that never imports highspy, so that `exact` and
# `exact-cpsat` can be used in one process in any order.
_POOL: Any = None


def _worker_solve(instance_data: dict, tasks: list[int] | None, kwargs: dict) -> CpsatOutcome:
    from tsac_bench.model.io import instance_from_dict

    return solve_cpsat(instance_from_dict(instance_data), tasks, **kwargs)


def solve_cpsat_isolated(instance: Instance, tasks: Sequence[int] | None = None,
                         **kwargs: Any) -> CpsatOutcome:
    """``solve_cpsat`` in the CP-SAT worker process (started on first use, then reused)."""
    import multiprocessing
    import multiprocessing.util
    from concurrent.futures import ProcessPoolExecutor

    from tsac_bench.model.io import instance_to_dict

    global _POOL
    if _POOL is None:
        _POOL = ProcessPoolExecutor(max_workers=1,
                                    mp_context=multiprocessing.get_context("spawn"))
        # A finalizer, not atexit: it also runs when this process is itself a
        # multiprocessing worker (which skips atexit), and before multiprocessing joins its
        # children at exit; otherwise the idle CP-SAT worker is joined forever.
        multiprocessing.util.Finalize(None, _POOL.shutdown, exitpriority=100)
    future = _POOL.submit(_worker_solve, instance_to_dict(instance),
                          None if tasks is None else list(tasks), kwargs)
    return future.result()
