"""PyVRP at fixed time budgets against every other method (static mode).

    python benchmarks/experiments/pyvrp_budget.py [--per-scale 5] [--budgets 1 10]

Runs ``pyvrp`` with no iteration cap (only the time budget stops it) on the first instances
of each scale of ``instances/paper-mc/`` and compares its J with the other methods' static J
on the same instances from the reproduction store (run benchmarks/paper_reproduction.py
first). Writes reports/archive/pyvrp-budget.md.
"""

from __future__ import annotations

import argparse
import platform
import sys
import time
from pathlib import Path

import pandas as pd

# paper_reproduction is a tool of benchmarks/, one folder up from the experiments.
sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from paper_reproduction import instance_files

from tsac_bench.model.io import read_instance
from tsac_bench.planning.solve import solve
from tsac_bench.reporting.data import load
from tsac_bench.solvers.pyvrp_peer import PyVRPAllocator

ROOT = Path(__file__).resolve().parents[2]
SCALES = ("4/10", "8/20", "16/40", "32/80")
STORE = ROOT / "results" / "paper-reproduction"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--per-scale", type=int, default=5)
    parser.add_argument("--budgets", type=float, nargs="+", default=[1.0, 10.0])
    parser.add_argument("--out", type=Path,
                        default=ROOT / "reports" / "archive" / "pyvrp-budget.md")
    args = parser.parse_args()
    rows = []
    for scale in SCALES:
        for path in instance_files(scale, args.per_scale):
            instance = read_instance(path)
            for budget in args.budgets:
                allocator = PyVRPAllocator(max_iterations=10**9, time_limit=budget)
                began = time.perf_counter()
                outcome = solve(instance, allocator, seed=0, time_limit=budget)
                rows.append({"scale": scale, "instance": instance.name,
                             "method": f"pyvrp {budget:g} s", "J": outcome.cost,
                             "wall": time.perf_counter() - began})
    ours = pd.DataFrame(rows)
    frame = load(STORE)
    others = frame[(frame["mode"] == "static") & (frame["status"] == "ok")
                   & frame["instance"].isin(ours["instance"])][["scale", "instance", "method",
                                                                 "J", "runtime"]]
    others = others.rename(columns={"runtime": "wall"})
    both = pd.concat([ours, others])
    means = both.pivot_table(index="method", columns="scale", values="J", aggfunc="mean")
    walls = both.pivot_table(index="method", columns="scale", values="wall", aggfunc="mean")
    columns = [s for s in SCALES if s in means.columns]
    lines = ["# PyVRP at fixed budgets (static mode)", "",
             "Command: `python benchmarks/experiments/pyvrp_budget.py "
             f"--per-scale {args.per_scale} "
             f"--budgets {' '.join(f'{b:g}' for b in args.budgets)}`  ",
             f"Machine: {platform.machine()}, 2 cores shared with other work; first "
             f"{args.per_scale} instances per scale of instances/paper-mc; other methods' J "
             "from results/paper-reproduction (their default settings). PyVRP runs without an "
             "iteration cap, so the budget alone stops it.", "",
             "| method | " + " | ".join(f"{s} mean J (wall s)" for s in columns) + " |",
             "|---|" + "---:|" * len(columns)]
    for method in means.sort_values(columns[-1]).index:
        cells = [f"{means.at[method, s]:.2f} ({walls.at[method, s]:.2f})" for s in columns]
        lines.append(f"| {method} | " + " | ".join(cells) + " |")
    args.out.write_text("\n".join(lines) + "\n")
    print("\n".join(lines))


if __name__ == "__main__":
    main()
