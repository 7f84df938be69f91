import json
import subprocess
import sys
from pathlib import Path

import pytest
from typer.testing import CliRunner

from tsac_bench.cli import app

runner = CliRunner()


def invoke(*args):
    return runner.invoke(app, [str(a) for a in args])


def test_evaluate_prints_J_and_json(data_dir):
    result = invoke("evaluate", data_dir / "hand.json", data_dir / "hand-solution.json")
    assert result.exit_code == 0, result.output
    assert "J = 212.821528" in result.output
    result = invoke("evaluate", data_dir / "hand.json", data_dir / "hand-solution.json", "--json")
    data = json.loads(result.stdout)
    assert data["feasible"] is True and data["errors"] == []
    assert data["J"] == pytest.approx(212.82152777777778, rel=1e-15)
    assert [t["task"] for t in data["per_task"]] == ["T0", "T1", "T2", "T3"]
    assert data["per_task"][1]["amounts"] == {"A1": 10}


def test_evaluate_infeasible_exits_1_with_named_errors(tmp_path, data_dir):
    solution = json.loads((data_dir / "hand-solution.json").read_text())
    solution["routes"]["A1"] = [{"node": "T3", "amount": 10}, {"node": "D0"}]
    path = tmp_path / "s.json"
    path.write_text(json.dumps(solution))
    result = invoke("evaluate", data_dir / "hand.json", path)
    assert result.exit_code == 1
    assert "routes.A1[0]" in result.output and "no-goods" in result.output
    as_json = invoke("evaluate", data_dir / "hand.json", path, "--json")
    assert as_json.exit_code == 1
    assert json.loads(as_json.stdout)["errors"][0]["code"] == "no-goods"


@pytest.mark.parametrize("bad", ["malformed", "duplicate-id", "unknown-format"])
def test_bad_input_is_one_line_and_exit_2(data_dir, bad):
    # A real process: exit code and stderr as a user sees them, no traceback.
    done = subprocess.run([sys.executable, "-m", "tsac_bench", "info",
                           str(data_dir / "bad" / f"{bad}.json")], capture_output=True, text=True)
    assert done.returncode == 2
    lines = done.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith(f"error: {data_dir / 'bad' / bad}.json: ")
    assert "Traceback" not in done.stderr


def test_unknown_method_exit_2(data_dir):
    result = invoke("solve", data_dir / "hand.json", "--method", "nope")
    assert result.exit_code == 2
    assert "unknown method 'nope'" in result.output


def test_solve_passes_settings_and_names_an_unknown_one(tmp_path, data_dir):
    out = tmp_path / "exact.json"
    result = invoke("solve", data_dir / "hand.json", "--method", "exact", "--set", "threads=2",
                    "--set", "cover_cuts=false", "--out", out)
    assert result.exit_code == 0, result.output
    settings = json.loads(out.read_text())["meta"]["settings"]
    assert settings["threads"] == 2 and settings["cover_cuts"] is False
    result = invoke("solve", data_dir / "hand.json", "--method", "exact", "--set", "thread=2")
    assert result.exit_code == 2
    assert "method 'exact' has no setting 'thread'; its settings: time_limit, threads" \
        in result.output
    assert invoke("solve", data_dir / "hand.json", "--set", "threads").exit_code == 2


def test_solve_writes_a_solution_that_evaluates_to_the_printed_J(tmp_path, data_dir):
    out = tmp_path / "greedy.json"
    result = invoke("solve", data_dir / "hand.json", "--method", "greedy", "--out", out)
    assert result.exit_code == 0, result.output
    claimed = json.loads(out.read_text())["cost"]
    assert f"J = {claimed:.6f}" in result.output
    check = invoke("evaluate", data_dir / "hand.json", out, "--json")
    assert json.loads(check.stdout)["J"] == claimed


QUICK = Path(__file__).resolve().parents[1] / "instances" / "quick"


def test_solve_prints_and_keeps_an_exact_methods_status_and_bound(tmp_path):
    # quick-2-4-s1's manifest: J* = 35.456039935500684, proven by every exact backend.
    out = tmp_path / "exact.json"
    result = invoke("solve", QUICK / "quick-2-4-s1.json", "--method", "exact", "--out", out)
    assert result.exit_code == 0, result.output
    assert "J = 35.456040" in result.output
    assert "status optimal, lower bound 35.456040, MIP gap 0.00 %" in result.output
    meta = json.loads(out.read_text())["meta"]
    assert meta["status"] == "optimal"
    assert meta["lower_bound"] == pytest.approx(35.456039935500684, rel=1e-6)


def test_solve_prints_the_gap_of_a_time_limited_exact_run(tmp_path):
    # No backend proves quick-4-10-s5 in a second: a plan, a bound below it and their gap.
    out = tmp_path / "exact.json"
    result = invoke("solve", QUICK / "quick-4-10-s5.json", "--method", "exact",
                    "--time-limit", "0.5", "--out", out)
    assert result.exit_code == 0, result.output
    data = json.loads(out.read_text())
    J, bound = data["cost"], data["meta"]["lower_bound"]
    assert data["meta"]["status"] == "feasible"
    # The manifest's best bound (1.3827, 600 s of each backend) is no weaker than this one.
    assert 0 < bound <= 1.3826844931115687 + 1e-9 < J
    assert (f"status feasible, lower bound {bound:.6f}, MIP gap {100 * (J - bound) / J:.2f} %"
            in result.output)


def test_a_heuristics_solve_shows_no_status_or_bound(tmp_path):
    out = tmp_path / "greedy.json"
    result = invoke("solve", QUICK / "quick-2-4-s1.json", "--method", "greedy", "--out", out)
    assert result.exit_code == 0, result.output
    assert "status" not in result.output and "lower bound" not in result.output
    meta = json.loads(out.read_text())["meta"]
    assert "status" not in meta and "lower_bound" not in meta


def test_generate_and_info(tmp_path):
    result = invoke("generate", "--scale", "4/10", "--count", "2", "--seed", "5", "--out", tmp_path)
    assert result.exit_code == 0, result.output
    assert sorted(p.name for p in tmp_path.iterdir()) == ["gen-4-10-s5.json", "gen-4-10-s6.json"]
    info = invoke("info", tmp_path / "gen-4-10-s5.json")
    assert info.exit_code == 0 and "scale 4/10" in info.output
    assert invoke("generate", "--scale", "x").exit_code == 2


def test_methods_lists_greedy():
    result = invoke("methods")
    assert result.exit_code == 0 and "greedy" in result.output
