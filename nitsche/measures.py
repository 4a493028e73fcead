"""Measures: where a density is integrated (cells, boundary facets).

A measure supplies, for every one of its elements e and quadrature points q,
the weight W[e, q] (quadrature weight times Jacobian), the point x, the
outward normal n (facets), the mesh size h[e] of the cell that owns the point,
and for each field the tabulation of its basis functions and local dofs.

The mesh size is the cell diameter (largest distance between two vertices);
for a boundary facet it is the diameter of the cell that owns the facet.
"""
import numpy as np
from skfem import CellBasis, FacetBasis

from .jets import ORDERS


def cell_diameters(mesh):
    """Largest vertex-to-vertex distance of every cell, shape (nelems,)."""
    p = mesh.p[:, mesh.t]  # (dim, nverts, nelems)
    nv = p.shape[1]
    return np.max([np.linalg.norm(p[:, i] - p[:, j], axis=0)
                   for i in range(nv) for j in range(i + 1, nv)], axis=0)


def _part(df, order):
    """Order `order` of a scikit-fem DiscreteField as an array."""
    return np.asarray(df) if order == 0 else np.asarray(getattr(df, ORDERS[order]))


class Measure:
    """Integration over the elements of a scikit-fem basis `self.basis`."""

    kind = "measure"

    def __init__(self, mesh, make_basis):
        self.mesh, self._make_basis, self._bases = mesh, make_basis, {}
        self.basis = None

    def basis_for(self, field, hessian=False):
        """The field's basis at this measure's points (with element-wise Hessians if asked)."""
        if field.mesh is not self.mesh:
            raise ValueError(f"field '{field.name}' lives on another mesh than this {self.kind} "
                             "measure; integrate it on its own mesh or through an interface")
        key = (id(field), hessian)
        if key not in self._bases:
            self._bases[key] = self._make_basis(field.element_with_hessian if hessian else field.element)
        return self._bases[key]

    def attach(self, field):
        """Fix the quadrature from the first field used on this measure."""
        b = self.basis_for(field)
        if self.basis is None:
            self.basis = b
        return b

    @property
    def weights(self):
        return np.asarray(self.basis.dx)

    @property
    def points(self):
        return np.asarray(self.basis.global_coordinates())

    @property
    def normals(self):
        return None

    @property
    def nelems(self):
        return self.basis.nelems

    def tabulation(self, field, orders):
        """T[e, q, c, k] (components c of the requested orders) and local dofs[e, k]."""
        b = self.basis_for(field, hessian=2 in orders)
        sizes = [int(np.prod(s, dtype=int)) for s in self.shapes(field, orders)]
        starts = np.cumsum([0] + sizes)
        T = np.empty((b.nelems, self.weights.shape[1], starts[-1], b.Nbfun))
        for k in range(b.Nbfun):
            df = b.basis[k][0]
            for o, a, c in zip(orders, starts[:-1], starts[1:]):
                part = _part(df, o).reshape(c - a, -1, T.shape[1])  # (components, e, q)
                T[:, :, a:c, k] = np.moveaxis(part, 0, -1)
        return T, np.ascontiguousarray(b.element_dofs.T)

    def shapes(self, field, orders):
        """Shape of each requested order's array at one point."""
        value = _part(self.basis_for(field).basis[0][0], 0).shape[:-2]
        return [value + (self.mesh.dim(),) * o for o in orders]


class Cells(Measure):
    kind = "cells"

    def __init__(self, mesh, intorder=None, quadrature=None):
        super().__init__(mesh, lambda e: CellBasis(mesh, e, intorder=intorder,
                                                    quadrature=quadrature))
        self.intorder = intorder

    @property
    def h(self):
        return cell_diameters(self.mesh)

    def attach(self, field):
        if self.basis is None and self.intorder is None and field.mesh is self.mesh:
            self._bases[(id(field), False)] = field.basis  # reuse the field's own quadrature
        return super().attach(field)


class Facets(Measure):
    kind = "facets"

    def __init__(self, mesh, facets, intorder=None):
        self.facets = np.asarray(facets, dtype=np.int64)
        if self.facets.size == 0:
            raise ValueError("the facet selection is empty: check the boundary predicate or name")
        super().__init__(mesh, lambda e: FacetBasis(mesh, e, facets=self.facets,
                                                     intorder=intorder))

    @property
    def h(self):
        return cell_diameters(self.mesh)[self.basis.tind]

    @property
    def normals(self):
        return np.asarray(self.basis.normals)


def cells(field, intorder=None):
    """All cells of the field's mesh (quadrature of the field unless intorder is given)."""
    m = Cells(field.mesh, intorder=intorder)
    m.attach(field)
    return m


def facets(field, where=None, intorder=None):
    """Boundary facets of the field's mesh: all, a named boundary, or those whose
    midpoints satisfy the predicate `where(x) -> bool`."""
    mesh = field.mesh
    if where is None:
        ids = mesh.boundary_facets()
    elif isinstance(where, str):
        names = sorted((mesh.boundaries or {}).keys())
        if where not in names:
            raise ValueError(f"unknown boundary {where!r}; the mesh has {names}")
        ids = mesh.boundaries[where]
    elif callable(where):
        ids = mesh.facets_satisfying(where, boundaries_only=True)
    else:
        ids = where
    m = Facets(mesh, ids, intorder=intorder)
    m.attach(field)
    return m
