"""The process's memory allocator, set for numpy's large temporaries (glibc's malloc; elsewhere nothing changes).

vfcli's kernels make and drop arrays of 0.1-30 MB many times a second: freezing a fit's frames rasterises each
frame into some twenty arrays of one value per fragment (84 000 fragments on a widened phantom's 256 x 256 frames),
84 frames per Gauss-Newton model. glibc serves every block above its mmap threshold (128 kB at start, raised only as
far as the largest block freed so far) with a fresh ``mmap`` and gives it back with ``munmap``, so each such array
pays a page fault per 4 kB page on first touch. Measured (session 69, one thread, a quiet 2-core machine):
rasterising a frame of panel store 2002 took 7.2 ms with glibc's defaults and 3.2-3.5 ms with the blocks kept in
the heap; two of tests/test_diagnose_refit_inertia.py's tests 77.9 -> 66.9 s, back to back (docs/benchmarks.md,
"Session 69: the allocator").

:func:`keep_freed_blocks` raises the mmap threshold to 32 MB (glibc's largest on 64-bit) and the trim threshold to
128 MB: blocks below 32 MB come from the heap and return to it, and up to 128 MB of free memory at the heap's top is
kept for reuse rather than given back to the system. The CLI calls it at start (:mod:`vfcli.cli.main`), a batch
worker before each recording (:func:`vfcli.batch.task.run_entry`), and the test suite; a process that imports vfcli as
a library keeps its allocator as it is.
"""
from __future__ import annotations

import ctypes
import sys

#: glibc's ``mallopt`` parameters (malloc.h)
M_TRIM_THRESHOLD, M_MMAP_THRESHOLD = -1, -3

#: blocks below this many bytes come from the heap (glibc's largest mmap threshold on 64-bit: 4 MiB * sizeof(long))
MMAP_THRESHOLD = 32 * 1024 * 1024

#: free memory at the heap's top kept for reuse, bytes
TRIM_THRESHOLD = 128 * 1024 * 1024


def keep_freed_blocks() -> bool:
    """Set glibc's mmap and trim thresholds (module docstring); True when both were set, False where there is no
    glibc (macOS, Windows, musl) or it refused them."""
    if not sys.platform.startswith("linux"):
        return False
    try:
        mallopt = ctypes.CDLL(None).mallopt          # the process's own symbols: glibc's malloc where it is linked
    except (OSError, AttributeError):
        return False
    mallopt.argtypes, mallopt.restype = (ctypes.c_int, ctypes.c_int), ctypes.c_int
    return bool(mallopt(M_MMAP_THRESHOLD, MMAP_THRESHOLD)) and bool(mallopt(M_TRIM_THRESHOLD, TRIM_THRESHOLD))
