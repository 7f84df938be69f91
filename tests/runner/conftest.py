"""Fixtures of the runner tests: small instance sets and a plug-in package of misbehaving
allocators, installed the way a real plug-in is (a dist-info with a
``tsac_bench.allocators`` entry point on PYTHONPATH), so worker processes find it too."""

import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).parent.parent.parent
QUICK = ROOT / "instances" / "quick"

PLUGIN_SOURCE = '''
import os
import time

from tsac_bench.planning import PlanResult, Settings
from tsac_bench.solvers.greedy import GreedyAllocator


class Boom(Settings):
    name = "boom"

    def plan(self, state, *, seed=0, time_limit=None):
        raise RuntimeError("boom on purpose")


class Abort(Settings):
    """Kills its own process, as a segfaulting native solver would."""

    name = "abort"

    def plan(self, state, *, seed=0, time_limit=None):
        os._exit(3)


class Hang(Settings):
    name = "hang"

    def plan(self, state, *, seed=0, time_limit=None):
        while True:
            time.sleep(1)


class Slow(GreedyAllocator):
    """greedy, slowed down so that a test can kill a run in the middle."""

    name = "slow"

    def plan(self, state, *, seed=0, time_limit=None):
        time.sleep(0.4)
        return super().plan(state, seed=seed, time_limit=time_limit)
'''

ENTRY_POINTS = """[tsac_bench.allocators]
boom = tsac_test_plugins:Boom
abort = tsac_test_plugins:Abort
hang = tsac_test_plugins:Hang
slow = tsac_test_plugins:Slow
"""


@pytest.fixture(scope="session")
def plugin_path(tmp_path_factory) -> Path:
    site = tmp_path_factory.mktemp("plugins")
    (site / "tsac_test_plugins.py").write_text(PLUGIN_SOURCE)
    dist = site / "tsac_test_plugins-0.1.dist-info"
    dist.mkdir()
    (dist / "METADATA").write_text("Metadata-Version: 2.1\nName: tsac-test-plugins\n"
                                   "Version: 0.1\n")
    (dist / "entry_points.txt").write_text(ENTRY_POINTS)
    return site


@pytest.fixture
def two_instances(tmp_path) -> Path:
    """A directory with the two smallest quick instances."""
    directory = tmp_path / "set"
    directory.mkdir()
    for name in ("quick-2-4-s1.json", "quick-2-5-s2.json"):
        shutil.copy(QUICK / name, directory / name)
    return directory


@pytest.fixture(scope="session")
def cli():
    return run_cli


def run_cli(*args, plugins: Path | None = None, check: bool = False, **kwargs):
    """``tsac-bench ARGS`` in a subprocess (as users run it), with the plug-ins on the path;
    ``background=True`` returns the running Popen."""
    env = dict(os.environ)
    if plugins is not None:
        env["PYTHONPATH"] = os.pathsep.join(filter(None, [str(plugins),
                                                          env.get("PYTHONPATH")]))
    command = [sys.executable, "-m", "tsac_bench", *map(str, args)]
    if kwargs.pop("background", False):
        return subprocess.Popen(command, env=env, stdout=subprocess.PIPE,
                                stderr=subprocess.PIPE, text=True)
    return subprocess.run(command, env=env, capture_output=True, text=True, check=check,
                          timeout=kwargs.pop("timeout", 120))
