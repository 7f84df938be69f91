"""The batch runner behind ``tsac-bench run``: every (instance, method, mode, seed) job of a
set of instance files, run on local worker processes or a Dask cluster, each finished job
recorded in the run directory's results store.

Restarting the same command on the same ``--out`` skips the jobs already recorded, so a run
killed at any moment loses nothing and ends as an uninterrupted one would. Failed jobs (an
allocator that raises, crashes its process or overruns its time limit) are recorded with their
status and message and count as finished; ``--retry-failed`` runs them again.
"""

from __future__ import annotations

import json
import os
import shlex
import sys
from collections.abc import Callable, Iterable, Iterator, Sequence
from contextlib import contextmanager
from dataclasses import dataclass, field
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

from tsac_bench.allocator import (
    MethodUnavailable,
    allocator_class,
    available_methods,
    supported_modes,
)
from tsac_bench.errors import InputError, TsacBenchError
from tsac_bench.io import sweep_sets_below
from tsac_bench.model import Instance
from tsac_bench.store import ResultStore, job_key
from tsac_bench.worker import GRACE_SECONDS, hard_timeout

#: Methods that prove optimality; their static runs may supply J* (see ``report``).
EXACT_METHODS = ("exact", "exact-cpsat", "exact-bp")
#: Default solver time limit, in seconds per 10 tasks (never below one unit), of one plan
#: call: a static job plans once, a dynamic one once plus once per release event. Sized so
#: that the shipped sets (<= 10 tasks) run with every method in a few minutes on 2 cores;
#: exact methods are capped short because there J* comes from the manifest, not from the run.
DEFAULT_TIME_LIMITS = {"exact": 10.0, "exact-cpsat": 10.0, "exact-bp": 10.0}
DEFAULT_TIME_LIMIT = 2.0


def default_time_limit(method: str, n_tasks: int) -> float:
    """The time limit a job gets without --time-limit: grows linearly with the task count."""
    per_ten = DEFAULT_TIME_LIMITS.get(method, DEFAULT_TIME_LIMIT)
    return per_ten * max(1.0, n_tasks / 10)
MODE_CHOICES = ("auto", "static", "dynamic", "both")
MANIFEST_NAME = "manifest.json"
#: What the local worker processes print (solver logs, warnings), in the run directory.
WORKER_LOG = "workers.log"
MANIFEST_FORMAT = "tsac-bench/manifest@1"
#: Statuses of a job that produced a scored solution; anything else is a failure.
OK = "ok"


@dataclass(frozen=True)
class Reference:
    """What is known of an instance's exact optimum before the run."""

    J_star: float | None = None
    lower_bound: float | None = None
    source: str | None = None


@dataclass(frozen=True)
class LoadedInstance:
    path: Path
    instance: Instance
    data: dict[str, Any]
    instance_set: str
    reference: Reference


@dataclass(frozen=True)
class Job:
    """One job: ``spec`` goes to a worker, ``row`` is the part of its record known up front."""

    spec: dict[str, Any]
    row: dict[str, Any]
    loaded: LoadedInstance


@dataclass
class BatchOutcome:
    run_dir: Path
    total: int = 0
    skipped: int = 0
    ran: int = 0
    failed: int = 0
    problems: list[str] = field(default_factory=list)


# --- inputs ------------------------------------------------------------------------------
def read_manifest(directory: Path) -> tuple[dict[str, Reference], list[str]]:
    """References by instance name from ``directory/manifest.json`` (none if absent), and
    the problems found in it (a malformed manifest is reported, not fatal: gaps are missing)."""
    path = directory / MANIFEST_NAME
    if not path.exists():
        return {}, []
    try:
        data = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
        return {}, [f"{path}: not readable as JSON: {exc}"]
    if not isinstance(data, dict) or data.get("format") != MANIFEST_FORMAT:
        got = data.get("format") if isinstance(data, dict) else type(data).__name__
        return {}, [f"{path}: format: expected {MANIFEST_FORMAT!r}, got {got!r}"]
    entries = data.get("instances")
    if not isinstance(entries, dict):
        return {}, [f"{path}: instances: expected an object of instance entries"]
    references, problems = {}, []
    for name, entry in entries.items():
        values = {}
        for key in ("J_star", "lower_bound"):
            value = entry.get(key) if isinstance(entry, dict) else None
            if value is not None and (isinstance(value, bool)
                                      or not isinstance(value, int | float)):
                problems.append(f"{path}: instances.{name}.{key}: expected a number or null, "
                                f"got {value!r}")
                value = None
            values[key] = None if value is None else float(value)
        references[name] = Reference(values["J_star"], values["lower_bound"], "manifest")
    return references, problems


def load_instances(paths: Sequence[Path]) -> tuple[list[LoadedInstance], list[str]]:
    """Every instance file under ``paths``; each unreadable file becomes one problem line
    (file and field) and the others load."""
    from tsac_bench.io import instance_to_dict, iter_instance_files, read_instance

    problems: list[str] = []
    for path in paths:
        if not path.exists():
            problems.append(f"{path}: no such file or directory")
    files = iter_instance_files([p for p in paths if p.exists()])
    manifests: dict[Path, dict[str, Reference]] = {}
    loaded: list[LoadedInstance] = []
    seen: dict[str, Path] = {}
    for path in files:
        try:
            instance = read_instance(path)
        except InputError as exc:
            problems.append(str(exc))
            continue
        if instance.name in seen:
            problems.append(f"{path}: name: instance name {instance.name!r} is already used by "
                            f"{seen[instance.name]}; skipped")
            continue
        seen[instance.name] = path
        if path.parent not in manifests:
            manifests[path.parent], manifest_problems = read_manifest(path.parent)
            problems.extend(manifest_problems)
        reference = manifests[path.parent].get(instance.name, Reference())
        loaded.append(LoadedInstance(path, instance, instance_to_dict(instance),
                                     path.parent.name, reference))
    return loaded, problems


def resolve_methods(requested: Sequence[str] | None) -> tuple[list[str], list[str]]:
    """The methods to run and notes on the ones left out.

    Named methods must exist and be importable (a typo is an error, not 100 failed jobs);
    by default every available method runs and the unavailable ones are noted."""
    if requested:
        for name in requested:
            allocator_class(name)  # raises UnknownMethodError / MethodUnavailable
        return list(dict.fromkeys(requested)), []
    methods, notes = [], []
    for name in available_methods():
        try:
            allocator_class(name)
        except MethodUnavailable as exc:
            notes.append(f"skipped method {name}: {exc}")
            continue
        except Exception as exc:  # a broken plug-in must not stop the built-in methods
            notes.append(f"skipped method {name}: cannot load it: {type(exc).__name__}: {exc}")
            continue
        methods.append(name)
    return methods, notes


def resolve_modes(mode: str) -> list[str]:
    """``auto``: static, plus dynamic where this build's ``solve`` supports it."""
    from tsac_bench.solve import MODES

    if mode == "auto":
        return [m for m in ("static", "dynamic") if m in MODES]
    if mode == "both":
        return ["static", "dynamic"]
    if mode in ("static", "dynamic"):
        return [mode]
    raise TsacBenchError(f"--mode: expected one of {', '.join(MODE_CHOICES)}, got {mode!r}")


def plan_jobs(instances: Iterable[LoadedInstance], methods: Sequence[str],
              modes: Sequence[str], seeds: int, time_limit: float | None,
              grace: float = GRACE_SECONDS) -> list[Job]:
    jobs = []
    for loaded in instances:
        instance = loaded.instance
        for method in methods:
            limit = (time_limit if time_limit is not None
                     else default_time_limit(method, instance.n_tasks))
            # A method that plans only some modes gets no job in the others (not a failure).
            for mode in (m for m in modes if m in supported_modes(allocator_class(method))):
                for seed in range(seeds):
                    key = job_key(instance.name, method, mode, seed)
                    spec = {"key": key, "instance": loaded.data, "instance_file": str(loaded.path),
                            "method": method, "mode": mode, "seed": seed, "time_limit": limit,
                            "settings": {}, "grace": grace}
                    row = {"key": key, "instance": instance.name,
                           "instance_set": loaded.instance_set,
                           "instance_file": str(loaded.path), "scale": instance.scale,
                           "n_aavs": instance.n_aavs, "n_tasks": instance.n_tasks,
                           "method": method, "mode": mode, "seed": seed,
                           "settings": {}, "time_limit": limit,
                           "J_star": loaded.reference.J_star,
                           "lower_bound": loaded.reference.lower_bound,
                           "reference": loaded.reference.source}
                    jobs.append(Job(spec, row, loaded))
    # Longest jobs first: a slow exact job started last would leave the other cores idle.
    jobs.sort(key=lambda j: -(hard_timeout(j.spec) or float("inf")))
    return jobs


# --- recording ---------------------------------------------------------------------------
def record_result(store: ResultStore, job: Job, result: dict[str, Any]) -> str:
    """Write one finished job (solution file, then its row); returns its status.

    The stored J is recomputed here by the evaluator from the solution as written to the file,
    so every stored cost is the evaluator's, whatever the worker claimed."""
    from tsac_bench.evaluator import CostEvaluator
    from tsac_bench.io import solution_from_dict, write_solution

    row = {**job.row, "status": result["status"], "message": result["message"],
           "detail": result.get("detail") or None, "runtime": result["runtime"],
           "stats": result["stats"], "versions": result["versions"],
           "host": result["host"], "J": None, "J_load": None, "J_time": None, "J_op": None,
           "solution_file": None,
           "finished_at": datetime.now(UTC).isoformat(timespec="seconds")}
    if result["status"] == OK:
        instance = job.loaded.instance
        solution = solution_from_dict(result["solution"], instance, job.row["key"])
        evaluation = CostEvaluator(instance).evaluate(solution)
        if not evaluation.feasible or evaluation.J is None:
            row.update(status="invalid", message="stored solution is infeasible: "
                       + "; ".join(str(e) for e in evaluation.errors))
        else:
            relative = store.solution_path(job.row["instance_set"], instance.name,
                                           job.row["method"], job.row["mode"], job.row["seed"])
            write_solution(solution.with_cost(evaluation.J), instance, store.run_dir / relative)
            row.update(J=evaluation.J, J_load=evaluation.terms["load"],
                       J_time=evaluation.terms["time"], J_op=evaluation.terms["op"],
                       solution_file=str(relative),
                       settings=dict(solution.meta.get("settings") or {}))
    store.record(row)
    return row["status"]


# --- the batch ---------------------------------------------------------------------------
@dataclass
class RunConfig:
    paths: list[Path]
    out: Path
    methods: list[str] | None = None
    mode: str = "auto"
    seeds: int = 1
    time_limit: float | None = None
    jobs: int = field(default_factory=lambda: os.cpu_count() or 1)
    executor: str = "local"
    scheduler: str | None = None
    retry_failed: bool = False
    grace: float = GRACE_SECONDS


def execute(config: RunConfig, specs: list[dict[str, Any]]) -> Iterator[tuple[dict, dict]]:
    from tsac_bench.executors import run_dask, run_local

    if config.executor == "local":
        if config.scheduler is not None:
            raise TsacBenchError("--scheduler needs --executor dask")
        return run_local(specs, config.jobs, log=config.out / WORKER_LOG)
    if config.executor == "dask":
        return run_dask(specs, config.jobs, config.scheduler)
    raise TsacBenchError(f"--executor: expected local or dask, got {config.executor!r}")


def run_batch(config: RunConfig, *, note: Callable[[str], None] = print,
              progress: bool = True) -> BatchOutcome:
    """Run every job of ``config`` not yet recorded in ``config.out``."""
    if config.seeds < 1:
        raise TsacBenchError("--seeds: must be at least 1")
    if config.time_limit is not None and config.time_limit <= 0:
        raise TsacBenchError("--time-limit: must be positive")
    if config.grace < 0:
        raise TsacBenchError("--grace: must be >= 0")
    modes = resolve_modes(config.mode)
    methods, method_notes = resolve_methods(config.methods)
    if not methods:
        raise TsacBenchError("no method to run: `tsac-bench methods` lists them")
    loaded, problems = load_instances(config.paths)
    outcome = BatchOutcome(config.out, problems=problems)
    sweep_notes = [f"skipped sweep set {sweep} (name it to run it)"
                   for path in config.paths for sweep in sweep_sets_below(path)]
    for line in [*method_notes, *sweep_notes, *problems]:
        note(line)
    jobs = plan_jobs(loaded, methods, modes, config.seeds, config.time_limit,
                     config.grace)
    outcome.total = len(jobs)
    with ResultStore(config.out) as store:
        done = store.finished_keys(["ok"] if config.retry_failed else None)
        todo = [job for job in jobs if job.spec["key"] not in done]
        outcome.skipped = len(jobs) - len(todo)
        store.set_meta({"command": shlex.join(sys.argv), "methods": methods, "modes": modes,
                        "seeds": config.seeds, "paths": [str(p) for p in config.paths],
                        "last_started": datetime.now(UTC).isoformat(timespec="seconds")})
        if outcome.skipped:
            note(f"resuming {config.out}: {outcome.skipped} of {len(jobs)} jobs already "
                 "recorded")
        by_key = {job.spec["key"]: job for job in todo}
        with _progress_bar(len(todo), enabled=progress) as advance:
            for spec, result in execute(config, [job.spec for job in todo]):
                status = record_result(store, by_key[spec["key"]], result)
                outcome.ran += 1
                if status != OK:
                    outcome.failed += 1
                    note(f"{spec['key']}: {status}: {result['message'] or status}")
                advance(status != OK)
    return outcome


@contextmanager
def _progress_bar(total: int, enabled: bool) -> Iterator[Callable[[bool], None]]:
    """A rich progress bar on stderr (jobs done, failures, elapsed time, ETA); yields the
    function that advances it by one job."""
    if not enabled:
        yield lambda failed: None
        return
    from rich.console import Console
    from rich.progress import (
        BarColumn,
        MofNCompleteColumn,
        Progress,
        TextColumn,
        TimeElapsedColumn,
        TimeRemainingColumn,
    )

    failures = 0
    with Progress(TextColumn("jobs"), BarColumn(), MofNCompleteColumn(),
                  TextColumn("[red]{task.fields[failed]} failed"), TimeElapsedColumn(),
                  TextColumn("ETA"), TimeRemainingColumn(),
                  console=Console(stderr=True)) as progress:
        task = progress.add_task("jobs", total=total, failed=0)

        def advance(failed: bool) -> None:
            nonlocal failures
            failures += failed
            progress.update(task, advance=1, failed=failures)

        yield advance
