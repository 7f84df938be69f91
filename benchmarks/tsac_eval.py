"""TSAC-OCF against HOCF and ROCF on held-out generated instances, dynamic mode (issue 6).

Mean and median J (the evaluator's, of the executed routes) per scale and method, the
reduction of TSAC-OCF's mean J against HOCF's (the paper: 39.76 % at 32/80), and per-instance
wins. Every row states its start (``init``) and games per plan call (``samples``): the OCF
methods share their defaults (``solvers/ocf/engine.py``), so a comparison is on equal footing
unless a row says otherwise. Extra rows: the sampled actors of policy files (``--ablation``;
the ``tsac-ocf`` row decodes the shipped policy by its default, ``margin``), any method
spec (``--row``, e.g. ``tsac-ocf:decode=margin``), the "incumbent" start
(``--incumbent-rows``), sampling temperatures (``--temperatures``), the noise control
(``--noise-control SHARE``: HOCF deviating to a uniformly drawn candidate in that share of
its decisions, what a policy that follows HOCF elsewhere gains by deviating at random).
Run by hand:
    python benchmarks/tsac_eval.py [--instances 10] [--first-seed 900000] [--policy FILE]
        [--jobs N]
With ``--jobs N`` the instances of a row run in N processes, each pinned to a core of its
own (one core each, as a plan call is timed); without, the script pins itself to one core.
Writes reports/tsac-eval-default.md (or ``--out``). Held-out instances: generator seeds
first-seed .. first-seed + instances - 1 (training draws its instance seeds from a generator
seeded by the training seed; a collision with this range is a 1-in-10^5 event per instance).
Method seed 0.
"""

from __future__ import annotations

import argparse
import multiprocessing
import os
import platform
import shlex
import statistics
import time
from collections.abc import Callable, Iterator
from concurrent.futures import ProcessPoolExecutor
from itertools import repeat
from pathlib import Path

import numpy as np
from paper_reproduction import instance_files

from tsac_bench.model import Instance
from tsac_bench.model.generator import generate
from tsac_bench.model.io import read_instance
from tsac_bench.planning import PlanningState, make_allocator
from tsac_bench.planning.solve import solve
from tsac_bench.reporting.stats import normal_half_width
from tsac_bench.solvers.ocf.engine import INIT, SAMPLES, DecisionView, SelectionRule
from tsac_bench.solvers.ocf.hocf import HOCFAllocator
from tsac_bench.solvers.ocf.rocf import UniformSelection

SCALES = ("16/40", "32/80")
#: DGA's start at a re-plan: half its population from the plan in force (solvers/dga.py).
DGA_START = "half from the plan in force, 1"


BASELINES = ("hocf", "rocf", "dga")


class RandomDeviation:
    """HOCF's choice, or with probability ``share`` ROCF's (a candidate drawn uniformly,
    from the rule's own stream, so the AAV orders stay HOCF's)."""

    def __init__(self, hocf: SelectionRule, share: float) -> None:
        self.hocf, self.share = hocf, share
        self.uniform = UniformSelection()

    def select(self, view: DecisionView, rng: np.random.Generator) -> int:
        rule = self.uniform if rng.random() < self.share else self.hocf
        return rule.select(view, rng)


class NoiseControl(HOCFAllocator):
    """The noise control of a learned policy: a policy that takes HOCF's choice in all but
    a share of its decisions gains from where it deviates only what it gains beyond this
    row's random deviations at that share."""

    def __init__(self, share: float, init: str = INIT, samples: int = SAMPLES) -> None:
        super().__init__(init=init, samples=samples)
        self.share = share

    def rule(self, state: PlanningState) -> SelectionRule:
        return RandomDeviation(super().rule(state), self.share)


def variants(policy: str | None, ablations: list[str], *, incumbent: bool,
             temperatures: bool, baselines: tuple[str, ...] = BASELINES,
             noise: tuple[float, ...] = (), specs: tuple[str, ...] = ()
             ) -> list[tuple[str, str | HOCFAllocator, dict]]:
    tsac = {"policy": policy} if policy else {}
    rows = [*((name, name, {}) for name in baselines), ("tsac-ocf", "tsac-ocf", tsac)]
    if temperatures:
        sampled = {**tsac, "decode": "sample"}
        rows += [("tsac-ocf T=0.5", "tsac-ocf", {**sampled, "temperature": 0.5}),
                 ("tsac-ocf T=0 (argmax)", "tsac-ocf", {**sampled, "temperature": 0.0})]
    for item in ablations:
        label, _, path = item.partition("=")
        rows.append((label, "tsac-ocf", {"policy": path, "decode": "sample"}))
    for item in specs:
        label, _, spec = item.partition("=")
        rows.append((label, spec, {}))
    if incumbent:
        rows += [("hocf init=incumbent", "hocf", {"init": "incumbent"}),
                 ("tsac-ocf init=incumbent", "tsac-ocf", {**tsac, "init": "incumbent"})]
    rows += [(f"hocf, {share:g} random", NoiseControl(share), {}) for share in noise]
    return rows


def footing(method: str | HOCFAllocator, settings: dict) -> str:
    """The row's start and games per plan call, as the method will run them (an OCF game's
    settings; other methods plan from scratch each call)."""
    allocator = make_allocator(method, **settings) if isinstance(method, str) else method
    resolved = allocator.settings()
    if "init" not in resolved:
        return DGA_START
    return f"{resolved['init']}, {resolved['samples']}"


def paired_rows(scale: str, costs: dict[str, list[float]], reference: str) -> list[str]:
    """Table rows of every row's per-instance difference in J from ``reference``'s."""
    base = costs[reference]
    rows = []
    for label, values in costs.items():
        if label == reference:
            continue
        diffs = [v - b for v, b in zip(values, base, strict=True)]
        mean = statistics.fmean(diffs)
        half = normal_half_width(diffs)
        rows.append(f"| {scale} | {label} | {mean:+.2f} | [{mean - half:+.2f}, "
                    f"{mean + half:+.2f}] | {100 * mean / statistics.fmean(base):+.1f} % | "
                    f"{sum(d < 0 for d in diffs)} / {sum(d > 0 for d in diffs)} |")
    return rows


#: One dynamic run: (J, wall time of the run, its longest plan call, its plan calls whose
#: stop was not "stable": an OCF game's budget stops).
RunRecord = tuple[float, float, float, int]


#: The rows this process has run once untimed: the first plan call of a process loads what
#: the method needs (torch, a policy file), a cost paid once, not per plan call.
_warmed: set[str] = set()


def dynamic_run(label: str, instance: Instance, method: str | HOCFAllocator,
                settings: dict) -> RunRecord:
    if label not in _warmed:
        solve(instance, method, seed=0, mode="dynamic", settings=settings)
        _warmed.add(label)
    began = time.perf_counter()
    outcome = solve(instance, method, seed=0, mode="dynamic", settings=settings)
    wall = time.perf_counter() - began
    replans = outcome.stats["replans"]
    unstable = sum(r["stats"]["stop"] != "stable" for r in replans)
    return outcome.cost, wall, max(r["wall_time"] for r in replans), unstable


def _pin_to_own_core(cores: multiprocessing.Queue) -> None:
    os.sched_setaffinity(0, {cores.get()})


def runner(jobs: int) -> tuple[Callable[..., Iterator], Callable[[], None]]:
    """(a ``map`` that keeps the order, close): the built-in one (``jobs`` 1), or that of
    ``jobs`` worker processes pinned to a core each (at most the cores this process may
    use)."""
    if jobs == 1:
        return map, lambda: None
    context = multiprocessing.get_context("spawn")
    queue = context.Queue()
    for core in sorted(os.sched_getaffinity(0))[:jobs]:
        queue.put(core)
    pool = ProcessPoolExecutor(jobs, mp_context=context, initializer=_pin_to_own_core,
                               initargs=(queue,))
    return pool.map, pool.shutdown


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--instances", type=int, default=10)
    parser.add_argument("--first-seed", type=int, default=900_000)
    parser.add_argument("--paper-mc", action="store_true",
                        help="the first --instances files of instances/paper-mc/ per scale "
                             "instead of generated seeds from --first-seed")
    parser.add_argument("--policy", default=None, help="policy file (default: shipped)")
    parser.add_argument("--scales", nargs="+", default=list(SCALES))
    parser.add_argument("--ablation", action="append", default=[], metavar="LABEL=FILE",
                        help="an extra tsac-ocf row: the actor of a policy file, sampled")
    parser.add_argument("--row", action="append", default=[], metavar="LABEL=SPEC",
                        help="an extra row: a method spec NAME[:KEY=VALUE...]")
    parser.add_argument("--incumbent-rows", action="store_true",
                        help="add hocf and tsac-ocf rows started from the incumbent plan")
    parser.add_argument("--temperatures", action="store_true",
                        help="add tsac-ocf rows sampled at T = 0.5 and T = 0")
    parser.add_argument("--noise-control", type=float, action="append", default=[],
                        metavar="SHARE", help="add a row of HOCF that deviates to a uniformly "
                        "drawn candidate in this share of its decisions (repeatable)")
    parser.add_argument("--baselines", nargs="+", choices=BASELINES, default=list(BASELINES),
                        help="the baseline rows; hocf, the reference of every row, always")
    parser.add_argument("--paired", metavar="LABEL", action="append", default=[],
                        help="add a table of every other row's per-instance difference in J "
                             "from this row's (mean, 95 %% interval, instances lower/higher); "
                             "repeatable, a table per reference row")
    parser.add_argument("--jobs", type=int, default=1,
                        help="worker processes, each pinned to a core of its own")
    parser.add_argument("--out", type=Path, default=Path("reports/tsac-eval-default.md"))
    args = parser.parse_args()
    if not 1 <= args.jobs <= len(os.sched_getaffinity(0)):
        parser.error(f"--jobs: from 1 to the {len(os.sched_getaffinity(0))} cores to pin "
                     "workers to")
    if "hocf" not in args.baselines:
        parser.error("--baselines: hocf is the reference of every row; keep it")
    baselines = tuple(args.baselines)
    labels = [label for label, _, _ in variants(
        args.policy, args.ablation, incumbent=args.incumbent_rows,
        temperatures=args.temperatures, baselines=baselines,
        noise=tuple(args.noise_control), specs=tuple(args.row))]
    for reference in args.paired:
        if reference not in labels:
            parser.error(f"--paired: no row {reference!r}; the rows: {', '.join(labels)}")
    if args.jobs == 1 and hasattr(os, "sched_setaffinity"):
        os.sched_setaffinity(0, {min(os.sched_getaffinity(0))})
    mapped, close = runner(args.jobs)
    seeds = range(args.first_seed, args.first_seed + args.instances)
    source = " --paper-mc" if args.paper_mc else f" --first-seed {args.first_seed}"
    command = (f"python benchmarks/tsac_eval.py --instances {args.instances}{source}"
               + (f" --policy {args.policy}" if args.policy else "")
               + f" --scales {' '.join(args.scales)}"
               + ("" if baselines == BASELINES else f" --baselines {' '.join(baselines)}")
               + "".join(f" --ablation {shlex.quote(a)}" for a in args.ablation)
               + "".join(f" --row {shlex.quote(r)}" for r in args.row)
               + (" --incumbent-rows" if args.incumbent_rows else "")
               + (" --temperatures" if args.temperatures else "")
               + "".join(f" --noise-control {share:g}" for share in args.noise_control)
               + "".join(f" --paired {shlex.quote(p)}" for p in args.paired)
               + (f" --jobs {args.jobs}" if args.jobs > 1 else ""))
    names = [name.upper() for name in baselines]
    against = " and ".join(filter(None, [", ".join(names[:-1]), names[-1]]))
    lines = [
        f"# TSAC-OCF against {against} (dynamic mode, held-out instances)",
        "",
        f"Command: `{command}`  ",
        f"Machine: {platform.processor() or platform.machine()}, Python "
        f"{platform.python_version()}, "
        + (f"{args.jobs} processes, each pinned to a core of its own" if args.jobs > 1
           else "pinned to one core")
        + " (shared with other work: wall times are indicative only). "
        + (f"Instances: the first {args.instances} of `instances/paper-mc/` per scale "
           "(generator seeds 0.."
           f"{args.instances - 1}; training draws its instance seeds uniformly below 2^31, so "
           "an episode meets one of these with odds of about 1 in 10^7)" if args.paper_mc else
           f"Generated instances (default generator), seeds {seeds.start}..{seeds.stop - 1}")
        + "; method seed 0; dynamic mode (plan at t = 0, "
        "re-plan at each release event); J is the evaluator's J of the executed routes. "
        "Budget of every OCF plan call: no time limit, k_max 200000 decisions, "
        "c_max 5000 consecutive rejections"
        + (" (DGA: its own generations, no time limit)" if "dga" in baselines else "")
        + "; `start, games` is the structure each plan call starts from (`init`) and the games "
        "it plays (`samples`).",
        "",
        "| scale | method | start, games | mean J | median J | mean wall (s) | "
        "longest plan call (s) | vs HOCF (mean J) | instances below HOCF |",
        "|---|---|---|---:|---:|---:|---:|---:|---:|",
    ]
    unstable = 0
    paired_lines: dict[str, list[str]] = {reference: [] for reference in args.paired}
    for scale in args.scales:
        instances = ([read_instance(path) for path in instance_files(scale, args.instances)]
                     if args.paper_mc else [generate(scale, seed) for seed in seeds])
        costs: dict[str, list[float]] = {}
        walls: dict[str, list[float]] = {}
        longest: dict[str, float] = {}
        rows = variants(args.policy, args.ablation, incumbent=args.incumbent_rows,
                        temperatures=args.temperatures, baselines=baselines,
                        noise=tuple(args.noise_control), specs=tuple(args.row))
        starts = {label: footing(method, settings) for label, method, settings in rows}
        for label, method, settings in rows:
            records = list(mapped(dynamic_run, repeat(label), instances, repeat(method),
                                  repeat(settings)))
            costs[label] = [cost for cost, _, _, _ in records]
            walls[label] = [wall for _, wall, _, _ in records]
            longest[label] = max(call for _, _, call, _ in records)
            if starts[label] != DGA_START:
                unstable += sum(stops for _, _, _, stops in records)
            print(f"{scale} {label}: mean J {statistics.fmean(costs[label]):.2f}", flush=True)
        hocf = costs["hocf"]
        for label, values in costs.items():
            mean = statistics.fmean(values)
            reduction = (statistics.fmean(hocf) - mean) / statistics.fmean(hocf)
            below = sum(v < h for v, h in zip(values, hocf, strict=True))
            lines.append(f"| {scale} | {label} | {starts[label]} | {mean:.2f} | "
                         f"{statistics.median(values):.2f} "
                         f"| {statistics.fmean(walls[label]):.2f} | {longest[label]:.2f} "
                         f"| {100 * reduction:+.1f} % "
                         f"| {below}/{len(values)} |")
        for reference, table in paired_lines.items():
            table += paired_rows(scale, costs, reference)
    lines += ["", "`vs HOCF` is (mean J(HOCF) - mean J(method)) / mean J(HOCF): positive means "
              "lower cost than HOCF (the paper reports +39.76 % for TSAC-OCF at 32/80).",
              "OCF plan calls that stopped on a budget rather than a stable structure: "
              f"{unstable}.",
              ""]
    for reference, table in paired_lines.items():
        lines += [f"Paired against `{reference}` (same instances): the difference "
                  "d = J(row) - J(reference) per instance; its mean with a 95 % interval "
                  "(mean +- 1.96 standard errors, normal approximation), the mean as a share of "
                  "the reference's mean J, and the instances where the row is lower / higher "
                  "(negative d: lower cost than the reference).",
                  "",
                  "| scale | row | mean d | 95 % interval | mean d / mean J(reference) | "
                  "lower / higher |",
                  "|---|---|---:|---:|---:|---:|",
                  *table, ""]
    close()
    args.out.write_text("\n".join(lines))
    print("\n".join(lines))


if __name__ == "__main__":
    main()
