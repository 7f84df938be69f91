"""The reproduction script's own tables (benchmarks/paper_reproduction.py), on hand-made data."""

from __future__ import annotations

import sys
from pathlib import Path

import pytest

pd = pytest.importorskip("pandas")
sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "benchmarks"))
import paper_reproduction  # noqa: E402


def rows(values: dict[tuple[str, str], list[float]]) -> pd.DataFrame:
    return pd.DataFrame([{"mode": "dynamic", "scale": scale, "instance": f"i{k}",
                          "method": method, "J": J}
                         for (scale, method), costs in values.items()
                         for k, J in enumerate(costs)])


def test_before_and_after_means_changes_and_ranks(tmp_path: Path) -> None:
    before = tmp_path / "before.csv"
    rows({("4/10", "a"): [10.0, 20.0], ("4/10", "b"): [12.0, 12.0]}).to_csv(before, index=False)
    # "b" has a third instance that "before" lacks: only instances both ran count.
    after = rows({("4/10", "a"): [11.0, 22.0], ("4/10", "b"): [9.0, 10.0, 100.0]})
    lines = paper_reproduction.before_and_after(before, after)
    assert "| 4/10 | b | 12.00 | 9.50 | -20.83% | 1 | 1 |" in lines
    assert "| 4/10 | a | 15.00 | 16.50 | 10.00% | 2 | 2 |" in lines


def test_a_missing_bound_prints_as_no_bound() -> None:
    assert paper_reproduction.percent(float("nan")) == "no bound"
    assert paper_reproduction.percent(0.1234) == "12.3%"


def test_headline_brackets_take_each_end_s_median_and_need_every_bound() -> None:
    def bracket(scale: str, method: str, instance: str, low: float, high: float) -> dict:
        return {"mode": "dynamic", "scale": scale, "method": method, "instance": instance,
                "at_least": low, "at_most": high}

    ran = pd.DataFrame([
        # 4/10: three instances, J* proven on one (low == high there).
        bracket("4/10", "dga", "a", 0.10, 0.10), bracket("4/10", "dga", "b", 0.20, 0.50),
        bracket("4/10", "dga", "c", 0.30, 0.90),
        # 8/20: one instance without a bound; the other's bound must not stand for both.
        bracket("8/20", "dga", "d", 0.00, 4.00), bracket("8/20", "dga", "e", 0.40, float("nan")),
        bracket("4/10", "hocf", "a", 1.00, 1.00), bracket("4/10", "hocf", "b", 1.00, 1.00),
        bracket("4/10", "hocf", "c", 1.00, 1.00),
        {**bracket("4/10", "dga", "a", 9.0, 9.0), "mode": "static"},  # not in the headline
    ])
    lines = paper_reproduction.headline_brackets(ran)
    assert lines[2] == "| method | 4/10 (3 inst.) | 8/20 (2 inst.) |"
    assert lines[4] == "| dga | 20.0% - 50.0% | >= 20.0% (no bound) |"
    assert lines[5] == "| hocf | 100.0% |  |"


def budget_rows() -> pd.DataFrame:
    def row(mode: str, budget: float, method: str, instance: str, J: float) -> dict:
        return {"mode": mode, "scale": "4/10", "instance": instance, "method": method,
                "budget": budget, "J": J, "seeds": 1, "over_budget": 0}

    costs = {("static", 1.0, "a"): (10.0, 12.0), ("static", 1.0, "b"): (11.0, 14.0),
             ("dynamic", 0.3, "a"): (20.0, 30.0), ("dynamic", 0.3, "b"): (25.0, 26.0)}
    return pd.DataFrame([row(mode, budget, method, f"i{k}", J)
                         for (mode, budget, method), pair in costs.items()
                         for k, J in enumerate(pair)])


def test_only_instances_every_method_ran_count() -> None:
    rows = [("dynamic", 3.0, "4/10", i, m) for i in ("a", "b") for m in ("dga", "hocf")]
    rows.append(("dynamic", 3.0, "4/10", "c", "dga"))  # hocf has not run c yet
    rows.append(("static", 1.0, "4/10", "c", "dga"))  # the only method at this budget
    table = pd.DataFrame(rows, columns=["mode", "budget", "scale", "instance", "method"])
    kept = paper_reproduction.complete_instances(table)
    assert sorted(zip(kept["mode"], kept["instance"], strict=True)) == [
        ("dynamic", "a"), ("dynamic", "a"), ("dynamic", "b"), ("dynamic", "b"),
        ("static", "c")]


def test_the_best_at_each_budget_with_its_paired_interval() -> None:
    # a - b per instance: -1, -2; mean -1.5, half-width 1.96 * 0.7071 / sqrt(2) = 0.98.
    assert paper_reproduction.best_at_each_budget(budget_rows(), "static")[2:] == [
        "| 4/10 | 1 | a (11.00) | b (12.50) | -1.50 [-2.48, -0.52] | 2 |"]


def test_the_budget_headline_gives_median_and_mean_at_the_dynamic_budget() -> None:
    assert paper_reproduction.budget_headline(budget_rows(), 0.3) == [
        "| method | 4/10 (2 inst.) |", "|---|---:|", "| a | 25.0 (25.0) |", "| b | 25.5 (25.5) |"]
    text = f"x\n{paper_reproduction.HEADLINE_BEGIN}\nold\n{paper_reproduction.HEADLINE_END}\ny"
    assert paper_reproduction.replace_headline(text, ["new"]) == (
        f"x\n{paper_reproduction.HEADLINE_BEGIN}\nnew\n{paper_reproduction.HEADLINE_END}\ny")


def test_the_readme_headline_is_the_committed_equal_budget_data() -> None:
    """Every number of the README's headline block is written by `write-budgets` from the
    committed per-instance table: edit one and this fails."""
    readme = (Path(__file__).resolve().parents[2] / "README.md").read_text()
    begin = readme.index(paper_reproduction.HEADLINE_BEGIN) + len(
        paper_reproduction.HEADLINE_BEGIN)
    block = readme[begin:readme.index(paper_reproduction.HEADLINE_END)].strip("\n")
    table = pd.read_csv(paper_reproduction.BUDGET_TABLE)
    assert block.split("\n") == paper_reproduction.headline_block(table)
