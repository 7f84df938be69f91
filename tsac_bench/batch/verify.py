"""Proven optima of instance directories: ``manifest.json`` (``tsac-bench/manifest@1``).

``prove`` solves every instance of a directory with both exact backends and records J* where
both prove optimality and agree; ``verify`` re-solves and compares with the manifest (what
``tsac-bench verify DIR`` runs).
"""

from __future__ import annotations

import json
import math
from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from tsac_bench.errors import InputError
from tsac_bench.planning import exact_methods

MANIFEST_FORMAT = "tsac-bench/manifest@1"
MANIFEST = "manifest.json"
#: Two J values agree when they differ by at most this, relative to max(1, |J|).
AGREEMENT = 1e-6

#: Solver stats copied into the manifest (wall times are informative only).
RECORDED = ("status", "J", "lower_bound", "mip_gap", "solver", "solver_version", "threads",
            "seed", "wall_time", "stop_reason")


def agree(a: float, b: float, tolerance: float = AGREEMENT) -> bool:
    return abs(a - b) <= tolerance * max(1.0, abs(a), abs(b))


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


def read_manifest(directory: Path) -> dict[str, Any]:
    path = directory / MANIFEST
    try:
        data = json.loads(path.read_text())
    except FileNotFoundError:
        raise InputError(str(path), None, "no manifest in this directory") from None
    except json.JSONDecodeError as exc:
        raise InputError(str(path), None, f"not JSON: {exc}") from None
    if not isinstance(data, dict) or data.get("format") != MANIFEST_FORMAT:
        raise InputError(str(path), "format", f"must be {MANIFEST_FORMAT!r}")
    if not isinstance(data.get("instances"), dict):
        raise InputError(str(path), "instances", "must be an object keyed by instance name")
    for name, entry in data["instances"].items():
        for key in ("file", "J_star", "lower_bound", "status"):
            if not isinstance(entry, dict) or key not in entry:
                raise InputError(str(path), f"instances.{name}.{key}", "missing")
    return data


def entry_from(results: dict[str, dict[str, Any]], file: str, command: str) -> dict[str, Any]:
    """The manifest entry of one instance from each backend's stats."""
    optimal = [r for r in results.values() if r["status"] == "optimal"]
    proven = len(optimal) == len(results) and all(agree(r["J"], optimal[0]["J"])
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
          names: Iterable[str] | None = None, log: Any = print) -> dict[str, Any]:
    """Solve every instance of ``directory`` with every exact method and write the manifest
    (entries of instances not solved this time are kept)."""
    from tsac_bench.model.io import iter_instance_files, read_instance

    path = directory / MANIFEST
    manifest = read_manifest(directory) if path.exists() else {
        "format": MANIFEST_FORMAT, "instances": {}}
    wanted = set(names) if names is not None else None
    for file in iter_instance_files([directory]):
        name = read_instance(file).name
        if wanted is not None and name not in wanted:
            continue
        results = {m: solve_exact(file, m, time_limit, threads) for m in exact_methods()}
        entry = entry_from(results, file.name, command)
        manifest["instances"][name] = entry
        log(f"{name}: {entry['status']} J*={entry['J_star']} LB={entry['lower_bound']:.6f} "
            + " ".join(f"{m}={r['status']}/{r['wall_time']:.1f}s" for m, r in results.items()))
        path.write_text(json.dumps(manifest, indent=1, sort_keys=False) + "\n")
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
    manifest = read_manifest(directory)
    methods = exact_methods() if methods is None else methods
    wanted = set(names) if names is not None else None
    checks = []
    for name, entry in manifest["instances"].items():
        if wanted is not None and name not in wanted:
            continue
        for method in methods:
            r = solve_exact(directory / entry["file"], method, time_limit, threads)
            J, bound, status = r["J"], r["lower_bound"], r["status"]
            J_star = entry["J_star"]
            if status == "error":
                passed, reason = False, f"solver error: {r['stop_reason']}"
            elif J_star is None:
                passed = entry["lower_bound"] - 1e-6 * max(1.0, abs(J)) <= J
                reason = "" if passed else f"J {J} below the recorded bound"
            elif status == "optimal":
                passed = agree(J, J_star)
                reason = "" if passed else f"optimum {J} != J* {J_star}"
            else:
                passed = J_star - 1e-6 * max(1.0, J_star) <= J and (
                    bound is None or bound <= J_star + 1e-6 * max(1.0, J_star))
                reason = "" if passed else "J* outside [LB, J]"
            checks.append(Check(name, method, J_star, J, bound, status, r["wall_time"],
                                passed, reason))
    return checks
