"""Threads: BLAS on one for everything but the numeric factorizations, and blocks of
independent NumPy work spread over the cores.

The library runs BLAS (OpenBLAS under CHOLMOD and NumPy) on one thread unless the user
set OPENBLAS_NUM_THREADS (nitsche/__init__): on 2 cores, threads made each triangular
solve of the factor-reusing CG several times slower.  A numeric factorization is dense
supernodal updates, which threads do speed up (a 1M-unknown 2D Laplacian: 2.8-3.1 s on
one thread, 1.6 s on two), so `factorization()` gives it the process's cores (shared
among the MPI ranks on the node), or NITSCHE_FACTOR_THREADS of them; where the user chose
OPENBLAS_NUM_THREADS, that stays.  The threads change only while the process runs no other
Python thread (e.g. nitsche.study's Ahead, building the finest level beside the coarser
solves), which could be inside a BLAS call of the same library meanwhile.

`blocks(work, starts)` runs work(start) for independent blocks on `cores()` threads: NumPy
releases the GIL in its large sorts, searches, gathers and arithmetic, so blocks of such
work run side by side (the sparsity pattern's pair positions at 1M unknowns: 2.3-2.9 s on
one thread, 1.3-1.5 s on two).
"""
import concurrent.futures
import contextlib
import functools
import os
import threading

from threadpoolctl import ThreadpoolController

DEFAULTED = "NITSCHE_BLAS_DEFAULTED"  # set where the library chose OPENBLAS_NUM_THREADS=1


def factorization_threads():
    """The BLAS threads of a numeric factorization (1: nothing to change)."""
    given = os.environ.get("NITSCHE_FACTOR_THREADS")
    if given:
        try:
            threads = int(given)
        except ValueError:
            threads = 0
        if threads < 1:
            raise ValueError(f"NITSCHE_FACTOR_THREADS={given!r}: give a whole number of threads >= 1")
        return threads
    if os.environ.get(DEFAULTED) != "1":
        return 1  # the user's OPENBLAS_NUM_THREADS holds
    return cores()


def cores():
    """The cores this process may use: those it may run on, shared among the MPI ranks on
    the node."""
    available = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else (os.cpu_count() or 1)
    return max(1, available // local_ranks())


def local_ranks():
    """The MPI ranks on this node (Open MPI's or MPICH's launcher says; 1 without mpirun)."""
    for name in ("OMPI_COMM_WORLD_LOCAL_SIZE", "MPI_LOCALNRANKS"):
        if os.environ.get(name, "").isdigit():
            return max(1, int(os.environ[name]))
    return 1


def factorization():
    """A context in which BLAS runs on factorization_threads() threads."""
    threads = factorization_threads()
    if threads == 1 or threading.active_count() > 1:
        return contextlib.nullcontext()
    return controller().limit(limits=threads, user_api="blas")


@functools.cache
def controller():
    """threadpoolctl's view of the loaded BLAS libraries (scanned once)."""
    return ThreadpoolController()


def blocks(work, starts):
    """Whether work(start) returned True for every start (the blocks independent: each writes
    its own part of the output), on cores() threads; stops at the first False (blocks not
    yet begun are not run)."""
    starts = list(starts)
    threads = min(cores(), len(starts))
    if threads <= 1:
        return all(work(s) for s in starts)
    pool = concurrent.futures.ThreadPoolExecutor(threads, thread_name_prefix="nitsche-block")
    try:
        for done in pool.map(work, starts):
            if not done:
                return False
        return True
    finally:
        pool.shutdown(wait=True, cancel_futures=True)


class Background:
    """make() run in a background thread from now on; value() waits for it and returns what
    it returned or raises what it raised.  Not a daemon thread: the interpreter's exit waits
    for it (a daemon thread still inside JAX's or NumPy's native code when the interpreter
    finalizes is unwound there and aborts the process, SIGABRT instead of the exit status)."""

    NAME = "nitsche-background"  # its threads' name

    def __init__(self, make):
        self._outcome = None
        self._thread = threading.Thread(target=self._run, args=(make,), name=self.NAME)
        self._thread.start()

    @classmethod
    def running(cls):
        """Whether a thread of this kind is still at work (e.g. a chain stopped on a coarser
        level while its finest one is built ahead)."""
        return any(t.name == cls.NAME and t.is_alive() for t in threading.enumerate())

    def _run(self, make):
        try:
            self._outcome = (True, make())
        except BaseException as e:  # noqa: BLE001 -- handed to value()'s caller
            self._outcome = (False, e)

    def value(self):
        self._thread.join()
        done, value = self._outcome
        self._outcome = None  # (not held here once handed over)
        if not done:
            raise value
        return value
