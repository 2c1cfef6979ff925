"""Test-wide settings."""

import pytest
import torch


@pytest.fixture(autouse=True, scope="session")
def _one_torch_thread():
    # The tests run tiny models: with several threads torch spends its time synchronising, and on a
    # loaded 2-core machine a step is ~60x slower than with one thread. Results do not depend on it.
    before = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(before)
