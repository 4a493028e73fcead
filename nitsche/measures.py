"""Measures: where a density is integrated (cells, boundary facets).

A measure supplies, for every one of its elements e and quadrature points q,
the weight W[e, q] (quadrature weight times Jacobian), the point x, the
outward normal n (facets), the mesh size h[e] of the cell that owns the point (cells[e]),
and for each field the tabulation of its basis functions and local dofs.

The mesh size is the cell diameter (largest distance between two vertices);
for a boundary facet it is the diameter of the cell that owns the facet.
"""
import weakref

import numpy as np
from skfem import CellBasis, FacetBasis
from skfem.quadrature import get_quadrature

from .elements import has_zero_hessian
from .jets import ORDERS


_DIAMETERS = {}  # id(mesh) -> diameters, dropped with the mesh


def cell_diameters(mesh):
    """Largest vertex-to-vertex distance of every cell, shape (nelems,) (once per mesh)."""
    if id(mesh) not in _DIAMETERS:
        p = mesh.p[:, mesh.t]  # (dim, nverts, nelems)
        nv = p.shape[1]
        squared = np.zeros(p.shape[2])
        for i in range(nv):
            for j in range(i + 1, nv):
                np.maximum(squared, np.sum((p[:, i] - p[:, j]) ** 2, axis=0), out=squared)
        _DIAMETERS[id(mesh)] = np.sqrt(squared)
        weakref.finalize(mesh, _DIAMETERS.pop, id(mesh), None)
    return _DIAMETERS[id(mesh)]


def boundary_facets(mesh):
    """Indices of the facets that belong to one cell only (as mesh.boundary_facets(),
    counted from t2f instead of building the facet-to-cell map)."""
    return np.flatnonzero(np.bincount(mesh.t2f.ravel(), minlength=mesh.facets.shape[1]) == 1)


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
        key = (id(field.element), hessian)  # fields with one element object share it
        if key not in self._bases:
            self._bases[key] = self._make_basis(field.element_with_hessian if hessian else field.element)
        return self._bases[key]

    def attach(self, field):
        """Fix the quadrature from the first field used on this measure."""
        b = self.basis_for(field)
        if self.basis is None:
            self.basis = b
        return b

    def release(self):
        """Drop the bases built for this measure (terms keep what they need)."""
        self._bases.clear()
        self.basis = None

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
        """T[e, q, c, k] (components c of the requested orders) and local dofs[e, k].
        T has a single row e when it is the same on every element (e.g. the values of
        Lagrange basis functions at the cells' reference points)."""
        zero_hessian = 2 in orders and has_zero_hessian(field.element_with_hessian)
        b = self.basis_for(field, hessian=2 in orders and not zero_hessian)
        sizes = [int(np.prod(s, dtype=int)) for s in self.shapes(field, orders)]
        starts = np.cumsum([0] + sizes)
        nq = self.weights.shape[1]
        parts = [[None if o == 2 and zero_hessian  # degree one: exact zeros, no Hessian basis
                  else _part(b.basis[k][0], o).reshape(c - a, -1, nq)  # (components, e, q)
                  for o, a, c in zip(orders, starts[:-1], starts[1:])] for k in range(b.Nbfun)]
        shared = all(p is None or (p == p[:, :1]).all() for row in parts for p in row)
        T = np.zeros((1 if shared else b.nelems, nq, starts[-1], b.Nbfun))
        for k, row in enumerate(parts):
            for p, a, c in zip(row, starts[:-1], starts[1:]):
                if p is not None:
                    T[:, :, a:c, k] = np.moveaxis(p[:, :T.shape[0]], 0, -1)
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

    @property
    def cells(self):
        """The cell owning each element: itself."""
        return np.arange(self.mesh.nelements)

    def attach(self, field):
        if field.mesh is self.mesh and self._same_quadrature(field.basis):
            self._bases[(id(field.element), False)] = field.basis  # reuse the field's own basis
        return super().attach(field)

    def _same_quadrature(self, basis):
        if self.intorder is None:
            return self.basis is None
        X, W = get_quadrature(self.mesh.refdom, self.intorder)
        return X.shape == basis.X.shape and np.array_equal(X, basis.X) and np.array_equal(W, basis.W)


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
        return cell_diameters(self.mesh)[self.cells]

    @property
    def cells(self):
        """The cell owning each facet."""
        return np.asarray(self.basis.tind)

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
        ids = boundary_facets(mesh)
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


class Interface:
    """The contact surface of one body, with the other bodies evaluated at its points.

    The quadrature (weights W, points x, normals n, mesh size h) is that of `base`:
    the boundary facets of the first body's mesh, or the cells of a membrane mesh.
    A field on the base mesh is tabulated as on `base`.  A field on another mesh
    is evaluated at the same physical points, mapped by `to_other(x)` (default:
    the identity; e.g. lift a membrane's (x, y) to (x, y, z0) on a solid): each
    point is located in the other mesh and the other field's basis functions of
    that cell are evaluated there.  The local dofs of a measure element are the
    union of the dofs of the other mesh's cells touched by its points (one cell
    for matching meshes, a few for non-matching ones; unused slots carry zeros),
    so the integral is exact wherever the other trace is polynomial on each
    measure element (matching or nested meshes) and a consistent mortar-type
    quadrature otherwise.
    """

    def __init__(self, base, to_other=None):
        self.base, self.to_other = base, to_other
        self.mesh, self.kind = base.mesh, base.kind
        self._other = {}

    def __getattr__(self, name):  # facets, basis, ... of the base measure
        if name in ("base", "_other"):
            raise AttributeError(name)
        return getattr(self.base, name)

    def _mine(self, field):
        return field.mesh is self.mesh

    def basis_for(self, field, hessian=False):
        return self.base.basis_for(field, hessian) if self._mine(field) else field.basis

    def attach(self, field):
        return self.base.attach(field) if self._mine(field) else field.basis

    weights = property(lambda self: self.base.weights)
    points = property(lambda self: self.base.points)
    normals = property(lambda self: self.base.normals)
    h = property(lambda self: self.base.h)
    cells = property(lambda self: self.base.cells)
    nelems = property(lambda self: self.base.nelems)

    def other_points(self, field):
        """The base points mapped into the other field's mesh, shape (dim_other, E, Q)."""
        x = self.points
        X = np.asarray(self.to_other(x) if self.to_other is not None else x, dtype=float)
        if X.shape[0] != field.mesh.dim():
            raise ValueError(f"interface: points of dimension {X.shape[0]} for field "
                             f"'{field.name}' on a {field.mesh.dim()}D mesh; give to_other")
        return X

    def _located(self, field):
        """Cells (E, Q) of the other mesh holding the points, the slots of those cells in
        each measure element and the slot cells (E, S)."""
        if id(field) not in self._other:
            from .locate import locate
            X = self.other_points(field)
            E, Q = X.shape[1:]
            cells = locate(field.basis, X.reshape(X.shape[0], -1)).reshape(E, Q)
            slots = np.empty((E, Q), dtype=np.int64)
            owners = np.full((E, Q), -1, dtype=np.int64)
            count = np.zeros(E, dtype=np.int64)
            rows = np.arange(E)
            for q in range(Q):
                c = cells[:, q]
                match = owners == c[:, None]
                found = match.any(axis=1)
                slots[:, q] = np.where(found, match.argmax(axis=1), count)
                new = ~found
                owners[rows[new], count[new]] = c[new]
                count[new] += 1
            S = int(count.max())
            owners = owners[:, :S]
            owners = np.where(owners < 0, owners[:, :1], owners)  # padding: a repeated cell
            self._other[id(field)] = (X, cells, slots, owners)
        return self._other[id(field)]

    def tabulation(self, field, orders):
        if self._mine(field):
            return self.base.tabulation(field, orders)
        X, cells, slots, owners = self._located(field)
        E, Q = cells.shape
        S = owners.shape[1]
        basis = field.basis
        elem = field.element_with_hessian if 2 in orders else field.element
        pts = X.reshape(X.shape[0], -1)
        ref = basis.mapping.invF(pts[:, :, None], tind=cells.ravel())  # (dim, E*Q, 1)
        nloc = basis.Nbfun
        parts = []
        for k in range(nloc):
            df = elem.gbasis(basis.mapping, ref, k, tind=cells.ravel())[0]
            comps = [_part(df, o) for o in orders]  # (*shape, E*Q, 1)
            parts.append(np.concatenate([a.reshape(-1, E, Q) for a in comps], axis=0))
        phi = np.stack(parts, axis=-1).transpose(1, 2, 0, 3)  # (E, Q, c, nloc)
        T = np.zeros((E, Q, phi.shape[2], S, nloc))
        e, q = np.meshgrid(np.arange(E), np.arange(Q), indexing="ij")
        T[e, q, :, slots, :] = phi
        dofs = basis.element_dofs[:, owners]  # (nloc, E, S)
        return (np.ascontiguousarray(T.reshape(E, Q, -1, S * nloc)),
                np.ascontiguousarray(dofs.transpose(1, 2, 0).reshape(E, S * nloc)))

    def shapes(self, field, orders):
        if self._mine(field):
            return self.base.shapes(field, orders)
        value = _part(field.basis.basis[0][0], 0).shape[:-2]
        return [value + (field.mesh.dim(),) * o for o in orders]


def interface(field, where=None, to_other=None, intorder=None):
    """An interface measure on the body of `field`: its boundary facets `where` (a
    boundary name, a predicate on facet midpoints, or facet indices), or where='cells'
    for all its cells (a membrane lying on another body).  Fields on other meshes are
    evaluated at the same physical points, mapped by to_other(x) -> points of the
    other mesh (arrays of shape (dim, elements, points)); the normal n is the outward
    normal of this body."""
    if isinstance(where, str) and where == "cells":
        base = cells(field, intorder=intorder)
    else:
        base = facets(field, where, intorder=intorder)
    return Interface(base, to_other)
