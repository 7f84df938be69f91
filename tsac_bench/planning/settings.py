"""Method settings: the constraints a method declares for its constructor keywords, their one
check, and method specs (``NAME[:KEY=VALUE[:KEY=VALUE...]]``).

A method declares ``setting_constraints`` (as scikit-learn's ``_parameter_constraints``), one
``Constraint`` per constructor keyword::

    setting_constraints = declare(k_max=Interval(int, 0, None), init=Options("empty", "greedy"))

``check_settings`` is the only place settings are checked: it converts text (a command-line
``--set`` or a method spec) by the declared type, checks every value against its constraint
and raises ``InvalidSetting`` with one line naming the method, the setting, the value and what
is allowed. A setting a method does not declare (a plug-in that declares nothing) reaches the
constructor as given, text included.

A method spec's ``label`` is the name alone when it has no settings, otherwise
``NAME:KEY=VALUE:...`` with the settings sorted by name and each value written so that it reads
back as itself (``true``, ``none``, ``0.5``); two specs that build the same method the same way
have the same label. Values may not contain ``:`` or ``,`` (the separators of specs and of
``--methods``); ``solve --set`` takes any value.
"""

from __future__ import annotations

import inspect
import math
import os
import re
from abc import ABC, abstractmethod
from collections.abc import Callable, Iterable, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from types import MappingProxyType
from typing import Any, Literal

from tsac_bench.errors import InvalidSetting, TsacBenchError

__all__ = [
    "Boolean",
    "Constraint",
    "ExistingFile",
    "Interval",
    "MethodSpec",
    "NoneOr",
    "Options",
    "Refused",
    "check_settings",
    "declare",
    "file_label",
    "format_value",
    "parse_method_spec",
    "parse_setting_pairs",
]

_NONE_WORDS = ("none", "null")


class Refused(Exception):
    """A value a constraint does not admit (the caller words the error; a message, if any,
    says why, e.g. what was wrong inside a file)."""


class Constraint(ABC):
    """What one setting admits. ``convert`` reads text and checks the type, ``admits`` the
    range (which may depend on the other settings, given in ``context``)."""

    @abstractmethod
    def convert(self, value: Any) -> Any:
        """The value as the method takes it (text read by the declared type); raises Refused."""

    def admits(self, value: Any, context: Mapping[str, Any]) -> bool:
        del value, context
        return True

    def depends_on(self) -> tuple[str, ...]:
        """Other settings this constraint's range refers to."""
        return ()

    @abstractmethod
    def describe(self, context: Mapping[str, Any]) -> str:
        """What is allowed, e.g. "an integer >= 1"."""

    def describe_default(self, value: Any) -> str:
        """The default as ``tsac-bench methods`` shows it: the text that converts back to it,
        unless a constraint knows a clearer name (a default that stands for something)."""
        return format_value(value)


Bound = float | int | str | None
_BRACKETS = {"both": "[]", "left": "[)", "right": "(]", "neither": "()"}


@dataclass(frozen=True)
class Interval(Constraint):
    """A finite ``int`` or ``float`` between ``low`` and ``high`` (None: unbounded); a bound may
    be the name of another setting (e.g. ``elite`` below ``population``). ``float`` settings
    take integers too and hold them as floats."""

    type: type
    low: Bound
    high: Bound
    closed: Literal["both", "left", "right", "neither"] = "both"

    def convert(self, value: Any) -> Any:
        if isinstance(value, str):
            try:
                value = self.type(value.strip())
            except ValueError:
                raise Refused from None
        if isinstance(value, bool) or not isinstance(value, int | float):
            raise Refused
        if self.type is int and not isinstance(value, int):
            raise Refused
        if not math.isfinite(value):
            raise Refused
        return self.type(value)

    def _bound(self, bound: Bound, context: Mapping[str, Any]) -> float | None:
        return context.get(bound) if isinstance(bound, str) else bound

    def admits(self, value: Any, context: Mapping[str, Any]) -> bool:
        low, high = self._bound(self.low, context), self._bound(self.high, context)
        left, right = _BRACKETS[self.closed]
        above = low is None or (value >= low if left == "[" else value > low)
        below = high is None or (value <= high if right == "]" else value < high)
        return above and below

    def depends_on(self) -> tuple[str, ...]:
        return tuple(b for b in (self.low, self.high) if isinstance(b, str))

    def describe(self, context: Mapping[str, Any]) -> str:
        kind = "an integer" if self.type is int else "a number"
        left, right = _BRACKETS[self.closed]
        names = [f"{b}={context.get(b)!r}" if isinstance(b, str) else b
                 for b in (self.low, self.high)]
        if self.high is None:
            return f"{kind} {'>=' if left == '[' else '>'} {names[0]}"
        if self.low is None:
            return f"{kind} {'<=' if right == ']' else '<'} {names[1]}"
        return f"{kind} in {left}{names[0]}, {names[1]}{right}"


class Options(Constraint):
    """One of a few strings."""

    def __init__(self, *choices: str) -> None:
        self.choices = choices

    def convert(self, value: Any) -> Any:
        if value not in self.choices:
            raise Refused
        return value

    def describe(self, context: Mapping[str, Any]) -> str:
        return "one of " + ", ".join(repr(c) for c in self.choices)


class Boolean(Constraint):
    """``true`` or ``false`` (any case, as text)."""

    def convert(self, value: Any) -> Any:
        if isinstance(value, str) and value.strip().lower() in ("true", "false"):
            return value.strip().lower() == "true"
        if not isinstance(value, bool):
            raise Refused
        return value

    def describe(self, context: Mapping[str, Any]) -> str:
        return "true or false"


class ExistingFile(Constraint):
    """The path of an existing file (held as a string, so that runs can record it)."""

    def convert(self, value: Any) -> Any:
        if not isinstance(value, str | os.PathLike) or not Path(value).is_file():
            raise Refused
        return str(value)

    def describe(self, context: Mapping[str, Any]) -> str:
        return "the path of an existing file"


@dataclass(frozen=True)
class NoneOr(Constraint):
    """None (``none`` or ``null`` as text) or what ``inner`` admits."""

    inner: Constraint

    def convert(self, value: Any) -> Any:
        if value is None or (isinstance(value, str) and value.strip().lower() in _NONE_WORDS):
            return None
        return self.inner.convert(value)

    def admits(self, value: Any, context: Mapping[str, Any]) -> bool:
        return value is None or self.inner.admits(value, context)

    def depends_on(self) -> tuple[str, ...]:
        return self.inner.depends_on()

    def describe(self, context: Mapping[str, Any]) -> str:
        return f"none or {self.inner.describe(context)}"


def declare(**constraints: Constraint) -> Mapping[str, Constraint]:
    """A method's ``setting_constraints``, read-only (a class attribute shared by instances)."""
    return MappingProxyType(constraints)


def constructor_keywords(cls: Callable[..., Any]) -> tuple[list[str], dict[str, Any], bool]:
    """The keywords a method's constructor takes, their defaults, and whether it takes any."""
    parameters = inspect.signature(cls).parameters.values()
    names = [p.name for p in parameters if p.kind in (p.POSITIONAL_OR_KEYWORD, p.KEYWORD_ONLY)]
    defaults = {p.name: p.default for p in parameters if p.default is not p.empty}
    return names, defaults, any(p.kind == p.VAR_KEYWORD for p in parameters)


def check_settings(method: str, cls: Callable[..., Any],
                   settings: Mapping[str, Any]) -> dict[str, Any]:
    """``settings`` converted and checked against the constraints ``cls`` declares: what its
    constructor is to be called with. Raises InvalidSetting (one line) on the first problem."""
    names, defaults, takes_any = constructor_keywords(cls)
    unknown = sorted(set(settings) - set(names))
    if unknown and not takes_any:
        raise InvalidSetting(f"method {method!r} has no setting {unknown[0]!r}; its settings: "
                             f"{', '.join(names) or 'none'}")
    constraints: Mapping[str, Constraint] = getattr(cls, "setting_constraints", {})

    def refuse(name: str, value: Any, context: Mapping[str, Any],
               why: str = "") -> InvalidSetting:
        default = "" if name in settings else " (its default)"
        why = f" ({why})" if why else ""
        return InvalidSetting(f"method {method!r} setting {name!r}: got {value!r}{default}; "
                              f"allowed: {constraints[name].describe(context)}{why}")

    converted, refused = dict(settings), []
    for name, value in settings.items():
        if name in constraints:
            try:
                converted[name] = constraints[name].convert(value)
            except Refused as exc:
                refused.append((name, str(exc)))
    # The range described with the other given settings (elite's with the given population).
    context = {**defaults, **converted}
    if refused:
        name, why = refused[0]
        raise refuse(name, settings[name], context, why)
    # A given setting, and a default whose range depends on a given one (elite < population).
    for name, constraint in constraints.items():
        checked = name in settings or set(constraint.depends_on()) & set(settings)
        if checked and name in context and not constraint.admits(context[name], context):
            raise refuse(name, settings.get(name, context[name]), context)
    return converted


def settings_table(cls: Callable[..., Any]) -> list[tuple[str, str, str]]:
    """A method's settings as (name, default, what is allowed) texts, in constructor order:
    what ``tsac-bench methods NAME`` prints. A setting without a declared constraint is
    checked by the method alone ("")."""
    names, defaults, _ = constructor_keywords(cls)
    constraints: Mapping[str, Constraint] = getattr(cls, "setting_constraints", {})
    return [(name, _default_text(defaults, constraints, name),
             constraints[name].describe(defaults) if name in constraints else "")
            for name in names]


def _default_text(defaults: Mapping[str, Any], constraints: Mapping[str, Constraint],
                  name: str) -> str:
    if name not in defaults:
        return "(required)"
    if name in constraints:
        return constraints[name].describe_default(defaults[name])
    return format_value(defaults[name])


# --- method specs ------------------------------------------------------------------------
def format_value(value: Any) -> str:
    """A setting's value as text that converts back to it."""
    if value is None:
        return "none"
    if isinstance(value, bool):
        return "true" if value else "false"
    return repr(value) if isinstance(value, float) else str(value)


@dataclass(frozen=True)
class MethodSpec:
    """A method name and settings: text as parsed, converted values once checked
    (``registry.resolve_spec``)."""

    name: str
    settings: Mapping[str, Any] = field(default_factory=dict)

    @property
    def label(self) -> str:
        """The name alone, or ``NAME:KEY=VALUE...`` with the settings sorted by name."""
        return "".join([self.name, *(f":{k}={format_value(self.settings[k])}"
                                     for k in sorted(self.settings))])

    def with_settings(self, more: Mapping[str, Any]) -> MethodSpec:
        """This spec with ``more`` settings; one given both ways is an error."""
        twice = sorted(set(more) & set(self.settings))
        if twice:
            raise InvalidSetting(f"method {self.name!r} setting {twice[0]!r}: given twice "
                                 f"({self.settings[twice[0]]!r} and {more[twice[0]]!r})")
        return MethodSpec(self.name, {**self.settings, **more})


def parse_setting_pairs(pairs: Iterable[str], where: str) -> dict[str, str]:
    """``KEY=VALUE`` texts as a dict of texts; ``where`` names their source in errors."""
    settings: dict[str, str] = {}
    for pair in pairs:
        name, sep, text = pair.partition("=")
        name = name.strip()
        if not sep or not name:
            raise TsacBenchError(f"{where}: {pair!r}: expected KEY=VALUE")
        if name in settings:
            raise InvalidSetting(f"{where}: setting {name!r} given twice")
        settings[name] = text.strip()
    return settings


def parse_method_spec(text: str) -> MethodSpec:
    """``NAME[:KEY=VALUE[:KEY=VALUE...]]`` as a MethodSpec of texts."""
    name, *pairs = text.strip().split(":")
    if not name.strip():
        raise TsacBenchError(f"method spec {text!r}: expected NAME[:KEY=VALUE...]")
    return MethodSpec(name.strip(), parse_setting_pairs(pairs, f"method spec {text!r}"))


def file_label(label: str) -> str:
    """A spec label as a file-name part: ``:`` as ``+``, any other character that is not a
    letter, digit, ``-``, ``_``, ``=`` or ``+`` as ``_`` (no ``.``: it would read as a file
    suffix); a built-in method's name stays as it is."""
    return re.sub(r"[^\w=+-]", "_", label.replace(":", "+"), flags=re.ASCII)


def config_from_settings(cls: Callable[..., Any], settings: Mapping[str, Any], where: str,
                         **given: Any) -> Any:
    """A configuration dataclass ``cls`` of ``given`` fields and ``settings`` (texts read by
    the types ``cls.setting_constraints`` declares, as a method's ``--set``); ``where``
    names their source in the one-line InvalidSetting raised for a field that cannot be set
    or a value it does not admit."""
    settable: Mapping[str, Constraint] = getattr(cls, "setting_constraints", {})
    name = getattr(cls, "__name__", str(cls))
    unknown = sorted(set(settings) - set(settable))
    if unknown:
        raise InvalidSetting(f"{where}: {name} has no settable field {unknown[0]!r}; the "
                             f"settable ones: {', '.join(settable)}")
    try:
        return cls(**given, **check_settings(name, cls, settings))
    except InvalidSetting as exc:
        raise InvalidSetting(f"{where}: {exc}") from None
