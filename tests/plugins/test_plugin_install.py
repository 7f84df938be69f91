"""A method installed as a separate distribution (entry-point group
``tsac_bench.allocators``) is listed by ``tsac-bench methods`` and run by ``tsac-bench
solve``: the plug-in is "installed" by putting its module and a ``.dist-info`` with an
``entry_points.txt`` on PYTHONPATH of a fresh interpreter, which is what pip leaves behind."""

import os
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).parents[2]

PLUGIN = '''
from tsac_bench.planning import PlanResult, Settings


class Idle(Settings):
    """Sends every AAV nowhere: the committed prefixes, closed. J = 110 per task."""

    name = "tiny-idle"

    def __init__(self, note: str = "") -> None:
        self.note = note

    def plan(self, state, *, seed=0, time_limit=None):
        return PlanResult(state.base_routes(), {"note": self.note})
'''


def install_plugin(site: Path) -> None:
    (site / "tiny_tsac_plugin.py").write_text(PLUGIN)
    info = site / "tiny_tsac_plugin-0.1.dist-info"
    info.mkdir()
    (info / "METADATA").write_text("Metadata-Version: 2.1\nName: tiny-tsac-plugin\n"
                                   "Version: 0.1\n")
    (info / "entry_points.txt").write_text(
        "[tsac_bench.allocators]\ntiny-idle = tiny_tsac_plugin:Idle\n")


def cli(site: Path, *args: str) -> subprocess.CompletedProcess:
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(site), str(ROOT)]),
           "COLUMNS": "200"}
    return subprocess.run([sys.executable, "-m", "tsac_bench", *args], env=env, cwd=ROOT,
                          capture_output=True, text=True, timeout=120)


def test_an_installed_plugin_is_listed_and_runs(tmp_path):
    install_plugin(tmp_path)
    listed = cli(tmp_path, "methods")
    assert listed.returncode == 0, listed.stderr
    row = next(line for line in listed.stdout.splitlines() if "tiny-idle" in line)
    assert "plug-in" in row and "available" in row
    instance = ROOT / "instances" / "quick" / "quick-2-4-s1.json"
    for mode in ("static", "dynamic"):
        out = tmp_path / f"{mode}.json"
        solved = cli(tmp_path, "solve", str(instance), "--method", "tiny-idle", "--mode", mode,
                     "--out", str(out))
        assert solved.returncode == 0, solved.stderr
        assert "J = 440.000000" in solved.stdout  # 4 unserved tasks at w1 + w2 = 110
        assert '"method": "tiny-idle"' in out.read_text()


PLUGIN_SUITE = '''
import pytest

from tsac_bench.testing import allocator_checks


@pytest.mark.parametrize("check", allocator_checks("tiny-idle"), ids=str)
def test_tiny_idle_conforms(check):
    check()
'''


def test_the_shipped_conformance_suite_runs_in_a_plugin_s_own_tests(tmp_path):
    install_plugin(tmp_path)
    suite = tmp_path / "plugin_tests"
    suite.mkdir()
    (suite / "test_conformance.py").write_text(PLUGIN_SUITE)
    env = {**os.environ, "PYTHONPATH": str(tmp_path)}
    done = subprocess.run([sys.executable, "-m", "pytest", "-q", "-p", "no:cacheprovider",
                           "-k", "no-tasks or one-aav", str(suite)], env=env, cwd=suite,
                          capture_output=True, text=True, timeout=300)
    # The idle plug-in sends nobody anywhere: right with no tasks, wrong with work to do.
    assert "2 failed, 2 passed" in done.stdout, done.stdout[-2000:]
    assert "tiny-idle:one-aav[static]" in done.stdout


def test_a_plugin_with_a_missing_dependency_is_listed_as_unavailable(tmp_path):
    install_plugin(tmp_path)
    module = tmp_path / "tiny_tsac_plugin.py"
    module.write_text("import a_package_nobody_installed\n" + module.read_text())
    listed = cli(tmp_path, "methods")
    assert listed.returncode == 0, listed.stderr
    row = next(line for line in listed.stdout.splitlines() if "tiny-idle" in line)
    assert "unavailable" in row and "a_package_nobody_installed" in row


def test_without_the_plugin_the_method_is_unknown(tmp_path):
    result = cli(tmp_path, "solve", str(ROOT / "instances" / "quick" / "quick-2-4-s1.json"),
                 "--method", "tiny-idle")
    assert result.returncode == 2
    assert "unknown method 'tiny-idle'" in result.stderr
