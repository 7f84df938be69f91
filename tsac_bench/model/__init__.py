"""The problem model of docs/model.md: instances and solutions."""

from tsac_bench.model.instance import (
    AAV,
    DEFAULT_HORIZON,
    DEFAULT_WEIGHTS,
    Depot,
    Instance,
    Task,
    TaskKind,
    is_int,
)
from tsac_bench.model.solution import Route, Solution, Visit, as_route

__all__ = [
    "AAV",
    "DEFAULT_HORIZON",
    "DEFAULT_WEIGHTS",
    "Depot",
    "Instance",
    "Route",
    "Solution",
    "Task",
    "TaskKind",
    "Visit",
    "as_route",
    "is_int",
]
