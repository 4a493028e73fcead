"""Errors against an exact solution, integrated in chunks of cells (nitsche.norms)."""
import numpy as np
from skfem import ElementTriP1, ElementTriP2, MeshTri

import nitsche as ni
from nitsche.norms import exact_errors


def test_exact_errors_closed_form_and_chunks():
    mesh = MeshTri.init_symmetric().scaled((2.0, 3.0)).refined(3)  # area 6
    u = ni.Field("u", mesh, ElementTriP2())
    x = u.dof_basis.doflocs
    dofs = x[0] ** 2 - x[0] * x[1]  # P2 interpolates this quadratic exactly
    value = lambda p: p[0] ** 2 - p[0] * p[1] + 1.0  # error 1 everywhere
    grad = lambda p: np.array([2 * p[0] - p[1] + 1.0, -p[0]])  # gradient error (1, 0)
    whole = exact_errors(u, dofs, value, grad)
    assert np.isclose(whole["L2"], np.sqrt(6.0), rtol=1e-12)
    assert np.isclose(whole["H1"], np.sqrt(6.0), rtol=1e-12)
    chunked = exact_errors(u, dofs, value, grad, chunk=7)  # 512 cells in 74 chunks
    assert np.isclose(chunked["L2"], whole["L2"], rtol=1e-13)
    assert np.isclose(chunked["H1"], whole["H1"], rtol=1e-13)


def test_exact_errors_of_p1_in_chunks_equal_the_whole():
    mesh = MeshTri().refined(4)
    u = ni.Field("u", mesh, ElementTriP1())
    rng = np.random.default_rng(0)
    dofs = rng.standard_normal(u.ndofs)
    value = lambda p: np.sin(p[0]) * p[1]
    grad = lambda p: np.array([np.cos(p[0]) * p[1], np.sin(p[0])])
    a = exact_errors(u, dofs, value, grad, chunk=10 ** 9)
    b = exact_errors(u, dofs, value, grad, chunk=100)
    assert abs(a["L2"] - b["L2"]) <= 1e-13 * a["L2"] and abs(a["H1"] - b["H1"]) <= 1e-13 * a["H1"]
