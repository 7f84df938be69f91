"""The exact-scaling benchmark's cache and tables (benchmarks/exact_scaling.py), on hand-made
runs."""

from __future__ import annotations

import sys
from pathlib import Path

import pytest

sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "benchmarks"))
import exact_scaling


def row(size: str, seed: int, method: str, J: float, bound: float | None, root: float | None,
        **extra: float) -> dict:
    return {"size": size, "seed": seed, "method": method, "time_limit": 600.0, "threads": 1,
            "status": "feasible", "J": J, "lower_bound": bound, "gap": None, "wall": 600.0,
            "greedy": 20.0, "root": root, "commit": "abc1234", **extra}


def test_a_cached_run_is_not_run_again_and_a_new_one_is_kept(tmp_path: Path,
                                                             monkeypatch: pytest.MonkeyPatch
                                                             ) -> None:
    cache = tmp_path / "runs.jsonl"
    solved = []

    def fake_solve(size: str, seed: int, method: str, time_limit: float, threads: int) -> dict:
        solved.append((size, seed, method))
        return row(size, seed, method, 10.0 + seed, 5.0, 4.0)

    monkeypatch.setattr(exact_scaling, "solve_one", fake_solve)
    first = exact_scaling.run([("3/8", 1, "exact-bp")], 600.0, 1, cache=cache)
    again = exact_scaling.run([("3/8", 1, "exact-bp"), ("3/8", 2, "exact-bp")], 600.0, 1,
                              cache=cache)
    assert solved == [("3/8", 1, "exact-bp"), ("3/8", 2, "exact-bp")]
    assert [r["J"] for r in first] == [11.0]
    assert [r["J"] for r in again] == [11.0, 12.0]
    assert len(cache.read_text().splitlines()) == 2
    # Another time limit is another run.
    exact_scaling.run([("3/8", 1, "exact-bp")], 60.0, 1, cache=cache)
    assert solved[-1] == ("3/8", 1, "exact-bp") and len(solved) == 3


def test_bounds_are_shares_of_the_best_plan_any_backend_found() -> None:
    rows = [row("8/20", 1, "exact", 30.0, 0.0, None),
            row("8/20", 1, "exact-bp", 16.0, 4.0, 2.0),
            row("8/20", 2, "exact-bp", 25.0, None, None)]
    # seed 1: best J min(30, 16, start 20) = 16; bounds 0/16 and 4/16. Seed 2: the start
    # (20) beats the run's J; exact did not run there and exact-bp has no bound.
    assert exact_scaling.bound_table(rows, ["8/20"], ("exact", "exact-bp"),
                                     "lower_bound").splitlines()[2:] == [
        "| 8/20 | 1 | 16.000000 | 0.0 % | 25.0 % |",
        "| 8/20 | 2 | 20.000000 | not run | - |",
    ]


def test_the_time_split_sums_each_part_over_the_instances_of_a_size() -> None:
    rows = [row("4/10", 1, "exact-bp", 10.0, 8.0, 7.0, pricing_time=50.0, lp_time=30.0,
                branching_time=10.0, other_time=10.0, nodes=10, columns=100),
            row("4/10", 2, "exact-bp", 10.0, 8.0, 7.0, pricing_time=250.0, lp_time=50.0,
                branching_time=0.0, dive_time=100.0, other_time=0.0, nodes=30, columns=300)]
    rows[1]["pricing_time"], rows[1]["cut_time"] = 150.0, 100.0
    # pricing 200 of 500 s, LP 80, cuts 100 and dives 100 (the first run has neither),
    # branching 10, other 10.
    assert exact_scaling.time_split_table(rows, ["4/10"]).splitlines()[2] == \
        "| 4/10 | 40 % | 16 % | 20 % | 2 % | 20 % | 2 % | 20 | 200 |"


def test_the_best_known_j_is_the_librarys_where_it_holds_the_same_instance_and_is_lower(
        tmp_path: Path) -> None:
    import json

    from tsac_bench.model.generator import generate
    from tsac_bench.model.io import write_instance

    directory = tmp_path / "3-8"
    directory.mkdir()
    write_instance(generate("3/8", 1), directory / "gen-3-8-s1.json")
    # Named as seed 2's instance but holding seed 1's: not the instance the benchmark solves.
    write_instance(generate("3/8", 1), directory / "gen-3-8-s2.json")
    entries = {f"gen-3-8-s{seed}": {"file": f"gen-3-8-s{seed}.json", "J_star": None,
                                    "lower_bound": None, "status": "feasible", "best_J": J}
               for seed, J in ((1, 12.5), (2, 1.0))}
    (directory / "manifest.json").write_text(json.dumps(
        {"format": "tsac-bench/manifest@1", "instances": entries}))
    known = exact_scaling.library_best({("3/8", 1), ("3/8", 2), ("3/8", 3)}, tmp_path)
    assert known == {("3/8", 1): 12.5}
    rows = [row("3/8", 1, "exact-bp", 16.0, 5.0, 4.0), row("3/8", 2, "exact-bp", 16.0, 5.0,
                                                             4.0)]
    # seed 1: the library's 12.5 is below the run's 16 and its start 20; 5/12.5 = 40 %.
    # Seed 2: the run's own 16 (5/16 = 31.25 %).
    assert exact_scaling.bound_table(rows, ["3/8"], ("exact-bp",), "lower_bound",
                                     known).splitlines()[2:] == [
        "| 3/8 | 1 | 12.500000 | 40.0 % |",
        "| 3/8 | 2 | 16.000000 | 31.2 % |",
    ]


def test_the_committed_pages_share_tables_follow_the_cache_and_the_library(
        tmp_path: Path) -> None:
    # The page's prose is kept by hand, so its tables are pasted from a --report-only run;
    # the library lowers best-known J under them. Paste the tables of this run when it fails.
    page = exact_scaling.ROOT / "reports" / "exact-scaling.md"
    command = page.read_text().split("Command: `", 1)[1].split("`", 1)[0]
    argv = command.split()[2:]
    argv[argv.index("--out") + 1] = str(tmp_path / "page.md")
    exact_scaling.main(argv)
    written = (tmp_path / "page.md").read_text().split("\n\n")
    tables = [block for block in written if block.startswith("| size | seed | best-known J |")]
    assert len(tables) == 2
    for table in tables:
        assert table in page.read_text()
