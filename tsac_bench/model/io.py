"""Reading and writing ``tsac-bench/instance@1`` and ``tsac-bench/solution@1`` JSON files.

The file schemas are pydantic models (strict types, unknown keys ignored); every problem is
raised as one ``InputError`` line naming the file and the field, e.g.
``bad.json: tasks[2].demand: must be an integer >= 1 kg, got 0``.
"""

from __future__ import annotations

import json
import math
import os
from pathlib import Path
from typing import Annotated, Any, Literal

from pydantic import (
    BaseModel,
    ConfigDict,
    Field,
    PlainValidator,
    StrictInt,
    StrictStr,
    ValidationError,
)
from pydantic_core import PydanticCustomError

from tsac_bench.errors import InputError, ModelError
from tsac_bench.model import AAV, Depot, Instance, Solution, Task, TaskKind, Visit

INSTANCE_FORMAT = "tsac-bench/instance@1"
SOLUTION_FORMAT = "tsac-bench/solution@1"



def _finite_number(value: Any) -> int | float:
    # json reads NaN, Infinity and -Infinity; every comparison with NaN is false, so one
    # would pass every check of the model and be priced.
    if isinstance(value, bool) or not isinstance(value, int | float):
        raise PydanticCustomError("number_type", "Input should be a number")
    if not math.isfinite(value):
        raise PydanticCustomError("finite_number", "Input should be a finite number")
    return value


#: A JSON number as written (an integer stays one), finite.
Number = Annotated[int | float, PlainValidator(_finite_number, json_schema_input_type=float)]


class _Schema(BaseModel):
    model_config = ConfigDict(extra="ignore", frozen=True)


class AAVRecord(_Schema):
    id: StrictStr
    type: StrictInt
    x: Number
    y: Number
    speed: Number
    capacity: StrictInt
    max_range: Number
    alpha: Number
    lam: Number


class DepotRecord(_Schema):
    id: StrictStr
    x: Number
    y: Number


class TaskRecord(_Schema):
    id: StrictStr
    x: Number
    y: Number
    kind: Literal["P", "D"]
    demand: StrictInt
    t_start: Number
    t_end: Number
    release: Number = 0


class InstanceRecord(_Schema):
    format: Literal["tsac-bench/instance@1"]
    name: StrictStr
    horizon: Number = 3600
    weights: tuple[Number, Number, Number] = (100, 10, 1)
    aavs: list[AAVRecord]
    depots: list[DepotRecord]
    tasks: list[TaskRecord]
    seed: StrictInt | None = None
    meta: dict[str, Any] = Field(default_factory=dict)


class VisitRecord(_Schema):
    node: StrictStr
    # Kept as parsed: the evaluator, not the parser, rules on 2.0, true or a depot amount
    # (and on the dynamic run's stamps below).
    amount: Any = None
    planned_at: Any = None
    load: Any = None


class SolutionRecord(_Schema):
    format: Literal["tsac-bench/solution@1"]
    instance: StrictStr
    routes: dict[str, list[VisitRecord]]
    cost: Number | None = None
    meta: dict[str, Any] = Field(default_factory=dict)


def _field_path(loc: tuple[int | str, ...]) -> str:
    path = ""
    for part in loc:
        path += f"[{part}]" if isinstance(part, int) else (f".{part}" if path else str(part))
    return path or "(document)"


def _load_json(path: str | os.PathLike[str]) -> Any:
    source = str(path)
    try:
        text = Path(path).read_text(encoding="utf-8")
    except FileNotFoundError:
        raise InputError(source, None, "no such file") from None
    except (OSError, UnicodeDecodeError) as exc:
        raise InputError(source, None, f"cannot read: {exc}") from None
    try:
        return json.loads(text)
    except json.JSONDecodeError as exc:
        raise InputError(source, None, f"not valid JSON: {exc.msg} at line {exc.lineno} "
                         f"column {exc.colno}") from None


def _validate(schema: type[_Schema], data: Any, source: str, expected_format: str) -> Any:
    if not isinstance(data, dict):
        raise InputError(source, None, f"expected a JSON object, got {type(data).__name__}")
    if data.get("format") != expected_format:
        raise InputError(source, "format", f"expected {expected_format!r}, got "
                         f"{data.get('format')!r}")
    try:
        return schema.model_validate(data)
    except ValidationError as exc:
        first = exc.errors()[0]
        got = first.get("input")
        detail = first["msg"] if first["type"] == "missing" else f"{first['msg']}, got {got!r}"
        raise InputError(source, _field_path(first["loc"]), detail) from None


# --- instances ---------------------------------------------------------------------------
def instance_from_dict(data: Any, source: str = "<instance>") -> Instance:
    record: InstanceRecord = _validate(InstanceRecord, data, source, INSTANCE_FORMAT)
    try:
        return Instance(
            name=record.name,
            aavs=tuple(AAV(**a.model_dump()) for a in record.aavs),
            depots=tuple(Depot(**d.model_dump()) for d in record.depots),
            tasks=tuple(Task(**{**t.model_dump(), "kind": TaskKind(t.kind)}) for t in record.tasks),
            horizon=record.horizon,
            weights=record.weights,
            seed=record.seed,
            meta=record.meta,
        )
    except ModelError as exc:
        raise InputError(source, exc.field, exc.message) from None


def instance_to_dict(instance: Instance) -> dict[str, Any]:
    return {
        "format": INSTANCE_FORMAT,
        "name": instance.name,
        "horizon": instance.horizon,
        "weights": list(instance.weights),
        "aavs": [
            {"id": a.id, "type": a.type, "x": a.x, "y": a.y, "speed": a.speed,
             "capacity": a.capacity, "max_range": a.max_range, "alpha": a.alpha, "lam": a.lam}
            for a in instance.aavs
        ],
        "depots": [{"id": d.id, "x": d.x, "y": d.y} for d in instance.depots],
        "tasks": [
            {"id": t.id, "x": t.x, "y": t.y, "kind": t.kind.value, "demand": t.demand,
             "t_start": t.t_start, "t_end": t.t_end, "release": t.release}
            for t in instance.tasks
        ],
        "seed": instance.seed,
        "meta": dict(instance.meta),
    }


def read_instance(path: str | os.PathLike[str]) -> Instance:
    return instance_from_dict(_load_json(path), str(path))


def write_instance(instance: Instance, path: str | os.PathLike[str]) -> None:
    _write_json(instance_to_dict(instance), path)


# --- solutions ---------------------------------------------------------------------------
def solution_from_dict(data: Any, instance: Instance, source: str = "<solution>") -> Solution:
    """Resolve ids against the instance. Unknown or missing ids are input errors; rule
    violations inside the routes (amounts, loads, order) are left to the evaluator."""
    record: SolutionRecord = _validate(SolutionRecord, data, source, SOLUTION_FORMAT)
    if record.instance != instance.name:
        raise InputError(source, "instance", f"solution is for instance {record.instance!r}, "
                         f"not {instance.name!r}")
    for aav_id in record.routes:
        if aav_id not in instance.aav_index:
            raise InputError(source, f"routes.{aav_id}", "unknown AAV id")
    routes = []
    for aav in instance.aavs:
        if aav.id not in record.routes:
            raise InputError(source, f"routes.{aav.id}", "missing: every AAV of the instance "
                             "needs a route key (an empty list for an idle AAV)")
        visits = []
        for k, v in enumerate(record.routes[aav.id]):
            node = instance.node_index.get(v.node)
            if node is None:
                raise InputError(source, f"routes.{aav.id}[{k}].node",
                                 f"unknown node id {v.node!r}")
            amount = v.amount
            if instance.is_depot(node) and amount is None:
                amount = 0
            visits.append(Visit(node, amount, v.planned_at, v.load))
        routes.append(tuple(visits))
    return Solution(record.instance, tuple(routes), record.cost, record.meta)


def solution_to_dict(solution: Solution, instance: Instance) -> dict[str, Any]:
    ids = instance.node_ids

    def record(v: Visit) -> dict[str, Any]:
        data: dict[str, Any] = {"node": ids[v.node]}
        if not instance.is_depot(v.node):
            data["amount"] = v.amount
        # The dynamic run's stamps are written only where present: offline files stay as
        # they were.
        if v.load is not None:
            data["load"] = v.load
        if v.planned_at is not None:
            data["planned_at"] = v.planned_at
        return data

    routes = {aav.id: [record(v) for v in route]
              for aav, route in zip(instance.aavs, solution.routes, strict=True)}
    return {"format": SOLUTION_FORMAT, "instance": solution.instance, "routes": routes,
            "cost": solution.cost, "meta": dict(solution.meta)}


def solution_instance_name(path: str | os.PathLike[str]) -> str:
    """The name of the instance a solution file is for (before the instance is read)."""
    data = _load_json(path)
    if not isinstance(data, dict) or data.get("format") != SOLUTION_FORMAT:
        raise InputError(str(path), "format", f"expected {SOLUTION_FORMAT!r}")
    name = data.get("instance")
    if not isinstance(name, str):
        raise InputError(str(path), "instance", "expected the instance's name")
    return name


def read_solution(path: str | os.PathLike[str], instance: Instance) -> Solution:
    return solution_from_dict(_load_json(path), instance, str(path))


def write_solution(solution: Solution, instance: Instance, path: str | os.PathLike[str], *,
                   compact: bool = False) -> None:
    """``compact``: one line, no spaces (the committed best-known plans: half the bytes)."""
    _write_json(solution_to_dict(solution, instance), path, compact)


def _write_json(data: dict[str, Any], path: str | os.PathLike[str],
                compact: bool = False) -> None:
    target = Path(path)
    target.parent.mkdir(parents=True, exist_ok=True)
    # Write-then-rename so a killed run never leaves a half-written file behind.
    tmp = target.with_suffix(target.suffix + ".tmp")
    text = (json.dumps(data, separators=(",", ":")) if compact
            else json.dumps(data, indent=1))
    tmp.write_text(text + "\n", encoding="utf-8")
    tmp.replace(target)
