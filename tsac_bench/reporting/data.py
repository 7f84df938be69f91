"""The data of a report, read from a run directory: the jobs frame, the exact references of
each instance (J* and lower bound), the per-instance frame every table and figure starts from,
and what the stored solutions and re-plans say (coalitions, the cost of each re-plan).

How the numbers are made (docs/reports.md says the same for readers of a report):
* Only jobs with status ``ok`` have a J; failed jobs are counted, never averaged.
* Per instance, J is first averaged over seeds; the statistics of a (mode, scale, method) cell
  are then taken over its instances.
* J* of an instance is the manifest's ``J_star``; failing that, the smallest J of a static run
  of a method that proves optimality whose plan's status is optimal (``PlanResult.status``,
  in the stored stats). The lower bound is the largest of the manifest's ``lower_bound`` and
  those runs' lower bounds.
  gap = (J - J*) / J*; where J* is unknown, ``gap_best`` = (J - B) / B with B the best J known
  (the manifest's ``best_J`` or the run's lowest J of the instance, whichever is lower) and
  ``gap_lb`` = (J - LB) / LB: the true gap lies between them.

Method labels are whatever the store's ``method`` column holds (a registered name or a method
spec such as ``hocf:init=incumbent``); nothing here takes them apart. A job with a budget per
plan call is its own series, ``hocf @ 1 s`` (``method_label``): no table or figure averages
over budgets, and a store without budgets shows its labels as they are.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from tsac_bench.batch.store import OK, ResultStore
from tsac_bench.model.evaluator import cost_at_least
from tsac_bench.planning import ALL_MODES, PlanStatus, is_exact_method, recorded_claim


def load(run_dir: str | Path) -> pd.DataFrame:
    with ResultStore(run_dir, create=False) as store:
        return store.frame()


def load_meta(run_dir: str | Path) -> dict[str, Any]:
    with ResultStore(run_dir, create=False) as store:
        return store.meta()


def seconds_text(seconds: float) -> str:
    """A budget as every table and caption prints it: ``0.1 s``, ``1 s``."""
    return f"{seconds:g} s"


def method_label(method: str, budget: float | None) -> str:
    """The series a job belongs to: its method label, with its budget where it had one."""
    if budget is None or pd.isna(budget):
        return method
    return f"{method} @ {seconds_text(budget)}"


def series_labels(frame: pd.DataFrame) -> pd.Series:
    """Each job's series (``method_label`` of its method and budget), on ``frame``'s index."""
    return pd.Series([method_label(m, b) for m, b in zip(frame["method"], frame["budget"],
                                                          strict=True)],
                     index=frame.index, dtype=object)


def by_series(frame: pd.DataFrame) -> pd.DataFrame:
    """``frame`` with each job's ``method`` replaced by its series (``method_label``) and no
    ``budget`` column, which the label now carries (so a second call changes nothing); a frame
    without one (hand-made, or read from an old export) as it is."""
    if "budget" not in frame.columns:
        return frame
    return frame.assign(method=series_labels(frame)).drop(columns="budget")


def scale_order(scales: Sequence[str]) -> list[str]:
    """``N/M`` labels by fleet size then task count (4/10 before 16/40)."""

    def key(scale: str) -> tuple[int, ...]:
        try:
            return tuple(int(part) for part in scale.split("/"))
        except ValueError:
            return (math.inf,)  # type: ignore[return-value]

    return sorted(set(scales), key=lambda s: (key(s), s))


def ordered_modes(modes: Sequence[str]) -> list[str]:
    known = [m for m in ALL_MODES if m in set(modes)]
    return known + sorted(set(modes) - set(ALL_MODES))


def references(frame: pd.DataFrame) -> pd.DataFrame:
    """Per instance: J_star, lower_bound and where J* came from (see the module notes)."""
    instances = frame["instance"].drop_duplicates().sort_values()
    refs = pd.DataFrame(index=pd.Index(instances, name="instance"))
    # A frame made by hand (not read from a store) may lack the newer best_J column.
    columns = [c for c in ("J_star", "lower_bound", "best_J") if c in frame]
    manifest = frame.groupby("instance")[columns].max().reindex(columns=["J_star",
                                                                       "lower_bound", "best_J"])
    refs["J_star"] = manifest["J_star"]
    refs["lower_bound"] = manifest["lower_bound"]
    # Every ok job's plan is feasible offline with no higher J (docs/model.md, "The dynamic
    # run"), so the run's own lowest J of an instance, in any mode, is a best known J too.
    run_best = frame[frame["status"] == OK].groupby("instance")["J"].min()
    refs["best_J"] = pd.concat([manifest["best_J"], run_best], axis=1).min(axis=1)
    refs["J_star_source"] = np.where(refs["J_star"].notna(), "manifest", None)
    exact = frame[frame["method"].map(is_exact_method).astype(bool) & (frame["mode"] == "static")
                  & (frame["status"] == OK)]
    for instance, rows in exact.groupby("instance"):
        claims = [recorded_claim(stats) for stats in rows["stats"]]
        optimal = rows[[status == PlanStatus.OPTIMAL for status, _ in claims]]
        if pd.isna(refs.at[instance, "J_star"]) and not optimal.empty:
            refs.at[instance, "J_star"] = optimal["J"].min()
            refs.at[instance, "J_star_source"] = "exact run"
        bounds = [bound for _, bound in claims if bound is not None]
        if bounds:
            refs.at[instance, "lower_bound"] = np.nanmax([refs.at[instance, "lower_bound"],
                                                          *bounds])
    return refs


def per_instance(frame: pd.DataFrame) -> pd.DataFrame:
    """One row per (mode, scale, instance, method): J and its terms averaged over the seeds
    that succeeded, with the instance's references and gaps; ``method`` is the series
    (``method_label``)."""
    ok = by_series(frame[frame["status"] == OK])
    keys = ["mode", "scale", "instance", "method"]
    values = ["J", "J_load", "J_time", "J_op", "runtime"]
    if ok.empty:
        table = pd.DataFrame(columns=[*keys, *values, "seeds"])
    else:
        grouped = ok.groupby(keys, sort=True)
        table = grouped[values].mean()
        table["seeds"] = grouped.size()
        table = table.reset_index()
    table = table.merge(references(frame), left_on="instance", right_index=True, how="left")
    j_star = table["J_star"].where(table["J_star"] > 0)
    bound = table["lower_bound"].where(table["lower_bound"] > 0)
    table["gap"] = (table["J"] - j_star) / j_star
    table["gap_lb"] = ((table["J"] - bound) / bound).where(j_star.isna())
    best = table["best_J"].where(table["best_J"] > 0)
    table["gap_best"] = ((table["J"] - best) / best).where(j_star.isna())
    return table


def below_reference(frame: pd.DataFrame) -> pd.DataFrame:
    """Jobs whose J is below their instance's J* or lower bound. Every executed plan is a
    feasible offline solution (docs/model.md, "The dynamic run"), so J >= J* >= LB always; a
    row here is a bug in an exact model, the evaluator or the simulator (or a wrong
    manifest)."""
    ok = frame[frame["status"] == OK].drop(columns=["J_star", "lower_bound"])
    ok = ok.merge(references(frame), left_on="instance", right_index=True, how="left")
    floor = ok[["J_star", "lower_bound"]].max(axis=1)
    at_least = [cost_at_least(j, f) if pd.notna(f) else True for j, f in zip(ok["J"], floor,
                                                                             strict=True)]
    below = ~pd.Series(at_least, index=ok.index, dtype=bool)
    return ok.loc[below, ["key", "J", "J_star", "lower_bound", "J_star_source"]]


class SolutionLoader:
    """Instances and stored solutions of a run, read back (instances cached by file)."""

    def __init__(self, run_dir: Path) -> None:
        self.run_dir = run_dir
        self._instances: dict[str, Any] = {}

    def instance(self, row: Any) -> Any | None:
        from tsac_bench.errors import InputError
        from tsac_bench.model.io import read_instance

        path = row["instance_file"]
        if not isinstance(path, str):
            return None
        if path not in self._instances:
            try:
                self._instances[path] = read_instance(path)
            except InputError:
                self._instances[path] = None  # moved since the run: its figures are skipped
        return self._instances[path]

    def solution(self, row: Any) -> tuple[Any, Any] | None:
        """(instance, solution) of an ok row, or None where a file is gone."""
        from tsac_bench.errors import InputError
        from tsac_bench.model.io import read_solution

        instance = self.instance(row)
        if instance is None or not isinstance(row["solution_file"], str):
            return None
        try:
            return instance, read_solution(self.run_dir / row["solution_file"], instance)
        except InputError:
            return None


def coalition_sizes(frame: pd.DataFrame, run_dir: Path) -> pd.DataFrame:
    """Per served task of every ok job: its demand and coalition size, as the evaluator
    computes them from the stored solution (the data of the paper's Fig. 6)."""
    from tsac_bench.model.evaluator import CostEvaluator

    loader = SolutionLoader(run_dir)
    rows = []
    for _, row in by_series(frame[frame["status"] == OK]).iterrows():
        loaded = loader.solution(row)
        if loaded is None:
            continue
        instance, solution = loaded
        evaluation = CostEvaluator(instance).evaluate(solution)
        for task, breakdown in zip(instance.tasks, evaluation.per_task, strict=True):
            if breakdown.coalition:
                rows.append({"mode": row["mode"], "method": row["method"],
                             "instance": row["instance"], "seed": row["seed"],
                             "task": task.id, "demand": task.demand,
                             "coalition_size": len(breakdown.coalition)})
    return pd.DataFrame(rows, columns=["mode", "method", "instance", "seed", "task", "demand",
                                       "coalition_size"])


def replan_records(stats: Any) -> list[Any]:
    """The simulator's per-re-plan records in a job's stats (``replans``)."""
    if not isinstance(stats, dict):
        return []
    return list(stats.get("replans") or [])


def replan_costs(stats: Any, instance: Any) -> tuple[list[float], list[float]]:
    """Times of a dynamic run's re-plans and the J of the plan in force after each, over the
    tasks released by then (the simulator's ``J_known``).

    A record without ``J_known`` (stores written before the simulator kept it) has only
    ``J``, over every task of the instance; the tasks not yet released are unserved in any
    plan of that moment (an allocator sees only released tasks), so each adds exactly the
    instance's unserved-task cost, which is taken off. A record without a time or a cost
    makes the curve unknown: ([], [])."""
    times: list[float] = []
    costs: list[float] = []
    for record in replan_records(stats):
        if not isinstance(record, dict) or record.get("time") is None:
            return [], []
        t = float(record["time"])
        if record.get("J_known") is not None:
            cost = float(record["J_known"])
        elif record.get("J") is not None:
            unreleased = sum(1 for task in instance.tasks if task.release > t)
            cost = float(record["J"]) - unreleased * instance.unserved_task_cost
        else:
            return [], []
        times.append(t)
        costs.append(cost)
    return times, costs
