"""The deviation verifier of tsac-ocf's margin rule: its labels, its check, its file, its
setting, its fit and its command."""

from __future__ import annotations

import numpy as np
import pytest

torch = pytest.importorskip("torch")

from tsac_bench.errors import InvalidSetting  # noqa: E402
from tsac_bench.model.generator import generate  # noqa: E402
from tsac_bench.planning import PlanningState, make_allocator  # noqa: E402
from tsac_bench.planning.solve import solve  # noqa: E402
from tsac_bench.solvers.ocf.engine import C_MAX, CoalitionGame, DecisionView  # noqa: E402
from tsac_bench.solvers.tsac.features import TASK_DIM, observe, teacher_action  # noqa: E402
from tsac_bench.solvers.tsac.net import NetConfig, PolicyNet, QNet, collate  # noqa: E402
from tsac_bench.solvers.tsac.policy import (  # noqa: E402
    MarginSelection,
    PolicyFileError,
    TSACOCFAllocator,
    VerifierCheck,
    read_policy,
    save_policy,
)
from tsac_bench.solvers.tsac.sac import rollout_values  # noqa: E402
from tsac_bench.solvers.tsac.verify import (  # noqa: E402
    DeviationLabel,
    RolloutCheck,
    VerifierConfig,
    agreement,
    fit_verifier,
    label_all,
    label_deviations,
    predicted_gains,
    split,
    train_verifier,
)

SMALL_V3 = NetConfig(11, TASK_DIM, 3, d_model=16, heads=2, layers=2,
                     feedforward=32, features=3, pass_action=True)


pytestmark = pytest.mark.usefixtures("one_torch_thread")


def random_policy(path, verifier: bool = False, unit: float = 1.0):
    """A policy file of random networks (twin critics, maybe a verifier)."""
    torch.manual_seed(3)
    save_policy(PolicyNet(SMALL_V3), path, {"made": "test"},
                critics=[QNet(SMALL_V3), QNet(SMALL_V3)], critic_unit=unit,
                verifier=QNet(SMALL_V3) if verifier else None)
    return path


def hocf_mid_game(scale="8/20", seed=3, decisions=15):
    """A game a few HOCF decisions in, HOCF's rule, and the next AAV's view with at least
    two candidates besides HOCF's choice."""
    state = PlanningState.static(generate(scale, seed))
    game = CoalitionGame(state)
    hocf = make_allocator("hocf").rule(state)
    game.run(hocf, np.random.default_rng(0), k_max=decisions, c_max=C_MAX)
    n = next(n for n in range(game.n_aavs) if len(game.candidates(n)) > 2)
    return game, DecisionView(game, n, game.candidates(n)), hocf


def test_a_deviation_label_is_the_rollout_gain_over_hocfs_choice():
    game, view, hocf = hocf_mid_game()
    state = observe(view)
    teacher = teacher_action(state)
    others = [a for a in np.flatnonzero(state.action_mask) if a != teacher]
    labels: list[DeviationLabel] = []
    check = RolloutCheck(hocf, 3, np.random.default_rng(5), labels, "8/20", 42)
    verdicts = [check(view, state, int(a), teacher) for a in others[:3]]
    seeds = np.random.default_rng(5).integers(2**31, size=3)
    for label, verdict, action, seed in zip(labels, verdicts, others, seeds, strict=False):
        finals = rollout_values(game, view, [int(action), teacher], hocf,
                                rollouts=3, seed=int(seed))
        assert label.gain == finals[1].mean() - finals[0].mean()
        assert verdict == (label.gain > 0)
        assert (label.action, label.teacher, label.scale, label.instance_seed) == (
            action, teacher, "8/20", 42)
    assert len({label.gain for label in labels}) > 1  # the check can fail and pass


def test_the_margin_rule_takes_only_the_deviations_its_check_confirms(tmp_path):
    """A check that refuses everything plays HOCF's game; one that confirms everything
    plays the unchecked margin rule's; the verifier's check lies between, by its margin."""
    path = str(random_policy(tmp_path / "p.pt", verifier=True))
    instance = generate("8/20", 5)
    hocf = solve(instance, "hocf", seed=2, mode="dynamic")

    def margin_rule(**settings):
        return solve(instance, "tsac-ocf", seed=2, mode="dynamic",
                     settings={"policy": path, "margin": 0, **settings})

    unchecked = margin_rule(verify="none")
    assert unchecked.cost != hocf.cost
    assert margin_rule(verify=1e9).solution.routes == hocf.solution.routes
    assert margin_rule(verify=-1e9).solution.routes == unchecked.solution.routes
    checked = margin_rule(verify=0)
    assert checked.evaluation.feasible and checked.claim_matches
    assert checked.solution.routes == margin_rule(verify=0).solution.routes  # same seed


def test_the_verifier_check_compares_the_deviation_with_hocfs_action_in_j():
    game, view, _ = hocf_mid_game()
    state = observe(view)
    values = torch.zeros((1, len(state.action_mask)))
    values[0, 2], values[0, 0] = 1.5, 0.25

    def verified(obs):
        return values

    assert VerifierCheck(verified, 1.0)(view, state, 2, 0)  # 1.25 above
    assert not VerifierCheck(verified, 1.25)(view, state, 2, 0)
    assert not VerifierCheck(verified, -1.0)(view, state, 0, 2)  # 1.25 below
    never = MarginSelection(lambda obs: values, 0.0, confirm=lambda *args: False)
    action = never.select(view, np.random.default_rng(0))
    hocf_choice = make_allocator("hocf").rule(PlanningState.static(game.instance)).select(
        view, np.random.default_rng(0))
    assert action == hocf_choice


def test_policy_files_carry_the_verifier_in_j(tmp_path):
    with_it = read_policy(random_policy(tmp_path / "v.pt", verifier=True, unit=2.0))
    assert with_it.verifier is not None and not any(
        p.requires_grad for p in with_it.verifier.parameters())
    _, view, _ = hocf_mid_game("4/10", 8, decisions=3)
    obs = collate([observe(view)])
    assert torch.equal(with_it.verified(obs), 2.0 * with_it.verifier(obs))
    assert read_policy(random_policy(tmp_path / "p.pt")).verifier is None


def test_verify_needs_a_policy_with_a_verifier(tmp_path):
    without = str(random_policy(tmp_path / "p.pt"))
    with pytest.raises(InvalidSetting, match=r"setting 'verify'.*carries none"):
        make_allocator("tsac-ocf", policy=without, verify=0)
    with pytest.raises(InvalidSetting, match=r"got 0.25 \(its default\).*verify=none"):
        make_allocator("tsac-ocf", policy=without)
    assert make_allocator("tsac-ocf", policy=without, verify="none").verify is None
    # decode=sample ignores it, as decode=margin ignores temperature.
    assert make_allocator("tsac-ocf", policy=without, decode="sample").decode == "sample"
    with_it = str(random_policy(tmp_path / "v.pt", verifier=True))
    assert make_allocator("tsac-ocf", policy=with_it, verify="0.5").verify == 0.5
    with pytest.raises(PolicyFileError, match="verify: its file carries no verifier"):
        TSACOCFAllocator(without, verify=0.0).rule(PlanningState.static(generate("4/10", 1)))


@pytest.fixture(scope="module")
def labels(tmp_path_factory):
    path = str(random_policy(tmp_path_factory.mktemp("policy") / "p.pt"))
    config = VerifierConfig(margin=0.0, rollouts=2, instances=(("4/10", 3),))
    return path, config, label_all(path, config).labels


def test_labels_are_the_same_with_worker_processes(labels):
    path, config, alone = labels
    assert len(alone) > 20 and {label.instance_seed for label in alone} == {
        700_000, 700_001, 700_002}
    shared = label_all(path, config, workers=2).labels
    assert [(x.action, x.teacher, x.gain) for x in shared] == [
        (x.action, x.teacher, x.gain) for x in alone]
    # The run of one instance goes on with a deviation only where its label confirms it.
    one = label_deviations("4/10", 700_001, path, 0.0, 2)
    assert [x.gain for x in one] == [x.gain for x in alone if x.instance_seed == 700_001]


def test_held_out_labels_are_the_last_instances_of_each_scale(labels):
    all_labels = labels[2]
    train, held = split(all_labels, VerifierConfig(instances=(("4/10", 3),), held_out=0.34))
    assert {x.instance_seed for x in held} == {700_002}
    assert len(train) + len(held) == len(all_labels)


def test_fitting_brings_the_verifier_to_its_labels_the_same_way_per_seed(labels):
    """Labels a network of the same shape can meet exactly (another random critic's value
    differences, in tens of J): the fit gets most of their signs and much of their size."""
    path, _, real = labels
    torch.manual_seed(11)
    target = QNet(SMALL_V3).eval()
    with torch.inference_mode():
        made = [DeviationLabel(x.state, x.action, x.teacher, float(
            10 * (target(collate([x.state]))[0, x.action] - target(collate([x.state]))[
                0, x.teacher])), x.scale, x.instance_seed) for x in real]
    policy = read_policy(path)
    config = VerifierConfig(epochs=20, lr=3e-3, batch_size=16)
    fitted, log = fit_verifier(policy, made, made[:5], config)
    assert log[-1]["train_huber"] < 0.5 * log[0]["train_huber"]
    assert log[-1]["train_sign_right"] > 0.8 > log[0]["train_sign_right"]
    again, _ = fit_verifier(policy, made, made[:5], config)
    predicted = predicted_gains(fitted, made)
    np.testing.assert_array_equal(predicted, predicted_gains(again, made))
    scores = agreement(predicted, made)
    gains = np.array([x.gain for x in made])
    assert scores["gain_all"] == pytest.approx(gains.mean())
    assert scores["kept"] == pytest.approx(float(np.mean(predicted > 0)))
    assert scores["sign_right"] == log[-1]["train_sign_right"]


def test_train_verifier_writes_a_policy_tsac_ocf_verifies_with(tmp_path, labels):
    path, _, all_labels = labels
    torch.save(all_labels, tmp_path / "labels.pt")
    summary = train_verifier(tmp_path / "out", path, VerifierConfig(
        margin=0.0, instances=(("4/10", 3),), epochs=2, held_out=0.34),
        labels=tmp_path / "labels.pt")
    assert summary["labels"] == len(all_labels) and summary["held_out"] > 0
    written = tmp_path / "out" / "policy.pt"
    policy = read_policy(written)
    assert policy.verifier is not None and len(policy.critics) == 2
    outcome = solve(generate("4/10", 3), "tsac-ocf", seed=0, mode="dynamic",
                    settings={"policy": str(written), "verify": 0})
    assert outcome.evaluation.feasible and outcome.claim_matches
    meta = torch.load(written, weights_only=True)["meta"]
    assert meta["made"] == "test" and meta["verifier"]["train"] == summary["train"]


def test_the_command_refuses_bad_settings_and_policies_in_one_line(tmp_path):
    from typer.testing import CliRunner

    from tsac_bench.cli import app

    def run(*args):
        return CliRunner().invoke(app, ["train-verifier", "--out", str(tmp_path / "o"),
                                        *args])

    for args, words in ((["--set", "epochs=-1"], "epochs"),
                        (["--set", "instances=3"], "no settable field 'instances'"),
                        (["--policy", str(tmp_path / "none.pt")], "is not a file"),
                        (["--labels", str(tmp_path / "none.pt")], "--labels")):
        result = run(*args)
        assert result.exit_code == 2, result.output
        assert result.stderr.count("\n") == 1 and words in result.stderr
    no_critics = tmp_path / "actor.pt"
    save_policy(PolicyNet(SMALL_V3), no_critics, {})
    result = run("--policy", str(no_critics))
    assert result.exit_code == 2 and "no twin critics" in result.stderr
