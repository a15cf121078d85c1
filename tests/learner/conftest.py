"""Fixtures shared by the learner tests."""

from __future__ import annotations

import pytest
import torch


@pytest.fixture
def one_thread():
    """The learner's setting next to local actors; with more threads than free cores the
    OpenMP barriers of 3 x 128 matmuls spin for most of the test's time."""
    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(threads)
