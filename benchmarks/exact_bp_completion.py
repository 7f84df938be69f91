"""exact-bp's root with and without completion bounds in its pricing, on validation
instances (generator seeds from 900000, apart from paper-mc).

    python benchmarks/exact_bp_completion.py --sizes 4/10:3 8/20:3 16/40:1 \
        --steps 0 128 512 --time-limit 300

Per instance and ``completion_steps`` (0: no completion bounds): the root LP's value, its
bound (the LP where column generation converged, else the Lagrangian bound), whether it
converged, the columns, the seconds, and the seconds of the relaxed and exact pricing
calls (the rounds the bounds are used in). Run one process on a core of its own: the
seconds are the result. Writes the table to stdout and to ``--out``.
"""

from __future__ import annotations

import argparse
import os
import platform
import shlex
import sys
import time
from pathlib import Path

from tsac_bench.formulations import pricing
from tsac_bench.formulations.branch_price import BranchPrice, BranchPriceOptions
from tsac_bench.model.generator import generate
from tsac_bench.reporting.report import shown_command

ROOT = Path(__file__).resolve().parent.parent
VALIDATION_SEED = 900000
HEADER = ["| instance | completion steps | root LP | bound | converged | columns | seconds "
          "| bounding pricing seconds |", "|---|---|---|---|---|---|---|---|"]


def _root(instance, steps: int, time_limit: float) -> tuple[dict, float]:
    """The root and the seconds spent in relaxed and exact pricing calls."""
    spent = [0.0]
    price = pricing.Pricer.price

    def timed(self, *args, **kwargs):
        began = time.perf_counter()
        try:
            return price(self, *args, **kwargs)
        finally:
            if not kwargs.get("label_cap"):
                spent[0] += time.perf_counter() - began

    pricing.Pricer.price = timed
    try:
        search = BranchPrice(instance, options=BranchPriceOptions(completion_steps=steps))
        return search.root(time_limit), spent[0]
    finally:
        pricing.Pricer.price = price


def main(argv: list[str]) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--sizes", nargs="+", default=["4/10:3", "8/20:3"],
                        help="SIZE:COUNT, the instances of each size")
    parser.add_argument("--steps", nargs="+", type=int, default=[0, 128])
    parser.add_argument("--time-limit", type=float, default=600.0)
    parser.add_argument("--out", type=Path,
                        default=ROOT / "reports" / "exact-bp-completion.md")
    args = parser.parse_args(argv)
    _root(generate("2/4", 1), 16, 10.0)  # compile the labelling outside the timings
    rows = []
    for spec in args.sizes:
        size, count = spec.split(":")
        for seed in range(VALIDATION_SEED, VALIDATION_SEED + int(count)):
            instance = generate(size, seed)
            for steps in args.steps:
                root, bounding = _root(instance, steps, args.time_limit)
                row = (f"| {size} seed {seed} | {steps or 'off'} | {root['lp']:.4f} "
                       f"| {root['bound']:.4f} | {'yes' if root['converged'] else 'no'} "
                       f"| {root['columns']} | {root['seconds']:.1f} | {bounding:.1f} |")
                print(row, flush=True)
                rows.append(row)
    command = shown_command(shlex.join(["python", "benchmarks/exact_bp_completion.py",
                                        *argv]), ROOT)
    args.out.write_text("\n".join([
        "# exact-bp's root with and without completion bounds (validation instances)", "",
        f"Command: `{command}`  ",
        f"Machine: {platform.machine()}, {os.cpu_count()} cores ({platform.python_version()}), "
        f"one process on a core of its own, time limit {args.time_limit:g} s per root.", "",
        *HEADER, *rows, ""]))


if __name__ == "__main__":
    main(sys.argv[1:])
