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
"""

from __future__ import annotations

import math
import time
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

from tsac_bench.model import Instance, Route, Visit
from tsac_bench.model.evaluator import CostEvaluator


@dataclass(frozen=True)
class Scale:
    time_scale: int = 1000  # ticks per second
    distance_scale: int = 1000  # units per metre

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


def build_cpsat(instance: Instance, tasks: Sequence[int] | None = None,
                scale: Scale | None = None) -> tuple[Any, CpsatData]:
    """The CP-SAT model over ``tasks`` (default all; the others stay unserved)."""
    from ortools.sat.python import cp_model

    scale = scale or Scale()
    S, Sd = scale.time_scale, scale.distance_scale
    obj_scale = scale.objective_scale(instance)
    w1, w2, w3 = instance.weights
    horizon = instance.horizon
    chosen = sorted(set(range(instance.n_tasks) if tasks is None else tasks))
    dist = instance.dist_rows
    depots = list(instance.depot_nodes)
    model = cp_model.CpModel()
    data = CpsatData(instance, chosen, scale, obj_scale,
                     instance.unserved_task_cost * (instance.n_tasks - len(chosen)))
    objective: list[Any] = []
    constant_units = 0

    def ticks_up(seconds: float) -> int:
        return math.ceil(seconds * S - 1e-9)

    opens = {j: ticks_up(instance.tasks[j].t_start) for j in chosen}
    closes = {j: math.floor(instance.tasks[j].t_end * S + 1e-9) for j in chosen}

    for n, aav in enumerate(instance.aavs):
        start = instance.start_node(n)
        cap = aav.capacity
        range_units = math.floor(aav.max_range * Sd + 1e-9)
        per_metre = w3 * aav.alpha / 1000.0 / instance.e_base * obj_scale
        full_units = round(w3 * aav.full_range_cost / instance.e_base * obj_scale)
        # Range tracking only where the AAV could pass its range before a window closes.
        track_range = any(aav.speed * instance.tasks[j].t_end > aav.max_range for j in chosen)
        index = {j: i + 1 for i, j in enumerate(chosen)}
        arcs = []
        t, dl, pl, dc, q = {}, {}, {}, {}, {}  # per task
        for j in chosen:
            task = instance.tasks[j]
            visit = model.NewBoolVar(f"v{n}_{j}")
            a = model.NewIntVar(0, min(cap, task.demand), f"a{n}_{j}")
            model.Add(a >= 1).OnlyEnforceIf(visit)
            model.Add(a == 0).OnlyEnforceIf(visit.Not())
            t[j] = model.NewIntVar(opens[j], max(opens[j], closes[j]), f"t{n}_{j}")
            if opens[j] > closes[j]:
                model.Add(visit == 0)
            dl[j] = model.NewIntVar(0, cap, f"dl{n}_{j}")
            pl[j] = model.NewIntVar(0, cap, f"pl{n}_{j}")
            delivered = a if task.is_delivery else 0
            picked = 0 if task.is_delivery else a
            model.Add(dl[j] + pl[j] <= cap)
            model.Add(dl[j] + delivered <= cap)
            model.Add(dl[j] == 0).OnlyEnforceIf(visit.Not())
            model.Add(pl[j] == 0).OnlyEnforceIf(visit.Not())
            if track_range:
                # v * t_end bounds Dcum; each leg rounded up adds at most one unit.
                dc[j] = model.NewIntVar(0, math.ceil(aav.speed * task.t_end * Sd)
                                        + 2 * len(chosen) + 2, f"dc{n}_{j}")
            data.visit[n, j], data.amount[n, j], data.arrival[n, j] = visit, a, t[j]
            arcs.append((index[j], index[j], visit.Not()))
            end = model.NewBoolVar(f"end{n}_{j}")
            arcs.append((index[j], 0, end))
            model.Add(dl[j] == 0).OnlyEnforceIf(end)  # the trip ends with no goods left
            data.ends[n, j] = end
        unused = model.NewBoolVar(f"unused{n}")
        arcs.append((0, 0, unused))
        data.ends[n, START] = unused
        legs_into: dict[int, list[tuple[Any, int]]] = {j: [] for j in chosen}
        for i in [START, *chosen]:
            p = start if i == START else i
            for j in chosen:
                if i == j:
                    continue
                task = instance.tasks[j]
                delivered = data.amount[n, j] if task.is_delivery else 0
                picked = 0 if task.is_delivery else data.amount[n, j]
                options = [(k, dist[p][k] + dist[k][j], dist[k][j]) for k in depots]
                if not (i == START and task.is_delivery):
                    options.insert(0, (DIRECT, dist[p][j], dist[p][j]))
                arc = model.NewBoolVar(f"x{n}_{i}_{j}")
                arcs.append((0 if i == START else index[i], index[j], arc))
                lits = []
                for mode, flown, leg in options:
                    lit = model.NewBoolVar(f"m{n}_{i}_{j}_{mode}")
                    lits.append(lit)
                    data.modes[n, i, j, mode] = lit
                    travel = ticks_up(flown / aav.speed)
                    if i == START:
                        model.Add(t[j] >= travel).OnlyEnforceIf(lit)
                    else:
                        model.Add(t[j] >= t[i] + travel).OnlyEnforceIf(lit)
                    if track_range:
                        before = 0 if i == START else dc[i]
                        model.Add(dc[j] == before + math.ceil(flown * Sd - 1e-9)) \
                            .OnlyEnforceIf(lit)
                    before_d = 0 if i == START else dl[i]
                    before_p = 0 if i == START else pl[i]
                    if mode == DIRECT:
                        model.Add(before_d == dl[j] + delivered).OnlyEnforceIf(lit)
                        model.Add(pl[j] == before_p + picked).OnlyEnforceIf(lit)
                    else:
                        model.Add(before_d == 0).OnlyEnforceIf(lit)
                        model.Add(pl[j] == picked).OnlyEnforceIf(lit)
                    legs_into[j].append((lit, round(per_metre * leg)))
                model.Add(sum(lits) == arc)
        model.AddCircuit(arcs)
        for j in chosen:
            visit = data.visit[n, j]
            if track_range:
                highest = max([full_units] + [cost for _, cost in legs_into[j]])
                q[j] = model.NewIntVar(0, highest, f"q{n}_{j}")
                over = model.NewBoolVar(f"o{n}_{j}")
                model.Add(dc[j] >= range_units + 1).OnlyEnforceIf([over, visit])
                model.Add(dc[j] <= range_units).OnlyEnforceIf(over.Not())
                model.Add(over == 0).OnlyEnforceIf(visit.Not())
                model.Add(q[j] == full_units).OnlyEnforceIf(over)
                for lit, cost in legs_into[j]:
                    model.Add(q[j] == cost).OnlyEnforceIf([lit, over.Not()])
                model.Add(q[j] == 0).OnlyEnforceIf(visit.Not())
                objective.append(q[j])
            else:
                objective.extend(cost * lit for lit, cost in legs_into[j])

    for j in chosen:
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
        per_tick = round(w2 * obj_scale / (horizon * S))
        objective.append(per_tick * latest)
        objective.append(-round(w2 * obj_scale) * served)
        constant_units += round((w1 + w2) * obj_scale) - round(per_tick * task.t_start * S)
    model.Minimize(sum(objective) + constant_units)
    return model, data


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
    gap = None if J is None or bound is None else max(0.0, J - bound) / max(abs(J), 1e-10)
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
