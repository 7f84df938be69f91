"""Make the regression set (instances/regression/) and prove its optima.

    python benchmarks/exact_regression.py make                 # write the instances
    python benchmarks/exact_regression.py prove instances/regression --time-limit 300
    python benchmarks/exact_regression.py prove instances/quick --time-limit 600

``make`` is deterministic (fixed seeds of the paper's scenario generator); ``prove`` solves
each instance with ``exact`` (HiGHS) and ``exact-cpsat`` and writes ``manifest.json``: J* where
both prove optimality and agree to 1e-6, otherwise the best J and bound ("feasible").
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from tsac_bench.batch.verify import prove
from tsac_bench.model.generator import ScenarioGenerator
from tsac_bench.model.io import write_instance

ROOT = Path(__file__).resolve().parent.parent
#: (AAVs, tasks, seeds): static instances (all tasks at t = 0) and instances with releases.
STATIC = [(2, 4, (1, 2, 3)), (2, 5, (1, 2, 3)), (2, 6, (1, 2, 3)), (3, 5, (1, 2)),
          (3, 6, (1, 2))]
RELEASES = [(2, 4, (11, 12, 13)), (2, 5, (11, 12, 13)), (2, 6, (11, 12)), (3, 5, (11, 12)),
            (3, 6, (11, 12))]


def make(out: Path) -> None:
    out.mkdir(parents=True, exist_ok=True)
    for share, kind, table in ((0.0, "static", STATIC), (0.5, "release", RELEASES)):
        generator = ScenarioGenerator(dynamic_share=share)
        for n, m, seeds in table:
            for seed in seeds:
                name = f"reg-{kind}-{n}-{m}-s{seed}"
                write_instance(generator.generate(n, m, seed, name=name), out / f"{name}.json")
                print("wrote", name)


def main(argv: list[str]) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    sub = parser.add_subparsers(dest="command", required=True)
    make_cmd = sub.add_parser("make")
    make_cmd.add_argument("--out", type=Path, default=ROOT / "instances" / "regression")
    prove_cmd = sub.add_parser("prove")
    prove_cmd.add_argument("directory", type=Path)
    prove_cmd.add_argument("--time-limit", type=float, default=300.0)
    prove_cmd.add_argument("--threads", type=int, default=1)
    prove_cmd.add_argument("--only", nargs="*", default=None)
    args = parser.parse_args(argv)
    if args.command == "make":
        make(args.out)
    else:
        command = (f"python benchmarks/exact_regression.py prove {args.directory} "
                   f"--time-limit {args.time_limit:g} --threads {args.threads}")
        prove(args.directory, args.time_limit, command, args.threads, args.only)


if __name__ == "__main__":
    main(sys.argv[1:])
