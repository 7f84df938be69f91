"""Root LP bounds of the MILP, strengthening by strengthening, and of one idea not kept.

    python benchmarks/exact_root_bounds.py --sizes 3/8 4/10 --per-size 5

Why this exists: at the paper's small scale (4/10) neither exact backend proves optimality in
600 s (reports/exact-scaling.md), and the reason is the LP bound. This prints, per instance,
the LP relaxation of the MILP with the big-M time rows only, with the arrival times carried on
the arcs (``time_flow``), with the coalition cover cuts as well (the default model), and with
route columns added on top: for every AAV whose elementary time-feasible paths through its
network number at most ``--route-limit``, one binary per path, linked to the arcs
(x_a = sum of the paths through a) and to the coalition's latest arrival (T_j - t_start(j) >=
sum over paths r through j of (t_j(r) - t_start(j)) * lambda_r, t_j(r) by Eq. 7 along r).
That model is exact (at an integer point lambda picks the AAV's path, whose Eq. 7 arrivals
are its arrivals), and its LP cannot average one AAV's visit orders any more. It is not in
the formulation because it moves the bound on one instance in five (docs/formulations.md).
Writes reports/archive/exact-root-bounds.md.
"""

from __future__ import annotations

import argparse
import shlex
import sys
import time
from pathlib import Path
from typing import Any

from tsac_bench.formulations.network import START
from tsac_bench.model import Instance
from tsac_bench.model.evaluator import CostEvaluator
from tsac_bench.model.generator import generate
from tsac_bench.planning import PlanningState
from tsac_bench.reporting.report import shown_command
from tsac_bench.solvers.greedy import GreedyAllocator

ROOT = Path(__file__).resolve().parent.parent


class TooManyPaths(Exception):
    pass


def time_feasible_paths(instance: Instance, network: Any, limit: int) -> list[tuple]:
    """Every non-empty elementary path from the start through ``network`` whose Eq. 7
    arrivals meet each window, as (arcs, {task: arrival}); TooManyPaths past ``limit``."""
    leaving: dict[int, list] = {}
    for arc in network.arcs:
        leaving.setdefault(arc.tail, []).append(arc)
    paths: list[tuple] = []

    def extend(node: int, now: float, arcs: list, arrivals: dict) -> None:
        for arc in leaving.get(node, []):
            if arc.head in arrivals:
                continue
            arrival = max(instance.tasks[arc.head].t_start, now + arc.travel)
            if arrival > network.latest[arc.head]:
                continue
            arcs.append(arc)
            arrivals[arc.head] = arrival
            paths.append((tuple(arcs), dict(arrivals)))
            if len(paths) > limit:
                raise TooManyPaths
            extend(arc.head, arrival, arcs, arrivals)
            arcs.pop()
            del arrivals[arc.head]

    extend(START, 0.0, [], {})
    return paths


def add_route_columns(model: Any, n: int, paths: list[tuple]) -> None:
    import pyomo.environ as pyo

    instance = model.data.instance
    lam = pyo.Var(range(len(paths)), domain=pyo.Binary)
    rows = pyo.ConstraintList()
    model.add_component(f"route_choice_{n}", lam)
    model.add_component(f"route_rows_{n}", rows)
    rows.add(sum(lam.values()) + model.end[n, START] == 1)
    through_arc: dict[tuple, list[int]] = {}
    arrivals_at: dict[int, list[tuple[int, float]]] = {}
    for r, (arcs, arrivals) in enumerate(paths):
        for arc in arcs:
            through_arc.setdefault((n, arc.tail, arc.head, arc.mode), []).append(r)
        for j, t in arrivals.items():
            arrivals_at.setdefault(j, []).append((r, t))
    for key in model.A:
        if key[0] == n:
            rows.add(model.x[key] == sum(lam[r] for r in through_arc.get(key, [])))
    for j, pairs in arrivals_at.items():
        opens = instance.tasks[j].t_start
        rows.add(model.Tm[j] - opens >= sum((t - opens) * lam[r] for r, t in pairs))


def root_bound(instance: Instance, variant: str, route_limit: int) -> tuple[float, list]:
    import pyomo.environ as pyo

    from tsac_bench.formulations.milp import MilpOptions, build_milp, solve_milp

    options = {"big-M": MilpOptions(time_flow=False, cover_cuts=False),
               "time flow": MilpOptions(cover_cuts=False)}.get(variant, MilpOptions())
    model = build_milp(instance, options=options)
    counts: list = []
    if variant == "route columns":
        for n, network in enumerate(model.data.networks):
            try:
                paths = time_feasible_paths(instance, network, route_limit)
            except TooManyPaths:
                counts.append(f"> {route_limit}")
                continue
            counts.append(len(paths))
            add_route_columns(model, n, paths)
    pyo.TransformationFactory("core.relax_integer_vars").apply_to(model)
    report = solve_milp(model)
    return report.objective, counts


VARIANTS = ("big-M", "time flow", "default", "route columns")


def main(argv: list[str]) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--sizes", nargs="+", default=["3/8", "4/10"])
    parser.add_argument("--per-size", type=int, default=5)
    parser.add_argument("--route-limit", type=int, default=100_000)
    parser.add_argument("--out", type=Path,
                        default=ROOT / "reports" / "archive" / "exact-root-bounds.md")
    args = parser.parse_args(argv)
    lines = ["| size | seed | greedy J | " + " | ".join(f"LP: {v}" for v in VARIANTS)
             + " | paths per AAV | seconds |", "|---" * (len(VARIANTS) + 5) + "|"]
    for size in args.sizes:
        for seed in range(1, args.per_size + 1):
            instance = generate(size, seed)
            greedy = CostEvaluator(instance).cost(
                GreedyAllocator().plan(PlanningState.static(instance)).routes)
            began = time.perf_counter()
            results = [root_bound(instance, v, args.route_limit) for v in VARIANTS]
            bounds = [bound for bound, _ in results]
            counts = results[-1][1]  # only the route-column variant enumerates paths
            row = (f"| {size} | {seed} | {greedy:.3f} | "
                   + " | ".join(f"{b:.3f}" for b in bounds)
                   + f" | {', '.join(map(str, counts))} | {time.perf_counter() - began:.0f} |")
            print(row, flush=True)
            lines.append(row)
    command = shown_command(shlex.join(["python", "benchmarks/exact_root_bounds.py", *argv]), ROOT)
    args.out.write_text("\n".join([
        "# Root LP bounds of the MILP", "", f"Command: `{command}`", "",
        "Each column is the LP relaxation of one model: big-M time rows only; with arrival "
        "times on the arcs; the default model (also coalition cover cuts); the default model "
        f"plus one binary per time-feasible path for each AAV with at most {args.route_limit} "
        "such paths (benchmarks/exact_root_bounds.py says how they are linked). "
        "`paths per AAV` counts each path with its depot choices.", "", *lines, ""]))


if __name__ == "__main__":
    main(sys.argv[1:])
