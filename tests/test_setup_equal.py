"""The problem set-up's shortcuts give what the plain scikit-fem path gives, bit for bit."""
import numpy as np
import pytest
from skfem import (Basis, ElementHex1, ElementTetP1, ElementTetP2, ElementTriP1, ElementTriP2,
                   ElementVector, MeshHex, MeshTet, MeshTri)

import nitsche as ni

MESHES = {"tet": lambda: MeshTet.init_tensor(*[np.linspace(0, 1, 5)] * 3),
          "hex": lambda: MeshHex.init_tensor(*[np.linspace(0, 1, 4)] * 3),
          "tri": lambda: MeshTri.init_tensor(*[np.linspace(0, 1, 7)] * 2)}
CASES = [("tet", lambda: ElementVector(ElementTetP1())), ("tet", ElementTetP1), ("tet", ElementTetP2),
         ("hex", lambda: ElementVector(ElementHex1())), ("tri", ElementTriP1), ("tri", ElementTriP2)]


def bottom(x):
    return x[-1] < 1e-12


@pytest.mark.parametrize("mesh, element", CASES)
def test_fixed_dofs_as_scikit_fem(mesh, element):
    """Field(fixed=...) holds the dofs skfem's get_dofs finds on a mesh of its own facets:
    a predicate, 'boundary', a named boundary and (vector fields) components."""
    plain = MESHES[mesh]()
    b = Basis(plain, element())
    named = lambda m: m.with_boundaries({"bottom": bottom})  # noqa: E731
    f = ni.Field("u", MESHES[mesh](), element(), fixed=bottom)
    assert np.array_equal(f.fixed_dofs, np.unique(b.get_dofs(plain.facets_satisfying(bottom, True)).all()))
    f = ni.Field("u", MESHES[mesh](), element(), fixed="boundary")
    assert np.array_equal(f.fixed_dofs, np.unique(b.get_dofs(plain.boundary_facets()).all()))
    m = named(plain)
    f = ni.Field("u", named(MESHES[mesh]()), element(), fixed="bottom")
    expect = np.asarray(Basis(m, element()).get_dofs(m.boundaries["bottom"]).all(), np.int64)
    assert np.array_equal(f.held["bottom"], expect) and f.held["bottom"].size > 0
    if isinstance(f.element, ElementVector):
        f = ni.Field("u", named(MESHES[mesh]()), element(), fixed={"bottom": "z", bottom: "x"})
        d = Basis(m, element()).get_dofs(m.boundaries["bottom"])
        assert np.array_equal(f.held["bottom"], np.asarray(d.all("u^3"), np.int64))
        x = np.asarray(b.get_dofs(plain.facets_satisfying(bottom, True)).all("u^1"))
        assert np.array_equal(f.fixed_dofs, np.unique(np.concatenate([d.all("u^3"), x])))
