"""Batch runs: ``run`` with budgets, the machine-speed calibration, the results store and
the report."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer
from rich.table import Column, Table

from tsac_bench.batch.runner import DEFAULT_EXACT_TIME_LIMIT, DEFAULT_TIME_LIMIT
from tsac_bench.batch.worker import GRACE_SECONDS
from tsac_bench.cli.app import app, console, say_error, user_errors
from tsac_bench.errors import TsacBenchError


def parse_budgets(text: str) -> list[float]:
    """``--budget 0.1,1,10``: seconds per plan call, each > 0; one line naming the value
    otherwise."""
    from tsac_bench.planning.budget import check_budget

    budgets = []
    for word in text.split(","):
        try:
            value = float(word)
        except ValueError:
            raise TsacBenchError(f"--budget: {word.strip()!r} is not a number of seconds "
                                 "(e.g. --budget 0.1,1,10)") from None
        budgets.append(check_budget(value))
    return sorted(set(budgets))


def parse_seeds(text: str) -> range:
    """``--seeds 5`` is seeds 0..4; ``--seeds 5-9`` seeds 5..9, so that a run can be given
    more seeds without running the ones it has again."""
    first, dash, last = text.partition("-")
    try:
        seeds = range(int(first), int(last) + 1) if dash else range(int(text))
    except ValueError:
        raise TsacBenchError(f"--seeds: {text!r} is neither a count nor a range FIRST-LAST "
                             "(e.g. --seeds 5 or --seeds 5-9)") from None
    if not seeds or seeds.start < 0:
        raise TsacBenchError(f"--seeds: {text!r} names no seed (a count >= 1, or FIRST-LAST "
                             "with 0 <= FIRST <= LAST)")
    return seeds



@app.command()
@user_errors
def calibrate(
    out: Annotated[Path | None, typer.Option(help="a run directory whose results store "
                                             "records the calibration")] = None,
) -> None:
    """Time the machine-speed reference workload (budgets in reference units)."""
    from tsac_bench.batch.calibrate import WORKLOAD
    from tsac_bench.batch.calibrate import calibrate as run_calibration

    if out is not None:
        from tsac_bench.batch.runner import record_calibration
        from tsac_bench.batch.store import ResultStore

        with ResultStore(out) as store:
            record_calibration(store, say_error)
        return
    calibration = run_calibration()
    console.print(f"reference workload: {WORKLOAD}")
    console.print(f"{calibration['seconds']:.4f} s on {calibration['host']} (median of "
                  f"{len(calibration['repeats'])}): a budget of 1 s is "
                  f"{1 / calibration['seconds']:.1f} reference units")



results_app = typer.Typer(help="Work with a run directory's results store.", no_args_is_help=True)



app.add_typer(results_app, name="results")



@app.command()
@user_errors
def run(
    paths: Annotated[list[Path], typer.Argument(metavar="PATH...", help="instance files or "
                                                "directories (searched recursively)")],
    methods: Annotated[str | None, typer.Option(help="comma-separated methods or specs "
                                                "NAME:KEY=VALUE... (default: every available "
                                                "method)")] = None,
    mode: Annotated[str, typer.Option(help="static, dynamic, both, or auto (static, plus "
                                      "dynamic where supported)")] = "auto",
    seeds: Annotated[str, typer.Option(help="N: seeds 0..N-1 per job; FIRST-LAST: those "
                                       "seeds (e.g. 5-9 adds five to a run of --seeds 5)")]
    = "1",
    time_limit: Annotated[float | None, typer.Option(help="solver seconds per plan call (a "
                                                     "dynamic job plans once per event too); "
                                                     "default per 10 tasks: exact methods "
                                                     f"{DEFAULT_EXACT_TIME_LIMIT:g}, others "
                                                     f"{DEFAULT_TIME_LIMIT:g}")] = None,
    budget: Annotated[str | None, typer.Option(
        help="seconds per plan call that every method spends, comma-separated for a sweep "
        "(e.g. 0.1,1,10): one job per budget, an anytime method runs until its budget is "
        "spent; the run is calibrated first (tsac-bench calibrate). Not with --time-limit")]
    = None,
    jobs: Annotated[int | None, typer.Option(min=1, help="parallel jobs (default: CPU "
                                             "count)")] = None,
    grace: Annotated[float, typer.Option(help="seconds a job may overrun 1.5 x its time limit "
                                         "before its process is killed")] = GRACE_SECONDS,
    executor: Annotated[str, typer.Option(help="local or dask")] = "local",
    scheduler: Annotated[str | None, typer.Option(help="Dask scheduler address (default: a "
                                                  "LocalCluster)")] = None,
    out: Annotated[Path, typer.Option(help="run directory (results store)")]
    = Path("results/latest"),
    report: Annotated[bool, typer.Option(help="write the report when the run ends")] = True,
    report_out: Annotated[Path | None, typer.Option(help="report directory (default: "
                                                    "reports/<name of --out>)")] = None,
    retry_failed: Annotated[bool, typer.Option(help="run again the jobs recorded as "
                                               "failed")] = False,
    progress: Annotated[bool, typer.Option(help="show a progress bar")] = True,
) -> None:
    """Run every (instance, method, mode, seed) job; resumes an interrupted run in --out."""
    import os

    from tsac_bench.batch.runner import RunConfig, run_batch

    config = RunConfig(
        paths=list(paths), out=out, seeds=parse_seeds(seeds), time_limit=time_limit, mode=mode,
        budgets=None if budget is None else parse_budgets(budget),
        methods=[m.strip() for m in methods.split(",") if m.strip()] if methods else None,
        jobs=jobs or os.cpu_count() or 1, executor=executor, scheduler=scheduler,
        retry_failed=retry_failed, grace=grace)
    outcome = run_batch(config, note=say_error,
                        progress=progress)
    _print_summary(out)
    console.print(f"{outcome.ran} job(s) run, {outcome.skipped} already recorded, "
                  f"{outcome.failed} failed; results in {out}")
    if report:
        from tsac_bench.reporting.report import write_report

        index = write_report(out, report_out or Path("reports") / out.name)
        console.print(f"report: {index}")
    if outcome.problems:
        say_error(f"error: {len(outcome.problems)} input problem(s), listed above")
        raise typer.Exit(2)



def _print_summary(run_dir: Path) -> None:
    from tsac_bench.reporting.data import below_reference, load
    from tsac_bench.reporting.tables import summary

    frame = load(run_dir)
    if frame.empty:
        return
    for row in below_reference(frame).itertuples():
        say_error(f"warning: {row.key}: J = {row.J:.6f} is below the exact reference "
                  f"(J* {row.J_star}, LB {row.lower_bound}): a bug in an exact model, the "
                  "evaluator or the simulator, or a wrong manifest")
    # A spec label's end tells variants apart: fold it rather than cut it off.
    table = Table("mode", "scale", Column("method", overflow="fold"), "jobs", "failed", "mean J",
                  "mean gap to J*",
                  title="Summary (J: mean over instances of the mean over seeds)")
    for row in summary(frame).itertuples():
        gap = (f"{row.gap_mean:.2%}" if row.gap_n
               else f"<= {row.gap_lb_mean:.2%} (vs LB)" if row.gap_lb_mean == row.gap_lb_mean
               else "-")
        if 0 < row.gap_n < row.instances:
            gap += f" ({row.gap_n} of {row.instances})"
        mean = f"{row.J_mean:.3f}" if row.J_mean == row.J_mean else "-"
        table.add_row(row.mode, row.scale, row.method, str(row.jobs), str(row.failed), mean,
                      gap)
    console.print(table)



@results_app.command("export")
@user_errors
def results_export(
    run_dir: Annotated[Path, typer.Argument(metavar="RUN_DIR")],
    fmt: Annotated[str, typer.Option("--format", help="parquet or csv")] = "parquet",
    out: Annotated[Path | None, typer.Option(help="output file (default: RUN_DIR/results."
                                             "FORMAT)")] = None,
) -> None:
    """Export a run's jobs table (one row per job) as Parquet or CSV."""
    from tsac_bench.batch.store import export

    target = out or run_dir / f"results.{fmt}"
    count = export(run_dir, fmt, target)
    console.print(f"wrote {count} row(s) to {target}")



@results_app.command("summary")
@user_errors
def results_summary(run_dir: Annotated[Path, typer.Argument(metavar="RUN_DIR")]) -> None:
    """Print a run's summary table (mean J and mean gap per mode, scale and method)."""
    from tsac_bench.batch.store import ResultStore

    ResultStore(run_dir, create=False).close()
    _print_summary(run_dir)



@app.command("report")
@user_errors
def report_command(
    run_dir: Annotated[Path, typer.Argument(metavar="RUN_DIR")],
    out: Annotated[Path | None, typer.Option(help="report directory (default: reports/<name "
                                             "of RUN_DIR>)")] = None,
) -> None:
    """Write tables (LaTeX, Markdown), statistics and figures of a run, with an index.md."""
    from tsac_bench.reporting.report import write_report

    index = write_report(run_dir, out or Path("reports") / run_dir.name)
    console.print(f"report: {index}")

