"""Dynamic mean J of every method before and after the physical dynamic run (issue 15).

    python benchmarks/experiments/physical_dynamic.py run --out results/physical-dynamic/after \
        [--per-scale 20]
    python benchmarks/experiments/physical_dynamic.py write BEFORE_DIR AFTER_DIR

``run`` runs the reproduction's heuristics (benchmarks/paper_reproduction.py) in dynamic mode,
seed 0, on the first ``--per-scale`` instances (by seed) of each scale of
``instances/paper-mc/`` into ``--out``, with the reproduction's machinery (the runner, its
default time limits). Which code runs is whichever ``tsac_bench`` Python imports: the
"before" store was made from a copy of the code before the change put first on PYTHONPATH.
``write`` puts the two stores' mean J side by side, with the ranking by mean J of each, and
counts in each store's executed routes (timed by Eq. 7 with their stamps, if any) the visits
that left toward a task before its release and the deliveries whose depot was left before
their release (the issue's independent check).
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import pandas as pd

# paper_reproduction is a tool of benchmarks/, one folder up from the experiments.
sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from paper_reproduction import OUR_METHODS, PAPER_METHODS, SCALES, instance_files

import tsac_bench
from tsac_bench.batch.runner import RunConfig, run_batch
from tsac_bench.model.evaluator import CostEvaluator
from tsac_bench.model.io import read_instance, read_solution
from tsac_bench.reporting.data import load, per_instance

ROOT = Path(__file__).resolve().parents[2]


def run(args: argparse.Namespace) -> None:
    from tsac_bench.planning import available_methods

    print(f"tsac_bench from {Path(tsac_bench.__file__).parent}")
    present = set(available_methods())
    methods = [m for m in (*PAPER_METHODS, *OUR_METHODS) if m in present]
    files = [f for scale in SCALES for f in instance_files(scale, args.per_scale)]
    run_batch(RunConfig(files, args.out, methods=methods, mode="dynamic", jobs=args.jobs))


def means(store: Path) -> pd.DataFrame:
    table = per_instance(load(store).query("status == 'ok'"))
    table = table[table["mode"] == "dynamic"]
    return table.pivot_table(index="method", columns="scale", values="J", aggfunc="mean")


def early_departures(store: Path) -> pd.DataFrame:
    """Per method: task visits left toward before the task's release, and deliveries whose
    loading depot was left before the delivery's release, summed over the store's runs."""
    frame = load(store).query("status == 'ok' and mode == 'dynamic'")
    rows = []
    for row in frame.itertuples():
        instance = read_instance(row.instance_file)
        routes = read_solution(store / row.solution_file, instance).routes
        evaluator = CostEvaluator(instance)
        early = stale = 0
        for n, route in enumerate(routes):
            trace = evaluator.trace(n, route)
            left_depot = None  # when the AAV left the depot that loaded the current trip
            for k, v in enumerate(route):
                if instance.is_depot(v.node):
                    left_depot = trace.departures[k + 1] if k + 1 < len(route) else None
                    continue
                release = instance.tasks[v.node].release
                early += trace.departures[k] < release
                stale += (instance.tasks[v.node].is_delivery and left_depot is not None
                          and left_depot < release)
        rows.append({"method": row.method, "early": early, "stale": stale})
    return pd.DataFrame(rows).groupby("method").sum()


def write(args: argparse.Namespace) -> None:
    before, after = means(args.before), means(args.after)
    scales = [s for s in SCALES if s in after.columns]
    counts = per_instance(load(args.after).query("status == 'ok'")).groupby("scale")[
        "instance"].nunique()
    lines = ["| method | " + " | ".join(f"{s} before | {s} after | change" for s in scales)
             + " |", "|---|" + "---:|---:|---:|" * len(scales)]
    for method in after.index:
        cells = []
        for s in scales:
            b, a = before.at[method, s], after.at[method, s]
            cells += [f"{b:.2f}", f"{a:.2f}", f"{100 * (a - b) / b:+.1f}%"]
        lines.append(f"| {method} | " + " | ".join(cells) + " |")
    lines += ["", "Ranking by mean J (lowest first):", "",
              "| scale | before | after | moved |", "|---|---|---|---|"]
    for s in scales:
        rank_b = list(before[s].sort_values().index)
        rank_a = list(after[s].sort_values().index)
        lines.append(f"| {s} | {', '.join(rank_b)} | {', '.join(rank_a)} | "
                     f"{'no' if rank_b == rank_a else 'yes'} |")
    lines.append("")
    lines.append("Instances per scale: " + ", ".join(f"{counts.get(s, 0)} at {s}"
                                                     for s in scales) + ".")
    checks = early_departures(args.before).merge(
        early_departures(args.after), left_index=True, right_index=True,
        suffixes=("_before", "_after"))
    lines += ["", "| method | visits left toward a task before its release (before / after) "
              "| deliveries whose depot was left before their release (before / after) |",
              "|---|---:|---:|"]
    for method, r in checks.iterrows():
        lines.append(f"| {method} | {r.early_before} / {r.early_after} | "
                     f"{r.stale_before} / {r.stale_after} |")
    print("\n".join(lines))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    commands = parser.add_subparsers(dest="command", required=True)
    runner = commands.add_parser("run")
    runner.add_argument("--out", type=Path, required=True)
    runner.add_argument("--per-scale", type=int, default=20)
    runner.add_argument("--jobs", type=int, default=1)
    writer = commands.add_parser("write")
    writer.add_argument("before", type=Path)
    writer.add_argument("after", type=Path)
    args = parser.parse_args()
    {"run": run, "write": write}[args.command](args)


if __name__ == "__main__":
    main()
