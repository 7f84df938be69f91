"""``tsac-bench train --set``: a scalar TrainConfig field given on the command line reaches the
training run, converted by its declared type; a bad one is one line and exit 2. The training
function is replaced, so nothing here trains."""

from __future__ import annotations

import pytest

torch = pytest.importorskip("torch")

from typer.testing import CliRunner  # noqa: E402

from tsac_bench.cli import app  # noqa: E402
from tsac_bench.solvers.tsac import training  # noqa: E402

runner = CliRunner()


@pytest.fixture
def trained(monkeypatch):
    """The (out, config, keywords) of each call of the training run, which is not run."""
    calls = []

    def record(out, config, **keywords):
        calls.append((out, config, keywords))
        return {"steps": config.steps, "episode_count": 0, "seconds": 0.0, "device": "cpu"}

    monkeypatch.setattr(training, "train", record)
    return calls


def train(*args):
    # The thread count the process already has: the command sets it for the whole process.
    return runner.invoke(app, ["train", "--device", "cpu", "--threads",
                               str(torch.get_num_threads()), *map(str, args)])


def test_set_fields_reach_the_training_configuration(tmp_path, trained):
    result = train("--out", tmp_path, "--steps", 4000, "--seed", 3,
                   "--set", "replan_share=0", "--set", "rollouts=4",
                   "--set", "demonstrator=none", "--set", " teacher_prior = 1")
    assert result.exit_code == 0, result.output
    [(out, config, _)] = trained
    assert out == tmp_path
    assert (config.steps, config.seed, config.replan_share, config.rollouts,
            config.demonstrator, config.teacher_prior) == (4000, 3, 0.0, 4, None, 1.0)
    assert type(config.replan_share) is float and type(config.rollouts) is int
    default = training.TrainConfig()
    assert (config.warmup, config.label_share, config.curriculum, config.net) == (
        default.warmup, default.label_share, default.curriculum, default.net)


def test_without_set_the_configuration_is_the_default(tmp_path, trained):
    assert train("--out", tmp_path, "--steps", 4000).exit_code == 0
    [(_, config, _)] = trained
    assert config == training.TrainConfig(steps=4000, seed=0)


@pytest.mark.parametrize(("pair", "words"), [
    ("nonsense=1", ["--set", "no settable field 'nonsense'", "replan_share"]),
    ("steps=5", ["--set", "no settable field 'steps'"]),
    ("curriculum=4/10", ["--set", "no settable field 'curriculum'"]),
    # Fields of the retired recipes (docs/tsac.md, "History") are not fields any more.
    ("signal=td", ["--set", "no settable field 'signal'"]),
    ("features=2", ["--set", "no settable field 'features'"]),
    ("teacher_prior=0", ["--set", "'teacher_prior'", "'0'", "> 0"]),
    ("rollouts=2.0", ["--set", "'rollouts'", "an integer"]),
    ("replan_share=1.5", ["--set", "'replan_share'", "[0, 1]"]),
    ("warmup=ten", ["--set", "'warmup'", "'ten'"]),
    ("demonstrator=dga", ["--set", "'demonstrator'", "'hocf', 'rocf'"]),
    ("label_scale=0", ["--set", "'label_scale'", "> 0"]),
    ("rollouts", ["--set", "'rollouts'", "expected KEY=VALUE"]),
])
def test_a_bad_set_is_one_line_naming_the_option_and_field(tmp_path, trained, pair, words):
    result = train("--out", tmp_path, "--set", pair)
    assert result.exit_code == 2
    lines = result.output.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("error: --set"), result.output
    assert all(w in lines[0] for w in words), lines[0]
    assert trained == []


def test_a_field_given_twice_is_refused(tmp_path, trained):
    result = train("--out", tmp_path, "--set", "rollouts=4", "--set", "rollouts=8")
    assert result.exit_code == 2
    assert result.output.strip() == "error: --set: setting 'rollouts' given twice"
    assert trained == []


def test_set_is_refused_with_resume(tmp_path, trained):
    checkpoint = tmp_path / "checkpoint.pt"
    checkpoint.write_bytes(b"")
    result = train("--out", tmp_path, "--resume", checkpoint, "--steps", 10,
                   "--set", "replan_share=0")
    assert result.exit_code == 2
    lines = result.output.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("error: --set: not with --resume")
    assert trained == []
