"""The best-known page (benchmarks/best_known_table.py): the committed page and CSV are what the
manifests give, and its summary numbers are the entries' own."""

from __future__ import annotations

import csv
import io
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "benchmarks"))
import best_known_table
import pytest

from tsac_bench.batch.manifests import read_manifest
from tsac_bench.formulations.network import canonical_routes
from tsac_bench.model.evaluator import CostEvaluator
from tsac_bench.model.io import read_instance, read_solution


def test_committed_page_and_table_are_the_manifests() -> None:
    rows = best_known_table.entries()
    assert best_known_table.PAGE.read_text() == best_known_table.page_text(rows), \
        "run `python benchmarks/best_known_table.py`: reports/best-known.md differs"
    assert best_known_table.TABLE.read_text() == best_known_table.csv_text(rows), \
        "run `python benchmarks/best_known_table.py`: reports/best-known.csv differs"


def test_every_paper_mc_entry_has_a_plan_and_a_bound_no_higher() -> None:
    rows = [row for row in best_known_table.entries() if row["set"].startswith("paper-mc/")]
    assert len(rows) == 400
    assert all(row["bound_kind"] != "none" for row in rows)
    assert all(row["lower_bound"] <= row["best_J"] * (1 + 1e-9) for row in rows)


def test_every_shipped_plan_is_in_canonical_form() -> None:
    # The library keeps each plan as take_plan stores it: late visits dropped and goods above
    # a demand cut, which lowered 112 of paper-mc's plans (up to 5.7 % at 32/80) when the
    # library first took them in that form.
    for name in best_known_table.SETS:
        directory = best_known_table.ROOT / "instances" / name
        for entry in read_manifest(directory).entries.values():
            if not entry.get("best_plan"):
                continue
            instance = read_instance(directory / entry["file"])
            routes = read_solution(directory / entry["best_plan"], instance).routes
            canonical = canonical_routes(instance, routes)
            assert CostEvaluator(instance).cost(canonical) == pytest.approx(
                entry["best_J"], rel=1e-12), f"{name}/{entry['file']}"


def _row(name: str, gap: float, kind: str, found_by: str) -> dict:
    best = 10.0
    return {"set": "s", "instance": name, "best_J": best, "lower_bound": best * (1 - gap),
            "gap": gap, "proved": kind == "proved", "bound_kind": kind, "found_by": found_by,
            "found_in": "run-a", "bound_by": None, "bound_in": None}


def test_page_counts_and_shares_are_the_rows() -> None:
    rows = [_row("a", 0.0, "proved", "exact-bp static"),
            _row("b", 0.2, "search", "dga static @ 30 s"),
            _row("c", 0.4, "search", "dga static @ 30 s"),
            _row("d", 0.9, "tasks-on-their-own", "hocf static @ 1 s")]
    page = best_known_table.page_text(rows, sets=("s",))
    # Shares of the two searched: 80 % and 60 %, median 70 %.
    assert ("| s | 4 | 1 | 2: 70.0 % (60.0-80.0) | 1: 10.0 % (10.0-10.0) | "
            "dga static @ 30 s 2; exact-bp static 1; hocf static @ 1 s 1 |") in page
    table = list(csv.DictReader(io.StringIO(best_known_table.csv_text(rows))))
    assert [r["lower_bound"] for r in table] == ["10.000000", "8.000000", "6.000000", "1.000000"]
    assert table[0]["proved"] == "True" and table[3]["bound_kind"] == "tasks-on-their-own"
