"""The best-known library as a page: per instance set, how many instances are proved, what
bounds the rest and how far from the best-known J, and which runs found the plans; beside it
every entry as CSV. Written from the sets' manifests only, so the page cannot drift from the
library (``tsac-bench bks update`` changes the manifests; this rewrites the page).

    python benchmarks/best_known_table.py            # write reports/best-known.md and .csv
    python benchmarks/best_known_table.py --check    # exit 1 where they differ from the manifests
"""

from __future__ import annotations

import argparse
import csv
import io
import statistics
import sys
from collections import Counter
from pathlib import Path

from generated_pages import sync

from tsac_bench.batch import best_known

ROOT = Path(__file__).resolve().parents[1]
SETS = ("quick", "paper", "regression", "paper-mc/4-10", "paper-mc/8-20", "paper-mc/16-40",
        "paper-mc/32-80")
PAGE = ROOT / "reports" / "best-known.md"
TABLE = PAGE.with_suffix(".csv")
COLUMNS = ("set", "instance", "best_J", "lower_bound", "gap", "proved", "bound_kind",
           "found_by", "found_in", "bound_by", "bound_in")
#: How many of a set's finders the page names; the rest are summed as "other".
FINDERS_SHOWN = 4


def entries() -> list[dict]:
    """Every entry of every set, a row per instance."""
    rows = []
    for name in SETS:
        for row in best_known.table(ROOT / "instances" / name):
            rows.append({"set": name, **row})
    return rows


def _number(value: float | None, digits: int = 6) -> str:
    return "" if value is None else f"{value:.{digits}f}"


def csv_text(rows: list[dict]) -> str:
    out = io.StringIO()
    writer = csv.writer(out, lineterminator="\n")
    writer.writerow(COLUMNS)
    for row in rows:
        writer.writerow([_number(row[c]) if isinstance(row[c], float) else
                         ("" if row[c] is None else row[c]) for c in COLUMNS])
    return out.getvalue()


def _shares(rows: list[dict]) -> str:
    """The bound as a share of the best J over ``rows``: median (least-most)."""
    shares = [100 * (1 - row["gap"]) for row in rows]
    if not shares:
        return "-"
    return f"{statistics.median(shares):.1f} % ({min(shares):.1f}-{max(shares):.1f})"


def _finders(rows: list[dict]) -> str:
    counts = Counter(row["found_by"] or "not recorded" for row in rows)
    shown = counts.most_common(FINDERS_SHOWN)
    rest = sum(counts.values()) - sum(n for _, n in shown)
    return "; ".join([f"{who} {n}" for who, n in shown] + ([f"other {rest}"] if rest else []))


def page_text(rows: list[dict], sets: tuple[str, ...] = SETS) -> str:
    lines = [
        "# Best-known solutions and bounds",
        "",
        "Written by `python benchmarks/best_known_table.py` from the instance sets' manifests "
        "(`instances/SET/manifest.json`, the library itself: docs/reports.md, \"Best-known "
        "solutions and bounds\"); every entry, with the job that found its plan and the one "
        "that proved its bound, is in [best-known.csv](best-known.csv). "
        "`tsac-bench verify DIR --plans-only` re-evaluates a set's plans.",
        "",
        "A bound's share is bound / best J of the instances not proved. A *search* bound is "
        "an exact method's after its time limit; *tasks-on-their-own* is the bound that needs "
        "no search (docs/formulations.md), far below the optimum at 8/20 and above, so gaps "
        "against it say little.",
        "",
        "| set | instances | proved | search bound: instances, share of best J | "
        "tasks-on-their-own only: instances, share | plans found by (most entries first) |",
        "|---|---:|---:|---|---|---|",
    ]
    for name in sets:
        mine = [row for row in rows if row["set"] == name]
        kinds = Counter(row["bound_kind"] for row in mine)
        search = [row for row in mine if row["bound_kind"] == "search"]
        alone = [row for row in mine if row["bound_kind"] == best_known.TASK_BOUND]
        lines.append(
            f"| {name} | {len(mine)} | {kinds['proved']} | {len(search)}: {_shares(search)} | "
            f"{len(alone)}: {_shares(alone)} | {_finders(mine)} |")
    unbounded = sum(row["bound_kind"] == "none" for row in rows)
    if unbounded:
        lines += ["", f"{unbounded} entries have no bound at all (`tsac-bench bks bound DIR`)."]
    return "\n".join(lines) + "\n"


def main(argv: list[str]) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--check", action="store_true",
                        help="change nothing; exit 1 if the page or table differs")
    args = parser.parse_args(argv)
    rows = entries()
    return sync(((PAGE, page_text(rows)), (TABLE, csv_text(rows))), args.check,
                "the manifests")


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
