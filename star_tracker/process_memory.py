# SPDX-License-Identifier: Apache-2.0
"""
Process memory: freed memory kept for reuse instead of returned to the operating system.

Every frame allocates and frees image-sized arrays (a 10 MP frame: tens of MB each). glibc
returns large freed blocks to the kernel (mmap'ed blocks at once, the heap's top beyond
M_TRIM_THRESHOLD), so the next frame page-faults them in again. On a virtual machine whose
host reclaims freed guest pages, that is slow and erratic: centroiding one 10 MP real image
took 0.39-3.2 s over 11 repeats of one solve here (median 0.47 s), 0.35-0.36 s once freed
memory is kept and the heap has grown. Keeping it is the usual
real-time setting (ROS 2's real-time demos do the same): no trimming, no mmap'ed blocks; the
process keeps its peak resident size.

For our own processes only (the CLI, the nodes, the benchmarks), never a library import: the
allocator belongs to the process that hosts it. A no-op off glibc.
"""
from __future__ import annotations

import ctypes
import ctypes.util
import sys

M_TRIM_THRESHOLD = -1  # glibc malloc.h
M_MMAP_MAX = -4

_applied: bool | None = None


def keep_freed_memory() -> bool:
    """Tell glibc's malloc to keep freed memory (no trim, no mmap); True if it accepted. Idempotent."""
    global _applied
    if _applied is not None:
        return _applied
    _applied = False
    if not sys.platform.startswith("linux"):
        return False
    try:
        libc = ctypes.CDLL(ctypes.util.find_library("c") or "libc.so.6")
        mallopt = libc.mallopt
    except (OSError, AttributeError):  # not glibc (musl has no mallopt)
        return False
    mallopt.argtypes, mallopt.restype = [ctypes.c_int, ctypes.c_int], ctypes.c_int
    _applied = bool(mallopt(M_TRIM_THRESHOLD, -1)) and bool(mallopt(M_MMAP_MAX, 0))
    return _applied
