"""OCF speed and quality: wall time of one rocf / hocf / tsac-ocf allocation (one static plan
call) at 16/40 and 32/80, and J against greedy, static and dynamic.

Goals: a 32/80 allocation within 5 s on one core, rocf and hocf below greedy's J on average
(issue 4); one 32/80 tsac-ocf plan call under 1 s on one core (issue 17; its benchmark,
tsac_eval.py, times the dynamic runs' plan calls, this one the static call, the largest).
Each method runs once untimed first, so that loading torch and a policy file is not counted
as a plan call. Run by hand, pinned to one core:
    python benchmarks/ocf_speed.py [--instances 5] [--first-seed 100]
Writes reports/ocf-speed.md. Instances are generated (tsac_bench.model.generator, default
settings) with seeds first-seed .. first-seed + instances - 1; the method seed is 0.
"""

from __future__ import annotations

import argparse
import os
import platform
import statistics
from pathlib import Path

from tsac_bench.model.generator import generate
from tsac_bench.planning.solve import solve
from tsac_bench.solvers.ocf.engine import C_MAX, INIT, K_MAX, SAMPLES

SCALES = ("16/40", "32/80")
#: (label, method, settings): the defaults, then the OCF games started from greedy's plan.
VARIANTS = (
    ("greedy", "greedy", {}),
    ("rocf", "rocf", {}),
    ("hocf", "hocf", {}),
    ("rocf init=greedy", "rocf", {"init": "greedy"}),
    ("hocf init=greedy", "hocf", {"init": "greedy"}),
    ("tsac-ocf", "tsac-ocf", {}),
)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--instances", type=int, default=5)
    parser.add_argument("--first-seed", type=int, default=100)
    parser.add_argument("--out", type=Path, default=Path("reports/ocf-speed.md"))
    args = parser.parse_args()
    if hasattr(os, "sched_setaffinity"):
        os.sched_setaffinity(0, {min(os.sched_getaffinity(0))})
    seeds = range(args.first_seed, args.first_seed + args.instances)
    lines = [
        "# OCF speed and quality (rocf, hocf, tsac-ocf against greedy)",
        "",
        f"Command: `python benchmarks/ocf_speed.py --instances {args.instances} "
        f"--first-seed {args.first_seed}`  ",
        f"Machine: {platform.processor() or platform.machine()}, Python "
        f"{platform.python_version()}, pinned to one core. Generated instances (default "
        f"generator), seeds {seeds.start}..{seeds.stop - 1}; method seed 0. Wall time is one "
        "static plan call; J is the evaluator's. Dynamic: the simulator's run (t = 0 and the "
        "generator's two release events), J of the executed routes. Budget of every OCF "
        f"plan call: one game (samples {SAMPLES}), no time limit, k_max {K_MAX} decisions, "
        f"c_max {C_MAX} consecutive rejections; each starts from the {INIT} structure "
        "unless its label says init=greedy.",
        "",
    ]
    goals = []
    summary = ["| scale | method | mean J static | mean J dynamic | below greedy (static) | "
               "mean wall (s) | max wall (s) | mean decisions |",
               "|---|---|---:|---:|---:|---:|---:|---:|"]
    for scale in SCALES:
        instances = [generate(scale, seed) for seed in seeds]
        results: dict[str, list] = {}
        for label, method, settings in VARIANTS:
            solve(instances[0], method, settings=settings, seed=0)
            for instance in instances:
                static = solve(instance, method, settings=settings, seed=0)
                dynamic = solve(instance, method, settings=settings, seed=0, mode="dynamic")
                results.setdefault(label, []).append((static, dynamic))
        greedy = [s.cost for s, _ in results["greedy"]]
        lines += [f"## {scale}", "",
                  "| seed | " + " | ".join(f"{label} J (s)" for label, _, _ in VARIANTS) + " |",
                  "|---:|" + "---:|" * len(VARIANTS)]
        for i, seed in enumerate(seeds):
            cells = [f"{results[label][i][0].cost:.2f} ({results[label][i][0].wall_time:.3f})"
                     for label, _, _ in VARIANTS]
            lines.append(f"| {seed} | " + " | ".join(cells) + " |")
        lines.append("")
        for label, _, _ in VARIANTS:
            runs = results[label]
            walls = [s.wall_time for s, _ in runs]
            below = sum(s.cost < g - 1e-9 for (s, _), g in zip(runs, greedy, strict=True))
            decisions = [s.stats.get("decisions") for s, _ in runs]
            mean_decisions = (f"{statistics.mean(decisions):.0f}"
                              if None not in decisions else "-")
            if label in ("rocf", "hocf"):
                mean_static = statistics.mean(s.cost for s, _ in runs)
                mean_dynamic = statistics.mean(d.cost for _, d in runs)
                goals.append(
                    f"- {scale} {label}: max wall {max(walls):.3f} s"
                    + (f" ({'meets' if max(walls) <= 5 else 'misses'} the 5 s goal)"
                       if scale == "32/80" else "")
                    + f"; mean J {mean_static:.2f} static / {mean_dynamic:.2f} dynamic against "
                    f"greedy's {statistics.mean(greedy):.2f} / "
                    f"{statistics.mean(d.cost for _, d in results['greedy']):.2f}: "
                    + ("below" if mean_static < statistics.mean(greedy) else "NOT below")
                    + " greedy (static)")
            if label == "tsac-ocf" and scale == "32/80":
                goals.append(f"- 32/80 tsac-ocf: max wall {max(walls):.3f} s, mean "
                             f"{statistics.mean(walls):.3f} s ("
                             + ("meets" if max(walls) < 1 else "misses")
                             + " issue 17's 1 s goal for a static plan call)")
            summary.append(
                f"| {scale} | {label} | {statistics.mean(s.cost for s, _ in runs):.2f} | "
                f"{statistics.mean(d.cost for _, d in runs):.2f} | {below}/{len(runs)} | "
                f"{statistics.mean(walls):.3f} | {max(walls):.3f} | {mean_decisions} |")
    lines += ["## Summary", "", *summary, "", "## Goals (issues 4 and 17)", "", *goals, ""]
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text("\n".join(lines) + "\n")
    print("\n".join(lines))


if __name__ == "__main__":
    main()
