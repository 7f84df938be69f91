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
    mode: Annotated[str, typer.Option(help="static")] = "static",
    out: Annotated[Path | None, typer.Option(help="write the solution JSON here")] = None,
    polish: Annotated[bool, typer.Option("--polish", help="re-optimise the payload amounts "
                                         "of the routes found (cvxpy + HiGHS)")] = False,
) -> None:
    """Run one method on one instance and print J."""
    from tsac_bench.io import read_instance, write_solution
    from tsac_bench.solve import solve as run_solve

    instance = read_instance(instance_path)
    outcome = run_solve(instance, method, seed=seed, time_limit=time_limit, mode=mode)
    solution = outcome.solution
    console.print(f"{instance.name}  {method}  J = {outcome.cost:.6f}  "
                  f"({outcome.wall_time:.3f} s)")
    if polish:
        from tsac_bench.polish import polish as polish_solution

        solution = polish_solution(instance, solution)
        console.print(f"{instance.name}  {method}+polish  J = {solution.cost:.6f}")
    if out is not None:
        write_solution(solution, instance, out)


@app.command()
@user_errors
def verify(
    directory: Annotated[Path, typer.Argument(metavar="DIR", help="a directory with a "
                                              "manifest.json of proven optima")],
    method: Annotated[list[str] | None, typer.Option(help="exact backend(s) to re-run "
                                                     "(default: exact and exact-cpsat)")]
    = None,
    only: Annotated[list[str] | None, typer.Option(help="instance name(s) to check")] = None,
    time_limit: Annotated[float | None, typer.Option(help="seconds per solve")] = 600.0,
    threads: Annotated[int, typer.Option(min=1)] = 1,
) -> None:
    """Re-solve a directory's instances and compare with its manifest (exit 1 on failure)."""
    from tsac_bench.formulations.regression import BACKENDS
    from tsac_bench.formulations.regression import verify as run_verify

    checks = run_verify(directory, tuple(method or BACKENDS), time_limit, only, threads)
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
    if failed or not checks:
        raise typer.Exit(1)


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


def main() -> None:
    app()
