"""``one_torch_thread``: a fixture body that runs a test with one torch thread and restores the count after.

Tiny tensors gain nothing from threads, and one thread keeps timings steady on the shared 2-core CI machine.
A test folder opts in from its conftest: ``_single_thread = pytest.fixture(autouse=True)(one_torch_thread)``.
"""

from __future__ import annotations

from collections.abc import Iterator

import torch


def one_torch_thread() -> Iterator[None]:
    previous = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(previous)
