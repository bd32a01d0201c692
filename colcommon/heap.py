"""Give freed heap memory back to the system between episodes.

Why: every episode builds a fresh JSBSim instance and drops the last one (``sitl.vehicle``), and
the learner's minibatches come and go; glibc keeps the pages those frees leave inside its heap.
Over a long run (bench/long_run.py) the free part of the heap grew by about 70 KiB an episode
while the memory in use grew only with the dataset: resident memory crept up with nothing
leaking. ``malloc_trim(0)`` returns the free pages to the system, a millisecond at most.
Elsewhere than glibc (musl, macOS) there is no such call and nothing is done.
"""

from __future__ import annotations

import ctypes
import ctypes.util
import functools
from typing import Any


@functools.cache
def _malloc_trim() -> Any:
    name = ctypes.util.find_library("c")
    if name is None:
        return None
    try:
        trim = ctypes.CDLL(name).malloc_trim
    except (OSError, AttributeError):
        return None
    trim.argtypes = [ctypes.c_size_t]
    trim.restype = ctypes.c_int
    return trim


def release_free_heap() -> bool:
    """Return the heap's free pages to the system; True if any were (False: none, or no glibc)."""
    trim = _malloc_trim()
    return bool(trim is not None and trim(0))
