"""common/gcpause.py: the heap is frozen inside the block and thawed on every path."""

from __future__ import annotations

import gc

import pytest

from common.gcpause import frozen_heap


def test_the_heap_is_frozen_inside_and_thawed_after_even_on_error():
    before = gc.get_freeze_count()
    with frozen_heap():
        assert gc.get_freeze_count() > before
    assert gc.get_freeze_count() == 0
    with pytest.raises(RuntimeError), frozen_heap():
        raise RuntimeError("a plant error")
    assert gc.get_freeze_count() == 0
