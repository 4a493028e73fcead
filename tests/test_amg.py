"""AMG-preconditioned CG (nitsche.linalg.AMGCG): its hierarchy, its reuse across Newton
matrices and its rebuild, and where 'auto' chooses it."""
import numpy as np
import pytest
import scipy.sparse as sp

from nitsche.cases import get
from nitsche.linalg import AMG_THRESHOLD_3D, AMGCG, make_solver

pyamg = pytest.importorskip("pyamg")


@pytest.fixture(scope="module")
def membrane_solid():
    """membrane-solid on P1 tetrahedra at level 1 (3711 unknowns): the problem and its Newton
    matrix at the solution (contact active: the springs between membrane and cube)."""
    c = get("membrane-solid")
    problem = c.problem(1, 1, c.parameters({"cells": "tet"}))
    result = problem.minimize(solver="superlu").check()
    A = problem.newton_system(result.x)[2].tocsr()
    return problem, A


def relative_residual(A, x, b):
    return np.linalg.norm(A @ x - b) / np.linalg.norm(b)


def test_amg_solves_to_its_tolerance_and_reuses_its_hierarchy(membrane_solid):
    problem, A = membrane_solid
    amg = AMGCG()
    amg.prepare(problem)
    assert amg.B.shape == (A.shape[0], 7)  # 3 translations, 3 rotations, the membrane's constant
    rng = np.random.default_rng(0)
    for tol in (1e-2, 1e-6, 1e-10):
        b = rng.standard_normal(A.shape[0])
        x = amg.solve(A, b, rtol=tol)
        assert relative_residual(A, x, b) <= tol * (1 + 1e-6)
    assert amg.setups == 1 and len(amg.iterations) == 3
    assert amg.iterations[2] <= amg.rebuild_factor * amg.rate * 10 + amg.slack


def test_amg_rebuilds_a_stale_hierarchy_and_measures_its_rate_again(membrane_solid):
    """A matrix far from the one the hierarchy was built on (a stiff diagonal on half the
    dofs) exceeds the iteration limit: the hierarchy is built on it and CG goes on to the
    tolerance; the next whole solve measures the rate of the new hierarchy."""
    problem, A = membrane_solid
    amg = AMGCG()
    amg.prepare(problem)
    b = np.random.default_rng(1).standard_normal(A.shape[0])
    amg.solve(A, b, rtol=1e-8)
    assert amg.setups == 1 and amg.rate is not None
    stiff = np.zeros(A.shape[0])
    stiff[::2] = 1e4 * A.diagonal()[::2]
    A2 = (A + sp.diags(stiff)).tocsr()
    x = amg.solve(A2, b, rtol=1e-8)
    assert relative_residual(A2, x, b) <= 1e-8 * (1 + 1e-6)
    assert amg.setups == 2 and amg.rate is None  # rebuilt midway: its few last iterations set no rate
    x = amg.solve(A2, b, rtol=1e-8)
    assert relative_residual(A2, x, b) <= 1e-8 * (1 + 1e-6)
    assert amg.setups == 2 and amg.rate == max(amg.iterations[-1], 1) / 8


def test_amg_strength_on_the_finest_level_is_the_matrix_same_aggregates(membrane_solid):
    """The hierarchy's strength of connection on the finest level is the matrix itself: the
    same aggregates as pyamg's symmetric measure at theta = 0, on every level."""
    problem, A = membrane_solid
    amg = AMGCG()
    amg.prepare(problem)
    kw = dict(AMGCG.options(), keep=True)
    plain = pyamg.smoothed_aggregation_solver(A, B=amg.B, **kw)
    kw["strength"] = ("symmetric", {"theta": 0.0})
    symmetric = pyamg.smoothed_aggregation_solver(A, B=amg.B, **kw)
    assert len(plain.levels) == len(symmetric.levels) > 1
    for a, b in zip(plain.levels[:-1], symmetric.levels[:-1]):
        assert a.AggOp.shape == b.AggOp.shape and (a.AggOp != b.AggOp).nnz == 0


def test_auto_takes_amg_in_3d_above_the_threshold():
    assert make_solver("auto", AMG_THRESHOLD_3D + 1, dim=3).name == "amg"
    assert make_solver("auto", AMG_THRESHOLD_3D, dim=3).name in ("cholmod", "superlu")
    assert make_solver("auto", 10 * AMG_THRESHOLD_3D, dim=2).name in ("cholmod", "superlu")
