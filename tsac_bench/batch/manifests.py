"""Instance sets on disk: the instance files of a directory, sweep sets, and the manifest of
proven optima beside them (``manifest.json``, format ``tsac-bench/manifest@1``).

One parser reads a manifest. It never raises on content: each malformed part becomes a
problem line (file, field, what) and the rest stays usable, which is what a batch run wants
(gaps go missing, the run goes on); ``Manifest.require_valid`` turns the first problem into
the one-line error that ``verify`` needs.
"""

from __future__ import annotations

import json
import math
import os
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from tsac_bench.errors import InputError

MANIFEST_NAME = "manifest.json"
MANIFEST_FORMAT = "tsac-bench/manifest@1"
#: Fields every manifest entry has: where the instance is, and what is known of its optimum.
ENTRY_FIELDS = ("file", "J_star", "lower_bound", "status")
#: A file of this name marks an instance set as a sweep (hundreds of instances): walking a
#: parent directory skips it; naming the set itself runs it.
SWEEP_MARKER = ".sweep"
#: The folder beside a manifest that holds its best-known plans (batch/best_known.py): solution
#: files, never instances.
PLAN_FOLDER = "best-known"


@dataclass(frozen=True)
class Reference:
    """What is known of an instance's exact optimum before the run."""

    J_star: float | None = None
    lower_bound: float | None = None
    source: str | None = None
    #: The lowest J of any plan found (``best_known``); a report's gap where J* is unknown.
    best_J: float | None = None


@dataclass
class Manifest:
    path: Path
    #: Entries by instance name, as stored; malformed entries are left out (see problems).
    entries: dict[str, dict[str, Any]] = field(default_factory=dict)
    #: (field, what is wrong) for each malformed part, in file order.
    problems: list[tuple[str | None, str]] = field(default_factory=list)
    #: Seconds per plan call at which a run that names no ``--budget`` also runs the set's
    #: jobs (a small budget sweep in the main job's report); None: none.
    budgets: list[float] | None = None

    def problem_lines(self) -> list[str]:
        return [str(InputError(str(self.path), where, what)) for where, what in self.problems]

    def require_valid(self) -> Manifest:
        if self.problems:
            where, what = self.problems[0]
            raise InputError(str(self.path), where, what)
        return self

    def references(self) -> dict[str, Reference]:
        return {name: Reference(_number(entry.get("J_star")), _number(entry.get("lower_bound")),
                                "manifest", _number(entry.get("best_J")))
                for name, entry in self.entries.items()}


def _number(value: Any) -> float | None:
    return None if value is None else float(value)


def _is_number_or_null(value: Any) -> bool:
    """JSON null or a finite number (Python's json reads NaN and Infinity as floats)."""
    return value is None or (isinstance(value, int | float) and not isinstance(value, bool)
                             and math.isfinite(value))


def read_manifest(directory: Path) -> Manifest:
    """The manifest of ``directory``; an absent one is an empty manifest with one problem."""
    path = directory / MANIFEST_NAME
    manifest = Manifest(path)
    try:
        data = json.loads(path.read_text(encoding="utf-8"))
    except FileNotFoundError:
        manifest.problems.append((None, "no manifest in this directory"))
        return manifest
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
        manifest.problems.append((None, f"not readable as JSON: {exc}"))
        return manifest
    if not isinstance(data, dict) or data.get("format") != MANIFEST_FORMAT:
        got = data.get("format") if isinstance(data, dict) else type(data).__name__
        manifest.problems.append(("format", f"expected {MANIFEST_FORMAT!r}, got {got!r}"))
        return manifest
    budgets = data.get("budgets")
    if budgets is not None:
        if (isinstance(budgets, list) and budgets
                and all(_is_number_or_null(b) and b is not None and b > 0 for b in budgets)):
            manifest.budgets = sorted({float(b) for b in budgets})
        else:
            manifest.problems.append(("budgets", f"expected a list of seconds > 0, got "
                                                 f"{budgets!r}"))
    entries = data.get("instances")
    if not isinstance(entries, dict):
        manifest.problems.append(("instances", "expected an object keyed by instance name"))
        return manifest
    for name, entry in entries.items():
        missing = [key for key in ENTRY_FIELDS if not isinstance(entry, dict) or key not in entry]
        if missing:
            manifest.problems.append((f"instances.{name}.{missing[0]}", "missing"))
            continue
        wrong = [key for key in ("J_star", "lower_bound", "best_J")
                 if not _is_number_or_null(entry.get(key))]
        if wrong:
            manifest.problems.append((f"instances.{name}.{wrong[0]}",
                                      f"expected a finite number or null, got {entry[wrong[0]]!r}"))
            continue
        manifest.entries[name] = entry
    return manifest


@contextmanager
def manifest_lock(directory: Path) -> Iterator[None]:
    """Hold ``directory``'s manifest for one read-change-write: an exclusive lock (flock on
    the directory itself, so no lock file is left beside the instances) that the same
    section of any other process waits for. The searches that run for hours (``bks
    improve``, ``bks recombine``, ``prove``) write after each instance; each reads the
    manifest afresh under it, so two of them on one set add to each other's results instead
    of writing over them with what they read at their start."""
    try:
        import fcntl

        handle = os.open(directory, os.O_RDONLY)
    except (ImportError, OSError):
        # Not POSIX (no advisory locks: one writer at a time is then the rule), or no such
        # directory (the read that follows says so, in one line).
        yield
        return
    try:
        fcntl.flock(handle, fcntl.LOCK_EX)
        yield
    finally:
        os.close(handle)  # releases the lock


def write_manifest(manifest: Manifest) -> None:
    data: dict[str, Any] = {"format": MANIFEST_FORMAT}
    if manifest.budgets is not None:
        data["budgets"] = manifest.budgets
    data["instances"] = manifest.entries
    manifest.path.write_text(json.dumps(data, indent=1, sort_keys=False) + "\n")


def iter_instance_files(paths: list[Path]) -> list[Path]:
    """Instance files under the given files or directories (recursive, sorted; no manifests,
    no files starting with ``_``, no best-known plans, no sweep sets below a given
    directory)."""
    found: list[Path] = []
    for path in paths:
        if not path.is_dir():
            found.append(path)
            continue
        sweeps = {marker.parent for marker in path.rglob(SWEEP_MARKER) if marker.parent != path}
        found.extend(
            p for p in sorted(path.rglob("*.json"))
            if not p.name.startswith("_") and p.name != MANIFEST_NAME
            and p.parent.name != PLAN_FOLDER
            and not any(parent in sweeps for parent in p.parents)
        )
    return found


def sweep_sets_below(path: Path) -> list[Path]:
    """The sweep sets a walk of ``path`` leaves out (see SWEEP_MARKER)."""
    if not path.is_dir():
        return []
    return sorted(marker.parent for marker in path.rglob(SWEEP_MARKER) if marker.parent != path)
