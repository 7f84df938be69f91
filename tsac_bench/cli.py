"""The ``tsac-bench`` command line. User errors print one line and exit non-zero; exit 2 is
bad input (unreadable file, unknown id or method), 1 an infeasible solution or plan."""

from __future__ import annotations

import functools
import json
import sys
from collections.abc import Callable
from pathlib import Path
from typing import Annotated, Any, TypeVar

import typer
from rich.console import Console
from rich.table import Column, Table

from tsac_bench.batch.worker import GRACE_SECONDS
from tsac_bench.errors import TsacBenchError

app = typer.Typer(
    name="tsac-bench",
    help="Benchmark dynamic heterogeneous multi-AAV logistics task allocation.",
    no_args_is_help=True,
    add_completion=False,
    pretty_exceptions_enable=False,
)
console = Console()


def say_error(line: str) -> None:
    """One unwrapped line on stderr, whatever the terminal width."""
    typer.echo(line, err=True)

F = TypeVar("F", bound=Callable[..., Any])


def user_errors(func: F) -> F:
    """Turn tsac-bench's own errors into one line on stderr and their exit code."""

    @functools.wraps(func)
    def wrapper(*args: Any, **kwargs: Any) -> Any:
        try:
            return func(*args, **kwargs)
        except TsacBenchError as exc:
            say_error(f"error: {exc}")
            raise typer.Exit(exc.exit_code) from None

    return wrapper  # type: ignore[return-value]


@app.command()
@user_errors
def generate(
    scale: Annotated[str, typer.Option(help="AAVs/tasks, e.g. 16/40")] = "4/10",
    count: Annotated[int, typer.Option(min=1, help="number of instances")] = 1,
    seed: Annotated[int, typer.Option(help="seed of the first instance; then seed+1, ...")] = 0,
    depots: Annotated[int | None, typer.Option(help="number of depots (default max(2, N/4))")]
    = None,
    dynamic_share: Annotated[float, typer.Option(min=0, max=1, help="share of tasks released "
                                                 "after t=0")] = 0.5,
    out: Annotated[Path, typer.Option(help="output directory")] = Path("instances/generated"),
) -> None:
    """Generate instances of the paper's scenario family (deterministic per seed)."""
    from tsac_bench.model.generator import ScenarioGenerator, parse_scale
    from tsac_bench.model.io import write_instance

    try:
        n, m = parse_scale(scale)
    except ValueError as exc:
        raise TsacBenchError(f"--scale: {exc}") from None
    generator = ScenarioGenerator(n_depots=depots, dynamic_share=dynamic_share)
    for s in range(seed, seed + count):
        instance = generator.generate(n, m, s)
        write_instance(instance, out / f"{instance.name}.json")
    console.print(f"wrote {count} instance(s) of scale {scale} to {out}")


@app.command()
@user_errors
def info(instance_path: Annotated[Path, typer.Argument(metavar="INSTANCE")]) -> None:
    """Summarise an instance: fleet, depots, tasks and their windows."""
    from tsac_bench.model.io import read_instance

    instance = read_instance(instance_path)
    console.print(f"[bold]{instance.name}[/]  scale {instance.scale}, {instance.n_depots} "
                  f"depot(s), horizon {instance.horizon:g} s, weights {instance.weights}")
    table = Table("task", "kind", "demand", "window", "release", "x", "y")
    for t in instance.tasks:
        table.add_row(t.id, t.kind.value, str(t.demand), f"[{t.t_start:g}, {t.t_end:g}]",
                      f"{t.release:g}", f"{t.x:g}", f"{t.y:g}")
    console.print(table)
    fleet = Table("aav", "type", "speed", "capacity", "range", "start")
    for a in instance.aavs:
        fleet.add_row(a.id, str(a.type), f"{a.speed:g}", str(a.capacity), f"{a.max_range:g}",
                      f"({a.x:g}, {a.y:g})")
    console.print(fleet)


@app.command()
@user_errors
def evaluate(
    instance_path: Annotated[Path, typer.Argument(metavar="INSTANCE")],
    solution_path: Annotated[Path, typer.Argument(metavar="SOLUTION")],
    as_json: Annotated[bool, typer.Option("--json", help="machine-readable output")] = False,
) -> None:
    """Check a solution and print J with its breakdown (exit 1 if infeasible)."""
    from tsac_bench.model.evaluator import CostEvaluator, costs_agree
    from tsac_bench.model.io import read_instance, read_solution

    instance = read_instance(instance_path)
    solution = read_solution(solution_path, instance)
    result = CostEvaluator(instance).evaluate(solution)
    if as_json:
        sys.stdout.write(json.dumps(result.to_dict(instance), indent=1) + "\n")
    elif result.feasible:
        _print_breakdown(result)
    else:
        for error in result.errors:
            say_error(f"{solution_path}: {error}")
    if not result.feasible:
        raise typer.Exit(1)
    claimed = solution.cost
    if claimed is not None and result.J is not None and not costs_agree(claimed, result.J):
        say_error(f"warning: {solution_path}: cost: the file claims {claimed}, the "
                  f"evaluator computes {result.J}")


def _print_breakdown(result: Any) -> None:
    table = Table("task", "C_load", "C_time", "C_op", "cost", "coalition (amount @ arrival)")
    for b in result.per_task:
        members = ", ".join(f"{a} ({b.amounts[a]} @ {b.arrivals[a]:.1f}"
                            f"{'' if b.on_time[a] else ' late'})" for a in b.coalition)
        table.add_row(b.task, f"{b.cost.load:.4f}", f"{b.cost.time:.4f}", f"{b.cost.op:.4f}",
                      f"{b.cost.total:.4f}", members or "-")
    console.print(table)
    terms = result.terms
    console.print(f"J = {result.J:.6f}  (w1*load {terms['load']:.4f} + w2*time "
                  f"{terms['time']:.4f} + w3*op {terms['op']:.4f})")


@app.command()
@user_errors
def solve(
    instance_path: Annotated[Path, typer.Argument(metavar="INSTANCE")],
    method: Annotated[str, typer.Option(help="method name (see `tsac-bench methods`) or spec "
                                        "NAME:KEY=VALUE..., e.g. hocf:init=incumbent")]
    = "greedy",
    seed: Annotated[int, typer.Option()] = 0,
    time_limit: Annotated[float | None, typer.Option(help="seconds")] = None,
    budget: Annotated[float | None, typer.Option(
        help="seconds per plan call that the method spends (an anytime method until the "
        "budget is spent; not with --time-limit)")] = None,
    mode: Annotated[str, typer.Option(help="static (every task known at t=0) or dynamic "
                                      "(re-plan at each release time)")] = "static",
    out: Annotated[Path | None, typer.Option(help="write the solution JSON here")] = None,
    polish: Annotated[bool, typer.Option("--polish", help="re-optimise the payload amounts "
                                         "of the routes found (cvxpy + HiGHS)")] = False,
    setting: Annotated[list[str] | None, typer.Option(
        "--set", metavar="NAME=VALUE", help="a setting of the method (its constructor "
        "keyword), repeatable, e.g. --set threads=2; VALUE is read by the setting's declared "
        "type (true, none, 0.5)")]
    = None,
) -> None:
    """Run one method on one instance and print J (dynamic: also J after each re-plan); an
    exact method's static run also its status, lower bound and gap.

    --time-limit caps each plan call; --budget is what each plan call spends."""
    from tsac_bench.model.io import read_instance, write_solution
    from tsac_bench.planning import parse_method_spec, resolve_spec
    from tsac_bench.planning.settings import parse_setting_pairs
    from tsac_bench.planning.solve import solve as run_solve

    spec = resolve_spec(parse_method_spec(method).with_settings(
        parse_setting_pairs(setting or [], "--set")))
    instance = read_instance(instance_path)
    outcome = run_solve(instance, spec, seed=seed, time_limit=time_limit, mode=mode,
                        budget=budget)
    solution = outcome.solution
    if mode == "dynamic":
        table = Table("t (s)", "released", "visible", "committed", "J known before",
                      "J known", "J", "plan (s)")
        for r in outcome.stats["replans"]:
            before = r["J_known_before"]
            table.add_row(f"{r['time']:g}", " ".join(r["released"]) or "-", str(r["visible"]),
                          str(r["committed"]), "-" if before is None else f"{before:.4f}",
                          f"{r['J_known']:.4f}", f"{r['J']:.4f}", f"{r['wall_time']:.3f}")
        console.print(table)
    console.print(f"{instance.name}  {spec.label}  {mode}  J = {outcome.cost:.6f}  "
                  f"({outcome.wall_time:.3f} s)")
    if outcome.status is not None:
        console.print(_claims_line(outcome))
    if budget is not None:
        console.print(_budget_line(outcome))
    if polish:
        from tsac_bench.planning.polish import polish as polish_solution

        solution = polish_solution(instance, solution)
        console.print(f"{instance.name}  {spec.label}+polish  J = {solution.cost:.6f}")
    if out is not None:
        write_solution(solution, instance, out)


def _claims_line(outcome: Any) -> str:
    """What the method proves about its plan: its status, lower bound and MIP gap (J - LB) / J."""
    if outcome.lower_bound is None:
        return f"status {outcome.status}, no lower bound"
    return (f"status {outcome.status}, lower bound {outcome.lower_bound:.6f}, MIP gap "
            f"{100 * outcome.gap:.2f} %")


def _budget_line(outcome: Any) -> str:
    """A budgeted solve's use of its budget: the plan calls over it and the work done (the
    count that, as the method's work setting, reproduces the plan without the budget)."""
    calls = outcome.stats.get("replans", [{"stats": outcome.stats}])
    work = [r["stats"].get("work") for r in calls]
    done = ("work " + " ".join("-" if w is None else str(w) for w in work)
            if any(w is not None for w in work) else "no work count (not an anytime method)")
    return (f"budget {outcome.budget:g} s per plan call: {outcome.over_budget} of "
            f"{len(outcome.plan_seconds)} plan call(s) over it; {done}")


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


@app.command()
@user_errors
def methods(
    name: Annotated[str | None, typer.Argument(metavar="[NAME]", help="a method: list its "
                                               "settings, defaults and allowed values")] = None,
) -> None:
    """List the registered methods (built-in and plug-ins), or one method's settings."""
    from tsac_bench.planning import (
        MethodUnavailable,
        allocator_class,
        available_methods,
        method_source,
    )
    from tsac_bench.planning.settings import settings_table

    if name is not None:
        rows = settings_table(allocator_class(name))  # unknown, unavailable: one line
        if not rows:
            console.print(f"{name} ({method_source(name)}) has no settings")
            return
        table = Table("setting", "default", "allowed", title=f"{name} ({method_source(name)})")
        for row in rows:
            table.add_row(*row)
        console.print(table)
        return
    table = Table("method", "source", "status")
    for method in available_methods():
        try:
            allocator_class(method)
            status = "available"
        except MethodUnavailable as exc:
            status = f"unavailable: {exc}"
        table.add_row(method, method_source(method), status)
    console.print(table)


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
    seeds: Annotated[int, typer.Option(min=1, help="seeds 0..N-1 per job")] = 1,
    time_limit: Annotated[float | None, typer.Option(help="solver seconds per plan call (a "
                                                     "dynamic job plans once per event too); "
                                                     "default per 10 tasks: exact methods 10, "
                                                     "others 2")] = None,
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
        paths=list(paths), out=out, seeds=seeds, time_limit=time_limit, mode=mode,
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
    for c in changes:
        was = "none" if c.before is None else f"{c.before:.6f}"
        console.print(f"{c.instance}: {c.what} {was} -> {c.after:.6f} ({c.by})")
    console.print(f"{len(changes)} improvement(s)")


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


@app.command()
@user_errors
def train(
    out: Annotated[Path, typer.Option(help="output folder: checkpoint.pt, policy.pt, "
                                      "curve.json, curve.png")],
    device: Annotated[str, typer.Option(help="auto, cpu or cuda")] = "auto",
    steps: Annotated[int | None, typer.Option(min=1, help="environment steps (decisions) "
                                              "in all; default the shipped policy's")] = None,
    seed: Annotated[int, typer.Option()] = 0,
    resume: Annotated[Path | None, typer.Option(help="a checkpoint.pt to continue from")]
    = None,
    threads: Annotated[int, typer.Option(min=1, help="torch CPU threads")] = 1,
    label_workers: Annotated[int, typer.Option(
        min=1, help="processes that run the rollout labels (the same run, faster on as many "
        "cores); may differ on --resume")] = 1,
    stop_after: Annotated[float | None, typer.Option(
        min=1, help="seconds: end this call at the next episode's end, with a checkpoint to "
        "--resume from")] = None,
    setting: Annotated[list[str] | None, typer.Option(
        "--set", metavar="FIELD=VALUE", help="a scalar field of the training configuration "
        "(TrainConfig), repeatable, e.g. --set rollouts=4 --set replan_share=0; not with "
        "--resume, which keeps the checkpoint's configuration")] = None,
) -> None:
    """Train the TSAC-OCF task-selection policy; the defaults are the shipped policy's
    recipe (docs/tsac.md)."""
    from tsac_bench.planning.settings import config_from_settings, parse_setting_pairs

    if device not in ("auto", "cpu", "cuda"):
        raise TsacBenchError(f"--device: expected auto, cpu or cuda, got {device!r}")
    settings = parse_setting_pairs(setting or [], "--set")
    if settings and resume is not None:
        raise TsacBenchError("--set: not with --resume (a resumed run keeps the configuration "
                             "in its checkpoint)")
    import torch
    from rich.progress import (
        BarColumn,
        MofNCompleteColumn,
        Progress,
        TextColumn,
        TimeElapsedColumn,
        TimeRemainingColumn,
    )

    from tsac_bench.solvers.tsac.sac import TrainConfig, resolve_device
    from tsac_bench.solvers.tsac.sac import train as run_training

    torch.set_num_threads(threads)
    if resume is not None and not resume.is_file():
        raise TsacBenchError(f"--resume: {resume} is not a file")
    try:
        resolve_device(device)
    except ValueError as exc:
        raise TsacBenchError(str(exc)) from None
    if steps is None:
        steps = (torch.load(resume, map_location="cpu", weights_only=False)["config"]["steps"]
                 if resume is not None else TrainConfig().steps)
    config = config_from_settings(TrainConfig, settings, "--set", steps=steps, seed=seed)
    columns = (TextColumn("[bold]train"), BarColumn(), MofNCompleteColumn(),
               TimeElapsedColumn(), TimeRemainingColumn(), TextColumn("{task.fields[info]}"))
    with Progress(*columns, console=console) as progress:
        bar = progress.add_task("train", total=steps, info="")

        def on_step(step: int, stats: dict[str, float]) -> None:
            info = " ".join(f"{k}={stats[k]:.3g}" for k in ("critic_loss", "entropy",
                                                             "eval_ratio_hocf") if k in stats)
            progress.update(bar, completed=step, info=info)

        summary = run_training(out, config, device=device, resume=resume, on_step=on_step,
                               stop_after=stop_after, label_workers=label_workers)
    console.print(f"trained {summary['steps']} steps ({summary['episode_count']} episodes) in "
                  f"{summary['seconds']:.0f} s on {summary['device']}; policy: "
                  f"{out / 'policy.pt'}")


@app.command("train-verifier")
@user_errors
def train_verifier_command(
    out: Annotated[Path, typer.Option(help="output folder: policy.pt (the policy with its "
                                      "verifier), labels.pt, verifier.json")],
    policy: Annotated[Path | None, typer.Option(
        help="the policy file whose critics' deviations are verified; default the shipped "
        "one")] = None,
    workers: Annotated[int, typer.Option(min=1, help="processes that label the instances "
                                         "(the same labels with any number)")] = 1,
    labels: Annotated[Path | None, typer.Option(
        help="the labels.pt of an earlier call (same policy and labelling settings): fit "
        "only")] = None,
    setting: Annotated[list[str] | None, typer.Option(
        "--set", metavar="FIELD=VALUE", help="a field of VerifierConfig, repeatable, e.g. "
        "--set epochs=10")] = None,
) -> None:
    """Train the deviation verifier of tsac-ocf's margin rule (docs/tsac.md)."""
    from tsac_bench.planning.settings import config_from_settings, parse_setting_pairs
    from tsac_bench.solvers.tsac.policy import margin_problem, policy_at
    from tsac_bench.solvers.tsac.verify import VerifierConfig, train_verifier

    config = config_from_settings(VerifierConfig, parse_setting_pairs(setting or [], "--set"),
                                  "--set")
    if policy is not None and not policy.is_file():
        raise TsacBenchError(f"--policy: {policy} is not a file")
    # An unreadable policy file is a PolicyFileError: one line naming the file.
    source = str(policy) if policy else None
    problem = margin_problem(policy_at(source))
    if problem is not None:
        raise TsacBenchError(f"--policy: {policy or 'the shipped policy'}: {problem}")
    if labels is not None and not labels.is_file():
        raise TsacBenchError(f"--labels: {labels} is not a file")
    summary = train_verifier(out, source, config, workers, labels)
    console.print(f"{summary['labels']} labels ({summary['seconds_labelling']:.0f} s), fitted "
                  f"in {summary['seconds_fit']:.0f} s; policy: {out / 'policy.pt'}")


def main() -> None:
    app()
