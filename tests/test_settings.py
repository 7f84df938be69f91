"""Method settings: the declared constraints of every built-in method, their one check (a bad
value is one line, exit 2, through the CLI), and method specs ``NAME:KEY=VALUE...``."""

import json

import pytest
from typer.testing import CliRunner

from tsac_bench.cli import app
from tsac_bench.errors import InvalidSetting, TsacBenchError
from tsac_bench.planning import (
    BUILTIN_METHODS,
    Boolean,
    ExistingFile,
    Interval,
    MethodSpec,
    MethodUnavailable,
    NoneOr,
    Options,
    allocator_class,
    declare,
    make_allocator,
    parse_method_spec,
    resolve_spec,
)
from tsac_bench.planning.settings import constructor_keywords, format_value, settings_table
from tsac_bench.testing import check_declared_settings

runner = CliRunner()


def builtin_class(name):
    try:
        return allocator_class(name)
    except MethodUnavailable as exc:
        pytest.skip(str(exc))


def refused_texts(constraint, context):
    """Texts ``constraint`` must refuse, as (kind, text): "type" (not of the declared type)
    and "range" (of the type, outside the range)."""
    if isinstance(constraint, NoneOr):
        return refused_texts(constraint.inner, context)
    if isinstance(constraint, Interval):
        texts = [("type", "abc"), ("type", "true"), ("type", "nan"), ("type", "inf")]
        if constraint.type is int:
            texts.append(("type", "2.5"))
        low = context[constraint.low] if isinstance(constraint.low, str) else constraint.low
        high = context[constraint.high] if isinstance(constraint.high, str) else constraint.high
        if low is not None:
            texts.append(("range", format_value(constraint.type(low - 1))))
            if constraint.closed in ("right", "neither"):
                texts.append(("range", format_value(constraint.type(low))))
        if high is not None:
            texts.append(("range", format_value(constraint.type(high + 1))))
            if constraint.closed in ("left", "neither"):
                texts.append(("range", format_value(constraint.type(high))))
        return texts
    if isinstance(constraint, Options):
        return [("range", "no-such-choice"), ("range", "")]
    if isinstance(constraint, Boolean):
        return [("type", "maybe"), ("type", "1")]
    if isinstance(constraint, ExistingFile):
        return [("range", "no/such/file.pt")]
    raise AssertionError(f"no bad values known for {constraint!r}")


def other_valid_text(constraint, default):
    """A text ``constraint`` admits, unlike the default where there is one, and its value."""
    if isinstance(constraint, NoneOr):
        return ("none", None) if default is not None else ("null", None)
    if isinstance(constraint, Interval):
        value = constraint.type(default) / 2 if constraint.type is float else default + 1
        return format_value(value), value
    if isinstance(constraint, Options):
        value = next(c for c in constraint.choices if c != default)
        return value, value
    if isinstance(constraint, Boolean):
        return ("FALSE", False) if default else ("True", True)
    raise AssertionError(f"no valid value known for {constraint!r}")


def one_error_line(result):
    assert result.exit_code == 2, result.output
    assert result.exception is None or isinstance(result.exception, SystemExit)
    lines = result.output.strip().splitlines()
    assert len(lines) == 1, result.output
    return lines[0]


@pytest.mark.parametrize("method", sorted(BUILTIN_METHODS))
def test_every_builtin_declares_every_setting_and_its_defaults_fit(method):
    check_declared_settings(builtin_class(method))


@pytest.mark.parametrize("method", sorted(BUILTIN_METHODS))
def test_bad_settings_are_one_line_and_exit_2_through_the_cli(method, data_dir):
    cls = builtin_class(method)
    _, defaults, _ = constructor_keywords(cls)
    solve = ["solve", str(data_dir / "hand.json"), "--method", method]
    line = one_error_line(runner.invoke(app, [*solve, "--set", "no_such_setting=1"]))
    assert line.startswith(f"error: method {method!r} has no setting 'no_such_setting'; "
                           "its settings: ")
    kinds = set()
    for name, constraint in cls.setting_constraints.items():
        for kind, text in refused_texts(constraint, defaults):
            line = one_error_line(runner.invoke(app, [*solve, "--set", f"{name}={text}"]))
            assert line == (f"error: method {method!r} setting {name!r}: got {text!r}; "
                            f"allowed: {constraint.describe(defaults)}")
            kinds.add(kind)
    if cls.setting_constraints:
        assert "range" in kinds
    if any(isinstance(c, Interval) for c in cls.setting_constraints.values()):
        assert "type" in kinds


@pytest.mark.parametrize("method", sorted(BUILTIN_METHODS))
def test_valid_texts_are_converted_and_reach_the_method(method):
    cls = builtin_class(method)
    _, defaults, _ = constructor_keywords(cls)
    for name, constraint in cls.setting_constraints.items():
        text, value = other_valid_text(constraint, defaults[name])
        allocator = make_allocator(f"{method}:{name}={text}")
        assert allocator.settings()[name] == value
        assert type(allocator.settings()[name]) is type(value)


def test_solve_takes_a_spec_and_set_and_records_the_converted_settings(tmp_path, data_dir):
    out = tmp_path / "hocf.json"
    result = runner.invoke(app, ["solve", str(data_dir / "hand.json"), "--method",
                                 "hocf:init=incumbent:w_distance=0.5", "--set", "k_max=7",
                                 "--out", str(out)])
    assert result.exit_code == 0, result.output
    assert "hocf:init=incumbent:k_max=7:w_distance=0.5" in result.output
    settings = json.loads(out.read_text())["meta"]["settings"]
    assert (settings["init"], settings["k_max"], settings["w_distance"]) == ("incumbent", 7, 0.5)
    assert type(settings["k_max"]) is int


def test_a_setting_given_both_ways_is_one_line(data_dir):
    line = one_error_line(runner.invoke(app, ["solve", str(data_dir / "hand.json"), "--method",
                                              "hocf:init=incumbent", "--set", "init=greedy"]))
    assert line == ("error: method 'hocf' setting 'init': given twice ('incumbent' and "
                    "'greedy')")


@pytest.mark.parametrize(("spec", "message"), [
    ("hocf:init", "method spec 'hocf:init': 'init': expected KEY=VALUE"),
    ("hocf:", "method spec 'hocf:': '': expected KEY=VALUE"),
    (":init=empty", "method spec ':init=empty': expected NAME[:KEY=VALUE...]"),
    ("hocf:=3", "method spec 'hocf:=3': '=3': expected KEY=VALUE"),
    ("hocf:k_max=1:k_max=2", "method spec 'hocf:k_max=1:k_max=2': setting 'k_max' given twice"),
    ("nope:a=1", "unknown method 'nope'"),
])
def test_bad_specs_are_one_line(spec, message, data_dir):
    with pytest.raises(TsacBenchError) as caught:
        resolve_spec(spec)
    assert str(caught.value).startswith(message)
    line = one_error_line(runner.invoke(app, ["solve", str(data_dir / "hand.json"),
                                              "--method", spec]))
    assert line.startswith(f"error: {message}")


@pytest.mark.parametrize("text", [
    "greedy",
    "hocf:init=incumbent",
    "hocf:k_max=5:init=greedy:w_urgency=0.25",
    "dga:population=4:elite=3:mutation_rate=1",
    "exact:time_limit=none:cover_cuts=False:mip_rel_gap=1e-06:threads=2",
    "exact-cpsat:threads=2:time_limit=1.5",
    "pyvrp:piece_size=null:max_iterations=10",
])
def test_specs_round_trip_through_their_label(text):
    spec = resolve_spec(text)
    again = resolve_spec(spec.label)
    assert again == spec and again.label == spec.label
    assert parse_method_spec(spec.label) == MethodSpec(spec.name, {
        k: format_value(v) for k, v in spec.settings.items()})
    # The label lists the settings sorted by name, whatever order they were given in.
    keys = [pair.partition("=")[0] for pair in spec.label.split(":")[1:]]
    assert keys == sorted(keys) == sorted(parse_method_spec(text).settings)


def test_labels_name_converted_values():
    assert resolve_spec("hocf").label == "hocf"
    assert resolve_spec("exact:threads=02:warm_start=TRUE:time_limit=5").label == \
        "exact:threads=2:time_limit=5.0:warm_start=true"
    assert resolve_spec(MethodSpec("dga", {"population": 4})).settings == {"population": 4}


def test_a_file_setting_takes_an_existing_file_as_text():
    assert ExistingFile().convert(__file__) == __file__
    builtin_class("tsac-ocf")
    with pytest.raises(InvalidSetting, match=r"allowed: none \(the shipped policy\) or the "
                                             "path of a tsac-ocf policy file"):
        make_allocator("tsac-ocf", policy="no/such/policy.pt")


def test_python_callers_get_the_same_check():
    with pytest.raises(InvalidSetting, match="method 'exact' setting 'threads': got 0; "
                                             "allowed: an integer >= 1"):
        make_allocator("exact", threads=0)
    with pytest.raises(InvalidSetting, match="setting 'warm_start': got 1; allowed: true or "
                                             "false"):
        make_allocator("exact-cpsat", warm_start=1)
    # An int where a float is declared is held as a float.
    assert make_allocator("hocf", w_urgency=2).settings()["w_urgency"] == 2.0


def test_an_undeclared_setting_reaches_the_method_as_given(monkeypatch):
    from tsac_bench.planning import Settings, registry

    class Undeclared(Settings):
        name = "test-undeclared"

        def __init__(self, level="low"):
            self.level = level

    monkeypatch.setitem(registry._registered, "test-undeclared", Undeclared)
    assert make_allocator("test-undeclared:level=3").settings() == {"level": "3"}
    with pytest.raises(InvalidSetting, match="has no setting 'depth'; its settings: level"):
        make_allocator("test-undeclared", depth=1)


def test_a_range_that_names_another_setting_is_described_with_its_given_value():
    with pytest.raises(InvalidSetting, match=r"setting 'elite': got 'x'; allowed: an integer "
                                             r"in \[0, population=4\)"):
        make_allocator("dga:population=4:elite=x")
    with pytest.raises(InvalidSetting, match=r"setting 'elite': got 4; allowed: an integer "
                                             r"in \[0, population=4\)"):
        make_allocator("dga", population=4, elite=4)
    assert make_allocator("dga:population=4:elite=3:migrants=3").settings()["elite"] == 3


def test_a_methods_settings_table_gives_each_default_and_what_is_allowed() -> None:
    class Method:
        setting_constraints = declare(population=Interval(int, 1, None),
                                      elite=Interval(int, 0, "population", closed="left"),
                                      rule=NoneOr(Options("a", "b")))

        def __init__(self, instance_path: str, *, population: int = 10, elite: int = 2,
                     rule: str | None = None, tolerance: float = 1e-6) -> None:
            pass

    assert settings_table(Method) == [
        ("instance_path", "(required)", ""),
        ("population", "10", "an integer >= 1"),
        ("elite", "2", "an integer in [0, population=10)"),
        ("rule", "none", "none or one of 'a', 'b'"),
        ("tolerance", "1e-06", ""),  # no declared constraint: the method checks it
    ]


def test_methods_name_lists_its_settings_and_an_unknown_name_is_one_line() -> None:
    hocf = runner.invoke(app, ["methods", "hocf"])
    assert hocf.exit_code == 0, hocf.output
    row = next(line for line in hocf.output.splitlines() if "w_distance" in line)
    assert "2.0" in row and "a number >= 0" in row
    assert "no settings" in runner.invoke(app, ["methods", "greedy"]).output
    unknown = runner.invoke(app, ["methods", "nope"])
    assert unknown.exit_code == 2
    [line] = unknown.output.strip().splitlines()
    assert line.startswith("error: unknown method 'nope'; known methods: cnp, dga, exact")
