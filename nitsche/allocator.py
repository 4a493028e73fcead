"""Freed memory kept in the process for the next Newton step (glibc's malloc).

glibc serves a block above its mmap threshold (128 kB, raised up to 32 MB as such blocks
are freed) by its own mmap and unmaps it when freed; the next Newton step's arrays of the
same sizes then touch new pages, one page fault per 4 kB, which on a virtual machine costs
system time comparable to the arithmetic.  With mmap off (M_MMAP_MAX = 0) and no trimming
below 2 GB (M_TRIM_THRESHOLD) the freed blocks stay in the heap and are reused.  Measured
(2026-12-02, two-membrane chain to 522k unknowns, one run each, load 4-5): 447k -> 171k
minor page faults, 14.1 -> 8.6 s system time, 40.5 -> 33.6 s CPU, the finest level's
assembly 18.1 -> 5.3 s wall; peak resident memory 2.30 -> 2.36 GB; J_h the same bitwise.
One arena (M_ARENA_MAX = 1) for all threads: a thread's own arena would keep the blocks it
freed for that thread alone (the finest level built ahead, nitsche.study.nested: +14 %
peak at 130k with an arena of its own).

What runs once after a solve (the outputs: errors, condition number, VTU, figures) gains
nothing from kept blocks: within freed_memory_returned() its blocks of a megabyte and more
get mappings of their own, unmapped when freed, and the heap's free top is trimmed, so that
the outputs do not hold the kept blocks' pages beside their own.

NITSCHE_MALLOC=system leaves the allocator as it is, and so does any MALLOC_*_ tunable
the user sets (glibc reads those at process start).
"""
import contextlib
import ctypes
import os

M_TRIM_THRESHOLD, M_MMAP_THRESHOLD, M_MMAP_MAX, M_ARENA_MAX = -1, -3, -4, -8  # glibc's mallopt parameters
TRIM_THRESHOLD = 2 ** 31 - 1  # bytes of free heap top kept (mallopt takes an int)
RETURNED = ((M_MMAP_THRESHOLD, 1 << 20), (M_MMAP_MAX, 65536), (M_TRIM_THRESHOLD, 128 * 1024))
kept = [False]  # whether keep_freed_memory set the allocator in this process
USER_TUNABLES = ("MALLOC_MMAP_MAX_", "MALLOC_TRIM_THRESHOLD_", "MALLOC_MMAP_THRESHOLD_",
                 "MALLOC_ARENA_MAX", "GLIBC_TUNABLES")


def keep_freed_memory():
    """mallopt(M_MMAP_MAX, 0), mallopt(M_TRIM_THRESHOLD, 2^31 - 1) and mallopt(M_ARENA_MAX,
    1) in this process, unless NITSCHE_MALLOC=system or the user tuned malloc; True when
    all three were set (False also without glibc's mallopt, e.g. on macOS)."""
    if os.environ.get("NITSCHE_MALLOC", "keep") == "system" or any(k in os.environ for k in USER_TUNABLES):
        return False
    mallopt = _mallopt()
    kept[0] = mallopt is not None and all(
        mallopt(*setting) for setting in ((M_MMAP_MAX, 0), (M_TRIM_THRESHOLD, TRIM_THRESHOLD), (M_ARENA_MAX, 1)))
    return kept[0]


@contextlib.contextmanager
def freed_memory_returned():
    """Within: the heap's free pages given back first (release_freed_memory), then blocks
    of 1 MB and more mapped on their own and unmapped when freed, the heap's free top above
    128 kB trimmed (mallopt M_MMAP_THRESHOLD, M_MMAP_MAX, M_TRIM_THRESHOLD: RETURNED);
    keep_freed_memory's settings after.  Nothing changes where keep_freed_memory did not
    set the allocator."""
    if not kept[0]:
        yield
        return
    release_freed_memory()
    mallopt = _mallopt()
    for setting in RETURNED:
        mallopt(*setting)
    try:
        yield
    finally:
        keep_freed_memory()


def _mallopt():
    """glibc's mallopt(parameter, value) (1 on success); None without it (e.g. macOS)."""
    try:
        mallopt = ctypes.CDLL(None).mallopt
    except (OSError, AttributeError):
        return None
    mallopt.argtypes, mallopt.restype = [ctypes.c_int, ctypes.c_int], ctypes.c_int
    return mallopt


def release_freed_memory():
    """Give the heap's free pages back to the system (glibc's malloc_trim(0)): after a
    solve, so that what follows (the outputs) does not build on the kept blocks' holes.
    True if memory was released."""
    try:
        trim = ctypes.CDLL(None).malloc_trim
    except (OSError, AttributeError):
        return False
    trim.argtypes, trim.restype = [ctypes.c_size_t], ctypes.c_int
    return bool(trim(0))
