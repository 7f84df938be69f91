"""The learnability diagnostic (benchmarks/experiments/tsac_learnability.py) on hand-made labels."""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "benchmarks" / "experiments"))
import tsac_learnability as tl

pytest.importorskip("torch")
from tsac_bench.solvers.tsac.features import TASK_DIM, Observation, teacher_action
from tsac_bench.solvers.tsac.sac import Labelled

WIDTH = TASK_DIM


def observation(tasks: np.ndarray) -> Observation:
    return Observation(agent=np.zeros(11, np.float32), tasks=tasks.astype(np.float32),
                       depots=np.zeros((1, 3), np.float32),
                       action_mask=np.ones(1 + len(tasks), bool),
                       pass_token=np.zeros(3, np.float32))


def test_advantages_are_the_labels_less_hocfs_whose_choice_is_the_teacher_column() -> None:
    tasks = np.zeros((3, WIDTH))
    tasks[1, -1] = 1.0  # HOCF chooses task row 1: action 2
    example = tl.Advantages.of(Labelled(observation(tasks), (0, 2, 3), (0.5, 0.2, -0.3)))
    assert example.reference == 2
    assert example.actions == (0, 3)
    assert example.gains == pytest.approx([0.3, -0.5])
    # No row set: HOCF passes (action 0); not labelled: no example.
    assert teacher_action(observation(np.zeros((3, WIDTH)))) == 0
    assert tl.Advantages.of(Labelled(observation(tasks), (0, 1), (0.1, -0.1))) is None


def test_deviation_gain_takes_the_predicted_best_where_it_clears_tau() -> None:
    predicted = [np.array([0.5, -1.0]), np.array([-0.2, -0.1]), np.array([2.0, 0.1])]
    true = [np.array([1.0, 3.0]), np.array([5.0, 5.0]), np.array([-1.0, 0.0])]
    # tau 0: states 1 and 3 deviate to their first action (+1, -1), state 2 stays (0):
    # gains (1, 0, -1), mean 0, sample sd 1, half-width 1.96 / sqrt(3).
    assert tl.deviation_gain(predicted, true, 0.0) == (0.0, pytest.approx(1.131607), 2)
    # tau 1: only state 3: gains (0, 0, -1), mean -1/3, sd sqrt(1/3).
    assert tl.deviation_gain(predicted, true, 1.0) == (pytest.approx(-1 / 3),
                                                       pytest.approx(0.653333), 1)


def test_repeat_summary_scores_the_first_labels_choice_on_the_second() -> None:
    pairs = [(np.array([1.0, 2.0]), np.array([0.5, -1.0])),  # believes +2, gets -1
             (np.array([-1.0, -0.5]), np.array([3.0, 3.0]))]  # HOCF best: 0 and 0
    summary = tl.repeat_summary(pairs)
    assert summary["believed"] == pytest.approx(1.0)
    assert summary["got"] == pytest.approx(-0.5)
    assert summary["deviates"] == pytest.approx(0.5)
    assert summary["correlation"] == pytest.approx(
        np.corrcoef([1.0, 2.0, -1.0, -0.5], [0.5, -1.0, 3.0, 3.0])[0, 1])


def learnable_examples(count: int) -> list[tl.Advantages]:
    """States of 6 tasks where HOCF takes row 0 and an action's label is 3 times its task
    row's first column: the advantage is a function of the rows."""
    rng = np.random.default_rng(0)
    examples = []
    for _ in range(count):
        tasks = rng.random((6, WIDTH))
        tasks[:, -1] = 0.0
        tasks[0, -1] = 1.0
        actions = (1, 2, 3, 4, 5)
        examples.append(tl.Advantages.of(Labelled(
            observation(tasks), actions, tuple(3.0 * tasks[a - 1, 0] for a in actions))))
    return examples


@pytest.mark.parametrize("model", ["boosting", "critic"])
def test_both_models_find_an_advantage_that_is_a_function_of_the_task_rows(model) -> None:
    examples = learnable_examples(400)
    if model == "boosting":
        pytest.importorskip("sklearn")
        predict = tl.fit_boosting(examples[:300], seed=0)
    else:
        net = {"agent_dim": 11, "task_dim": WIDTH, "depot_dim": 3, "d_model": 32,
               "heads": 4, "layers": 2, "feedforward": 64, "features": 3,
               "pass_action": True}
        import torch

        threads = torch.get_num_threads()
        torch.set_num_threads(1)
        try:
            predict = tl.fit_critic(examples[:300], net, epochs=10, seed=0)
        finally:
            torch.set_num_threads(threads)
    test = examples[300:]
    truth = [e.gains for e in test]
    oracle = np.mean([max(0.0, g.max()) for g in truth])
    gain, _, _ = tl.deviation_gain([predict(e) for e in test], truth, 0.0)
    assert gain > 0.8 * oracle


def test_the_repeated_labels_leave_hocfs_game_as_it_is() -> None:
    from tsac_bench.model.generator import generate
    from tsac_bench.planning import PlanningState, make_allocator
    from tsac_bench.solvers.ocf.engine import C_MAX, K_MAX, CoalitionGame, sample_rng

    state = PlanningState.static(generate("4/10", 3))
    hocf = make_allocator("hocf").rule(state)
    plain = CoalitionGame(state, state.base_routes())
    plain.run(hocf, sample_rng(0, 0), k_max=K_MAX, c_max=C_MAX)
    rule = tl.RepeatedLabels(hocf, share=1.0, candidates=4, rollouts=1)
    game = CoalitionGame(state, state.base_routes())
    game.run(rule, sample_rng(0, 0), k_max=K_MAX, c_max=C_MAX)
    assert game.cost == plain.cost
    assert len(rule.pairs) > 0
    assert all(len(first) == len(second) <= 3 for first, second in rule.pairs)


@pytest.mark.parametrize("tau", [float("inf"), -1.0])
def test_margin_selection_plays_hocfs_game_when_it_keeps_or_values_the_teachers_choice(
        tau) -> None:
    """tau = inf: never deviates; tau = -1 with the teacher-choice column as the value (0
    for the pass): always takes the best value, which is HOCF's choice. Both: HOCF's J."""
    import torch

    from tsac_bench.model.generator import generate
    from tsac_bench.planning.solve import solve
    from tsac_bench.solvers.tsac.features import TEACHER_CHOICE_COLUMN

    def teacher_column(obs: dict[str, torch.Tensor]) -> torch.Tensor:
        choice = obs["tasks"][..., TEACHER_CHOICE_COLUMN]
        return torch.cat([torch.zeros_like(choice[:, :1]), choice], dim=1)

    def contrary(obs: dict[str, torch.Tensor]) -> torch.Tensor:
        return -teacher_column(obs)

    instance = generate("8/20", 5)
    hocf = solve(instance, "hocf", seed=0, mode="dynamic").cost
    score = contrary if tau == float("inf") else teacher_column
    played = solve(instance, tl.MarginAllocator(score, tau), seed=0, mode="dynamic").cost
    assert played == hocf
    # Preferring anything but HOCF's choice plays another game.
    other = solve(instance, tl.MarginAllocator(contrary, -1.0), seed=0, mode="dynamic").cost
    assert other != hocf


def test_agree_and_veto_are_the_critics_restricted_as_documented() -> None:
    """On a freshly initialised run: ``veto`` keeps the critic's values of HOCF's choice
    and the pass only; ``agree`` is each twin's gain over HOCF's choice, the smaller one,
    in J (0 at HOCF's choice)."""
    import torch

    from tsac_bench.solvers.tsac.net import collate
    from tsac_bench.solvers.tsac.sac import DiscreteSAC
    from tsac_bench.solvers.tsac.training import TrainConfig

    torch.manual_seed(0)
    config = TrainConfig(teacher_prior=0.3, label_scale=2.0)
    sac = DiscreteSAC(config.net, config.sac, "cpu", config.teacher_prior)
    scores = tl.run_scores({"config": config.to_dict(), "sac": sac.state_dict()})
    rng = np.random.default_rng(1)
    tasks = rng.random((4, WIDTH))
    tasks[:, -1] = 0.0
    tasks[2, -1] = 1.0  # HOCF chooses task row 2: action 3
    obs = collate([observation(tasks)])
    with torch.inference_mode():
        critic = scores["critic"](obs)[0].numpy()
        veto = scores["veto"](obs)[0].numpy()
        agree = scores["agree"](obs)[0].numpy()
        twins = [q(obs)[0].numpy() for q in sac.critics]
    assert veto[[0, 3]] == pytest.approx(critic[[0, 3]])
    assert np.all(np.isneginf(veto[[1, 2, 4]]))
    gains = np.minimum(*(2.0 * (q - q[3]) for q in twins))
    assert agree[:5] == pytest.approx(gains, abs=1e-5)
    assert agree[3] == 0.0
