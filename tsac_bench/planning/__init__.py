"""Planning: the ``Allocator`` protocol, the planning state a method sees, the registry of
methods, and (in their own modules) the priced edits every heuristic shares
(``insertion``), the dynamic simulator (``simulator``) and one solve (``solve``).

This package is what a plug-in author imports; it depends only on ``tsac_bench.model``.
"""

from tsac_bench.planning.allocator import (
    ALL_MODES,
    Allocator,
    PlanningState,
    PlanResult,
    Settings,
    proves_optimality,
    supported_modes,
)
from tsac_bench.planning.registry import (
    BUILTIN_METHODS,
    ENTRY_POINT_GROUP,
    MethodUnavailable,
    allocator_class,
    available_methods,
    exact_methods,
    is_exact_method,
    make_allocator,
    method_source,
    register,
)

__all__ = [
    "ALL_MODES",
    "BUILTIN_METHODS",
    "ENTRY_POINT_GROUP",
    "Allocator",
    "MethodUnavailable",
    "PlanResult",
    "PlanningState",
    "Settings",
    "allocator_class",
    "available_methods",
    "exact_methods",
    "is_exact_method",
    "make_allocator",
    "method_source",
    "proves_optimality",
    "register",
    "supported_modes",
]
