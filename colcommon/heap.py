"""Keep a long run's resident memory to what it uses: glibc's heap, told how to behave.

Why: over 1,000 lockstep episodes (bench/long_run.py) resident memory grew by 12-15 % while
the memory in use grew only with the dataset. glibc's main heap kept growing with free holes in
it: after a large block (the dataset's arrays as they double, an episode's JSBSim) is freed,
glibc raises its mmap threshold to that block's size, so later large blocks come from the heap
and leave holes when they go. A fixed threshold (:func:`fix_mmap_threshold`) keeps every block
of 256 KiB or more in its own mapping, returned to the system when freed: measured over
episodes 100-200, +1.6 MB instead of +11.4 MB. ``malloc_trim(0)`` between episodes
(:func:`release_free_heap`) returns the whole free pages left in the heap.

Elsewhere than glibc (musl, macOS) there are no such calls and nothing is done.
"""

from __future__ import annotations

import ctypes
import ctypes.util
import functools
from typing import Any

M_MMAP_THRESHOLD = -3  # mallopt's parameter number (malloc.h)
MMAP_THRESHOLD_BYTES = 256 * 1024  # above a camera frame (230 KB): frames stay in the heap


@functools.cache
def _libc_function(name: str, argtypes: tuple[Any, ...]) -> Any:
    """A function of glibc, or None where the C library has no such function."""
    path = ctypes.util.find_library("c")
    if path is None:
        return None
    try:
        function = getattr(ctypes.CDLL(path), name)
    except (OSError, AttributeError):
        return None
    function.argtypes = list(argtypes)
    function.restype = ctypes.c_int
    return function


def fix_mmap_threshold(threshold_bytes: int = MMAP_THRESHOLD_BYTES) -> bool:
    """Blocks of ``threshold_bytes`` or more get their own mapping from now on (no dynamic
    threshold); True if glibc took the setting."""
    mallopt = _libc_function("mallopt", (ctypes.c_int, ctypes.c_int))
    return bool(mallopt is not None and mallopt(M_MMAP_THRESHOLD, int(threshold_bytes)))


def release_free_heap() -> bool:
    """Return the heap's free pages to the system; True if any were (False: none, or no glibc)."""
    trim = _libc_function("malloc_trim", (ctypes.c_size_t,))
    return bool(trim is not None and trim(0))
