"""Freed heap pages go back to the system between episodes (colcommon/heap.py)."""

from __future__ import annotations

import ctypes
import ctypes.util
import os
import subprocess
import sys
from pathlib import Path

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


class _MallInfo2(ctypes.Structure):
    _fields_ = [(n, ctypes.c_size_t) for n in
                ("arena", "ordblks", "smblks", "hblks", "hblkhd", "usmblks", "fsmblks", "uordblks", "fordblks", "keepcost")]


def _mapped_blocks() -> int:
    libc = ctypes.CDLL(ctypes.util.find_library("c"))
    libc.mallinfo2.restype = _MallInfo2
    return int(libc.mallinfo2().hblks)


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="glibc's mallopt and mallinfo2")
def test_with_a_fixed_threshold_a_large_block_keeps_its_own_mapping_after_a_larger_one_was_freed() -> None:
    """glibc's default: freeing a 4 MB block raises the threshold, and the next 1 MB block comes
    from the heap (where its hole stays resident). Fixed: it is mapped, and unmapped when freed."""
    code = (
        "import ctypes, ctypes.util, sys\n"
        "sys.path[:0] = {path!r}\n"
        "from colcommon.heap import fix_mmap_threshold\n"
        "from tests.reliability.test_heap import _mapped_blocks\n"
        "if {fixed}: assert fix_mmap_threshold()\n"
        "big = bytearray(4 << 20); del big\n"
        "before = _mapped_blocks(); block = bytearray(1 << 20)\n"
        "print(_mapped_blocks() - before)\n"
    )
    counts = []
    for fixed in (False, True):
        out = subprocess.run([sys.executable, "-c", code.format(path=sys.path, fixed=fixed)],
                             capture_output=True, text=True, check=True, cwd=Path(__file__).parents[2])
        counts.append(int(out.stdout.strip()))
    assert counts == [0, 1]
