"""tsac-bench: dynamic heterogeneous multi-AAV logistics task allocation, with exact gaps.

Importing this package loads only numpy and pydantic; the solver backends (Pyomo, HiGHS,
OR-Tools, torch) are imported by the methods that use them.
"""

from importlib.metadata import version

from tsac_bench.model import AAV, Depot, Instance, Route, Solution, Task, TaskKind, Visit
from tsac_bench.model.evaluator import CostEvaluator, Evaluation, PlanState, evaluate
from tsac_bench.model.io import read_instance, read_solution, write_instance, write_solution

__version__ = version("tsac-bench")  # pyproject.toml owns the number

__all__ = [
    "AAV",
    "CostEvaluator",
    "Depot",
    "Evaluation",
    "Instance",
    "PlanState",
    "Route",
    "Solution",
    "Task",
    "TaskKind",
    "Visit",
    "__version__",
    "evaluate",
    "read_instance",
    "read_solution",
    "write_instance",
    "write_solution",
]
