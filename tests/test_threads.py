"""BLAS threads: one for the solves, the cores for the numeric factorizations."""
import threading

import numpy as np
import pytest
import scipy.sparse as sp
from threadpoolctl import threadpool_info

from nitsche import threads
from nitsche.linalg import HAVE_CHOLMOD, Cholmod


def blas_threads():
    return {i["filepath"]: i["num_threads"] for i in threadpool_info() if i["user_api"] == "blas"}


def test_the_rule(monkeypatch):
    monkeypatch.delenv("NITSCHE_FACTOR_THREADS", raising=False)
    monkeypatch.delenv("OMPI_COMM_WORLD_LOCAL_SIZE", raising=False)
    monkeypatch.delenv("MPI_LOCALNRANKS", raising=False)
    monkeypatch.setattr(threads.os, "sched_getaffinity", lambda pid: {0, 1, 2, 3})
    monkeypatch.setenv(threads.DEFAULTED, "1")  # the library chose OPENBLAS_NUM_THREADS=1
    assert threads.factorization_threads() == 4
    monkeypatch.setenv("OMPI_COMM_WORLD_LOCAL_SIZE", "2")  # two ranks on this node share them
    assert threads.factorization_threads() == 2
    monkeypatch.setenv("MPI_LOCALNRANKS", "8")
    assert threads.factorization_threads() == 2  # (Open MPI's own variable first)
    monkeypatch.delenv("OMPI_COMM_WORLD_LOCAL_SIZE")
    assert threads.factorization_threads() == 1  # more ranks than cores: one each
    monkeypatch.delenv(threads.DEFAULTED)  # the user set OPENBLAS_NUM_THREADS: it holds
    assert threads.factorization_threads() == 1
    monkeypatch.setenv("NITSCHE_FACTOR_THREADS", "3")  # said outright: taken
    assert threads.factorization_threads() == 3
    for bad in ("0", "two", "-1"):
        monkeypatch.setenv("NITSCHE_FACTOR_THREADS", bad)
        with pytest.raises(ValueError, match="NITSCHE_FACTOR_THREADS.*whole number"):
            threads.factorization_threads()


def test_the_factorizations_context_sets_the_blas_threads_and_puts_them_back(monkeypatch):
    monkeypatch.setenv("NITSCHE_FACTOR_THREADS", "2")
    before = blas_threads()
    assert before, "no BLAS library loaded"
    with threads.factorization():
        assert set(blas_threads().values()) == {2}
    assert blas_threads() == before
    monkeypatch.setenv("NITSCHE_FACTOR_THREADS", "1")
    with threads.factorization():
        assert blas_threads() == before
    # while another Python thread runs (it might be inside a BLAS call), nothing changes
    monkeypatch.setenv("NITSCHE_FACTOR_THREADS", "2")
    release = threading.Event()
    other = threading.Thread(target=release.wait)
    other.start()
    try:
        with threads.factorization():
            assert blas_threads() == before
    finally:
        release.set()
        other.join()


@pytest.mark.skipif(not HAVE_CHOLMOD, reason="scikit-sparse is not installed")
def test_a_factorization_on_two_threads_solves_to_round_off(monkeypatch):
    n = 40  # a 2D Laplacian with a shift: supernodes large enough for threaded BLAS
    T = sp.diags([-np.ones(n - 1), 4.01 * np.ones(n), -np.ones(n - 1)], [-1, 0, 1])
    A = (sp.kron(sp.eye(n), T) + sp.kron(sp.diags([-np.ones(n - 1), -np.ones(n - 1)], [-1, 1]),
                                        sp.eye(n))).tocsc()
    b = np.random.default_rng(0).random(n * n)
    x = {}
    for t in ("1", "2"):
        monkeypatch.setenv("NITSCHE_FACTOR_THREADS", t)
        lin = Cholmod()
        x[t] = lin.solve(A, b)
        assert lin.factorizations == 1
    assert np.linalg.norm(A @ x["2"] - b) <= 1e-12 * np.linalg.norm(b)
    assert np.allclose(x["1"], x["2"], rtol=1e-12, atol=0)
