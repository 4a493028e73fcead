"""The geometric nested dissection (nitsche.ordering) and CHOLMOD on the matrices it reorders."""
import numpy as np
import pytest
import scipy.sparse as sp
from skfem import BilinearForm, Basis, ElementTriP1, ElementVector, MeshTri, asm
from skfem.helpers import grad, inner

from nitsche.linalg import HAVE_CHOLMOD, Cholmod, dof_coordinates
from nitsche.ordering import nested_dissection

needs_cholmod = pytest.mark.skipif(not HAVE_CHOLMOD, reason="scikit-sparse is not installed")


def p1(mesh, element=None):
    """K + M (every element coupling) of P1 (or `element`) on the mesh, and its dofs' points."""
    b = Basis(mesh, element or ElementTriP1())
    return asm(stiffness_and_mass, b).tocsc(), b.doflocs.T


@BilinearForm
def stiffness_and_mass(u, v, _):
    return inner(grad(u), grad(v)) + inner(u, v)


def is_permutation(p, n):
    return p.shape == (n,) and np.array_equal(np.sort(p), np.arange(n))


def check_dissection(A, x, rows, order, leaf):
    """That `order` is the dissection of `rows` (ascending) by the rule of nested_dissection,
    subdomain by subdomain (a loop: the reference for the vectorized levels): the cut, its
    separator S last, L - S and R - S before it with no edge of A between them."""
    if rows.size == 0:  # an empty child (S took a whole side)
        assert order.size == 0
        return 0
    sub, y = A[rows][:, rows].tocoo(), x[rows]
    n, lo = rows.size, y.min(axis=0)
    a = int(np.argmax(y.max(axis=0) - lo))
    width = y[:, a].max() - lo[a]
    if n <= leaf or width == 0:
        assert np.array_equal(order, rows)  # a leaf: its rows as given
        return 0
    bucket = np.minimum(((y[:, a] - lo[a]) * (n / width)).astype(int), n - 1)
    median = np.sort(bucket)[n // 2]
    left = bucket < median if np.any(bucket < median) else bucket <= median
    cross = left[sub.row] & ~left[sub.col]
    on_left, on_right = np.unique(sub.row[cross]), np.unique(sub.col[cross])
    S = np.zeros(n, dtype=bool)
    S[on_left if on_left.size <= on_right.size else on_right] = True
    first, second = rows[left & ~S], rows[~left & ~S]
    assert A[first][:, second].nnz == 0
    assert np.array_equal(order[first.size + second.size:], rows[S])
    return 1 + max(check_dissection(A, x, first, order[:first.size], leaf),
                   check_dissection(A, x, second, order[first.size:first.size + second.size], leaf))


@pytest.mark.parametrize("mesh, element", [(MeshTri.init_circle(3), None), (MeshTri().refined(4), None),
                                           (MeshTri().refined(3), ElementVector(ElementTriP1()))])
def test_the_order_is_the_dissection_and_its_separators_separate(mesh, element):
    """An unstructured mesh, a grid (ties of the median) and a vector field (two rows at each
    point: they fall on one side of every cut): every subdomain down to the leaves."""
    A, x = p1(mesh, element)
    for leaf in (4, 16):
        p = nested_dissection(A, x, leaf=leaf)
        assert is_permutation(p, A.shape[0])
        assert check_dissection(A, x, np.arange(A.shape[0]), p, leaf) >= 3  # levels cut


def test_degenerate_inputs_give_permutations():
    A, x = p1(MeshTri().refined(3))
    n = A.shape[0]
    assert np.array_equal(nested_dissection(A, np.zeros((n, 2))), np.arange(n))  # one point: a leaf
    assert is_permutation(nested_dissection(A[:1][:, :1], x[:1]), 1)
    assert is_permutation(nested_dissection(sp.csc_matrix((0, 0)), np.zeros((0, 2))), 0)
    diagonal = sp.identity(40, format="csc")  # no edges: empty separators
    assert is_permutation(nested_dissection(diagonal, np.random.default_rng(0).random((40, 3)), leaf=2), 40)


@needs_cholmod
def test_fill_below_amd_and_near_metis_on_a_66k_mesh():
    """P1 on the criss-cross mesh of 256 x 256 squares (66,049 nodes): nnz(L) of the
    geometric order below AMD's and within 1.2 of METIS's (measured: 0.78 x AMD's, 1.02 x
    METIS's; on the 224 x 224 squares all cut one way, 0.995 x AMD's, 1.01 x METIS's)."""
    from nitsche.linalg import cholmod_factor
    A, x = p1(MeshTri.init_sqsymmetric().refined(7))
    p = nested_dissection(A, x)
    B = A[p][:, p].tocsc()
    nnz = {"ours": cholmod_factor(B, "natural").nnz}
    for method in ("amd", "metis"):
        nnz[method] = cholmod_factor(A.tocsc(), method).nnz
    assert nnz["ours"] < nnz["amd"] and nnz["ours"] < 1.2 * nnz["metis"]


@needs_cholmod
def test_a_solve_through_the_reordered_factor_is_the_plain_one():
    """Two fields at each node (u, v, coupled on a part of the nodes by a penalty, the rest
    of the coupling pattern exact zeros that the analysis drops): the same solution by the
    reordered factor as by AMD's, by a direct solve and by CG preconditioned with the factor
    of an earlier matrix, and the same positive-definiteness test."""
    mesh = MeshTri().refined(5)
    K, x = p1(mesh)
    n = K.shape[0]
    c = np.where(x[:, 0] < 0.5, 3.0, 0.0)
    pattern = sp.bmat([[K + sp.identity(n), -sp.identity(n)], [-sp.identity(n), K + sp.identity(n)]]).tocsr()

    def matrix(c):
        C = sp.diags(c)
        A = sp.csr_matrix(sp.bmat([[K + C, -C], [-C, K + C]]))
        return sp.csr_matrix((A[pattern.nonzero()].A1, pattern.indices, pattern.indptr), shape=pattern.shape)
    A, A2 = matrix(c), matrix(c + 0.5 * (np.arange(n) % 50 == 0))
    b = np.random.default_rng(0).standard_normal(2 * n)
    ours, plain = Cholmod(ordering="amd", geometric=True), Cholmod(ordering="amd")
    points = np.concatenate([x, x])
    ours.coordinates = lambda: points
    for A_ in (A, A2):
        y, z = ours.solve(A_, b, rtol=1e-12), plain.solve(A_, b, rtol=1e-12)
        assert np.linalg.norm(A_ @ y - b) <= 1e-10 * np.linalg.norm(b)
        assert np.abs(y - z).max() <= 1e-10 * np.abs(z).max()
    assert ours.perm is not None and not ours.analyzed.all and ours.iterations and ours.factorizations == 1
    assert ours.is_positive_definite(A2) and not ours.is_positive_definite(matrix(c - 10.0))
    x_direct = ours.solve(A2, b)
    assert np.abs(x_direct - plain.solve(A2, b)).max() <= 1e-10 * np.abs(x_direct).max()


@needs_cholmod
@pytest.mark.parametrize("case, parameters", [("two-membrane", {}), ("membrane-solid", {"cells": "tet"})])
def test_newton_with_the_geometric_order_reaches_the_same_minimum(case, parameters):
    """Two fields on one mesh (two membranes), and a vector field on tetrahedra with a
    membrane's scalar field (membrane-solid): the dofs' points from the problem, the same
    energy and Newton iterations as with CHOLMOD's own ordering."""
    from nitsche.cases import get
    c = get(case)
    problem = c.problem(1, 1, c.parameters(parameters))
    X = dof_coordinates(problem)
    assert X.shape == (problem.free.size, problem.dim)
    ours = Cholmod(ordering="amd", geometric=True)
    result = problem.minimize(solver=ours).check()
    reference = problem.minimize(solver=Cholmod(ordering="amd")).check()
    assert ours.perm is not None
    assert abs(result.energy - reference.energy) <= 1e-12 * abs(reference.energy)
    assert result.iterations == reference.iterations


def test_make_solver_orders_large_2d_problems_geometrically():
    from nitsche.linalg import (GEOMETRIC_THRESHOLD_2D, GEOMETRIC_THRESHOLD_3D, METIS_KEPT_2D,
                                METIS_THRESHOLD_2D, make_solver)
    if not HAVE_CHOLMOD:
        pytest.skip("scikit-sparse is not installed")
    assert make_solver("auto", GEOMETRIC_THRESHOLD_2D + 1, dim=2).geometric
    assert not make_solver("cholmod", GEOMETRIC_THRESHOLD_2D, dim=2).geometric
    assert make_solver("cholmod", GEOMETRIC_THRESHOLD_3D + 1, dim=3).geometric
    assert not make_solver("cholmod", GEOMETRIC_THRESHOLD_3D, dim=3).geometric
    assert not make_solver("auto", METIS_KEPT_2D, dim=2).geometric  # METIS's smaller factor
    assert make_solver("auto", METIS_THRESHOLD_2D, dim=2).geometric
    lin = make_solver("auto", METIS_KEPT_2D + 1, dim=2)  # without prepare: METIS, as before
    assert lin.geometric and lin.ordering == "metis" and lin.coordinates is None
