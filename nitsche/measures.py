"""Measures: where a density is integrated (cells, boundary facets, interfaces).

A measure supplies, for every one of its elements e and quadrature points q,
the weight W[e, q] (quadrature weight times Jacobian), the point x, the
outward normal n (facets), the mesh size h[e] of the cell that owns the point (cells[e]),
and for each field the tabulation of its basis functions and local dofs.

The mesh size is the cell diameter (largest distance between two vertices);
for a boundary facet it is the diameter of the cell that owns the facet.

A measure may carry a weight w(x) >= 0, W[e, q] = quadrature weight x Jacobian x w(x_q):
e.g. 2 pi x[0] for an axisymmetric problem in (r, z), or a plate's thickness.  Every
integral on the measure sees it: the energy, the constraints, the stability limit of
alpha0 and the reported forces.
"""
import time
import weakref

import numpy as np
from skfem import CellBasis, ElementVector, FacetBasis, MeshHex1
from skfem.element import ElementH1
from skfem.mapping import MappingAffine
from skfem.quadrature import get_quadrature

from . import partition
from .elements import has_zero_hessian
from .jets import ORDERS
from .locate import reference_coordinates
from .pattern import changes, run_numbers, sort_with_order


_DIAMETERS = {}  # id(mesh) -> diameters, dropped with the mesh


def cell_diameters(mesh):
    """Largest vertex-to-vertex distance of every cell, shape (nelems,) (once per mesh)."""
    if id(mesh) not in _DIAMETERS:
        p = np.take(mesh.p, mesh.t, axis=1)  # (dim, nverts, nelems); (take: 3x mesh.p[:, mesh.t])
        nv = p.shape[1]
        squared = np.zeros(p.shape[2])
        for i in range(nv):
            for j in range(i + 1, nv):
                np.maximum(squared, np.sum((p[:, i] - p[:, j]) ** 2, axis=0), out=squared)
        _DIAMETERS[id(mesh)] = np.sqrt(squared)
        weakref.finalize(mesh, _DIAMETERS.pop, id(mesh), None)
    return _DIAMETERS[id(mesh)]


def build_facets(mesh):
    """Set mesh.facets and mesh.t2f as scikit-fem builds them (the vertex tuples of the
    cells' facets, sorted, in lexicographic order of the sorted tuples, and each cell's
    facets; hexahedra keep each facet's vertices in the order of its first occurrence, as
    scikit-fem does), unless built: `entities`, one sort of integers instead of
    scikit-fem's np.unique over columns."""
    if hasattr(mesh, "_facets") or hasattr(mesh, "_t2f"):
        return
    built = entities(mesh.t, mesh.elem.refdom.facets, mesh.p.shape[1], isinstance(mesh, MeshHex1))
    if built is not None:
        mesh._facets, mesh._t2f = built


def build_edges(mesh):
    """Set mesh.edges and mesh.t2e of a 3D mesh as scikit-fem builds them (sorted vertex
    pairs in lexicographic order, each cell's edges), unless built (`entities`)."""
    if mesh.dim() != 3 or hasattr(mesh, "_edges") or hasattr(mesh, "_t2e"):
        return
    built = entities(mesh.t, mesh.elem.refdom.edges, mesh.p.shape[1])
    if built is not None:
        mesh._edges, mesh._t2e = built


def entities(t, local, N, keep_order=False):
    """(entities, t2x) of the cells t (k, n) of a mesh of N vertices: the entities made by
    each cell's vertices local[i] (e.g. its facets), one per distinct vertex set, and each
    cell's entities (len(local), n), numbered as scikit-fem's Mesh.build_entities numbers
    them (in the lexicographic order of their sorted vertex tuples; each entity's vertices
    sorted, or with keep_order as its first occurrence lists them); None where the keys
    would overflow.  The tuple (a_0 <= ... <= a_m) is the integer key sum_i a_i N^(m-i),
    so one sort of integers (pattern.sort_with_order) replaces np.unique over columns:
    entity j is the j-th distinct key, first met at its first occurrence; where N^(m+1)
    would overflow, (a_0, a_1) is first replaced by the rank of the pair among the distinct
    pairs (one more sort; quadrilateral facets of meshes above 55,000 vertices)."""
    indexing = np.hstack([t[ix] for ix in local]).astype(np.int64)
    columns = sorted_columns(indexing)
    rows = list(columns)
    while float(N) ** len(rows) >= 2.0 ** 63 and len(rows) > 2:  # the first two rows as the
        ordered, order = sort_with_order(rows[0] * N + rows[1])  # rank of their pair (the same order)
        pair = np.empty(ordered.size, np.int64)
        pair[order] = run_numbers(changes(ordered))
        rows = [pair] + rows[2:]
        N = max(N, int(pair.max(initial=0)) + 1)
    if float(N) ** len(rows) >= 2.0 ** 63:  # keys would overflow: scikit-fem's way
        return None
    key = rows[0]
    for row in rows[1:]:
        key = key * N + row
    ordered, order = sort_with_order(key)
    new = changes(ordered)
    inverse = np.empty(key.size, np.int64)
    inverse[order] = run_numbers(new)
    chosen = np.take(indexing if keep_order else columns, order[new], axis=1)  # (take: 5x [:, i])
    return chosen.astype(t.dtype), inverse.reshape(len(local), t.shape[1])


def sorted_columns(a):
    """The columns of an integer array a (m, n) sorted, as np.sort(a, axis=0), by
    compare-exchanges of its rows (np.sort along the short axis sorts each of the n columns
    apart: 6x slower for m = 2)."""
    rows = list(a)
    for i in range(len(rows) - 1, 0, -1):
        for j in range(i):
            rows[j], rows[j + 1] = np.minimum(rows[j], rows[j + 1]), np.maximum(rows[j], rows[j + 1])
    return np.array(rows)


def boundary_facets(mesh):
    """Indices of the facets that belong to one cell only (as mesh.boundary_facets(),
    counted from t2f instead of building the facet-to-cell map); on a rank-local mesh
    (nitsche.local_mesh) those on the whole mesh's boundary."""
    numbering = getattr(mesh, "numbering", None)
    if numbering is not None:
        return np.flatnonzero(numbering.boundary)
    build_facets(mesh)
    return np.flatnonzero(np.bincount(mesh.t2f.ravel(), minlength=mesh.facets.shape[1]) == 1)


def weighted(W, weight, points, kind):
    """W x w(x) at the quadrature points (dim, elements, points); w finite and >= 0."""
    w = np.broadcast_to(np.asarray(weight(points), dtype=float), W.shape)
    if not np.all(np.isfinite(w) & (w >= 0)):
        raise ValueError(f"the weight of a {kind} measure must be finite and >= 0 at every "
                         "quadrature point")
    return W * w


def _part(df, order):
    """Order `order` of a scikit-fem DiscreteField as an array."""
    return np.asarray(df) if order == 0 else np.asarray(getattr(df, ORDERS[order]))


class Measure:
    """Integration over the elements of a scikit-fem basis `self.basis`."""

    kind = "measure"

    def __init__(self, mesh, make_basis, weight=None):
        if weight is not None and not callable(weight):
            raise TypeError(f"weight must be a function of the point x, not {weight!r}")
        self.mesh, self._make_basis, self._bases = mesh, make_basis, {}
        self.basis = self._first = None
        self.weight = weight

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
        """Fix the quadrature from the first field used on this measure (the same field
        fixes it again after release())."""
        self._first = self._first or field
        if self.basis is None:
            self.basis = self.basis_for(self._first)
        return self.basis_for(field)

    def release(self):
        """Drop the bases built for this measure (terms keep what they need; a later
        attach builds them again)."""
        self._bases.clear()
        self.basis = None

    @property
    def separable_weights(self):
        """(d (e,), w (q,)) with W[e, q] = d[e] * w[q] exactly, where the weights factor so
        (the terms then hold d, not W); None here."""
        return None

    @property
    def weights(self):
        """W[e, q] = quadrature weight x Jacobian (x the measure's weight w(x))."""
        W = np.asarray(self.basis.dx)
        return W if self.weight is None else weighted(W, self.weight, self.points, self.kind)

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
        shared = b.nelems > 0 and all(p is None or (p == p[:, :1]).all() for row in parts for p in row)
        T = np.zeros((1 if shared else b.nelems, nq, starts[-1], b.Nbfun))
        for k, row in enumerate(parts):
            for p, a, c in zip(row, starts[:-1], starts[1:]):
                if p is not None:
                    T[:, :, a:c, k] = np.moveaxis(p[:, :T.shape[0]], 0, -1)
        return T, np.ascontiguousarray(b.element_dofs.T)

    def shapes(self, field, orders):
        return value_shapes(field, orders)

    @property
    def vertices(self):
        """Mesh vertices of every measure element, shape (vertices, elements)."""
        return self.mesh.t[:, self.cells] if self.kind == "cells" else self.mesh.facets[:, self.facets]


class Cells(Measure):
    """The cells of a mesh (this rank's inside nitsche.partition.local), from the mesh's
    mapping x = F_e(X) and a reference quadrature (X_q, w_q): W = |det DF_e(X_q)| w_q,
    x = F_e(X_q) (x = A_e X + b_e on affine cells); Lagrange fields are tabulated without a
    scikit-fem basis (Mapped)."""
    kind = "cells"

    def __init__(self, mesh, intorder=None, quadrature=None, weight=None):
        self.elements = partition.cells(mesh)  # None: all
        super().__init__(mesh, lambda e: CellBasis(mesh, e, quadrature=self.reference_quadrature(),
                                                    elements=self.elements),
                         weight)  # (a basis only for the tabulations that need one)
        self.intorder, self.quadrature = intorder, quadrature
        self.affine = isinstance(mesh.mapping(), MappingAffine)

    @property
    def h(self):
        d = cell_diameters(self.mesh)
        return d if self.elements is None else d[self.elements]

    @property
    def cells(self):
        """The cell owning each element: itself."""
        return np.arange(self.mesh.nelements) if self.elements is None else self.elements

    def attach(self, field):
        if field.mesh is not self.mesh:
            return self.basis_for(field)  # the error that says so
        self._first = self._first or field  # fixes the quadrature; bases are built where a
        return None                          # tabulation needs one

    def reference_quadrature(self):
        """Points X (dim, q) and weights w (q,) on the reference cell: the given ones, those
        of intorder, or the first field's."""
        if self.quadrature is not None:
            return self.quadrature
        if self.intorder is not None:
            return get_quadrature(self.mesh.refdom, self.intorder)
        return self._first.quadrature

    def _mine(self, a, axis=0):
        """a restricted to this rank's cells along `axis` (all cells: a itself)."""
        return a if self.elements is None else np.take(a, self.elements, axis=axis)

    @property
    def weights(self):
        mapping, (X, w) = self.mesh.mapping(), self.reference_quadrature()
        J = np.abs(mapping.detA)[:, None] if self.affine else np.abs(mapping.detDF(X))
        W = self._mine(J) * w[None, :]
        return W if self.weight is None else weighted(W, self.weight, self.points, self.kind)

    @property
    def separable_weights(self):
        """On affine cells without a weight function, W[e, q] = |det A_e| w_q: (|det A_e|,
        w_q), the product that `weights` forms; else None."""
        if not self.affine or self.weight is not None:
            return None
        return self._mine(np.abs(self.mesh.mapping().detA)), np.asarray(self.reference_quadrature()[1], float)

    @property
    def points(self):
        """x (dim, e, q); on affine cells x[e, q] = A_e X_q + b_e, stored point-major
        (e, q, dim: the layout of the terms' x) and returned as a view."""
        mapping, X = self.mesh.mapping(), self.reference_quadrature()[0]
        if not self.affine:
            return self._mine(np.asarray(mapping.F(X)), axis=1)
        A = self._mine(np.moveaxis(mapping.A, -1, 0))  # (e, dim, dim)
        x = np.matmul(X.T, A.transpose(0, 2, 1))  # (e, q, dim): X_q^T A_e^T
        x += self._mine(mapping.b.T)[:, None, :]
        return np.moveaxis(x, -1, 0)

    @property
    def nelems(self):
        return self.cells.size

    def tabulation(self, field, orders):
        """A Lagrange field's values and gradients without a scikit-fem basis: the reference
        tabulation (shared by all cells) and, with gradients, the inverse Jacobians
        (Mapped); other elements, or non-zero Hessians, from the basis."""
        lagrange = isinstance(field.element.elem if isinstance(field.element, ElementVector)
                              else field.element, ElementH1)
        if not (lagrange and field.mesh is self.mesh) or \
                (2 in orders and not has_zero_hessian(field.element_with_hessian)):
            return super().tabulation(field, orders)
        X = self.reference_quadrature()[0]
        R = reference_tabulation(field, orders, X)
        dofs = np.ascontiguousarray(field.dof_basis.dofs.element_dofs[:, self.cells].T)
        if 1 not in orders:
            return R, dofs
        mapping = self.mesh.mapping()
        invJ = self._mine(mapping.invA.transpose(2, 0, 1))[:, None] if self.affine \
            else self._mine(mapping.invDF(X).transpose(2, 3, 0, 1))  # (e, q or 1, i, m) = d xi_i / d x_m
        d = field.element.dim if isinstance(field.element, ElementVector) else 1
        return Mapped(R, np.ascontiguousarray(invJ), orders, d, X.shape[0]), dofs


class Mapped:
    """A Lagrange field's tabulation T[e, q, c, k] kept factored: the reference tabulation
    R[0, q, c, k] (values, reference gradients d phi / d xi, zero Hessians, in the rows of
    T) and the inverse Jacobians invJ[e, q, i, m] = d xi_i / d x_m (one q on affine cells):

        value rows T = R,   gradient rows T[e, q, (j, m), k] = sum_i invJ[e, q, i, m] R[q, (j, i), k]

    (j: a component of a vector field), formed inside the compiled kernels (assembly.mapped):
    dim^2 numbers per point or cell are stored instead of a (rows x functions) block."""

    def __init__(self, R, invJ, orders, components, dim):
        self.R, self.invJ = R, invJ
        self.spec = (tuple(orders), components, dim)  # static: how rows are formed

    def nonzero_rows(self):
        """Rows of T that are not identically zero: values and gradients of the
        components that R moves (Hessians of degree one are zero)."""
        (orders, vc, dim), R = self.spec, self.R[0]
        rows, start = [], 0
        for o in orders:
            size = vc * dim ** o
            block = R[:, start:start + size]
            if o == 0:
                rows.append(block.any(axis=(0, 2)))
            elif o == 1:
                rows.append(np.repeat(block.reshape(R.shape[0], vc, dim, -1).any(axis=(0, 2, 3)), dim))
            else:
                rows.append(np.zeros(size, bool))
            start += size
        return np.concatenate(rows)


def reference_tabulation(field, orders, X):
    """R[0, q, c, k] of a Lagrange field at reference points X (dim, q): values phi_j(X_q),
    reference gradients d phi_j / d xi (X_q), zero Hessians (degree one); for a vector
    field with d components, function k = j d + i is phi_j in component i, and the rows
    of an order are component-major (as the field's jets)."""
    element = field.element
    scalar, d = (element.elem, element.dim) if isinstance(element, ElementVector) else (element, 1)
    dim, nq = X.shape
    ns = field.dof_basis.Nbfun // d
    phi, dphi = (np.stack(a, axis=-1) for a in zip(*(scalar.lbasis(X, j) for j in range(ns))))
    blocks = [phi[:, None, :] if o == 0 else dphi.transpose(1, 0, 2) if o == 1
              else np.zeros((nq, dim * dim, ns)) for o in orders]  # (q, rows of one component, j)
    R = np.zeros((1, nq, sum(d * b.shape[1] for b in blocks), ns, d))
    start = 0
    for b in blocks:  # component i of an order of m rows: rows start + i m .. start + (i+1) m
        m = b.shape[1]
        for i in range(d):
            R[0, :, start + i * m: start + (i + 1) * m, :, i] = b
        start += d * m
    return R.reshape(1, nq, -1, ns * d)


def empty_selection(mesh, facets):
    """Whether a facet selection is empty: on every rank for a rank-local mesh (which may
    hold none of the facets: collective there), else here."""
    if hasattr(mesh, "numbering"):
        return partition.everywhere(np.size(facets) == 0)
    return np.size(facets) == 0


class Facets(Measure):
    """Boundary facets of a mesh (those of this rank's cells inside nitsche.partition.local)."""
    kind = "facets"

    def __init__(self, mesh, facets, intorder=None, weight=None):
        facets = np.asarray(facets, dtype=np.int64)
        if empty_selection(mesh, facets):
            raise ValueError("the facet selection is empty: check the boundary predicate or name")
        self.facets = facets[partition.owned(mesh, mesh.f2t[0, facets])]
        super().__init__(mesh, lambda e: FacetBasis(mesh, e, facets=self.facets,
                                                     intorder=intorder), weight)

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


def cells(field, intorder=None, weight=None):
    """All cells of the field's mesh (quadrature of the field unless intorder is given),
    with the weight w(x) if given (see the module docstring)."""
    m = Cells(field.mesh, intorder=intorder, weight=weight)
    m.attach(field)
    return m


def select_facets(mesh, where=None):
    """Boundary facet indices: all (None), a named boundary, those whose midpoints satisfy
    the predicate `where(x) -> bool`, or the given indices."""
    if where is None:
        return boundary_facets(mesh)
    if isinstance(where, str):
        names = sorted((mesh.boundaries or {}).keys())
        if where not in names:
            raise ValueError(f"unknown boundary {where!r}; the mesh has {names}")
        return mesh.boundaries[where]
    if callable(where):
        return np.intersect1d(mesh.facets_satisfying(where), boundary_facets(mesh))
    return where


def facets(field, where=None, intorder=None, weight=None):
    """Boundary facets of the field's mesh: all, a named boundary, or those whose
    midpoints satisfy the predicate `where(x) -> bool`; weight w(x) as for cells."""
    m = Facets(field.mesh, select_facets(field.mesh, where), intorder=intorder, weight=weight)
    m.attach(field)
    return m


def value_shapes(field, orders):
    """Shape of each requested derivative order of the field at one point."""
    if getattr(field, "tangents_of", None) is not None:
        raise ValueError(f"facet tangents '{field.name}' are read on an interface with "
                         "pairing='current' onto their body only")
    value = field.dof_basis.value_shape
    return [value + (field.mesh.dim(),) * o for o in orders]


def tabulate_at(field, orders, cells, x):
    """The field's basis at physical points x (dim, E, Q) lying in the cells (E, Q) of its
    mesh: T[e, q, c, k] (components c of the requested orders, local basis functions k)."""
    basis = field.dof_basis
    E, Q = cells.shape
    elem = field.element_with_hessian if 2 in orders else field.element
    ref = reference_coordinates(basis.mapping, x.reshape(x.shape[0], -1, 1), cells.ravel())
    parts = []
    for k in range(basis.Nbfun):
        df = elem.gbasis(basis.mapping, ref, k, tind=cells.ravel())[0]
        values = [_part(df, o) for o in orders]  # (components..., E Q, 1)
        parts.append(np.concatenate([v.reshape(int(np.prod(v.shape[:-2])), E, Q) for v in values]))
    return np.ascontiguousarray(np.stack(parts, axis=-1).transpose(1, 2, 0, 3))


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
    measure element (matching meshes, a coarser nested other body) and a consistent
    quadrature otherwise, whose error does not fall with refinement (the other trace's
    kinks between the points); nitsche.supermesh integrates exactly there.
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
        return self.base.basis_for(field, hessian) if self._mine(field) else field.dof_basis

    def attach(self, field):
        return self.base.attach(field) if self._mine(field) else field.dof_basis

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
            cells = locate(field.dof_basis, X.reshape(X.shape[0], -1)).reshape(E, Q)
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
            S = int(count.max(initial=1))  # (1: a rank without elements here)
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
        phi = tabulate_at(field, orders, cells, X)  # (E, Q, c, nloc)
        nloc = phi.shape[-1]
        T = np.zeros((E, Q, phi.shape[2], S, nloc))
        e, q = np.meshgrid(np.arange(E), np.arange(Q), indexing="ij")
        T[e, q, :, slots, :] = phi
        dofs = field.dof_basis.dofs.element_dofs[:, owners]  # (nloc, E, S)
        return (np.ascontiguousarray(T.reshape(E, Q, phi.shape[2], S * nloc)),
                np.ascontiguousarray(dofs.transpose(1, 2, 0).reshape(E, S * nloc)))

    def shapes(self, field, orders):
        return value_shapes(field, orders)


def _check_local_interface(field, other, pairing):
    """On rank-local meshes (nitsche.local_mesh) an interface reads the other body's cells
    that this rank's points reach: they must be held (the other mesh built with
    nitsche.meshes.refined(..., ghosts_for=(this mesh, to_other)), or whole)."""
    comm = partition.active()
    if comm is None or comm.size == 1:
        return
    if pairing == "current":
        raise ValueError("an interface paired in the current configuration (pairing='current') "
                         "on a rank-local mesh is not built: it pairs with the other body's whole "
                         "current surface; build the meshes whole (run without --local-meshes)")
    theirs = getattr(other.mesh, "numbering", None) if other is not None else None
    if other is not None and theirs is not None and theirs.owned is None:
        raise ValueError(f"interface: the other body's mesh (field '{other.name}') is rank-local "
                         "without the cells that this rank's points reach: refine it with "
                         "nitsche.meshes.refined(..., ghosts_for=(this body's mesh, to_other)), "
                         "or build the meshes whole (run without --local-meshes)")


def interface(field, where=None, to_other=None, intorder=None, other=None, pairing="auto",
              reach=None, weight=None, onto=None, hysteresis=None):
    """An interface measure on the body of `field`: its boundary facets `where` (a
    boundary name, a predicate on facet midpoints, or facet indices), or where='cells'
    for all its cells (a membrane lying on another body); the normal n is the outward
    normal of this body.  Points of this body are mapped into the other body's mesh by
    to_other(x) (arrays of shape (dim, ...); default the identity).

    other: the other body's field.  pairing: 'supermesh' integrates over the
    intersection of the two traces (nitsche.supermesh: exact for polynomial densities
    on affine coplanar elements, whatever the meshes); 'points' uses this surface's own
    quadrature and locates its points in the other mesh (exact for matching meshes or a
    coarser nested other body); 'auto': the supermesh unless the meshes match on the
    interface, where both are exact and 'points' keeps the facets' own quadrature.
    Without `other` the pairing is 'points'.  reach: see nitsche.supermesh.Supermesh.
    'current': each point is paired with the closest point of the other body's current
    boundary `onto` (a boundary name) at every Newton iterate, for large sliding
    (nitsche.sliding: a polyline in 2D; flat triangles or bilinear quadrilaterals in 3D).
    hysteresis (with 'current'): the share of a facet beyond it within which a point keeps
    its facet (default nitsche.sliding.HYSTERESIS).  weight w(x) as for cells."""
    if pairing not in ("auto", "supermesh", "points", "current"):
        raise ValueError(f"pairing must be 'auto', 'supermesh', 'points' or 'current', not {pairing!r}")
    if any(hasattr(f.mesh, "numbering") for f in (field, other) if f is not None):
        _check_local_interface(field, other, pairing)
    if pairing == "current":
        from .sliding import sliding
        if other is None:
            raise ValueError("pairing='current' needs the other body's field: other=...")
        return sliding(field, where, other, onto, intorder=intorder, weight=weight, hysteresis=hysteresis)
    if hysteresis is not None:
        raise ValueError("hysteresis applies to pairing='current' only: leave it out or pair 'current'")
    if other is None and pairing == "supermesh":
        raise ValueError("pairing='supermesh' needs the other body's field: other=...")
    on_cells = isinstance(where, str) and where == "cells"
    if other is not None and pairing != "points":
        from . import supermesh as sm
        mine = None if on_cells else np.asarray(select_facets(field.mesh, where), dtype=np.int64)
        if mine is not None and empty_selection(field.mesh, mine):
            raise ValueError("the facet selection is empty: check the boundary predicate or name")
        theirs = boundary_facets(other.mesh)
        cell_diameters(field.mesh)  # the mesh's, shared with every measure on it
        start = time.perf_counter()  # the supermesh's own cost, from the facet selections
        points = None if to_other is None else np.asarray(to_other(field.mesh.p), dtype=float)
        s1 = sm.cell_surface(field.mesh, points, partition.cells(field.mesh)) if on_cells else \
            sm.facet_surface(field.mesh, mine[partition.owned(field.mesh, field.mesh.f2t[0, mine])],
                             points)  # this rank's own facets against the other's whole boundary
        m = sm.Supermesh(s1, sm.facet_surface(other.mesh, theirs),
                         2 * field.element.maxdeg if intorder is None else intorder, reach)
        m.stats["seconds"] = time.perf_counter() - start
        if pairing == "supermesh" or not partition.everywhere(m.conforming):
            if weight is not None:
                m.W = weighted(m.W, weight, m.points, "interface")
            return m
    base = cells(field, intorder=intorder, weight=weight) if on_cells else \
        facets(field, where, intorder=intorder, weight=weight)
    return Interface(base, to_other)
