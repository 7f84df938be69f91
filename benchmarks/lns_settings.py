"""The neighbourhood search's settings (``tsac-bench bks lns``: AAVs a repair frees, tasks
beyond theirs, seconds per repair, the order of the AAVs) on validation instances
(generator seeds from 900000, apart from paper-mc), every setting from the same start:
DGA's plan, seed 0, after exact-bp's incumbent generations or ``--start-seconds``.

    python benchmarks/lns_settings.py --sizes 8/20:4 16/40:2 \
        --settings 2/6/30 3/4/60 2/4/30 3/6/30 --time-limit 120 --workers 2

A size is SIZE:COUNT, its instances, or SIZE:COUNT:SECONDS, searched that long in place of
``--time-limit``. A setting is AAVS/EXTRA/REPAIR_LIMIT, and /ORDER where not "shuffled".
Per instance and setting: the start's J, the J the search reached in the time limit, the
change, repairs run, lowered and proved, and the most AAVs a neighbourhood freed; then per
size and setting the mean change and the instances where the setting reached the least J.
Each worker a core of its own: the seconds bound the search. Writes the tables to stdout
and to ``--out``.
"""

from __future__ import annotations

import argparse
import functools
import os
import platform
import shlex
import sys
from collections import defaultdict
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

from tsac_bench.formulations.branch_price.options import NeighbourhoodSettings
from tsac_bench.model.evaluator import CostEvaluator, costs_agree
from tsac_bench.model.generator import generate
from tsac_bench.reporting.report import shown_command

ROOT = Path(__file__).resolve().parent.parent
VALIDATION_SEED = 900000
HEADER = ["| instance | setting | start J | J | change | repairs | lowered | proved "
          "| largest |", "|---|---|---|---|---|---|---|---|---|"]


def _settings(text: str) -> NeighbourhoodSettings:
    aavs, extra, repair_limit, *order = text.split("/")
    return NeighbourhoodSettings(int(aavs), int(extra), float(repair_limit), *order)


def _label(settings: NeighbourhoodSettings) -> str:
    label = f"{settings.aavs}/{settings.extra}/{settings.repair_limit:g}"
    return label if settings.order == NeighbourhoodSettings.order else f"{label}/{settings.order}"


def _start(size: str, seed: int, seconds: float | None) -> tuple:
    """DGA's plan, seed 0: after exact-bp's incumbent generations, or ``seconds`` of it
    (as the library's plans at 16/40 and 32/80, where those generations take minutes)."""
    from tsac_bench.planning import PlanningState, make_allocator
    from tsac_bench.solvers.exact import INCUMBENT_GENERATIONS

    state = PlanningState.static(generate(size, seed))
    if seconds is not None:
        return make_allocator("dga").plan(state, seed=0, time_limit=seconds).routes
    dga = make_allocator("dga", generations=INCUMBENT_GENERATIONS)
    return dga.plan(state, seed=0).routes


def _search(size: str, seed: int, start: tuple, settings: NeighbourhoodSettings,
            time_limit: float) -> dict:
    from tsac_bench.formulations.branch_price.neighbourhoods import search

    instance = generate(size, seed)
    cost = CostEvaluator(instance).cost
    plan, report = search(instance, start, time_limit, settings)
    return {"size": size, "seed": seed, "seconds": time_limit, "setting": _label(settings),
            "start": cost(start),
            "J": cost(plan), "repairs": report.repairs, "lowered": report.improved,
            "proved": report.proved, "largest": report.largest}


def _summary(results: list[dict]) -> list[str]:
    """Per size and setting: the mean change and on how many instances it reached the least
    J (ties counted for each)."""
    by_instance = defaultdict(list)
    for row in results:
        by_instance[row["size"], row["seed"]].append(row)
    changes, wins = defaultdict(list), defaultdict(int)
    for (size, _), rows in by_instance.items():
        least = min(row["J"] for row in rows)
        for row in rows:
            changes[size, row["setting"]].append(row["J"] / row["start"] - 1)
            wins[size, row["setting"]] += costs_agree(row["J"], least)
    seconds = {row["size"]: row["seconds"] for row in results}
    lines = ["| size | seconds | setting | mean change | least J on |", "|---|---|---|---|---|"]
    for (size, setting), values in changes.items():
        lines.append(f"| {size} | {seconds[size]:g} | {setting} "
                     f"| {100 * sum(values) / len(values):+.2f} % "
                     f"| {wins[size, setting]} of {len(values)} |")
    return lines


def main(argv: list[str]) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--sizes", nargs="+", default=["8/20:4", "16/40:2"],
                        help="SIZE:COUNT[:SECONDS], the instances of each size")
    parser.add_argument("--settings", nargs="+", type=_settings,
                        default=[NeighbourhoodSettings()],
                        help="AAVS/EXTRA/REPAIR_LIMIT[/ORDER]")
    parser.add_argument("--time-limit", type=float, default=120.0)
    parser.add_argument("--start-seconds", type=float, default=None,
                        help="DGA's start after this many seconds, not its generations")
    parser.add_argument("--workers", type=int, default=1)
    parser.add_argument("--out", type=Path, default=ROOT / "reports" / "lns-settings.md")
    args = parser.parse_args(argv)
    seconds, instances = {}, []
    for spec in args.sizes:
        size, count, *limit = spec.split(":")
        seconds[size] = float(limit[0]) if limit else args.time_limit
        instances += [(size, seed)
                      for seed in range(VALIDATION_SEED, VALIDATION_SEED + int(count))]
    with ProcessPoolExecutor(args.workers) as pool:
        sizes, seeds = [size for size, _ in instances], [seed for _, seed in instances]
        dga_start = functools.partial(_start, seconds=args.start_seconds)
        starts = dict(zip(instances, pool.map(dga_start, sizes, seeds), strict=True))
        jobs = [pool.submit(_search, size, seed, starts[size, seed], settings,
                            seconds[size])
                for size, seed in instances for settings in args.settings]
        results = []
        for job in jobs:
            row = job.result()
            results.append(row)
            print(row, flush=True)
    rows = [f"| {r['size']} seed {r['seed']} | {r['setting']} | {r['start']:.6f} "
            f"| {r['J']:.6f} | {100 * (r['J'] / r['start'] - 1):+.2f} % | {r['repairs']} "
            f"| {r['lowered']} | {r['proved']} | {r['largest']} |" for r in results]
    start = (f"after {args.start_seconds:g} s" if args.start_seconds is not None
             else "exact-bp's incumbent generations")
    command = shown_command(shlex.join(["python", "benchmarks/lns_settings.py", *argv]), ROOT)
    args.out.write_text("\n".join([
        "# The neighbourhood search's settings (validation instances)", "",
        f"Command: `{command}`  ",
        f"Machine: {platform.machine()}, {os.cpu_count()} cores ({platform.python_version()}), "
        f"{args.workers} worker(s), each search the size's seconds from DGA's plan "
        f"({start}, seed 0). A setting is AAVS/EXTRA/REPAIR_LIMIT, "
        "and /ORDER where not shuffled (`tsac-bench bks lns --aavs --extra --repair-limit "
        "--order`).", "",
        *_summary(results), "", *HEADER, *rows, ""]))


if __name__ == "__main__":
    main(sys.argv[1:])
