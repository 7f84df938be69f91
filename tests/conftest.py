from pathlib import Path

import pytest

from tsac_bench.model import Instance
from tsac_bench.model.io import read_instance

DATA = Path(__file__).parent / "data"
ROOT = Path(__file__).parent.parent


@pytest.fixture(scope="session")
def data_dir() -> Path:
    return DATA


@pytest.fixture(scope="session")
def hand() -> Instance:
    """Two AAVs, two depots, four tasks with round distances (tests/data/hand.json)."""
    return read_instance(DATA / "hand.json")


@pytest.fixture(scope="session")
def paper_x20() -> Instance:
    return read_instance(ROOT / "instances" / "paper" / "paper-small-x20.json")


def pytest_collection_modifyitems(config, items):
    """Long checks (full training, large sweeps) run only with TSAC_BENCH_SLOW=1."""
    import os

    if os.environ.get("TSAC_BENCH_SLOW") == "1":
        return
    skip = pytest.mark.skip(reason="slow: set TSAC_BENCH_SLOW=1 to run")
    for item in items:
        if "slow" in item.keywords:
            item.add_marker(skip)
