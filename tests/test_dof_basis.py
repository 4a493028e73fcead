"""The fields' one-point dof basis (nitsche.fields.DofBasis) against scikit-fem's CellBasis
at the same point: the same dofs, locations, cells, weights and, once read, basis functions;
nothing tabulated until read."""
import numpy as np
import pytest
from skfem import (Basis, ElementHex1, ElementTetP1, ElementTriMorley, ElementTriP1, ElementTriP2,
                   ElementVector, MeshHex, MeshTet, MeshTri)
from skfem.quadrature import get_quadrature

from nitsche.fields import DofBasis, Field
from nitsche.measures import value_shapes

CASES = [(MeshTet().refined(2), ElementVector(ElementTetP1())),
         (MeshTri().refined(2), ElementTriP2()),
         (MeshTri().refined(2), ElementTriMorley()),
         (MeshHex().refined(1), ElementVector(ElementHex1())),
         (MeshTri().refined(2), ElementTriP1())]


@pytest.mark.parametrize("mesh, element", CASES, ids=lambda c: type(c).__name__)
@pytest.mark.parametrize("elements", [None, "some"])
def test_dof_basis_equals_one_point_cell_basis(mesh, element, elements):
    cells = None if elements is None else np.arange(1, mesh.nelements, 3)
    X, W = get_quadrature(mesh.refdom, 0)
    ref = Basis(mesh, element, quadrature=(X.mean(axis=1, keepdims=True), W.sum(keepdims=True)),
                elements=cells)
    b = DofBasis(mesh, element, elements=cells)
    assert "basis" not in vars(b) and "dx" not in vars(b)  # nothing tabulated yet
    assert b.N == ref.N and b.Nbfun == ref.Nbfun and b.nelems == ref.nelems
    np.testing.assert_array_equal(b.dofs.element_dofs, ref.dofs.element_dofs)
    np.testing.assert_array_equal(b.doflocs, ref.doflocs)
    np.testing.assert_array_equal(b.nodal_dofs, ref.nodal_dofs)
    np.testing.assert_array_equal(b.X, ref.X)
    np.testing.assert_array_equal(b.W, ref.W)
    assert (b.tind is None) == (ref.tind is None)
    if cells is not None:
        np.testing.assert_array_equal(b.tind, ref.tind)
    facets = mesh.boundary_facets()
    np.testing.assert_array_equal(b.get_dofs(facets).all(), ref.get_dofs(facets).all())
    assert b.value_shape == np.asarray(ref.basis[0][0]).shape[:-2]
    assert "basis" not in vars(b)
    np.testing.assert_array_equal(b.dx, ref.dx)
    for mine, theirs in zip(b.basis, ref.basis):  # tabulated on first read, equal
        for f, g in zip(mine[0].astuple, theirs[0].astuple):
            assert (f is None) == (g is None)
            if f is not None:
                np.testing.assert_array_equal(np.asarray(f), np.asarray(g))


def test_field_reads_no_basis_functions():
    """Building a field and the value shapes of a vector P1 field on tetrahedra tabulate no
    basis function on the dof basis."""
    f = Field("u", MeshTet().refined(2), ElementVector(ElementTetP1()), fixed="boundary")
    assert value_shapes(f, [0, 1]) == [(3,), (3, 3)]
    assert "basis" not in vars(f.dof_basis)
