"""Commands on one instance: generate, inspect, evaluate and solve it; the methods."""

from __future__ import annotations

import json
import sys
from pathlib import Path
from typing import Annotated, Any

import typer
from rich.table import Table

from tsac_bench.cli.app import app, console, say_error, user_errors
from tsac_bench.errors import TsacBenchError


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

