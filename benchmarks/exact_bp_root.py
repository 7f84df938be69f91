"""Root bounds of exact-bp's route master against the MILP's LP relaxations, as % of J*.

    python benchmarks/exact_bp_root.py --sizes 2-6 3-5 3-6 4-10

Instances: the regression set (instances/regression, J* proven by both compact backends)
whose name has one of the given ``AAVs-tasks`` sizes. Columns: the MILP's LP with big-M time
rows only, with arrival times on the arcs ("arc-flow"), the default MILP's LP (cover cuts
too); the route master of exact-bp after column generation to convergence (exact pricing)
with the per-AAV time rows only, with the closer rows too, with the coalition cover cuts as
well, with the goods-time rows as well, and with the arrival cuts as well (exact-bp's
root). Writes the
table to stdout and to ``--out`` (the table of docs/formulations.md, "exact-bp").
"""

from __future__ import annotations

import argparse
import json
import shlex
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))

from exact_root_bounds import root_bound

from tsac_bench.formulations.branch_price import BranchPrice, BranchPriceOptions
from tsac_bench.model.io import read_instance
from tsac_bench.reporting.report import shown_command

ROOT = Path(__file__).resolve().parent.parent
REGRESSION = ROOT / "instances" / "regression"


def _root(instance, **options) -> dict[str, float]:
    """exact-bp's root with ``options`` (BranchPriceOptions fields), the others default."""
    return BranchPrice(instance, options=BranchPriceOptions(**options)).root()


def main(argv: list[str]) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--sizes", nargs="+", default=["2-6", "3-5", "3-6"])
    parser.add_argument("--out", type=Path, default=ROOT / "reports" / "exact-bp-root.md")
    args = parser.parse_args(argv)
    manifest = json.loads((REGRESSION / "manifest.json").read_text())["instances"]
    lines = ["| instance | J* | big-M LP | arc-flow LP | default MILP LP | route master, "
             "per-AAV time rows | + closer rows | + cover cuts | + goods-time rows | + arrival "
             "cuts (exact-bp root) | columns | root seconds |",
             "|---|---|---|---|---|---|---|---|---|---|---|---|"]
    for name, entry in sorted(manifest.items()):
        if not any(f"-{size}-" in name for size in args.sizes):
            continue
        instance = read_instance(REGRESSION / entry["file"])
        J_star = entry["J_star"]
        milp = [root_bound(instance, v, 0)[0] for v in ("big-M", "time flow", "default")]
        plain = _root(instance, closer_rows=False, cover_cuts=False, goods_time_rows=False,
                      arrival_cut_rounds=0)
        closer = _root(instance, cover_cuts=False, goods_time_rows=False, arrival_cut_rounds=0)
        cuts = _root(instance, goods_time_rows=False, arrival_cut_rounds=0)
        goods = _root(instance, arrival_cut_rounds=0)
        full = _root(instance)
        bounds = [*milp, plain["lp"], closer["lp"], cuts["lp"], goods["lp"], full["lp"]]
        row = (f"| {name} | {J_star:.4f} | "
               + " | ".join(f"{100 * b / J_star:.1f}" for b in bounds)
               + f" | {full['columns']} | {full['seconds']:.1f} |")
        print(row, flush=True)
        lines.append(row)
    command = shown_command(shlex.join(["python", "benchmarks/exact_bp_root.py", *argv]), ROOT)
    args.out.write_text("\n".join([
        "# Root bounds of exact-bp's route master (% of J*)", "", f"Command: `{command}`", "",
        *lines, ""]))


if __name__ == "__main__":
    main(sys.argv[1:])
