"""Planning: the ``Allocator`` protocol, the planning state a method sees, the registry of
methods, the constraints of their settings and method specs (``settings``), and (in their own
modules) the priced edits every heuristic shares (``insertion``), the dynamic simulator
(``simulator``) and one solve (``solve``).

This package is what a plug-in author imports; it depends only on ``tsac_bench.model``.
"""

from tsac_bench.planning.allocator import (
    ALL_MODES,
    Allocator,
    Anchor,
    PlanningState,
    PlanResult,
    PlanStatus,
    Settings,
    mip_gap,
    proves_optimality,
    recorded_claim,
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
    resolve_spec,
)
from tsac_bench.planning.settings import (
    Boolean,
    Constraint,
    ExistingFile,
    Interval,
    MethodSpec,
    NoneOr,
    Options,
    Refused,
    declare,
    parse_method_spec,
)

__all__ = [
    "ALL_MODES",
    "BUILTIN_METHODS",
    "ENTRY_POINT_GROUP",
    "Allocator",
    "Anchor",
    "Boolean",
    "Constraint",
    "ExistingFile",
    "Interval",
    "MethodSpec",
    "MethodUnavailable",
    "NoneOr",
    "Options",
    "PlanResult",
    "PlanStatus",
    "PlanningState",
    "Refused",
    "Settings",
    "allocator_class",
    "available_methods",
    "declare",
    "exact_methods",
    "is_exact_method",
    "make_allocator",
    "method_source",
    "mip_gap",
    "parse_method_spec",
    "proves_optimality",
    "recorded_claim",
    "register",
    "resolve_spec",
    "supported_modes",
]
