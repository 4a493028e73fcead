"""BLAS threads: one for everything but the numeric factorizations.

The library runs BLAS (OpenBLAS under CHOLMOD and NumPy) on one thread unless the user
set OPENBLAS_NUM_THREADS (nitsche/__init__): on 2 cores, threads made each triangular
solve of the factor-reusing CG several times slower.  A numeric factorization is dense
supernodal updates, which threads do speed up (a 1M-unknown 2D Laplacian: 2.8-3.1 s on
one thread, 1.6 s on two), so `factorization()` gives it the process's cores (shared
among the MPI ranks on the node), or NITSCHE_FACTOR_THREADS of them; where the user chose
OPENBLAS_NUM_THREADS, that stays.  The threads change only while the process runs no other
Python thread (e.g. nitsche.study's Ahead, building the finest level beside the coarser
solves), which could be inside a BLAS call of the same library meanwhile.
"""
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
    cores = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else (os.cpu_count() or 1)
    return max(1, cores // local_ranks())


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
