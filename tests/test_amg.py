"""AMG-preconditioned CG (nitsche.linalg.AMGCG): its hierarchy, its reuse across Newton
matrices and its rebuild, and where 'auto' chooses it."""
import numpy as np
import pytest
import scipy.sparse as sp
import scipy.sparse.linalg as spla

from nitsche.cases import get
from nitsche.linalg import AMG_THRESHOLD_3D, AMGCG, lanczos_largest, make_solver, vcycle

pyamg = pytest.importorskip("pyamg")


@pytest.fixture(scope="module")
def membrane_solid():
    """membrane-solid on P1 tetrahedra at level 1 (3711 unknowns): the problem and its Newton
    matrix at the solution (contact active: the springs between membrane and cube)."""
    c = get("membrane-solid")
    problem = c.problem(1, 1, c.parameters({"cells": "tet"}))
    result = problem.minimize(solver="superlu").check()
    A = problem.newton_system(result.x)[2].tocsr()
    return problem, A, result


def relative_residual(A, x, b):
    return np.linalg.norm(A @ x - b) / np.linalg.norm(b)


def test_amg_solves_to_its_tolerance_and_reuses_its_hierarchy(membrane_solid):
    problem, A, _ = membrane_solid
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
    """A matrix far from the one the hierarchy was built on (A scaled by 1e4: the refreshed
    finest level fits it, the coarser levels are 1e-4 of its Galerkin operators) exceeds the
    iteration limit: the hierarchy is built on it and CG goes on to the tolerance; the next
    whole solve measures the rate of the new hierarchy."""
    problem, A, _ = membrane_solid
    amg = AMGCG()
    amg.prepare(problem)
    b = np.random.default_rng(1).standard_normal(A.shape[0])
    amg.solve(A, b, rtol=1e-8)
    assert amg.setups == 1 and amg.rate is not None
    A2 = (1e4 * A).tocsr()
    x = amg.solve(A2, b, rtol=1e-8)
    assert relative_residual(A2, x, b) <= 1e-8 * (1 + 1e-6)
    assert amg.setups == 2 and amg.rate is None  # rebuilt midway: its few last iterations set no rate
    x = amg.solve(A2, b, rtol=1e-8)
    assert relative_residual(A2, x, b) <= 1e-8 * (1 + 1e-6)
    assert amg.setups == 2 and amg.rate == max(amg.iterations[-1], 1) / 8


def test_refreshed_hierarchy_takes_about_a_new_ones_iterations(membrane_solid):
    """A hierarchy built on the Newton matrix A_0 of the start (zero: another active set,
    180 rows differ) with its finest level refreshed to the final one A (S A S with A_0's
    scaling S, in single precision) takes CG to 1e-10 on A within 5 iterations of a hierarchy
    built on A, and fewer than the unrefreshed one; the next solve with a matrix of one
    shape reuses it (no set-up) and refreshes it."""
    problem, A, _ = membrane_solid
    A0 = problem.newton_system(problem.initial(None))[2].tocsr()
    assert abs(A - A0).sum(axis=1).A1.nonzero()[0].size > 100
    b = np.random.default_rng(4).standard_normal(A.shape[0])
    its = {}
    for name, built, refreshed in (("new", A, False), ("stale", A0, False), ("refreshed", A0, True)):
        amg = AMGCG()
        amg.prepare(problem)
        amg._build(built)
        if refreshed:
            amg.refresh(A)
            s = 1 / np.sqrt(A0.diagonal())
            level = amg.ml.levels[0].A
            assert level.dtype == np.float32 and level.nnz == A.nnz
            assert abs(level - (sp.diags(s) @ A @ sp.diags(s)).astype(np.float32)).max() <= 1e-6 * abs(level).max()
        x, info, its[name] = amg._cg(A, b, 1e-10)
        assert info == 0 and relative_residual(A, x, b) <= 1e-10 * (1 + 1e-6)
    assert its["refreshed"] <= its["new"] + 5 and its["refreshed"] < its["stale"], its
    amg = AMGCG()
    amg.prepare(problem)
    amg.solve(A0, b, rtol=1e-8)
    x = amg.solve(A, b, rtol=1e-10)
    assert amg.setups == 1 and relative_residual(A, x, b) <= 1e-10 * (1 + 1e-6)
    assert amg.ml.levels[0].A.data.tobytes() == level.data.tobytes()


def test_amg_strength_on_the_finest_level_is_the_matrix_same_aggregates(membrane_solid):
    """The hierarchy's strength of connection on the finest level is the matrix itself: the
    same aggregates as pyamg's symmetric measure at theta = 0, on every level."""
    problem, A, _ = membrane_solid
    amg = AMGCG()
    amg.prepare(problem)
    kw = dict(AMGCG.options(), keep=True)
    plain = pyamg.smoothed_aggregation_solver(A, B=amg.B, **kw)
    kw["strength"] = ("symmetric", {"theta": 0.0})
    symmetric = pyamg.smoothed_aggregation_solver(A, B=amg.B, **kw)
    assert len(plain.levels) == len(symmetric.levels) > 1
    for a, b in zip(plain.levels[:-1], symmetric.levels[:-1]):
        assert a.AggOp.shape == b.AggOp.shape and (a.AggOp != b.AggOp).nnz == 0


def test_vcycle_is_pyamgs_v_cycle(membrane_solid):
    """One application of our V-cycle (without pyamg's two residual norms of the finest level)
    is pyamg's own V-cycle from zero, to round-off (double precision)."""
    problem, A, _ = membrane_solid
    amg = AMGCG(dtype=np.float64)
    amg.prepare(problem)
    amg._build(A)
    assert len(amg.ml.levels) > 2
    b = np.random.default_rng(2).standard_normal(A.shape[0])
    ours = vcycle(amg.ml, b)
    theirs = amg.ml.solve(b, maxiter=1, cycle="V", tol=1e-12)
    assert np.linalg.norm(ours - theirs) <= 1e-12 * np.linalg.norm(theirs)


def test_single_precision_hierarchy_solves_to_1e_10_as_the_double_one(membrane_solid):
    """The hierarchy kept in single precision (every level's A, P, R float32) preconditions CG
    in double precision to a relative residual of 1e-10, in the iterations of the double one
    (within one)."""
    problem, A, _ = membrane_solid
    b = np.random.default_rng(3).standard_normal(A.shape[0])
    its = {}
    for dtype in (np.float32, np.float64):
        amg = AMGCG(dtype=dtype)
        amg.prepare(problem)
        x = amg.solve(A, b, rtol=1e-10)
        assert x.dtype == np.float64 and relative_residual(A, x, b) <= 1e-10 * (1 + 1e-6)
        assert all(getattr(level, m).dtype == dtype for level in amg.ml.levels[:-1] for m in "APR")
        its[dtype] = amg.iterations[0]
    assert abs(its[np.float32] - its[np.float64]) <= 1, its


def test_lanczos_largest_estimates_the_largest_eigenvalue_from_below(membrane_solid):
    """rho(S A S), S = diag(A)^-1/2 (the Jacobi smoother's rho(D^-1 A)): Lanczos' 20 steps are
    within 1 % below ARPACK's value."""
    _, A, _ = membrane_solid
    S = sp.diags(1 / np.sqrt(A.diagonal()))
    scaled = (S @ A @ S).tocsr()
    rho = spla.eigsh(scaled, k=1, which="LA", tol=1e-12)[0][0]
    assert 0.99 * rho <= lanczos_largest(scaled) <= rho * (1 + 1e-10)


def test_newton_with_single_precision_amg_as_with_double(membrane_solid):
    """Newton with AMG-CG (inexact steps: CG to Newton's forcing terms; minimum check by
    LOBPCG) takes the same Newton and CG iterations with the hierarchy in single precision as
    in double, and reaches the J_h of Newton with SuperLU to 1e-12 relative (Newton's
    tolerance: relative gradient 1e-10)."""
    problem, _, direct = membrane_solid
    runs = {}
    for dtype in (np.float32, np.float64):
        amg = AMGCG(dtype=dtype)
        runs[dtype] = (problem.minimize(solver=amg).check(), amg.stats())
    (single, stats), (double, stats_double) = runs[np.float32], runs[np.float64]
    assert single.iterations == double.iterations and stats == stats_double
    for r in (single, double):
        assert abs(r.energy - direct.energy) <= 1e-12 * abs(direct.energy)
        assert np.abs(r.x - direct.x).max() <= 1e-8 * np.abs(direct.x).max()


def test_auto_takes_amg_in_3d_above_the_threshold():
    assert make_solver("auto", AMG_THRESHOLD_3D + 1, dim=3).name == "amg"
    assert make_solver("auto", AMG_THRESHOLD_3D, dim=3).name in ("cholmod", "superlu")
    assert make_solver("auto", 10 * AMG_THRESHOLD_3D, dim=2).name in ("cholmod", "superlu")
