"""The report's figures (matplotlib, Agg backend), each saved as PNG and PDF.

* box plots of J per method and scale (the paper's Fig. 7);
* Dolan-More performance profiles over the gap to J*;
* mean coalition size against task demand per method (Fig. 6, coalitions computed by the
  evaluator from the stored solutions);
* for one dynamic instance, a Gantt chart of every AAV's visits with, where the run's stats
  carry the simulator's re-plans, the J of the plan in force after each re-plan (Fig. 5);
* route maps of one instance per scale;
* J against the budget per plan call (``budgets.budget_curves``), drawn by the report's
  section on budgets.

Every figure is drawn from the frames and objects of ``data`` (and ``stats`` for the
performance ratios); nothing here reads a store or writes a table. Imported only when a report
draws figures: ``import tsac_bench`` never loads matplotlib.
"""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path
from typing import Any

import matplotlib

matplotlib.use("Agg")

import matplotlib.pyplot as plt
import numpy as np
import pandas as pd

from tsac_bench.batch.store import OK
from tsac_bench.planning.settings import file_label
from tsac_bench.reporting.data import (
    SolutionLoader,
    by_series,
    coalition_sizes,
    ordered_modes,
    replan_costs,
    replan_records,
    scale_order,
    seconds_text,
)
from tsac_bench.reporting.stats import performance_ratios

Figure = tuple[str, list[Path], str]  # title, PNG paths, note
#: Route maps and Gantt charts draw at most this many methods side by side.
MAX_PANELS = 8


def _save(fig: Any, path: Path) -> Path:
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path.with_suffix(".png"), dpi=150, bbox_inches="tight")
    # No creation date: a report re-written from the same results is the same file.
    fig.savefig(path.with_suffix(".pdf"), bbox_inches="tight",
                metadata={"CreationDate": None})
    plt.close(fig)
    return path.with_suffix(".png")


def draw_all(frame: pd.DataFrame, instances: pd.DataFrame, run_dir: Path,
             out: Path) -> list[Figure]:
    """Every figure the run's data allows; a figure without data is listed with a note."""
    frame = by_series(frame)  # a method at a budget is a panel and a file of its own
    figures: list[Figure] = []
    modes = ordered_modes(frame["mode"].unique())
    loader = SolutionLoader(run_dir)
    for mode in modes:
        rows = instances[(instances["mode"] == mode) & instances["J"].notna()]
        if rows.empty:
            continue
        figures.append((f"Total cost J per method and scale ({mode}; paper Fig. 7)",
                        [_save(box_plots(rows), out / f"boxplot-J-{mode}")], ""))
        figures.append(_profile(rows, mode, out))
    coalitions = coalition_sizes(frame, run_dir)
    for mode in modes:
        data = coalitions[coalitions["mode"] == mode]
        if not data.empty:
            figures.append((f"Coalition size against task demand ({mode}; paper Fig. 6)",
                            [_save(coalition_figure(data), out / f"coalitions-{mode}")],
                            "Mean number of AAVs serving a task, over the served tasks of every "
                            "run, by demand."))
    figures.append(dynamic_gantt(frame, loader, out))
    maps = list(_route_maps(frame, loader, out))
    if maps:
        figures.append(("Route maps (one instance per scale)", maps,
                        "Squares: depots; triangles up/down: pickup/delivery tasks (size by "
                        "demand); circles: AAV starts."))
    return figures


# --- Fig. 7 ------------------------------------------------------------------------------
def box_plots(rows: pd.DataFrame) -> Any:
    """One panel per scale, one box per method: J per instance (mean over seeds)."""
    scales = scale_order(rows["scale"].unique())
    methods = sorted(rows["method"].unique())
    fig, axes = plt.subplots(1, len(scales), figsize=(max(4.0, 2.6 * len(scales)), 3.6),
                             squeeze=False)
    for ax, scale in zip(axes[0], scales, strict=True):
        data = [rows[(rows["scale"] == scale) & (rows["method"] == m)]["J"].to_numpy()
                for m in methods]
        ax.boxplot(data, tick_labels=methods, showmeans=True)
        ax.set_title(f"{scale}")
        ax.tick_params(axis="x", rotation=45)
        ax.grid(axis="y", alpha=0.3)
    axes[0][0].set_ylabel("total cost J")
    fig.suptitle("Total cost per method and scale (N AAVs / M tasks)")
    fig.tight_layout()
    return fig


# --- performance profiles ----------------------------------------------------------------
def _profile(rows: pd.DataFrame, mode: str, out: Path) -> Figure:
    ratios, basis = performance_ratios(rows)
    values = ratios.to_numpy()
    top = max(1.0 + 1e-9, float(values[np.isfinite(values)].max(initial=1.0)))
    taus = np.linspace(1.0, top * 1.02, 400)
    fig, ax = plt.subplots(figsize=(5.2, 3.6))
    for method in sorted(ratios.columns):
        share = [(ratios[method] <= tau).mean() for tau in taus]
        ax.step((taus - 1.0) * 100.0, share, where="post", label=method)
    ax.set_xlabel(f"gap to {'J*' if basis == 'J*' else 'reference'} (%)")
    ax.set_ylabel("share of instances within the gap")
    ax.set_ylim(-0.02, 1.02)
    ax.grid(alpha=0.3)
    ax.legend(fontsize="small")
    ax.set_title(f"Performance profile ({mode})")
    fig.tight_layout()
    return (f"Performance profile over gaps ({mode})",
            [_save(fig, out / f"profile-{mode}")],
            f"Dolan-More profile: share of instances on which a method's J is within the given "
            f"gap of the reference ({basis}).")


# --- Fig. 6 ------------------------------------------------------------------------------
def coalition_figure(data: pd.DataFrame) -> Any:
    """Grouped bars: mean coalition size per task demand, one bar per method."""
    means = data.groupby(["demand", "method"])["coalition_size"].mean().unstack("method")
    methods = sorted(means.columns)
    demands = means.index.to_numpy()
    width = 0.8 / max(1, len(methods))
    fig, ax = plt.subplots(figsize=(max(5.0, 0.9 * len(demands) + 2), 3.6))
    positions = np.arange(len(demands))
    for i, method in enumerate(methods):
        ax.bar(positions + (i - (len(methods) - 1) / 2) * width, means[method].to_numpy(),
               width, label=method)
    ax.set_xticks(positions, [str(d) for d in demands])
    ax.set_xlabel("task demand (kg)")
    ax.set_ylabel("mean coalition size (AAVs)")
    ax.grid(axis="y", alpha=0.3)
    ax.legend(fontsize="small")
    fig.tight_layout()
    return fig


# --- Fig. 5 ------------------------------------------------------------------------------
def dynamic_gantt(frame: pd.DataFrame, loader: SolutionLoader, out: Path) -> Figure:
    title = "Dynamic run: AAV visits and the cost of the plan after each re-plan (paper Fig. 5)"
    ok = frame[(frame["status"] == OK) & (frame["mode"] == "dynamic")].sort_values("key")
    if ok.empty:
        return title, [], "No dynamic run in this results store."
    has_replans = ok["stats"].map(lambda s: bool(replan_records(s)))
    chosen = ok[has_replans] if has_replans.any() else ok
    instance_name = chosen.iloc[0]["instance"]
    rows = chosen[(chosen["instance"] == instance_name)]
    rows = rows[rows["seed"] == rows["seed"].min()].head(MAX_PANELS)
    paths = []
    for _, row in rows.iterrows():
        loaded = loader.solution(row)
        if loaded is None:
            continue
        instance, solution = loaded
        fig = gantt_figure(instance, solution, replan_costs(row["stats"], instance),
                           f"{instance.name}: {row['method']} (J = {row['J']:.2f})")
        paths.append(_save(fig, out / f"gantt-{instance.name}-{file_label(row['method'])}"))
    note = ("Lower panel: J of the plan in force after each re-plan, over the tasks released "
            "by then (a task released later is not in it).") if has_replans.any() else (
            "The runs carry no re-plans (stats['replans']): only the visits are drawn.")
    return title, paths, note


#: The cost panel's axis label: what its curve is.
COST_AXIS_LABEL = "J of the plan in force\nafter each re-plan\n(released tasks)"


def gantt_figure(instance: Any, solution: Any, curve: tuple[list[float], list[float]],
                 title: str) -> Any:
    """Top: one lane per AAV, a bar per leg (flight solid, waiting for the window hatched),
    labelled with the node it reaches. Bottom (when the run has re-plans): the J of the plan
    in force after each re-plan (``data.replan_costs``), held until the next."""
    from tsac_bench.model.evaluator import CostEvaluator

    times, costs = curve
    evaluator = CostEvaluator(instance)
    traces = [evaluator.trace(n, route) for n, route in enumerate(solution.routes)]
    end = max((t.arrivals[-1] for t in traces if t.arrivals), default=1.0)
    lanes = 2 if times else 1
    fig, axes = plt.subplots(lanes, 1, figsize=(9, 1.0 + 0.55 * instance.n_aavs + 2.2 *
                                                (lanes - 1)), squeeze=False, sharex=True,
                             gridspec_kw={"height_ratios": [max(2, instance.n_aavs), 2][:lanes]})
    ax = axes[0][0]
    colours = plt.get_cmap("tab20")
    ids = instance.node_ids
    for n, trace in enumerate(traces):
        prev, clock = instance.start_node(n), 0.0
        for visit, arrival in zip(trace.route, trace.arrivals, strict=True):
            flight = instance.dist[prev][visit.node] / instance.aavs[n].speed
            depot = instance.is_depot(visit.node)
            colour = "0.6" if depot else colours(visit.node % 20)
            ax.barh(n, flight, left=clock, height=0.6, color=colour, edgecolor="k", lw=0.3)
            if arrival > clock + flight:
                ax.barh(n, arrival - clock - flight, left=clock + flight, height=0.6,
                        color="none", edgecolor=colour, hatch="///", lw=0.3)
            if flight >= end / 40:  # no label on a sliver (a start at the depot)
                text = ids[visit.node] if depot else f"{ids[visit.node]}:{visit.amount}"
                ax.text(clock + flight / 2, n, text, ha="center", va="center", fontsize=6)
            prev, clock = visit.node, arrival
    ax.set_yticks(range(instance.n_aavs), [a.id for a in instance.aavs])
    ax.invert_yaxis()
    ax.set_title(title)
    releases = sorted({t.release for t in instance.tasks if t.release > 0})
    for t in releases:
        for row in axes:
            row[0].axvline(t, color="r", ls="--", lw=0.8)
    if times:
        times = [*times, max(end, times[-1])]  # the last plan's cost holds to the end
        costs = [*costs, costs[-1]]
        cost_ax = axes[1][0]
        cost_ax.step(times, costs, where="post", marker="o")
        cost_ax.set_ylabel(COST_AXIS_LABEL, fontsize=8)
        cost_ax.grid(alpha=0.3)
    axes[-1][0].set_xlabel("time (s); dashed: task releases")
    fig.tight_layout()
    return fig


# --- cost against budget ----------------------------------------------------------------
def cost_against_budget(curves: pd.DataFrame, mode: str, reference: float | None,
                        out: Path) -> Figure:
    """The figure of J against budget of one mode (``budget_figure``), saved."""
    note = ("Median J over the instances (each J the mean over seeds) per method against the "
            "budget per plan call, log scale, with the interquartile range as a band"
            + ("; top axis: the budget in reference units." if reference else "."))
    return (f"Total cost J against the budget per plan call ({mode})",
            [_save(budget_figure(curves[curves["mode"] == mode], reference),
                   out / f"budget-J-{mode}")], note)


def budget_figure(curves: pd.DataFrame, reference: float | None = None) -> Any:
    """One panel per scale: per method, the median J against the budget (log x axis) and
    the band between the quartiles; a top axis in reference units where ``reference`` (the
    calibration's seconds) is known."""
    scales = scale_order(curves["scale"].unique())
    budgets = sorted(curves["budget"].unique())
    fig, axes = plt.subplots(1, len(scales), figsize=(max(4.4, 3.2 * len(scales)), 3.6),
                             squeeze=False)
    for ax, scale in zip(axes[0], scales, strict=True):
        rows = curves[curves["scale"] == scale]
        for method in sorted(rows["method"].unique()):
            line = rows[rows["method"] == method].sort_values("budget")
            drawn = ax.plot(line["budget"], line["median"], marker="o", label=method)
            ax.fill_between(line["budget"], line["q1"], line["q3"], alpha=0.2,
                            color=drawn[0].get_color(), lw=0)
        ax.set_xscale("log")
        ax.set_xticks(budgets, [seconds_text(b) for b in budgets])
        ax.minorticks_off()
        ax.set_xlabel("budget per plan call")
        ax.set_title(scale)
        ax.grid(alpha=0.3)
        if reference:
            top = ax.secondary_xaxis("top", functions=(lambda b: b / reference,
                                                       lambda u: u * reference))
            units = [b / reference for b in budgets]
            top.set_xticks(units, [f"{u:.3g}" for u in units])
            top.minorticks_off()
            top.set_xlabel("reference units", fontsize="small")
    axes[0][0].set_ylabel("total cost J")
    axes[0][-1].legend(fontsize="small")
    fig.tight_layout()
    return fig


# --- route maps --------------------------------------------------------------------------
def _route_maps(frame: pd.DataFrame, loader: SolutionLoader, out: Path) -> Iterator[Path]:
    ok = frame[frame["status"] == OK]
    if ok.empty:
        return
    mode = "static" if (ok["mode"] == "static").any() else ok["mode"].iloc[0]
    ok = ok[ok["mode"] == mode]
    for scale in scale_order(ok["scale"].unique()):
        first = sorted(ok[ok["scale"] == scale]["instance"].unique())[0]
        rows = ok[(ok["instance"] == first)]
        rows = rows[rows["seed"] == rows["seed"].min()].sort_values("method").head(MAX_PANELS)
        panels = [(row, loader.solution(row)) for _, row in rows.iterrows()]
        panels = [(row, loaded) for row, loaded in panels if loaded is not None]
        if not panels:
            continue
        cols = min(4, len(panels))
        lines = -(-len(panels) // cols)
        fig, axes = plt.subplots(lines, cols, figsize=(3.6 * cols, 3.6 * lines), squeeze=False)
        for ax in axes.flat[len(panels):]:
            ax.axis("off")
        for ax, (row, (instance, solution)) in zip(axes.flat, panels, strict=False):
            route_map(ax, instance, solution)
            ax.set_title(f"{row['method']}: J = {row['J']:.2f}", fontsize=9)
        fig.suptitle(f"{first} ({scale}, {mode})")
        fig.tight_layout()
        yield _save(fig, out / f"routes-{first}")


def route_map(ax: Any, instance: Any, solution: Any) -> None:
    pos = instance.positions / 1000.0
    colours = plt.get_cmap("tab10")
    for n, route in enumerate(solution.routes):
        if not route:
            continue
        path = pos[[instance.start_node(n), *[v.node for v in route]]]
        ax.plot(path[:, 0], path[:, 1], "-", color=colours(n % 10), lw=1.0, alpha=0.8,
                label=instance.aavs[n].id)
    for m, task in enumerate(instance.tasks):
        ax.scatter(*pos[m], marker="^" if task.kind.value == "P" else "v",
                   s=10 + 2 * task.demand, color="k", zorder=3)
        ax.annotate(task.id, pos[m], fontsize=6, xytext=(2, 2), textcoords="offset points")
    depots = pos[list(instance.depot_nodes)]
    ax.scatter(depots[:, 0], depots[:, 1], marker="s", s=40, color="0.3", zorder=3)
    starts = pos[[instance.start_node(n) for n in range(instance.n_aavs)]]
    ax.scatter(starts[:, 0], starts[:, 1], marker="o", s=25, facecolors="none",
               edgecolors="k", zorder=3)
    ax.set_aspect("equal")
    ax.set_xlabel("x (km)")
    ax.set_ylabel("y (km)")
    ax.tick_params(labelsize=7)
    ax.legend(fontsize=6, loc="best")
