"""Best-known solutions and bounds of an instance set, kept beside the instances as CVRPLIB
keeps its ``.sol`` files: the gap of any method is then measured against a plan anyone can
re-evaluate and a bound whose source is named.

They live in the set's manifest (``manifest.json``, the one owner of what is known of an
instance's optimum), each entry gaining

- ``best_J``: the lowest J of any plan the project found, as an offline plan (a dynamic
  run's stamps removed: docs/model.md, "The dynamic run", such a plan is feasible offline and
  its J no higher);
- ``best_plan``: that plan in canonical form (late visits dropped, amounts above a demand
  cut; J no higher), a solution file relative to the set's directory
  (``best-known/NAME.json``);
- ``found_by``: the method, settings, mode, seed and budget of the job that found it;
- ``bound_by``: what proved ``lower_bound`` (an exact method and its time limit, or
  ``tasks-on-their-own``, the bound that needs no search: formulations/task_bound.py).

``J_star`` is set (``status`` "optimal") once the bound reaches the best J. ``update`` takes a
run's better plans and bounds in; ``check`` re-evaluates every stored plan.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable, Iterable, Iterator, Sequence
from contextlib import ExitStack, contextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from tsac_bench.batch.manifests import (
    PLAN_FOLDER,
    Manifest,
    iter_instance_files,
    manifest_lock,
    read_manifest,
    write_manifest,
)
from tsac_bench.batch.store import OK, ResultStore
from tsac_bench.errors import InputError
from tsac_bench.formulations.branch_price.options import NeighbourhoodSettings
from tsac_bench.formulations.network import canonical_routes
from tsac_bench.model import Instance, Solution
from tsac_bench.model.evaluator import cost_at_least, costs_agree, evaluate
from tsac_bench.model.io import (
    read_instance,
    read_solution,
    solution_instance_name,
    write_solution,
)
from tsac_bench.planning import PlanningState, mip_gap, recorded_claim
from tsac_bench.planning.simulator import offline_routes

TASK_BOUND = "tasks-on-their-own"
#: The key of a ``found_by`` or ``bound_by`` that ``improve`` made: its sources and plans.
IMPROVED = "improved_from"


def offline_plan(solution: Solution, instance: Instance) -> Solution:
    """``solution`` with the dynamic run's stamps removed, in canonical form (late visits
    dropped, amounts above a demand cut: docs/formulations.md, "canonical solutions"): an
    offline plan of no higher J. An infeasible plan is left as it is, for the checks to
    refuse: cutting its amounts could make it feasible, a plan no run found."""
    routes = offline_routes(solution.routes)
    if evaluate(instance, routes).feasible:
        routes = canonical_routes(instance, routes)
    return Solution(solution.instance, routes)


@dataclass(frozen=True)
class Change:
    """One improvement a run brought to a set: a lower J or a higher bound."""

    instance: str
    what: str  # "plan" or "bound"
    before: float | None
    after: float
    by: str


class _Set:
    """One directory of instances and its manifest, read once, written once."""

    def __init__(self, directory: Path) -> None:
        self.directory = directory
        manifest = read_manifest(directory)
        if manifest.problems and manifest.path.exists():
            manifest.require_valid()
        # An absent manifest starts empty; the entries made here give it its first content.
        self.manifest = Manifest(manifest.path, manifest.entries, [], manifest.budgets)
        self.instances = {read_instance(f).name: f for f in iter_instance_files([directory])
                          if f.parent == directory}
        self.changed = False

    def entry(self, name: str) -> dict[str, Any]:
        entry = self.manifest.entries.get(name)
        if entry is None:
            entry = {"file": self.instances[name].name, "J_star": None, "lower_bound": None,
                     "status": "feasible"}
            self.manifest.entries[name] = entry
        return entry


@contextmanager
def _held(directory: Path) -> Iterator[_Set]:
    """The set as it is now, read under its manifest lock (``manifest_lock``: other searches
    on it may have written since this one began) and written back, if changed, before the
    lock goes."""
    with manifest_lock(directory):
        current = _Set(directory)
        yield current
        if current.changed:
            write_manifest(current.manifest)


def _job_label(row: dict[str, Any], run_dir: Path) -> dict[str, Any]:
    return {**{key: row.get(key) for key in ("method", "settings", "mode", "seed", "budget")},
            "run": run_dir.name}


def _describe(found_by: dict[str, Any]) -> str:
    budget = found_by.get("budget")
    return (f"{found_by['method']} {found_by.get('mode', '')}".strip()
            + ("" if budget is None else f" @ {budget:g} s")
            + (" (bks improve)" if IMPROVED in found_by else ""))


def take_plan(entry: dict[str, Any], directory: Path, instance: Instance, solution: Solution,
              found_by: dict[str, Any], where: str) -> bool:
    """Store ``solution`` (offline, canonical) as the entry's best plan if its J is lower
    than the best known, or equal to it where no plan is stored yet (a manifest proved
    before plans were kept); returns whether it did. A plan below a proved J* refutes the
    proof: refused, loudly."""
    plan = offline_plan(solution, instance)
    cost = evaluate(instance, plan).J
    best, J_star = entry.get("best_J"), entry.get("J_star")
    if J_star is not None and not cost_at_least(cost, J_star):
        raise InputError(where, "J", f"{cost!r} from {_describe(found_by)} is below the proved "
                         f"J* {J_star!r}: the proof or the plan is wrong")
    if best is not None:
        no_lower = cost_at_least(cost, best)
        # Without a stored plan, one that matches the recorded best J is taken too.
        if no_lower and (entry.get("best_plan") or not costs_agree(cost, best)):
            return False
    relative = f"{PLAN_FOLDER}/{instance.name}.json"
    write_solution(plan.with_cost(cost).with_meta(found_by=found_by), instance,
                   directory / relative, compact=True)
    entry.update(best_J=cost, best_plan=relative, found_by=found_by)
    _settle(entry)
    return True


def take_bound(entry: dict[str, Any], bound: float, bound_by: dict[str, Any],
               where: str) -> bool:
    """Raise the entry's lower bound to ``bound`` if higher; returns whether it did. A bound
    above the best plan's J is a defect of whatever produced it: refused, loudly."""
    best = entry.get("best_J")
    if best is not None and not cost_at_least(best, bound):
        raise InputError(where, "lower_bound", f"{bound!r} from {_describe(bound_by)} is above "
                         f"the best-known J {best!r}: a bound that is not a bound")
    current = entry.get("lower_bound")
    # Within the evaluator's tolerance a bound is no news (solvers differ in the last bits).
    if current is not None and cost_at_least(current, bound):
        return False
    entry.update(lower_bound=bound, bound_by=bound_by)
    _settle(entry)
    return True


def _settle(entry: dict[str, Any]) -> None:
    """J* once the bound meets the best J (to the evaluator's tolerance); the gap `prove`
    recorded kept true."""
    best, bound = entry.get("best_J"), entry.get("lower_bound")
    if best is None or bound is None:
        return
    if "mip_gap" in entry:
        entry["mip_gap"] = mip_gap(best, bound)
    if cost_at_least(bound, best):
        entry.update(J_star=best, status="optimal")


def carried_over(old: dict[str, Any], new: dict[str, Any]) -> dict[str, Any]:
    """``new`` (an entry ``prove`` made afresh) with what ``old`` knew that it does not: the
    stored plan where no lower J came with ``new``, the bound where ``new``'s is lower."""
    entry = dict(new)
    if old.get("best_plan") and (entry.get("best_J") is None
                                 or cost_at_least(entry["best_J"], old["best_J"])):
        entry.update({key: old[key] for key in ("best_J", "best_plan", "found_by")})
    if old.get("lower_bound") is not None and (entry.get("lower_bound") is None or not
                                               cost_at_least(entry["lower_bound"],
                                                             old["lower_bound"])):
        entry["lower_bound"] = old["lower_bound"]
        if old.get("bound_by"):
            entry["bound_by"] = old["bound_by"]
    _settle(entry)
    return entry


def _take(target: _Set, entry: dict[str, Any], instance: Instance,
          solution: Solution | None, found_by: dict[str, Any], bound: float | None,
          bound_by: dict[str, Any], where: str) -> list[Change]:
    """Take a plan and a bound (either may be None) into ``entry``; the changes they made."""
    changes = []
    if solution is not None:
        before = entry.get("best_J") if entry.get("best_plan") else None
        if take_plan(entry, target.directory, instance, solution, found_by, where):
            changes.append(Change(instance.name, "plan", before, entry["best_J"],
                                  _describe(found_by)))
    if bound is not None:
        before = entry.get("lower_bound")
        if take_bound(entry, bound, bound_by, where):
            changes.append(Change(instance.name, "bound", before, entry["lower_bound"],
                                  _describe(found_by)))
    target.changed = target.changed or bool(changes)
    return changes


def update(run_dir: Path, sets: Iterable[Path] | None = None,
           note: Callable[[str], None] = print) -> list[Change]:
    """Take ``run_dir``'s better plans and bounds into the manifests of the instance sets
    (each a directory of instances; default: the directories of the run's instance files).
    A job's instance is found by name in a set; jobs of instances in no set are skipped, with
    one note saying how many."""
    with ResultStore(run_dir, create=False) as store:
        rows = [row for row in store.rows() if row["status"] == OK]
    if sets is None:
        sets = sorted({Path(row["instance_file"]).parent for row in rows
                       if row.get("instance_file")})
    changes: list[Change] = []
    skipped = 0
    with ExitStack() as stack:
        # Every set held from its read to its write, taken in one order (so that no two
        # updates wait on each other).
        held = {directory: stack.enter_context(_held(directory))
                for directory in sorted({Path(d).resolve() for d in sets})}
        loaded = [held[Path(d).resolve()] for d in sets]
        by_name = {name: s for s in loaded for name in s.instances}
        instances: dict[str, Instance] = {}
        for row in rows:
            target = by_name.get(row["instance"])
            if target is None:
                skipped += 1
                continue
            name = row["instance"]
            if name not in instances:
                instances[name] = read_instance(target.instances[name])
            instance = instances[name]
            entry = target.entry(name)
            found_by = _job_label(row, run_dir)
            solution = (read_solution(run_dir / row["solution_file"], instance)
                        if row.get("solution_file") else None)
            # The job's own claim (its stats), not the row's lower_bound column, which is the
            # manifest's bound copied in when the job was planned. A dynamic run's plan calls
            # bound their re-planning states, not the instance.
            _, bound = recorded_claim(row.get("stats"))
            changes += _take(target, entry, instance, solution, found_by,
                             bound if row["mode"] == "static" else None,
                             {**found_by, "time_limit": row.get("time_limit")},
                             f"{run_dir} job {row['key']}")
    if skipped:
        note(f"{skipped} job(s) of instances in none of the sets were left out")
    return changes


def _wanted(target: _Set, only: Sequence[str] | None) -> set[str]:
    unknown = sorted(set(only or ()) - set(target.instances))
    if unknown:
        raise InputError(str(target.directory), "--only", f"no instance named {unknown[0]!r} here")
    return set(only or target.instances)


def _source_plans(sources: Sequence[Path], wanted: set[str]) -> dict[str, list[Path]]:
    """The solution files of the ``wanted`` instances among ``sources`` (run directories,
    whose finished jobs' plans count, or solution files), by instance."""
    files: dict[str, list[Path]] = {}
    for source in sources:
        if source.is_file():
            planned = [(solution_instance_name(source), source)]
        else:
            with ResultStore(source, create=False) as store:
                planned = [(row["instance"], source / row["solution_file"])
                           for row in store.rows()
                           if row["status"] == OK and row.get("solution_file")]
        for name, path in planned:
            if name in wanted:
                files.setdefault(name, []).append(path)
    return files


def _known_plans(target: _Set, name: str, instance: Instance, paths: Sequence[Path]
                 ) -> list[Solution]:
    """The offline plans of ``paths`` and the instance's best-known plan."""
    entry = target.entry(name)
    solutions = [offline_plan(read_solution(path, instance), instance) for path in paths]
    if entry.get("best_plan"):
        solutions.append(read_solution(target.directory / entry["best_plan"], instance))
    return solutions


def recombine(directory: Path, sources: Sequence[Path], time_limit: float,
              only: Sequence[str] | None = None) -> list[Change]:
    """Each instance of ``directory`` that the sources planned (run directories, or
    solution files such as a set's earlier best-known plans) gets the plan of least J over
    the routes of all their plans of it and of its best-known plan
    (``formulations/branch_price/recombine.py``, ``time_limit`` seconds of MIP each), where
    that is lower than its best-known J. ``only``: those instances."""
    from tsac_bench.formulations.branch_price.recombine import recombined_plan

    target = _Set(directory)
    files = _source_plans(sources, _wanted(target, only))
    found_by = {"method": "recombine", "runs": [source.name for source in sources],
                "time_limit": time_limit}
    changes = []
    for name, paths in sorted(files.items()):
        instance = read_instance(target.instances[name])
        solutions = _known_plans(target, name, instance, paths)
        routes = recombined_plan(instance, [s.routes for s in solutions], time_limit)
        if routes is None:
            continue
        with _held(directory) as now:
            changes += _take(now, now.entry(name), instance, Solution(name, routes),
                             {**found_by, "plans": len(solutions)}, None, {},
                             f"recombining {name}")
    return changes


def improve(directory: Path, sources: Sequence[Path], time_limit: float,
            only: Sequence[str] | None = None,
            note: Callable[[str], None] = print) -> list[Change]:
    """Search each instance of ``directory`` (``only``: those; else those the sources
    planned, or every instance where there are no sources) with ``exact-bp`` for
    ``time_limit`` seconds, its own starts joined by the instance's best-known plan and the
    sources' plans of it (every route of them a column of its master: the integer master
    and the dives recombine them with the routes it prices); take its plan where lower and
    its bound where higher. The manifest is written after each instance, so a stopped
    search keeps what the finished ones found."""
    from tsac_bench.solvers.exact import BranchPriceAllocator

    target = _Set(directory)
    wanted = _wanted(target, only)
    files = _source_plans(sources, wanted)
    search = BranchPriceAllocator()
    # As a run's job records them: the settings in order, the time limit beside them.
    label = {"method": search.name, "settings": dict(sorted(search.settings().items())),
             "mode": "static", "seed": 0, "budget": None, "time_limit": time_limit}
    changes = []
    for name in sorted(wanted if only or not sources else files):
        instance = read_instance(target.instances[name])
        plans = _known_plans(target, name, instance, files.get(name, ()))
        note(f"{name}: exact-bp for {time_limit:g} s from {len(plans)} known plan(s)")
        result = search.plan_from(PlanningState.static(instance), [p.routes for p in plans],
                                  time_limit=time_limit)
        found_by = {**label, IMPROVED: {"sources": [source.name for source in sources],
                                        "plans": len(plans)}}
        with _held(directory) as now:
            changes += _take(now, now.entry(name), instance, Solution(name, result.routes),
                             found_by, result.lower_bound, found_by, f"improving {name}")
    return changes


def neighbourhood_search(directory: Path, time_limit: float,
                         only: Sequence[str] | None = None,
                         settings: NeighbourhoodSettings | None = None, *,
                         seed: int = 0, note: Callable[[str], None] = print) -> list[Change]:
    """Search the best-known plan of each unproved instance of ``directory`` (``only``:
    those) for ``time_limit`` seconds with exact-bp repairs of a few related AAVs and the
    tasks near them (``formulations/branch_price/neighbourhoods.py``; ``settings``: None,
    the defaults); take its plan where lower."""
    from tsac_bench.formulations.branch_price.neighbourhoods import search

    settings = settings or NeighbourhoodSettings()
    target = _Set(directory)
    found_by = {"method": "lns", "settings": dataclasses.asdict(settings),
                "mode": "static", "seed": seed, "budget": None, "time_limit": time_limit}
    changes = []
    for name in sorted(_wanted(target, only)):
        entry = target.entry(name)
        if entry.get("J_star") is not None or not entry.get("best_plan"):
            continue
        instance = read_instance(target.instances[name])
        start = read_solution(directory / entry["best_plan"], instance)
        note(f"{name}: neighbourhood search for {time_limit:g} s from J {entry['best_J']:.6f}")
        plan, report = search(instance, start.routes, time_limit, settings, seed=seed,
                              note=lambda line: note(f"  {line}"))
        with _held(directory) as now:
            changes += _take(now, now.entry(name), instance, Solution(name, plan),
                             {**found_by, "repairs": report.repairs}, None, {},
                             f"searching {name}")
    return changes


def add_task_bounds(directory: Path) -> int:
    """Give every instance of ``directory`` at least the tasks-on-their-own bound (cheap:
    0.06 s at 32/80); returns how many bounds it raised."""
    from tsac_bench.formulations.task_bound import task_lower_bound
    from tsac_bench.planning import PlanningState

    raised = 0
    with _held(directory) as target:
        for name, path in sorted(target.instances.items()):
            bound = task_lower_bound(PlanningState.static(read_instance(path)))
            if take_bound(target.entry(name), bound, {"method": TASK_BOUND}, str(path)):
                raised += 1
        target.changed = raised > 0
    return raised


@dataclass(frozen=True)
class PlanCheck:
    instance: str
    stored: float | None
    evaluated: float | None
    problem: str | None

    @property
    def passed(self) -> bool:
        return self.problem is None


def check(directory: Path) -> list[PlanCheck]:
    """Re-evaluate every best plan of ``directory``'s manifest: its J must equal the stored
    best J, and neither the bound nor J* (where set) may exceed it. A best J above J* is no
    fault: the proof's own plan was not kept, and no run has matched it since."""
    manifest = read_manifest(directory).require_valid()
    checks = []
    for name, entry in sorted(manifest.entries.items()):
        if entry.get("best_plan") is None:
            continue
        instance = read_instance(directory / entry["file"])
        try:
            plan = read_solution(directory / entry["best_plan"], instance)
            cost = evaluate(instance, plan).J
        except (OSError, ValueError, InputError) as exc:
            checks.append(PlanCheck(name, entry.get("best_J"), None, f"unreadable: {exc}"))
            continue
        best, bound, J_star = entry.get("best_J"), entry.get("lower_bound"), entry.get("J_star")
        problem = None
        if best is None or not costs_agree(cost, best):
            problem = f"plan evaluates to {cost!r}, best_J says {best!r}"
        elif bound is not None and not cost_at_least(best, bound):
            problem = f"lower_bound {bound!r} above best_J"
        elif J_star is not None and not cost_at_least(best, J_star):
            problem = f"best_J below the proved J_star {J_star!r}"
        checks.append(PlanCheck(name, best, cost, problem))
    return checks


def bound_kind(entry: dict[str, Any]) -> str:
    """Where an entry's bound stands: ``proved``, a ``search``'s bound (an exact method's
    after its time limit), only the bound that needs no search (``tasks-on-their-own``), or
    ``none``."""
    if entry.get("status") == "optimal":
        return "proved"
    if entry.get("lower_bound") is None:
        return "none"
    return TASK_BOUND if (entry.get("bound_by") or {}).get("method") == TASK_BOUND \
        else "search"


def table(directory: Path) -> list[dict[str, Any]]:
    """The manifest's best-known entries as rows (instance, J, bound, gap, proved, the kind
    of bound, who found the plan and proved the bound, and in which run directory): what
    ``tsac-bench bks show`` prints."""
    manifest = read_manifest(directory).require_valid()
    rows = []
    for name, entry in sorted(manifest.entries.items()):
        best, bound = entry.get("best_J"), entry.get("lower_bound")
        row = {"instance": name, "best_J": best, "lower_bound": bound,
               "gap": None if best is None or bound is None else mip_gap(best, bound),
               "proved": entry.get("status") == "optimal", "bound_kind": bound_kind(entry)}
        for key in ("found", "bound"):
            source = entry.get(f"{key}_by")
            row[f"{key}_by"] = _describe(source) if source else None
            row[f"{key}_in"] = source.get("run") if source else None
        rows.append(row)
    return rows
