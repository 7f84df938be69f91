"""Fixtures shared by the solvers' tests."""

from __future__ import annotations

import pytest


@pytest.fixture
def one_torch_thread():
    """Small networks run fastest on one thread, and a shared machine stays usable."""
    torch = pytest.importorskip("torch")
    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(threads)
