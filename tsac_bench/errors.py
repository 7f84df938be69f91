"""Errors that reach users: each names where the problem is, in one line."""

from __future__ import annotations


class TsacBenchError(Exception):
    """Base class of every error tsac-bench reports to a user without a traceback."""

    exit_code = 2


class ModelError(TsacBenchError, ValueError):
    """Data that breaks the model (docs/model.md), with the path of the offending field."""

    def __init__(self, field: str, message: str) -> None:
        super().__init__(f"{field}: {message}")
        self.field = field
        self.message = message


class InputError(TsacBenchError):
    """A file that cannot be read as what it claims to be: names the file and the field."""

    def __init__(self, source: str, field: str | None, message: str) -> None:
        where = f"{source}: {field}" if field else source
        super().__init__(f"{where}: {message}")
        self.source = source
        self.field = field
        self.message = message


class UnknownMethodError(TsacBenchError, KeyError):
    def __init__(self, name: str, known: list[str]) -> None:
        super().__init__(f"unknown method {name!r}; known methods: {', '.join(known)}")
        self.name = name

    def __str__(self) -> str:
        return str(self.args[0])


class InvalidSetting(TsacBenchError, ValueError):
    """A method setting that the method does not take, or a value its declared constraint
    does not admit (``tsac_bench.planning.settings``)."""
