"""Keep freed heap memory in the process, so XLA's per-call scratch buffer is not page-faulted anew.

Why (benchmarks/README.md §1): XLA:CPU allocates one temporary buffer per executable call
(``compiled.memory_analysis().temp_size_in_bytes``: 102 MB for a train step at 790 nodes / 8 x 64,
1.54 GB at 3,000 nodes / 15 x 128, mostly the activations kept for the backward pass) and frees it
at the end of the call. glibc serves a block that large with a fresh ``mmap`` (anything above its
mmap threshold, at most 32 MB, or above 64 MB in a worker thread's arena) and ``munmap``\\ s it on free,
so every call touches every page of it anew: one minor page fault (kernel zero-fill) per 4 kB,
~25,000 faults and ~40-60 ms of system time per call at 790 nodes, ~375,000 faults and ~0.55 s at
3,000 nodes on this VM -- the "per-dispatch overhead" of a jitted train step (a ``lax.scan`` of K
steps pays it once per K steps).

:func:`keep_freed_memory` sets three glibc ``mallopt`` options:

- ``M_ARENA_MAX = 1``: every thread allocates from the main arena (XLA runs executables on its own
  worker threads, whose arenas would ``mmap`` any block above 64 MB regardless of the options below);
- ``M_MMAP_MAX = 0``: large blocks come from the heap (``brk``), not from ``mmap``;
- ``M_TRIM_THRESHOLD = -1``: freed memory at the top of the heap is never returned to the kernel.

The freed scratch buffer is then reused by the next call with its pages already mapped: no faults.
Cost: the process keeps its peak heap (RSS does not shrink after a large call). It must run before
XLA's threads first allocate, i.e. before the first JAX computation; the entry points call it
(``experiments/__init__.py``, ``benchmarks/__init__.py``, ``tests/conftest.py``); importing the library does not.
Opt out with the environment variable ``PCMGN_KEEP_HEAP=0``. No-op off glibc.
"""
from __future__ import annotations

import ctypes
import ctypes.util
import os
import platform

M_TRIM_THRESHOLD = -1
M_MMAP_MAX = -4
M_ARENA_MAX = -8

_applied: bool | None = None


def keep_freed_memory() -> bool:
    """Apply the mallopt settings above (once per process). Returns True when they are in effect."""
    global _applied
    if _applied is not None:
        return _applied
    _applied = False
    if os.environ.get("PCMGN_KEEP_HEAP", "1").strip().lower() in ("0", "false", "no", "off"):
        return False
    if platform.system() != "Linux" or platform.libc_ver()[0] != "glibc":
        return False
    try:
        libc = ctypes.CDLL(ctypes.util.find_library("c") or "libc.so.6")
        mallopt = libc.mallopt
    except (OSError, AttributeError):
        return False
    mallopt.argtypes, mallopt.restype = [ctypes.c_int, ctypes.c_int], ctypes.c_int
    _applied = all(mallopt(param, value) == 1
                   for param, value in ((M_ARENA_MAX, 1), (M_MMAP_MAX, 0), (M_TRIM_THRESHOLD, -1)))
    return _applied


def applied() -> bool:
    """Whether :func:`keep_freed_memory` is in effect in this process."""
    return bool(_applied)
