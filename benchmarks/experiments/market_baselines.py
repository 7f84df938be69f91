"""The paper's horizontal baselines side by side: J and wall time per method at the paper's four
scales (Fig. 7), on generated instances, static mode (every task known at t = 0).

Run by hand, one at a time (the development machine has 2 shared cores):
    python benchmarks/experiments/market_baselines.py --instances 10
    python benchmarks/experiments/market_baselines.py --methods greedy,cnp,dga,rocf,hocf
Writes reports/archive/market-baselines.md. Every J is the evaluator's, recomputed by ``solve``.
"""

from __future__ import annotations

import argparse
import platform
import statistics
import sys
from pathlib import Path

from tsac_bench.model.generator import PAPER_SCALES, generate
from tsac_bench.planning.solve import solve


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--methods", default="greedy,cnp,dga",
                        help="comma-separated method names; the first is the reference")
    parser.add_argument("--scales", default=",".join(PAPER_SCALES))
    parser.add_argument("--instances", type=int, default=10, help="instances per scale")
    parser.add_argument("--first-seed", type=int, default=0, help="generator seed of the first")
    parser.add_argument("--seed", type=int, default=0, help="the methods' seed")
    parser.add_argument("--out", type=Path, default=Path("reports/archive/market-baselines.md"))
    args = parser.parse_args()
    methods = args.methods.split(",")
    scales = args.scales.split(",")
    seeds = range(args.first_seed, args.first_seed + args.instances)

    rows: dict[tuple[str, str], list[tuple[float, float]]] = {}
    for scale in scales:
        for seed in seeds:
            instance = generate(scale, seed)
            for method in methods:
                outcome = solve(instance, method, seed=args.seed)
                rows.setdefault((scale, method), []).append((outcome.cost, outcome.wall_time))
                print(f"{scale} s{seed} {method}: J={outcome.cost:.3f} "
                      f"t={outcome.wall_time:.2f}s", file=sys.stderr, flush=True)

    reference = methods[0]
    command = "python benchmarks/experiments/market_baselines.py " + " ".join(
        [f"--methods {args.methods}", f"--scales {args.scales}",
         f"--instances {args.instances}", f"--first-seed {args.first_seed}",
         f"--seed {args.seed}"])
    lines = [
        "# Market baselines: DGA and CNP against greedy (static mode)",
        "",
        f"Command: `{command}`  ",
        f"Instances: `generate(scale, seed)` for seeds {seeds.start}..{seeds.stop - 1} at every "
        f"scale (default generator settings); methods run with seed {args.seed} and their "
        "default settings, no time limit.  ",
        f"Machine: {platform.machine()}, Python {platform.python_version()}, 2 cores shared "
        "with other jobs: wall times are indicative only.  ",
        "Static mode (every task known at t = 0): CNP's persistent contracts and DGA's "
        "incumbent seeding act only in dynamic runs, which wait for the simulator.",
        "",
        f"vs {reference}: mean over instances of (J - J_{reference}) / J_{reference}; "
        f"wins: instances where J < J_{reference} (ties within 1e-9 are not wins).",
        "",
        f"| scale | method | mean J | median J | min J | max J | vs {reference} | wins | "
        "mean wall (s) | max wall (s) |",
        "|---|---|---:|---:|---:|---:|---:|---:|---:|---:|",
    ]
    for scale in scales:
        base = [j for j, _ in rows[(scale, reference)]]
        for method in methods:
            costs = [j for j, _ in rows[(scale, method)]]
            walls = [t for _, t in rows[(scale, method)]]
            rel = statistics.fmean((j - b) / b for j, b in zip(costs, base, strict=True))
            wins = sum(j < b - 1e-9 for j, b in zip(costs, base, strict=True))
            lines.append(
                f"| {scale} | {method} | {statistics.fmean(costs):.2f} | "
                f"{statistics.median(costs):.2f} | {min(costs):.2f} | {max(costs):.2f} | "
                f"{rel:+.1%} | {wins}/{len(costs)} | {statistics.fmean(walls):.2f} | "
                f"{max(walls):.2f} |")
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text("\n".join(lines) + "\n")
    print("\n".join(lines))


if __name__ == "__main__":
    main()
