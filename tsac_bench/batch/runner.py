"""The batch runner behind ``tsac-bench run``: every (instance, method, mode, seed) job of a
set of instance files, run on local worker processes or a Dask cluster, each finished job
recorded in the run directory's results store.

Restarting the same command on the same ``--out`` skips the jobs already recorded, so a run
killed at any moment loses nothing and ends as an uninterrupted one would. Failed jobs (an
allocator that raises, crashes its process or overruns its time limit) are recorded with their
status and message and count as finished; ``--retry-failed`` runs them again. A recorded job
whose method takes other settings today than it ran with is kept and named in a note
(``changed_settings``).
"""

from __future__ import annotations

import itertools
import os
import shlex
import sys
from collections.abc import Callable, Iterable, Iterator, Sequence
from contextlib import contextmanager
from dataclasses import dataclass, field
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

from tsac_bench.batch.manifests import (
    Reference,
    iter_instance_files,
    read_manifest,
    sweep_sets_below,
)
from tsac_bench.batch.records import JobIdentity, JobResult, JobRow, JobSpec
from tsac_bench.batch.store import OK, ResultStore, job_key
from tsac_bench.batch.worker import GRACE_SECONDS, hard_timeout
from tsac_bench.errors import InputError, TsacBenchError
from tsac_bench.model import Instance
from tsac_bench.planning import (
    ALL_MODES,
    MethodSpec,
    MethodUnavailable,
    allocator_class,
    available_methods,
    is_exact_method,
    make_allocator,
    resolve_spec,
    supported_modes,
)
from tsac_bench.planning.budget import budgeted_settings, check_budget
from tsac_bench.planning.solve import recorded_settings

#: Default solver time limit, in seconds per 10 tasks (never below one unit), of one plan
#: call: a static job plans once, a dynamic one once plus once per release event. Sized so
#: that the shipped sets (<= 10 tasks) run with every method in a few minutes on 2 cores;
#: exact methods are capped short because there J* comes from the manifest, not from the run
#: (at 10 s the main job took 10 min 36 s on 2 cores, 955 of its 1 158 job-seconds in the
#: exact jobs of the regression set, most of them at the 4/10 instances' limit).
DEFAULT_TIME_LIMIT = 2.0
DEFAULT_EXACT_TIME_LIMIT = 5.0


def default_time_limit(method: str, n_tasks: int) -> float:
    """The time limit a job of ``method`` (a name) gets without --time-limit: grows linearly
    with the task count."""
    per_ten = DEFAULT_EXACT_TIME_LIMIT if is_exact_method(method) else DEFAULT_TIME_LIMIT
    return per_ten * max(1.0, n_tasks / 10)

MODE_CHOICES = ("auto", *ALL_MODES, "both")
#: What the local worker processes print (solver logs, warnings), in the run directory.
WORKER_LOG = "workers.log"


@dataclass(frozen=True)
class LoadedInstance:
    path: Path
    instance: Instance
    data: dict[str, Any]
    instance_set: str
    reference: Reference
    #: The set's manifest ``budgets``: run too when the run names no budget.
    set_budgets: tuple[float, ...] = ()


@dataclass(frozen=True)
class Job:
    """One job: ``spec`` goes to a worker, ``row`` is the part of its record known up front."""

    spec: JobSpec
    row: JobRow
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
def load_instances(paths: Sequence[Path]) -> tuple[list[LoadedInstance], list[str]]:
    """Every instance file under ``paths``; each unreadable file becomes one problem line
    (file and field) and the others load."""
    from tsac_bench.model.io import instance_to_dict, read_instance

    problems: list[str] = []
    for path in paths:
        if not path.exists():
            problems.append(f"{path}: no such file or directory")
    files = iter_instance_files([p for p in paths if p.exists()])
    manifests: dict[Path, tuple[dict[str, Reference], tuple[float, ...]]] = {}
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
            manifest = read_manifest(path.parent)
            if manifest.path.exists():  # a set without a manifest simply has no references
                problems.extend(manifest.problem_lines())
            manifests[path.parent] = (manifest.references(), tuple(manifest.budgets or ()))
        references, set_budgets = manifests[path.parent]
        loaded.append(LoadedInstance(path, instance, instance_to_dict(instance),
                                     path.parent.name,
                                     references.get(instance.name, Reference()), set_budgets))
    return loaded, problems


def resolve_methods(requested: Sequence[str] | None) -> tuple[list[MethodSpec], list[str]]:
    """The method specs to run (settings checked, one per label) and notes on the methods
    left out.

    Named methods must exist and be importable and their settings valid (a typo is an error,
    not 100 failed jobs); by default every available method runs with its default settings
    and the unavailable ones are noted."""
    if requested:
        specs = [resolve_spec(text) for text in requested]  # raises for any bad spec
        return list({spec.label: spec for spec in specs}.values()), []
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
        methods.append(MethodSpec(name))
    return methods, notes


def resolve_modes(mode: str) -> list[str]:
    """``auto`` and ``both``: every planning mode (a method that declares fewer gets jobs
    only in its own)."""
    if mode in ("auto", "both"):
        return list(ALL_MODES)
    if mode in ALL_MODES:
        return [mode]
    raise TsacBenchError(f"--mode: expected one of {', '.join(MODE_CHOICES)}, got {mode!r}")


def plan_jobs(instances: Iterable[LoadedInstance], methods: Sequence[MethodSpec],
              modes: Sequence[str], seeds: Sequence[int], time_limit: float | None,
              grace: float = GRACE_SECONDS,
              budgets: Sequence[float] | None = None) -> list[Job]:
    """One job per (instance, method spec, mode, seed, budget). A job's ``method`` in the
    store is the spec's label (the name alone without settings, so stores of plain names
    resume). With ``budgets`` each plan call has a budget's seconds (its time limit: an
    anytime method spends them, ``tsac_bench.planning.budget``); without, the time limit,
    and the budgets its set's manifest declares too."""
    jobs = []
    for loaded in instances:
        instance = loaded.instance
        for method in methods:
            own_limit = (time_limit if time_limit is not None
                         else default_time_limit(method.name, instance.n_tasks))
            modes_of_method = supported_modes(allocator_class(method.name))
            # A method that plans only some modes gets no job in the others (not a failure).
            for mode, seed, budget in itertools.product(
                    [m for m in modes if m in modes_of_method], seeds,
                    budgets or [None, *set_budgets(loaded, method)]):
                identity = JobIdentity(
                    key=job_key(instance.name, method.label, mode, seed, budget),
                    instance_file=str(loaded.path), mode=mode, seed=seed,
                    settings=dict(method.settings),
                    time_limit=own_limit if budget is None else budget, budget=budget)
                spec = JobSpec(**identity, instance=loaded.data, method=method.name,
                               grace=grace)
                row = JobRow(**identity, instance=instance.name,
                             instance_set=loaded.instance_set, scale=instance.scale,
                             n_aavs=instance.n_aavs, n_tasks=instance.n_tasks,
                             method=method.label, J_star=loaded.reference.J_star,
                             lower_bound=loaded.reference.lower_bound,
                             best_J=loaded.reference.best_J,
                             reference=loaded.reference.source)
                jobs.append(Job(spec, row, loaded))
    # Longest jobs first: a slow exact job started last would leave the other cores idle.
    jobs.sort(key=lambda j: -(hard_timeout(j.spec) or float("inf")))
    return jobs


def set_budgets(loaded: LoadedInstance, method: MethodSpec) -> tuple[float, ...]:
    """The budgets of ``loaded``'s set that ``method`` runs at when the run names none: all
    of them for a heuristic or learned method whose settings a budget leaves as they are,
    none for an exact method (its proof is what it is run for) or a spec with a work cap."""
    if not loaded.set_budgets or is_exact_method(method.name):
        return ()
    try:
        budgeted_settings(method.name, allocator_class(method.name), method.settings)
    except TsacBenchError:
        return ()
    return loaded.set_budgets


# --- recording ---------------------------------------------------------------------------
def record_result(store: ResultStore, job: Job, result: JobResult) -> str:
    """Write one finished job (solution file, then its row); returns its status.

    The stored J is recomputed here by the evaluator from the solution as written to the file,
    so every stored cost is the evaluator's, whatever the worker claimed."""
    from tsac_bench.model.evaluator import CostEvaluator
    from tsac_bench.model.io import solution_from_dict, write_solution

    row = JobRow(**job.row, status=result["status"], message=result["message"],
                 detail=result.get("detail") or None, runtime=result["runtime"],
                 stats=result["stats"], versions=result["versions"], host=result["host"],
                 over_budget=result.get("over_budget"), J=None, J_load=None, J_time=None,
                 J_op=None, solution_file=None,
                 finished_at=datetime.now(UTC).isoformat(timespec="seconds"))
    if result["status"] == OK:
        instance = job.loaded.instance
        solution = solution_from_dict(result["solution"], instance, job.row["key"])
        evaluation = CostEvaluator(instance).evaluate(solution)
        if not evaluation.feasible or evaluation.J is None:
            row.update(status="invalid", message="stored solution is infeasible: "
                       + "; ".join(str(e) for e in evaluation.errors))
        else:
            relative = store.solution_path(job.row["instance_set"], instance.name,
                                           job.row["method"], job.row["mode"], job.row["seed"],
                                           job.row["budget"])
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
    seeds: int | Sequence[int] = 1  # a count n is seeds 0..n-1
    time_limit: float | None = None
    budgets: list[float] | None = None
    jobs: int = field(default_factory=lambda: os.cpu_count() or 1)
    executor: str = "local"
    scheduler: str | None = None
    retry_failed: bool = False
    grace: float = GRACE_SECONDS


def execute(config: RunConfig, specs: list[JobSpec]) -> Iterator[tuple[JobSpec, JobResult]]:
    from tsac_bench.batch.executors import run_dask, run_local

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
    seeds = range(config.seeds) if isinstance(config.seeds, int) else list(config.seeds)
    if not seeds or min(seeds) < 0:
        raise TsacBenchError("--seeds: must name at least one seed, none negative")
    if config.time_limit is not None and config.time_limit <= 0:
        raise TsacBenchError("--time-limit: must be positive")
    if config.budgets is not None:
        if config.time_limit is not None:
            raise TsacBenchError("--budget: not with --time-limit (a budget is the time limit "
                                 "of every plan call)")
        if not config.budgets:
            raise TsacBenchError("--budget: expected seconds, e.g. 0.1,1,10")
        for budget in config.budgets:
            check_budget(budget)
    if config.grace < 0:
        raise TsacBenchError("--grace: must be >= 0")
    modes = resolve_modes(config.mode)
    methods, method_notes = resolve_methods(config.methods)
    if not methods:
        raise TsacBenchError("no method to run: `tsac-bench methods` lists them")
    if config.budgets is not None:
        for method in methods:  # a spec that a budget contradicts fails here, not per job
            budgeted_settings(method.name, allocator_class(method.name), method.settings)
    loaded, problems = load_instances(config.paths)
    outcome = BatchOutcome(config.out, problems=problems)
    sweep_notes = [f"skipped sweep set {sweep} (name it to run it)"
                   for path in config.paths for sweep in sweep_sets_below(path)]
    for line in [*method_notes, *sweep_notes, *problems]:
        note(line)
    jobs = plan_jobs(loaded, methods, modes, seeds, config.time_limit,
                     config.grace, config.budgets)
    outcome.total = len(jobs)
    with ResultStore(config.out) as store:
        done = store.finished_keys(["ok"] if config.retry_failed else None)
        todo = [job for job in jobs if job.spec["key"] not in done]
        outcome.skipped = len(jobs) - len(todo)
        if config.budgets is not None:
            record_calibration(store, note)
        store.set_meta({"command": shlex.join(sys.argv),
                        "methods": [method.label for method in methods], "modes": modes,
                        "seeds": list(seeds), "paths": [str(p) for p in config.paths],
                        "last_started": datetime.now(UTC).isoformat(timespec="seconds")})
        if outcome.skipped:
            note(f"resuming {config.out}: {outcome.skipped} of {len(jobs)} jobs already "
                 "recorded")
            skipped = {job.spec["key"] for job in jobs if job.spec["key"] in done}
            for line in changed_settings(store.rows(), methods, skipped):
                note(line)
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


def record_calibration(store: ResultStore, note: Callable[[str], None]) -> None:
    """Time the machine-speed reference (``calibrate``) and store it in the run's meta:
    ``calibration`` the latest, ``calibrations`` every one (a run resumed on another machine
    adds its own)."""
    from tsac_bench.batch.calibrate import calibrate

    calibration = calibrate()
    earlier = store.meta().get("calibrations", [])
    store.set_meta({"calibration": calibration, "calibrations": [*earlier, calibration]})
    note(f"calibration: the reference workload takes {calibration['seconds']:.4f} s on "
         f"{calibration['host']} (a budget of 1 s is {1 / calibration['seconds']:.1f} "
         "reference units)")


_ABSENT = object()


def changed_settings(rows: Iterable[JobRow], methods: Sequence[MethodSpec],
                     keys: set[str]) -> list[str]:
    """One note per method whose recorded ok jobs among ``keys`` ran with other settings than
    the method takes today (a default changed since, e.g. a new shipped policy): resuming
    keeps those results, so the store would mix two versions of the method unnoticed."""
    today = {}
    for method in methods:
        for budgeted in (False, True):
            try:
                # A budgeted job records the settings with the work caps its budget lifts.
                spec = MethodSpec(method.name, budgeted_settings(
                    method.name, allocator_class(method.name), method.settings)
                ) if budgeted else method
                today[method.label, budgeted] = recorded_settings(make_allocator(spec))
            except Exception:  # a method that cannot be built fails in its own jobs
                continue
    changed: dict[str, tuple[int, set[str]]] = {}
    for row in rows:
        recorded = row["settings"]
        now = today.get((row["method"], row.get("budget") is not None))
        # Stores from before settings were recorded say nothing either way.
        if row["key"] not in keys or row["status"] != OK or not recorded or now is None:
            continue
        names = {name for name in recorded.keys() | now.keys()
                 if recorded.get(name, _ABSENT) != now.get(name, _ABSENT)}
        if names:
            count, seen = changed.get(row["method"], (0, set()))
            changed[row["method"]] = (count + 1, seen | names)
    return [f"{count} recorded {label} job(s) ran with other settings than {label} takes now "
            f"({', '.join(sorted(names))}); they are kept: delete them from the store to run "
            "them again" for label, (count, names) in changed.items()]


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
