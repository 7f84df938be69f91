import json
import math
from pathlib import Path

import pytest

from tsac_bench.errors import InputError
from tsac_bench.model import Solution
from tsac_bench.model.generator import generate
from tsac_bench.model.io import (
    instance_from_dict,
    instance_to_dict,
    read_instance,
    read_solution,
    solution_to_dict,
    write_instance,
    write_solution,
)


@pytest.mark.parametrize(
    ("name", "message"),
    [
        ("duplicate-id", "tasks[1].id: duplicate id 'T0' (already used in tasks)"),
        ("negative-demand", "tasks[2].demand: must be an integer >= 1 kg, got -5"),
        ("window-reversed", "tasks[1].t_end: window ends before it starts (100 < t_start 300)"),
        ("release-after-start", "tasks[1].release: must lie in [0, t_start=300], got 400"),
        ("wrong-type", "aavs[0].capacity: Input should be a valid integer, got '30'"),
        ("float-demand", "tasks[0].demand: Input should be a valid integer, got 10.0"),
        ("unknown-format", "format: expected 'tsac-bench/instance@1', got "
                           "'tsac-bench/instance@9'"),
        ("missing-field", "tasks[3].t_end: Field required"),
        ("bad-kind", "tasks[3].kind: Input should be 'P' or 'D', got 'X'"),
        ("zero-speed", "aavs[1].speed: must be positive, got 0"),
        ("malformed", "not valid JSON"),
    ],
)
def test_bad_instance_files_name_the_file_and_field(data_dir, name, message):
    path = data_dir / "bad" / f"{name}.json"
    with pytest.raises(InputError) as caught:
        read_instance(path)
    text = str(caught.value)
    assert text.startswith(f"{path}: ") and message in text
    assert "\n" not in text


def test_missing_file(tmp_path):
    with pytest.raises(InputError, match="no such file"):
        read_instance(tmp_path / "nope.json")


def test_instance_round_trip(tmp_path, hand):
    generated = generate("8/20", seed=3)
    for instance in (hand, generated):
        write_instance(instance, tmp_path / "i.json")
        again = read_instance(tmp_path / "i.json")
        assert again == instance
        assert instance_to_dict(again) == instance_to_dict(instance)


def test_unknown_keys_are_ignored(hand):
    data = instance_to_dict(hand) | {"comment": "extra"}
    data["tasks"][0]["colour"] = "red"
    assert instance_from_dict(data) == hand


def test_solution_round_trip(tmp_path, hand):
    solution = Solution.from_ids(hand, {"A1": ["D0", ("T1", 10), "D0"]}, cost=50.0,
                                 meta={"method": "hand"})
    write_solution(solution, hand, tmp_path / "s.json")
    assert read_solution(tmp_path / "s.json", hand) == solution
    written = json.loads((tmp_path / "s.json").read_text())
    assert written["routes"] == {"A0": [], "A1": [{"node": "D0"}, {"node": "T1", "amount": 10},
                                                  {"node": "D0"}]}


def _solution_file(tmp_path, hand, mutate):
    data = solution_to_dict(Solution.from_ids(hand, {"A0": [("T0", 5), "D0"]}), hand)
    mutate(data)
    path = tmp_path / "s.json"
    path.write_text(json.dumps(data))
    return path


@pytest.mark.parametrize(
    ("mutate", "message"),
    [
        (lambda d: d["routes"]["A0"][0].update(node="T9"),
         "routes.A0[0].node: unknown node id 'T9'"),
        (lambda d: d["routes"].update(A7=[]), "routes.A7: unknown AAV id"),
        (lambda d: d["routes"].pop("A1"), "routes.A1: missing"),
        (lambda d: d.update(format="tsac-bench/solution@2"), "format: expected"),
        (lambda d: d.update(instance="other"), "instance: solution is for instance 'other'"),
        (lambda d: d["routes"]["A0"][0].pop("node"), "routes.A0[0].node: Field required"),
        (lambda d: d.update(routes=[]), "routes: Input should be a valid dictionary"),
    ],
)
def test_bad_solution_files(tmp_path, hand, mutate, message):
    path = _solution_file(tmp_path, hand, mutate)
    with pytest.raises(InputError, match=None) as caught:
        read_solution(path, hand)
    assert str(caught.value).startswith(f"{path}: ") and message in str(caught.value)


def test_amount_types_reach_the_evaluator_unchanged(tmp_path, hand):
    # 2.0 and true are not kilograms: the parser keeps them so the evaluator can say so.
    path = _solution_file(tmp_path, hand, lambda d: d["routes"]["A0"][0].update(amount=2.0))
    assert read_solution(path, hand).routes[0][0].amount == 2.0


def test_instances_and_solutions_pickle_for_worker_processes(hand):
    import pickle

    solution = Solution.from_ids(hand, {"A0": [("T0", 5), "D0"]}, cost=1.0, meta={"m": 1})
    assert pickle.loads(pickle.dumps(hand)) == hand
    assert pickle.loads(pickle.dumps(solution)) == solution


def test_a_walk_skips_sweep_sets_unless_they_are_named(tmp_path, hand):
    from tsac_bench.batch.manifests import SWEEP_MARKER, iter_instance_files, sweep_sets_below

    for folder in ("quick", "big"):
        write_instance(hand, tmp_path / folder / "hand.json")
    (tmp_path / "big" / SWEEP_MARKER).touch()
    assert iter_instance_files([tmp_path]) == [tmp_path / "quick" / "hand.json"]
    assert iter_instance_files([tmp_path / "big"]) == [tmp_path / "big" / "hand.json"]
    assert sweep_sets_below(tmp_path) == [tmp_path / "big"]


def numeric_fields(schema, document, path=()):
    """The path of every number the file schema ``schema`` declares, found by walking its
    types (lists and dicts entered at their first item of ``document``, tuples at each);
    ``Any`` (a visit's amount, ruled on by the evaluator; ``meta``) is no number field."""
    import types
    import typing

    from pydantic import BaseModel

    origin, args = typing.get_origin(schema), typing.get_args(schema)
    if isinstance(schema, type) and issubclass(schema, BaseModel):
        for name, field in schema.model_fields.items():
            yield from numeric_fields(field.annotation, (document or {}).get(name),
                                      (*path, name))
    elif origin is typing.Annotated:
        yield from numeric_fields(args[0], document, path)
    elif origin in (typing.Union, types.UnionType):
        members = [a for a in args if a is not type(None)]
        if any(m in (int, float) for m in members):
            yield path
        else:
            for member in members:
                yield from numeric_fields(member, document, path)
    elif origin is list:
        yield from numeric_fields(args[0], document[0], (*path, 0))
    elif origin is tuple:
        for k, member in enumerate(args):
            yield from numeric_fields(member, document[k], (*path, k))
    elif origin is dict and args[1] is not typing.Any:
        key = next(iter(document))
        yield from numeric_fields(args[1], document[key], (*path, key))
    elif schema in (int, float):
        yield path


def _field_text(path):
    return "".join(f"[{p}]" if isinstance(p, int) else f".{p}" for p in path).lstrip(".")


def _put(document, path, value):
    for part in path[:-1]:
        document = document[part]
    if isinstance(document, list) and len(document) <= path[-1]:
        document.append(value)
    else:
        document[path[-1]] = value


def _non_finite_cases():
    from tsac_bench.model.io import InstanceRecord, SolutionRecord

    hand = read_instance(Path(__file__).parent / "data" / "hand.json")
    instance = instance_to_dict(hand)
    solution = solution_to_dict(Solution.from_ids(hand, {"A0": [("T0", 5), "D0"]}, cost=1.0),
                                hand)
    for kind, schema, document in (("instance", InstanceRecord, instance),
                                   ("solution", SolutionRecord, solution)):
        for path in numeric_fields(schema, document):
            for value in (math.nan, math.inf, -math.inf):
                yield pytest.param(kind, document, path, value,
                                   id=f"{kind}:{_field_text(path)}={value}")


NON_FINITE = list(_non_finite_cases())


def test_the_non_finite_cases_cover_every_numeric_field():
    fields = {(case.values[0], _field_text(case.values[2])) for case in NON_FINITE}
    assert {("instance", "tasks[0].t_end"), ("instance", "weights[2]"),
            ("instance", "aavs[0].lam"), ("instance", "tasks[0].release"),
            ("instance", "seed"), ("solution", "cost")} <= fields
    assert len(fields) == 8 + 2 + 6 + 5 + 1  # aavs, depots, tasks, top level, cost


@pytest.mark.parametrize(("kind", "document", "path", "value"), NON_FINITE)
def test_non_finite_numbers_are_one_line_naming_file_and_field(tmp_path, data_dir, kind,
                                                               document, path, value):
    from typer.testing import CliRunner

    from tsac_bench.cli import app

    broken = json.loads(json.dumps(document))
    _put(broken, path, value)
    file = tmp_path / f"{kind}.json"
    file.write_text(json.dumps(broken))  # json writes NaN, Infinity, -Infinity
    args = (["info", file] if kind == "instance"
            else ["evaluate", data_dir / "hand.json", file])
    result = CliRunner().invoke(app, [str(a) for a in args])
    assert result.exit_code == 2, result.output
    lines = result.output.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith(f"error: {file}: {_field_text(path)}: ")
    assert lines[0].endswith(f"got {value!r}")


def test_stamps_round_trip_and_offline_files_stay_as_they_were(tmp_path, hand, data_dir):
    from tsac_bench.model import Visit

    d0, t1 = hand.node_index["D0"], hand.node_index["T1"]
    solution = Solution(hand.name, ((), (Visit(d0, load=10), Visit(t1, 10, planned_at=25.5),
                                         Visit(d0, planned_at=25.5))))
    write_solution(solution, hand, tmp_path / "s.json")
    assert read_solution(tmp_path / "s.json", hand) == solution
    written = json.loads((tmp_path / "s.json").read_text())
    assert written["routes"]["A1"] == [{"node": "D0", "load": 10},
                                       {"node": "T1", "amount": 10, "planned_at": 25.5},
                                       {"node": "D0", "planned_at": 25.5}]
    # An offline file reads without stamps and is written back exactly as it was.
    original = json.loads((data_dir / "hand-solution.json").read_text())
    offline = read_solution(data_dir / "hand-solution.json", hand)
    assert all(v.planned_at is None and v.load is None for r in offline.routes for v in r)
    assert solution_to_dict(offline, hand)["routes"] == original["routes"]
