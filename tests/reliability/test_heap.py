"""Freed heap pages go back to the system between episodes (colcommon/heap.py)."""

from __future__ import annotations

import os
import sys

import pytest

from colcommon.heap import release_free_heap
from companion.testing.fuzz_targets import rss_kib


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="glibc's malloc_trim, read through /proc")
def test_pages_freed_inside_the_heap_are_returned() -> None:
    """A heap of 2 KB blocks with every 200th kept (so the heap cannot shrink from its top):
    freeing the rest leaves the pages resident until they are released."""
    kept, dropped = [], []
    for i in range(30_000):
        (kept if i % 200 == 0 else dropped).append(bytes(2000 + i % 7))
    del dropped
    before = rss_kib(os.getpid())
    assert release_free_heap()
    assert before - rss_kib(os.getpid()) > 20_000  # KiB: most of the ~60 MB freed
    assert len(kept) == 150
