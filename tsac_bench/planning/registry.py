"""The registry that finds methods by name: built-ins and ``tsac_bench.allocators`` plug-ins."""

from __future__ import annotations

import importlib
from collections.abc import Callable
from importlib.metadata import entry_points
from typing import Any

from tsac_bench.errors import TsacBenchError, UnknownMethodError
from tsac_bench.planning.allocator import Allocator, proves_optimality
from tsac_bench.planning.settings import MethodSpec, check_settings, parse_method_spec

ENTRY_POINT_GROUP = "tsac_bench.allocators"

#: Built-in methods by name, as "module:Class" so that listing them imports nothing heavy.
BUILTIN_METHODS: dict[str, str] = {
    "greedy": "tsac_bench.solvers.greedy:GreedyAllocator",
    "hocf": "tsac_bench.solvers.ocf.hocf:HOCFAllocator",
    "rocf": "tsac_bench.solvers.ocf.rocf:ROCFAllocator",
    "dga": "tsac_bench.solvers.dga:DGAAllocator",
    "cnp": "tsac_bench.solvers.cnp:ContractNetAllocator",
    "exact": "tsac_bench.solvers.exact:ExactAllocator",
    "exact-cpsat": "tsac_bench.solvers.exact:CpSatAllocator",
    "exact-bp": "tsac_bench.solvers.exact:BranchPriceAllocator",
    "tsac-ocf": "tsac_bench.solvers.tsac.policy:TSACOCFAllocator",
    "pyvrp": "tsac_bench.solvers.pyvrp_peer:PyVRPAllocator",
}

#: The pyproject extra that installs what a built-in method needs, where it needs one.
METHOD_EXTRAS: dict[str, str] = {"pyvrp": "peers"}

_registered: dict[str, Callable[..., Allocator]] = {}


def register(name: str) -> Callable[[type], type]:
    """Class decorator registering a method in this process (tests and notebooks)."""

    def decorate(cls: type) -> type:
        _registered[name] = cls
        return cls

    return decorate


def _plugin_methods() -> dict[str, Any]:
    return {ep.name: ep for ep in entry_points(group=ENTRY_POINT_GROUP)}


def available_methods() -> list[str]:
    return sorted({*BUILTIN_METHODS, *_registered, *_plugin_methods()})


def method_source(name: str) -> str:
    if name in _registered:
        return "registered"
    if name in BUILTIN_METHODS:
        return "built-in"
    return "plug-in"


class MethodUnavailable(TsacBenchError):
    """A known method whose optional dependencies are not installed."""


def allocator_class(name: str) -> Callable[..., Allocator]:
    if name in _registered:
        return _registered[name]
    plugins = _plugin_methods()
    if name in BUILTIN_METHODS:
        module_name, _, attr = BUILTIN_METHODS[name].partition(":")
        try:
            return getattr(importlib.import_module(module_name), attr)
        except ImportError as exc:
            extra = METHOD_EXTRAS.get(name, "all")
            raise MethodUnavailable(f"method {name!r} needs {exc.name!r}: "
                                    f"pip install -e '.[{extra}]'") from None
    if name in plugins:
        try:
            return plugins[name].load()
        except ImportError as exc:
            raise MethodUnavailable(f"plug-in method {name!r} needs {exc.name!r}") from None
    raise UnknownMethodError(name, available_methods())


def resolve_spec(spec: str | MethodSpec) -> MethodSpec:
    """``spec`` (a MethodSpec or its text) with its settings checked and converted by the
    method's declared constraints: the spec a run records and the allocator is built from."""
    if isinstance(spec, str):
        spec = parse_method_spec(spec)
    return MethodSpec(spec.name, check_settings(spec.name, allocator_class(spec.name),
                                                spec.settings))


def make_allocator(method: str | MethodSpec, **settings: Any) -> Allocator:
    """The method ``method`` (a name, a spec or a spec's text ``NAME:KEY=VALUE...``) built with
    its spec's settings and ``settings`` (constructor keywords), checked and converted first
    (``settings.check_settings``: an unknown, wrong-typed or out-of-range setting is one
    InvalidSetting line)."""
    spec = method if isinstance(method, MethodSpec) else parse_method_spec(method)
    resolved = resolve_spec(spec.with_settings(settings))
    return allocator_class(resolved.name)(**resolved.settings)


def exact_methods() -> list[str]:
    """The available methods that declare ``proves_optimality`` (unloadable ones left out)."""
    return [name for name in available_methods() if is_exact_method(name)]


def is_exact_method(label: str) -> bool:
    """Whether the method of a stored label (``NAME`` or ``NAME:KEY=VALUE...``) proves
    optimality; a method not installed here is not taken as exact."""
    try:
        return proves_optimality(allocator_class(parse_method_spec(label).name))
    except Exception:  # unknown or unloadable: its results cannot be taken as proven optima
        return False
