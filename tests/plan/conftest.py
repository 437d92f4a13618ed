"""Model tests run single-threaded: tiny tensors gain nothing from threads, and it keeps timings steady."""

from __future__ import annotations

import pytest

from tests.threads import one_torch_thread

_single_thread = pytest.fixture(autouse=True)(one_torch_thread)
