"""The heap top pad that keeps a training step's freed memory for the next step."""

from __future__ import annotations

import sys

import pytest

from pasta.train.allocator import keep_freed_memory


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="glibc's mallopt")
def test_sets_the_pad_on_glibc_and_can_be_called_again():
    assert keep_freed_memory(1 << 20) is True
    assert keep_freed_memory() is True


def test_rejects_a_negative_pad():
    with pytest.raises(ValueError, match="-1"):
        keep_freed_memory(-1)
