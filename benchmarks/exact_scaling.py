"""Time to proven optimality and final gap of the exact backends, by instance size.

    python benchmarks/exact_scaling.py --time-limit 600 --per-size 5      # the issue's setting
    python benchmarks/exact_scaling.py --time-limit 60 --per-size 3 \
        --sizes 2/4 2/6 3/6 3/8 4/10                                       # a short run

    python benchmarks/exact_scaling.py --sizes 3/8 4/10 8/20 16/40 32/80 --per-size 5 \
        --large-per-size 3 --time-limit 600 --cache reports/exact-scaling.jsonl
                                                      # the three backends side by side

Instances: the paper's scenario generator (TABLE 1 fleet, demands 5-60 kg, windows of 15-40
minutes), seeds 1..per-size (1..large-per-size from 8/20 up), J over all tasks (releases
ignored offline). Each backend runs on one thread unless --threads says otherwise. Writes
reports/exact-scaling.md (tables plus the command and machine) and prints one line per run.

``--cache`` keeps every finished run as one JSON line, with the commit that measured it: a
run already there (same instance, backend, limit and threads) is not run again, so a long
benchmark can be run in parts (one per core) and an interrupted one loses nothing. The report
names every commit its rows come from. The cache of reports/exact-scaling.md is committed
beside it (reports/exact-scaling.jsonl), so that the report can be written again, or a size
re-run alone, from a clean checkout: delete a backend's rows of a size and run the command.
"""

from __future__ import annotations

import argparse
import dataclasses
import functools
import json
import math
import os
import platform
import shlex
import statistics
import subprocess
import sys
import time
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

from tsac_bench.batch.manifests import read_manifest
from tsac_bench.model.generator import generate
from tsac_bench.model.io import read_instance
from tsac_bench.planning.solve import solve
from tsac_bench.reporting.report import shown_command

ROOT = Path(__file__).resolve().parent.parent
PAPER_SETS = ROOT / "instances" / "paper-mc"
BACKENDS = ("exact", "exact-cpsat", "exact-bp")
#: Sizes from which only the bound against the best plan is reported (none is proved).
LARGE = ("8/20", "16/40", "32/80")
#: exact-bp's time split (its stats), summed per size in the report.
TIME_SPLIT = ("pricing_time", "lp_time", "cut_time", "branching_time", "dive_time",
              "other_time")
NOTES = (
    "Notes: an unproved run counts as slower than the limit in the median. The gap of an "
    "optimal CP-SAT run is the scaling slack its reported bound subtracts (docs/"
    "formulations.md), not an open gap. exact and exact-cpsat start from the greedy plan, "
    "exact-bp from the best of greedy, dga and 100 hocf games (rows measured before the "
    "games were a start: the better of greedy and dga; see the start J column); its root "
    "bound is the Lagrangian bound of the route master at the root node.")


def solve_one(size: str, seed: int, method: str, time_limit: float, threads: int) -> dict:
    commit = _commit()
    instance = generate(size, seed)
    began = time.perf_counter()
    outcome = solve(instance, method, seed=0, time_limit=time_limit,
                    settings={"threads": threads})
    wall = time.perf_counter() - began
    stats = outcome.stats
    row = {"size": size, "seed": seed, "method": method, "time_limit": time_limit,
           "threads": threads, "status": outcome.status, "J": outcome.cost,
           "lower_bound": outcome.lower_bound, "gap": stats.get("mip_gap"), "wall": wall,
           "greedy": stats.get("warm_start_J"), "root": stats.get("root_bound"),
           "commit": commit,
           **{key: stats[key] for key in (*TIME_SPLIT, "nodes", "columns", "dives",
                                          "purged_columns", "lp_solves")
              if key in stats}}
    if method == "exact" and size not in LARGE:
        # Outside the timed solve: the LP relaxation of the model HiGHS is given.
        from exact_root_bounds import root_bound
        row["root"] = root_bound(instance, "default", 0)[0]
    print(f"{size} s{seed} {method:12s} {row['status']:9s} J={row['J']:.6f} "
          f"LB={row['lower_bound']} gap={row['gap']} {wall:.1f}s", flush=True)
    return row


@functools.cache
def _commit() -> str:
    """The commit checked out when this process first asks: the code it imported, even if
    the checkout moves on during a long run."""
    try:
        return subprocess.run(["git", "rev-parse", "--short", "HEAD"], cwd=ROOT, text=True,
                              capture_output=True, check=True).stdout.strip()
    except (OSError, subprocess.CalledProcessError):
        return "unknown"


def _key(size: str, seed: int, method: str, time_limit: float, threads: int) -> tuple:
    return size, seed, method, float(time_limit), threads


def _cached(cache: Path | None) -> dict[tuple, dict]:
    if cache is None or not cache.exists():
        return {}
    rows = (json.loads(line) for line in cache.read_text().splitlines())
    return {_key(r["size"], r["seed"], r["method"], r["time_limit"], r["threads"]): r
            for r in rows}


def run(keys: list[tuple], time_limit: float, threads: int, jobs: int = 1,
        cache: Path | None = None) -> list[dict]:
    """Every (size, seed, backend) run not already in ``cache``; ``jobs`` runs go side by
    side, each in its own process (give each its own core: jobs * threads <= cores, or the
    times mean little)."""
    done = _cached(cache)
    todo = [key for key in keys if _key(*key, time_limit, threads) not in done]

    def keep(row: dict) -> None:
        if cache is not None:
            cache.parent.mkdir(parents=True, exist_ok=True)
            with cache.open("a") as handle:
                handle.write(json.dumps(row) + "\n")
        done[_key(row["size"], row["seed"], row["method"], time_limit, threads)] = row

    if jobs == 1:
        for key in todo:
            keep(solve_one(*key, time_limit, threads))
    else:
        with ProcessPoolExecutor(max_workers=jobs) as pool:
            futures = [pool.submit(solve_one, *key, time_limit, threads) for key in todo]
            for future in futures:
                keep(future.result())
    return [done[_key(*key, time_limit, threads)] for key in keys]


def table(rows: list[dict], sizes: list[str], time_limit: float,
          methods: tuple[str, ...] = BACKENDS) -> str:
    lines = ["| size | backend | proved | median time to optimality (s) | median final gap | "
             "max final gap |", "|---|---|---|---|---|---|"]
    for size in sizes:
        for method in methods:
            runs = [r for r in rows if r["size"] == size and r["method"] == method]
            if not runs:
                continue
            proved = [r for r in runs if r["status"] == "optimal"]
            # An unproved run counts as taking longer than the limit.
            times = sorted(r["wall"] if r["status"] == "optimal" else math.inf for r in runs)
            median = statistics.median(times)
            gaps = [r["gap"] or 0.0 for r in runs]
            shown = f"> {time_limit:g}" if median == math.inf else f"{median:.1f}"
            lines.append(
                f"| {size} | {method} | {len(proved)}/{len(runs)} | {shown} | "
                f"{100 * statistics.median(gaps):.2f} % | {100 * max(gaps):.2f} % |")
    return "\n".join(lines)


def library_best(keys: set[tuple[str, int]], sets: Path = PAPER_SETS) -> dict[tuple, float]:
    """The best-known J of the shipped library (``tsac-bench bks``) for each (size, seed) it
    holds: ``generate(size, seed)`` is paper-mc's ``gen-N-M-sSEED`` (checked, the meta left
    aside: older files name the generator's module as it was)."""
    known: dict[tuple, float] = {}
    manifests: dict[str, dict] = {}
    for size, seed in keys:
        folder = size.replace("/", "-")
        directory = sets / folder
        if folder not in manifests:
            manifests[folder] = (read_manifest(directory).require_valid().entries
                                 if (directory / "manifest.json").exists() else {})
        entry = manifests[folder].get(f"gen-{folder}-s{seed}")
        if entry is None or entry.get("best_J") is None:
            continue
        generated = generate(size, seed)
        stored = read_instance(directory / entry["file"])
        if dataclasses.replace(stored, meta=generated.meta) == generated:
            known[size, seed] = float(entry["best_J"])
    return known


def best_plans(rows: list[dict], known: dict[tuple, float] | None = None
               ) -> dict[tuple, float]:
    """The best-known J per instance: the lowest any backend found or started from, or the
    library's (``known``) where lower."""
    best: dict[tuple, float] = dict(known or {})
    for r in rows:
        found = min(r["J"], r["greedy"] if r["greedy"] is not None else math.inf)
        best[r["size"], r["seed"]] = min(best.get((r["size"], r["seed"]), math.inf), found)
    return best


def _share(value: float | None, best: float) -> str:
    return "-" if value is None else f"{100 * value / best:.1f} %"


def bound_table(rows: list[dict], sizes: list[str], methods: tuple[str, ...],
                field: str, known: dict[tuple, float] | None = None) -> str:
    """Per instance, each backend's ``field`` bound as a share of the best-known J."""
    best = best_plans(rows, known)
    lines = ["| size | seed | best-known J | " + " | ".join(methods) + " |",
             "|---|---|---|" + "---|" * len(methods)]
    for size in sizes:
        for seed in sorted({r["seed"] for r in rows if r["size"] == size}):
            by_method = {r["method"]: r for r in rows if (r["size"], r["seed"]) == (size, seed)}
            cells = [_share(by_method[m][field], best[size, seed]) if m in by_method
                     else "not run" for m in methods]
            lines.append(f"| {size} | {seed} | {best[size, seed]:.6f} | "
                         + " | ".join(cells) + " |")
    return "\n".join(lines)


def time_split_table(rows: list[dict], sizes: list[str]) -> str:
    """Where exact-bp's time goes, summed over the instances of a size."""
    lines = ["| size | pricing | LP | arrival cuts | branching | dives | other | "
             "nodes (median) | columns (median) |", "|---|---|---|---|---|---|---|---|---|"]
    for size in sizes:
        runs = [r for r in rows if r["size"] == size and r["method"] == "exact-bp"
                and "pricing_time" in r]
        if not runs:
            continue
        # Runs from before the dives (the arrival cuts) have no dive (cut) time.
        totals = [sum(r.get(key, 0.0) for r in runs) for key in TIME_SPLIT]
        shares = " | ".join(f"{100 * t / sum(totals):.0f} %" for t in totals)
        lines.append(f"| {size} | {shares} | {statistics.median(r['nodes'] for r in runs):g} | "
                     f"{statistics.median(r['columns'] for r in runs):g} |")
    return "\n".join(lines)


def main(argv: list[str]) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--sizes", nargs="+", default=["2/4", "2/6", "3/6", "3/8", "4/10",
                                                        "5/12"])
    parser.add_argument("--per-size", type=int, default=5)
    parser.add_argument("--large-per-size", type=int, default=3,
                        help="instances per size from 8/20 up")
    parser.add_argument("--time-limit", type=float, default=600.0)
    parser.add_argument("--threads", type=int, default=1)
    parser.add_argument("--jobs", type=int, default=1, help="runs side by side")
    parser.add_argument("--methods", nargs="+", default=list(BACKENDS))
    parser.add_argument("--cache", type=Path, default=None,
                        help="JSON lines of finished runs, read and extended")
    parser.add_argument("--report-only", action="store_true",
                        help="write the report from --cache without running what it lacks")
    parser.add_argument("--out", type=Path, default=ROOT / "reports" / "exact-scaling.md")
    args = parser.parse_args(argv)
    methods = tuple(args.methods)
    keys = [(size, seed, method) for size in args.sizes
            for seed in range(1, (args.large_per_size if size in LARGE else args.per_size) + 1)
            for method in methods]
    if args.report_only:
        if args.cache is None:
            parser.error("--report-only needs --cache")
        done = _cached(args.cache)
        rows = [done[key] for key in (_key(*k, args.time_limit, args.threads) for k in keys)
                if key in done]
    else:
        rows = run(keys, args.time_limit, args.threads, args.jobs, args.cache)
    small = [size for size in args.sizes if size not in LARGE]
    large = [size for size in args.sizes if size in LARGE]
    command = shown_command(shlex.join(["python", "benchmarks/exact_scaling.py", *argv]), ROOT)
    commits = sorted({r.get("commit", "unknown") for r in rows})
    text = [
        "# Exact backends: time to proven optimality and final gap",
        "",
        f"Command: `{command}`  ",
        f"Machine: {platform.machine()}, {os.cpu_count()} cores ({platform.python_version()}), "
        f"{args.threads} thread(s) per solve, time limit {args.time_limit:g} s, "
        f"{args.per_size} instances per size (generator seeds 1..{args.per_size}; "
        f"1..{args.large_per_size} from 8/20 up). Measured at commit(s) {', '.join(commits)}.",
        "",
        table(rows, small, args.time_limit, methods),
        "",
        NOTES,
    ]
    known = library_best({(r["size"], r["seed"]) for r in rows})
    best_known = ("the best-known J: the lowest any backend found or started from, or the "
                  "library's (`best_J` of instances/paper-mc, `tsac-bench bks show`) where "
                  "lower")
    if small:
        text += ["", f"Root bound as a share of {best_known}:", "",
                 bound_table(rows, small, methods, "root", known)]
    if large:
        text += ["", f"From 8/20 up: the lower bound after {args.time_limit:g} s as a share of "
                 f"{best_known}:", "",
                 bound_table(rows, large, methods, "lower_bound", known)]
    if any(r["method"] == "exact-bp" for r in rows):
        text += ["", "Where exact-bp's time goes (shares of its total time per size):", "",
                 time_split_table(rows, args.sizes)]
    text += [
        "",
        "Runs:",
        "",
        "| size | seed | backend | status | J | lower bound | gap | time (s) | start J | "
        "root bound | commit |",
        "|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for r in rows:
        bound = "-" if r["lower_bound"] is None else f"{r['lower_bound']:.6f}"
        gap = "-" if r["gap"] is None else f"{100 * r['gap']:.3f} %"
        start = "-" if r["greedy"] is None else f"{r['greedy']:.6f}"
        text.append(f"| {r['size']} | {r['seed']} | {r['method']} | {r['status']} | "
                    f"{r['J']:.6f} | {bound} | {gap} | {r['wall']:.1f} | {start} | "
                    + ("-" if r["root"] is None else f"{r['root']:.6f}")
                    + f" | {r.get('commit', 'unknown')} |")
    args.out.write_text("\n".join(text) + "\n")


if __name__ == "__main__":
    main(sys.argv[1:])
