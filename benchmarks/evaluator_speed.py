"""Evaluator speed: full evaluation of a 32/80 plan and one incremental route change.

Goal (issue: foundation): full <= 1 ms, incremental <= 100 us per call on the 2-core
development machine. Run by hand:  python benchmarks/evaluator_speed.py [--instances 5]
Writes reports/evaluator-speed.md.
"""

from __future__ import annotations

import argparse
import os
import platform
import statistics
import timeit
from pathlib import Path

from tsac_bench.model.evaluator import CostEvaluator
from tsac_bench.model.generator import generate
from tsac_bench.planning.insertion import removal_route
from tsac_bench.planning.solve import solve


def median_seconds(call, repeat: int = 7, number: int = 200) -> float:
    return statistics.median(t / number for t in timeit.repeat(call, repeat=repeat, number=number))


def measure(seed: int) -> dict[str, float]:
    instance = generate("32/80", seed)
    routes = solve(instance, "greedy").solution.routes
    evaluator = CostEvaluator(instance)
    state = evaluator.state(routes)
    # A realistic incremental call: one AAV drops one of its tasks (the OCF REMOVE move).
    n = max(range(instance.n_aavs), key=lambda k: len(routes[k]))
    task = next(v.node for v in routes[n] if v.node < instance.n_tasks)
    changed = removal_route(instance, routes[n], task)
    visits = sum(len(r) for r in routes)
    return {
        "visits": visits,
        "route_length": len(routes[n]),
        "full": median_seconds(lambda: evaluator.evaluate(routes)),
        "cost_only": median_seconds(lambda: evaluator.cost(routes)),
        "incremental": median_seconds(lambda: state.propose(n, changed), number=2000),
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--instances", type=int, default=5)
    parser.add_argument("--out", type=Path, default=Path("reports/evaluator-speed.md"))
    args = parser.parse_args()
    rows = [measure(seed) for seed in range(args.instances)]
    # Other processes on the machine slow the timings; the report says how busy it was.
    load = os.getloadavg()[0] if hasattr(os, "getloadavg") else float("nan")
    lines = [
        "# Evaluator speed (32/80, greedy plans)",
        "",
        f"Command: `python benchmarks/evaluator_speed.py --instances {args.instances}`  ",
        f"Machine: {platform.processor() or platform.machine()}, Python "
        f"{platform.python_version()}, {os.cpu_count()} cores, load average {load:.1f} "
        "(1 min) at the end of the run; median of 7 repeats per instance.",
        "",
        "| instance seed | visits | route changed (visits) | full evaluate (us) | "
        "cost only (us) | incremental propose (us) |",
        "|---:|---:|---:|---:|---:|---:|",
    ]
    for seed, r in enumerate(rows):
        lines.append(f"| {seed} | {r['visits']} | {r['route_length']} | {r['full'] * 1e6:.0f} | "
                     f"{r['cost_only'] * 1e6:.0f} | {r['incremental'] * 1e6:.1f} |")
    med = {k: statistics.median(r[k] for r in rows) for k in ("full", "incremental")}
    lines += ["", f"Median: full {med['full'] * 1e6:.0f} us (goal <= 1000 us), incremental "
              f"{med['incremental'] * 1e6:.1f} us (goal <= 100 us)."]
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text("\n".join(lines) + "\n")
    print("\n".join(lines))


if __name__ == "__main__":
    main()
