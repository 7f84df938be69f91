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
from rich.table import Table

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
    from tsac_bench.generator import ScenarioGenerator, parse_scale
    from tsac_bench.io import write_instance

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
    from tsac_bench.io import read_instance

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
    from tsac_bench.evaluator import CostEvaluator
    from tsac_bench.io import read_instance, read_solution

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
    if solution.cost is not None and result.J is not None and not _close(solution.cost, result.J):
        say_error(f"warning: {solution_path}: cost: the file claims {solution.cost}, the "
                  f"evaluator computes {result.J}")


def _close(a: float, b: float) -> bool:
    return abs(a - b) <= 1e-6 * max(1.0, abs(b))


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
    method: Annotated[str, typer.Option(help="method name (see `tsac-bench methods`)")]
    = "greedy",
    seed: Annotated[int, typer.Option()] = 0,
    time_limit: Annotated[float | None, typer.Option(help="seconds")] = None,
    mode: Annotated[str, typer.Option(help="static (every task known at t=0) or dynamic "
                                      "(re-plan at each release time)")] = "static",
    out: Annotated[Path | None, typer.Option(help="write the solution JSON here")] = None,
) -> None:
    """Run one method on one instance and print J (dynamic: also J after each re-plan).

    --time-limit is the budget of each plan call."""
    from tsac_bench.io import read_instance, write_solution
    from tsac_bench.solve import solve as run_solve

    instance = read_instance(instance_path)
    outcome = run_solve(instance, method, seed=seed, time_limit=time_limit, mode=mode)
    if out is not None:
        write_solution(outcome.solution, instance, out)
    if mode == "dynamic":
        table = Table("t (s)", "released", "visible", "committed", "J known before",
                      "J known", "J", "plan (s)")
        for r in outcome.stats["replans"]:
            before = r["J_known_before"]
            table.add_row(f"{r['time']:g}", " ".join(r["released"]) or "-", str(r["visible"]),
                          str(r["committed"]), "-" if before is None else f"{before:.4f}",
                          f"{r['J_known']:.4f}", f"{r['J']:.4f}", f"{r['wall_time']:.3f}")
        console.print(table)
    console.print(f"{instance.name}  {method}  {mode}  J = {outcome.cost:.6f}  "
                  f"({outcome.wall_time:.3f} s)")


@app.command()
@user_errors
def methods() -> None:
    """List the registered methods (built-in and plug-ins)."""
    from tsac_bench.allocator import (
        MethodUnavailable,
        allocator_class,
        available_methods,
        method_source,
    )

    table = Table("method", "source", "status")
    for name in available_methods():
        try:
            allocator_class(name)
            status = "available"
        except MethodUnavailable as exc:
            status = f"unavailable: {exc}"
        table.add_row(name, method_source(name), status)
    console.print(table)


@app.command()
@user_errors
def train(
    out: Annotated[Path, typer.Option(help="output folder: checkpoint.pt, policy.pt, "
                                      "curve.json, curve.png")],
    device: Annotated[str, typer.Option(help="auto, cpu or cuda")] = "auto",
    steps: Annotated[int | None, typer.Option(min=1, help="environment steps (decisions) "
                                              "in all; default 16000")] = None,
    seed: Annotated[int, typer.Option()] = 0,
    resume: Annotated[Path | None, typer.Option(help="a checkpoint.pt to continue from")]
    = None,
    threads: Annotated[int, typer.Option(min=1, help="torch CPU threads")] = 1,
) -> None:
    """Train the TSAC-OCF task-selection policy (discrete SAC, docs/tsac.md)."""
    if device not in ("auto", "cpu", "cuda"):
        raise TsacBenchError(f"--device: expected auto, cpu or cuda, got {device!r}")
    import torch
    from rich.progress import (
        BarColumn,
        MofNCompleteColumn,
        Progress,
        TextColumn,
        TimeElapsedColumn,
        TimeRemainingColumn,
    )

    from tsac_bench.solvers.tsac_sac import TrainConfig, resolve_device
    from tsac_bench.solvers.tsac_sac import train as run_training

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
    config = TrainConfig(steps=steps, seed=seed)
    columns = (TextColumn("[bold]train"), BarColumn(), MofNCompleteColumn(),
               TimeElapsedColumn(), TimeRemainingColumn(), TextColumn("{task.fields[info]}"))
    with Progress(*columns, console=console) as progress:
        bar = progress.add_task("train", total=steps, info="")

        def on_step(step: int, stats: dict[str, float]) -> None:
            info = " ".join(f"{k}={stats[k]:.3g}" for k in ("critic_loss", "alpha",
                                                             "eval_ratio_hocf") if k in stats)
            progress.update(bar, completed=step, info=info)

        summary = run_training(out, config, device=device, resume=resume, on_step=on_step)
    console.print(f"trained {summary['steps']} steps ({summary['episode_count']} episodes) in "
                  f"{summary['seconds']:.0f} s on {summary['device']}; policy: "
                  f"{out / 'policy.pt'}")


def main() -> None:
    app()
