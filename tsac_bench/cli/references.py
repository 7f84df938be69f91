"""What is known of the optima: ``verify`` against a set's manifest and the best-known plans
and bounds (``bks``)."""

from __future__ import annotations

import enum
from pathlib import Path
from typing import TYPE_CHECKING, Annotated

import typer
from rich.table import Table

from tsac_bench.cli.app import app, console, say_error, user_errors
from tsac_bench.formulations.branch_price.options import (
    NEIGHBOURHOOD_ORDERS,
    NeighbourhoodSettings,
)

#: The choices of ``bks lns --order``, as typer takes a choice.
NeighbourhoodOrder = enum.Enum("NeighbourhoodOrder", {o: o for o in NEIGHBOURHOOD_ORDERS},
                               type=str)
DEFAULT_ORDER = NeighbourhoodOrder(NeighbourhoodSettings.order)

if TYPE_CHECKING:
    from tsac_bench.batch.best_known import Change


@app.command()
@user_errors
def verify(
    directory: Annotated[Path, typer.Argument(metavar="DIR", help="a directory with a "
                                              "manifest.json of proven optima")],
    method: Annotated[list[str] | None, typer.Option(
        help="exact backend(s) to re-run (default: every method that proves optimality)")]
    = None,
    only: Annotated[list[str] | None, typer.Option(help="instance name(s) to check")] = None,
    time_limit: Annotated[float | None, typer.Option(help="seconds per solve")] = 600.0,
    threads: Annotated[int, typer.Option(min=1)] = 1,
    plans_only: Annotated[bool, typer.Option(
        "--plans-only", help="only re-evaluate the stored best-known plans (seconds for a "
        "whole set), re-solve nothing")] = False,
) -> None:
    """Re-evaluate a directory's best-known plans, then re-solve its instances and compare
    with its manifest (exit 1 on failure)."""
    from tsac_bench.batch import best_known
    from tsac_bench.batch.verify import verify as run_verify

    plans = [c for c in best_known.check(directory) if not only or c.instance in only]
    if plans:
        table = Table("instance", "best J", "plan's J", "result")
        for p in plans:
            table.add_row(p.instance, _number(p.stored), _number(p.evaluated),
                          "pass" if p.passed else f"FAIL {p.problem}")
        console.print(table)
        console.print(f"{sum(p.passed for p in plans)}/{len(plans)} best-known plans passed")
    if plans_only:
        if not plans or not all(p.passed for p in plans):
            raise typer.Exit(1)
        return
    checks = run_verify(directory, method or None, time_limit, only, threads)
    table = Table("instance", "method", "J*", "J", "lower bound", "status", "time (s)",
                  "result")
    for c in checks:
        table.add_row(c.instance, c.method, "-" if c.J_star is None else f"{c.J_star:.6f}",
                      f"{c.J:.6f}", "-" if c.lower_bound is None else f"{c.lower_bound:.6f}",
                      c.status, f"{c.wall_time:.1f}",
                      "pass" if c.passed else f"FAIL {c.reason}")
    console.print(table)
    failed = sum(not c.passed for c in checks)
    console.print(f"{len(checks) - failed}/{len(checks)} passed")
    if failed or not checks or not all(p.passed for p in plans):
        raise typer.Exit(1)



bks_app = typer.Typer(help="Best-known plans and bounds of instance sets, kept in their "
                      "manifests.", no_args_is_help=True)



app.add_typer(bks_app, name="bks")



@bks_app.command("update")
@user_errors
def bks_update(
    run_dir: Annotated[Path, typer.Argument(metavar="RUN_DIR")],
    instance_set: Annotated[list[Path] | None, typer.Option(
        "--set", help="instance directory to update (default: those of the run's jobs)")]
    = None,
) -> None:
    """Take a run's better plans (re-evaluated, stamps removed) and higher bounds in."""
    from tsac_bench.batch import best_known

    changes = best_known.update(run_dir, instance_set or None, note=say_error)
    _print_changes(changes)



@bks_app.command("recombine")
@user_errors
def bks_recombine(
    directory: Annotated[Path, typer.Argument(metavar="DIR")],
    sources: Annotated[list[Path], typer.Argument(
        metavar="SOURCE...", help="run directories or solution files")],
    time_limit: Annotated[float, typer.Option(min=0.01, help="seconds of MIP per "
                                              "instance")] = 60.0,
    only: Annotated[list[str] | None, typer.Option(help="instance name(s) to recombine")]
    = None,
) -> None:
    """Put together, per instance of DIR, the best plan over the routes of the sources'
    plans and of its best-known plan; keep it where it is lower."""
    from tsac_bench.batch import best_known

    changes = best_known.recombine(directory, sources, time_limit, only)
    for c in changes:
        was = "none" if c.before is None else f"{c.before:.6f}"
        console.print(f"{c.instance}: plan {was} -> {c.after:.6f} (recombined)")
    console.print(f"{len(changes)} improvement(s)")



@bks_app.command("improve")
@user_errors
def bks_improve(
    directory: Annotated[Path, typer.Argument(metavar="DIR")],
    sources: Annotated[list[Path] | None, typer.Argument(
        metavar="[SOURCE...]", help="run directories or solution files whose plans start "
        "the search too")] = None,
    time_limit: Annotated[float, typer.Option(min=0.01, help="seconds of exact-bp per "
                                              "instance")] = 600.0,
    only: Annotated[list[str] | None, typer.Option(help="instance name(s) to search")]
    = None,
) -> None:
    """Search, per instance of DIR (--only, else those the sources planned, else all), with
    exact-bp from its best-known plan and the sources' plans; keep its plan where lower and
    its bound where higher."""
    from tsac_bench.batch import best_known

    changes = best_known.improve(directory, sources or [], time_limit, only, note=say_error)
    _print_changes(changes)



@bks_app.command("lns")
@user_errors
def bks_lns(
    directory: Annotated[Path, typer.Argument(metavar="DIR")],
    time_limit: Annotated[float, typer.Option(min=0.01, help="seconds per instance")]
    = 600.0,
    only: Annotated[list[str] | None, typer.Option(help="instance name(s) to search")]
    = None,
    aavs: Annotated[int, typer.Option(min=1, help="AAVs each repair re-plans")]
    = NeighbourhoodSettings.aavs,
    extra: Annotated[int, typer.Option(min=0, help="tasks beyond theirs each repair may "
                                       "give them")] = NeighbourhoodSettings.extra,
    repair_limit: Annotated[float, typer.Option(min=0.01, help="seconds of exact-bp per "
                                                "repair (doubled after a round in vain)")]
    = NeighbourhoodSettings.repair_limit,
    order: Annotated[NeighbourhoodOrder, typer.Option(
        help="order of the AAVs the neighbourhoods are built around")]
    = DEFAULT_ORDER,
    seed: Annotated[int, typer.Option(min=0, help="order of the neighbourhoods")] = 0,
) -> None:
    """Large neighbourhood search from each unproved instance's best-known plan: a few
    related AAVs re-planned by exact-bp over the tasks near them, the others held to their
    routes; keep the plan where lower."""
    from tsac_bench.batch import best_known

    settings = NeighbourhoodSettings(aavs, extra, repair_limit, order.value)
    changes = best_known.neighbourhood_search(directory, time_limit, only, settings,
                                              seed=seed, note=say_error)
    _print_changes(changes)



@bks_app.command("bound")
@user_errors
def bks_bound(directory: Annotated[Path, typer.Argument(metavar="DIR")]) -> None:
    """Give every instance of DIR at least the tasks-on-their-own bound."""
    from tsac_bench.batch import best_known

    console.print(f"{best_known.add_task_bounds(directory)} bound(s) raised")



@bks_app.command("show")
@user_errors
def bks_show(directory: Annotated[Path, typer.Argument(metavar="DIR")]) -> None:
    """Print DIR's best-known J, bound, gap and who found each."""
    from tsac_bench.batch import best_known

    table = Table("instance", "best J", "bound", "gap", "proved", "found by", "bound by")
    for row in best_known.table(directory):
        table.add_row(row["instance"], _number(row["best_J"]), _number(row["lower_bound"]),
                      "-" if row["gap"] is None else f"{100 * row['gap']:.1f} %",
                      "yes" if row["proved"] else "no", row["found_by"] or "-",
                      row["bound_by"] or "-")
    console.print(table)



def _number(value: float | None) -> str:
    return "-" if value is None else f"{value:.6f}"


def _print_changes(changes: list[Change]) -> None:
    """A line per plan or bound taken in, then their count."""
    for c in changes:
        was = "none" if c.before is None else f"{c.before:.6f}"
        console.print(f"{c.instance}: {c.what} {was} -> {c.after:.6f} ({c.by})")
    console.print(f"{len(changes)} improvement(s)")
