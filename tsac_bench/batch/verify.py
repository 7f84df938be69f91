"""Proven optima of instance directories: ``manifest.json`` (``tsac-bench/manifest@1``).

``prove`` solves every instance of a directory with both exact backends and records J* where
both prove optimality and agree; ``verify`` re-solves and compares with the manifest (what
``tsac-bench verify DIR`` runs).
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from tsac_bench.batch.manifests import (
    Manifest,
    iter_instance_files,
    read_manifest,
    write_manifest,
)
from tsac_bench.model.evaluator import cost_at_least, costs_agree
from tsac_bench.planning import exact_methods

#: Solver stats copied into the manifest (wall times are informative only).
RECORDED = ("status", "J", "lower_bound", "mip_gap", "solver", "solver_version", "threads",
            "seed", "wall_time", "stop_reason")


def solve_exact(path: Path, method: str, time_limit: float | None, threads: int = 1,
                seed: int = 0) -> dict[str, Any]:
    """One exact backend on one instance file; the stats of its PlanResult plus J."""
    from tsac_bench.model.io import read_instance
    from tsac_bench.planning.solve import solve

    instance = read_instance(path)
    outcome = solve(instance, method, seed=seed, time_limit=time_limit,
                    settings={"threads": threads})
    stats = {k: outcome.stats.get(k) for k in RECORDED}
    stats["J"] = outcome.cost
    return stats


def entry_from(results: dict[str, dict[str, Any]], file: str, command: str) -> dict[str, Any]:
    """The manifest entry of one instance from each backend's stats."""
    optimal = [r for r in results.values() if r["status"] == "optimal"]
    proven = len(optimal) == len(results) and all(costs_agree(r["J"], optimal[0]["J"])
                                                  for r in optimal)
    best = min(r["J"] for r in results.values())
    bounds = [r["lower_bound"] for r in results.values() if r["lower_bound"] is not None]
    # HiGHS's bound is exact; CP-SAT's is for its scaled model less the scaling slack.
    bound = min(best, max(bounds)) if bounds else -math.inf
    return {
        "file": file,
        "J_star": min(r["J"] for r in optimal) if proven else None,
        "lower_bound": min(best, bound) if not proven else min(r["J"] for r in optimal),
        "status": "optimal" if proven else "feasible",
        "mip_gap": 0.0 if proven else max(0.0, best - bound) / max(abs(best), 1e-10),
        "best_J": best,
        "solvers": results,
        "command": command,
    }


def prove(directory: Path, time_limit: float, command: str, threads: int = 1,
          names: Iterable[str] | None = None, log: Any = print) -> Manifest:
    """Solve every instance of ``directory`` with every exact method and write the manifest
    (entries of instances not solved this time are kept)."""
    from tsac_bench.model.io import read_instance

    manifest = read_manifest(directory)
    if manifest.path.exists():
        manifest.require_valid()
    wanted = set(names) if names is not None else None
    for file in iter_instance_files([directory]):
        name = read_instance(file).name
        if wanted is not None and name not in wanted:
            continue
        results = {m: solve_exact(file, m, time_limit, threads) for m in exact_methods()}
        entry = entry_from(results, file.name, command)
        manifest.entries[name] = entry
        log(f"{name}: {entry['status']} J*={entry['J_star']} LB={entry['lower_bound']:.6f} "
            + " ".join(f"{m}={r['status']}/{r['wall_time']:.1f}s" for m, r in results.items()))
        write_manifest(manifest)
    return manifest


@dataclass(frozen=True)
class Check:
    instance: str
    method: str
    J_star: float | None
    J: float
    lower_bound: float | None
    status: str
    wall_time: float
    passed: bool
    reason: str


def verify(directory: Path, methods: Sequence[str] | None = None,
           time_limit: float | None = None, names: Iterable[str] | None = None,
           threads: int = 1) -> list[Check]:
    """Re-solve the manifest's instances: an optimal J* must be matched (and proved again,
    unless the time limit stops the solver, in which case J* must lie in [LB, J]); an open
    entry's best known bound must not exceed the new J. ``methods``: every installed method
    that proves optimality when None."""
    manifest = read_manifest(directory).require_valid()
    methods = exact_methods() if methods is None else methods
    wanted = set(names) if names is not None else None
    checks = []
    for name, entry in manifest.entries.items():
        if wanted is not None and name not in wanted:
            continue
        for method in methods:
            r = solve_exact(directory / entry["file"], method, time_limit, threads)
            J, bound, status = r["J"], r["lower_bound"], r["status"]
            J_star = entry["J_star"]
            if status == "error":
                passed, reason = False, f"solver error: {r['stop_reason']}"
            elif J_star is None:
                passed = cost_at_least(J, entry["lower_bound"])
                reason = "" if passed else f"J {J} below the recorded bound"
            elif status == "optimal":
                passed = costs_agree(J, J_star)
                reason = "" if passed else f"optimum {J} != J* {J_star}"
            else:
                passed = cost_at_least(J, J_star) and (
                    bound is None or cost_at_least(J_star, bound))
                reason = "" if passed else "J* outside [LB, J]"
            checks.append(Check(name, method, J_star, J, bound, status, r["wall_time"],
                                passed, reason))
    return checks
