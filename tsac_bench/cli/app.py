"""The ``tsac-bench`` application and what every command shares: user errors print one line
and exit non-zero; exit 2 is bad input (unreadable file, unknown id or method), 1 an
infeasible solution or plan."""

from __future__ import annotations

import functools
from collections.abc import Callable
from typing import Any, TypeVar

import typer
from rich.console import Console

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

