"""Proven optima of instance directories: ``manifest.json`` (``tsac-bench/manifest@1``).

``prove`` solves every instance of a directory with the exact backends and records J* where
at least one proves optimality and every backend agrees with it (the provers on J*, the
others with a J no lower and a bound no higher); ``verify`` re-solves and compares with the
manifest (what ``tsac-bench verify DIR`` runs).
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from tsac_bench.batch.best_known import carried_over
from tsac_bench.batch.manifests import (
    Manifest,
    iter_instance_files,
    manifest_lock,
    read_manifest,
    write_manifest,
)
from tsac_bench.model.evaluator import cost_at_least, costs_agree
from tsac_bench.planning import PlanStatus, exact_methods

#: Solver stats copied into the manifest (wall times are informative only).
RECORDED = ("mip_gap", "solver", "solver_version", "threads", "seed", "wall_time",
            "stop_reason")


def solve_exact(path: Path, method: str, time_limit: float | None, threads: int = 1,
                seed: int = 0) -> dict[str, Any]:
    """One exact backend on one instance file, as a manifest records it: its status, J and
    lower bound, some of its stats (``RECORDED``) and the time limit it ran under."""
    from tsac_bench.model.io import read_instance
    from tsac_bench.planning.solve import solve

    instance = read_instance(path)
    outcome = solve(instance, method, seed=seed, time_limit=time_limit,
                    settings={"threads": threads})
    return {"status": outcome.status, "J": outcome.cost, "lower_bound": outcome.lower_bound,
            **{k: outcome.stats.get(k) for k in RECORDED}, "time_limit": time_limit}


def entry_from(results: dict[str, dict[str, Any]], file: str, command: str) -> dict[str, Any]:
    """The manifest entry of one instance from each backend's stats. J* needs one backend
    that proves it and no disagreement: the other provers reach the same J, and every
    backend's J is no lower and its bound no higher (status "conflict" otherwise: a defect
    of a backend, to be looked into)."""
    optimal = {m: r for m, r in results.items() if r["status"] == PlanStatus.OPTIMAL}
    best = min(r["J"] for r in results.values())
    J_star = min((r["J"] for r in optimal.values()), default=None)
    agreed = J_star is not None and all(costs_agree(r["J"], J_star) for r in optimal.values()) \
        and all(cost_at_least(r["J"], J_star) and (r["lower_bound"] is None
                                                   or cost_at_least(J_star, r["lower_bound"]))
                for r in results.values())
    bounds = [r["lower_bound"] for r in results.values() if r["lower_bound"] is not None]
    # HiGHS's bound is exact; CP-SAT's is for its scaled model less the scaling slack.
    bound = min(best, max(bounds)) if bounds else -math.inf
    status = "optimal" if agreed else ("conflict" if optimal else "feasible")
    return {
        "file": file,
        "J_star": J_star if agreed else None,
        "lower_bound": J_star if agreed else min(best, bound),
        "status": status,
        "mip_gap": 0.0 if agreed else max(0.0, best - bound) / max(abs(best), 1e-10),
        "best_J": best,
        "proved_by": sorted(optimal) if agreed else [],
        "solvers": results,
        "command": command,
    }


def _readable_manifest(directory: Path) -> Manifest:
    """``directory``'s manifest, the first problem of one that exists raised (an absent one
    is empty: ``prove`` writes its first content)."""
    manifest = read_manifest(directory)
    if manifest.path.exists():
        manifest.require_valid()
    return manifest


def prove(directory: Path, time_limit: float, command: str, threads: int = 1,
          names: Iterable[str] | None = None, log: Any = print,
          methods: Sequence[str] | None = None) -> Manifest:
    """Solve every instance of ``directory`` with ``methods`` (default: every exact method)
    and write the manifest. A backend re-run replaces its record; the records of the other
    backends in an existing entry are kept and judged with it (so a slow backend can be run
    under its own time limit); entries of instances not solved this time are kept."""
    from tsac_bench.model.io import read_instance

    manifest = _readable_manifest(directory)  # a malformed one stops it before any solving
    wanted = set(names) if names is not None else None
    methods = exact_methods() if methods is None else list(methods)
    for file in iter_instance_files([directory]):
        name = read_instance(file).name
        if wanted is not None and name not in wanted:
            continue
        solved = {m: solve_exact(file, m, time_limit, threads) | {"command": command}
                  for m in methods}
        with manifest_lock(directory):
            # As other runs on the set may have left it meanwhile, not as it was at the start.
            manifest = _readable_manifest(directory)
            old = manifest.entries.get(name, {})
            results = {**old.get("solvers", {}), **solved}
            entry = carried_over(old, entry_from(results, file.name, command))
            manifest.entries[name] = entry
            write_manifest(manifest)
        log(f"{name}: {entry['status']} J*={entry['J_star']} LB={entry['lower_bound']:.6f} "
            + " ".join(f"{m}={r['status']}/{r['wall_time']:.1f}s" for m, r in results.items()))
    return manifest


@dataclass(frozen=True)
class Check:
    instance: str
    method: str
    J_star: float | None
    J: float
    lower_bound: float | None
    status: PlanStatus | None
    wall_time: float
    passed: bool
    reason: str


def verify(directory: Path, methods: Sequence[str] | None = None,
           time_limit: float | None = None, names: Iterable[str] | None = None,
           threads: int = 1) -> list[Check]:
    """Re-solve the manifest's instances: an optimal J* must be matched (and proved again,
    unless the time limit stops the solver, in which case J* must lie in [LB, J]); an open
    entry's best known bound must not exceed the new J. ``methods``: when None, the backends
    that proved the entry's J* (re-proving it), or every installed exact method for an
    entry without J*."""
    manifest = read_manifest(directory).require_valid()
    installed = exact_methods()
    wanted = set(names) if names is not None else None
    checks = []
    for name, entry in manifest.entries.items():
        if wanted is not None and name not in wanted:
            continue
        provers = [m for m, r in entry.get("solvers", {}).items()
                   if r.get("status") == PlanStatus.OPTIMAL and m in installed]
        chosen = methods if methods is not None else (
            provers if entry["J_star"] is not None and provers else installed)
        for method in chosen:
            r = solve_exact(directory / entry["file"], method, time_limit, threads)
            J, bound, status = r["J"], r["lower_bound"], r["status"]
            J_star = entry["J_star"]
            if status == PlanStatus.ERROR:
                passed, reason = False, f"solver error: {r['stop_reason']}"
            elif J_star is None:
                passed = cost_at_least(J, entry["lower_bound"])
                reason = "" if passed else f"J {J} below the recorded bound"
            elif status == PlanStatus.OPTIMAL:
                passed = costs_agree(J, J_star)
                reason = "" if passed else f"optimum {J} != J* {J_star}"
            else:
                passed = cost_at_least(J, J_star) and (
                    bound is None or cost_at_least(J_star, bound))
                reason = "" if passed else "J* outside [LB, J]"
            checks.append(Check(name, method, J_star, J, bound, status, r["wall_time"],
                                passed, reason))
    return checks
