"""Fields: named unknowns, each on its own scikit-fem basis."""
import weakref
from functools import cached_property

import numpy as np
from skfem import Basis, CellBasis, ElementHex1, ElementQuad1, ElementTetP1, ElementTriP1, ElementVector
from skfem.assembly.basis.abstract_basis import AbstractBasis
from skfem.quadrature import get_quadrature
from skfem.element import ElementH1

from . import partition
from .elements import with_hessian, provided_orders, own_instance
from .locate import probes, locate, reference_coordinates
from .measures import boundary_facets, build_facets


# (id(mesh), id(element), intorder) -> basis, while a field holds it (the basis keeps its
# mesh and element alive, so their ids are not reused meanwhile)
_BASES = weakref.WeakValueDictionary()


DOFS = "dofs"  # shared_basis's quadrature of one point per cell


class DofBasis(CellBasis):
    """A scikit-fem CellBasis at one point per cell (the reference centroid, weight |K_ref|)
    that holds the dofs (element_dofs, doflocs), the mapping and the cells, and tabulates
    the basis functions there (`basis`: phi_k and its derivatives on every cell, Nbfun x
    (components x derivatives) floats per cell, 1152 bytes per P1 vector tetrahedron) and
    dx = |det DF| |K_ref| only when first read."""

    def __init__(self, mesh, elem, elements=None):
        X, W = get_quadrature(mesh.refdom, 0)
        mapped = hasattr(elem, "doflocs")  # else scikit-fem's warning that it has none
        AbstractBasis.__init__(self, mesh, elem, quadrature=(X.mean(axis=1, keepdims=True),
                                                             W.sum(keepdims=True)),
                               refdom=mesh.refdom, disable_doflocs=mapped)
        if mapped:
            self.doflocs = self._doflocs()
        self.tind = None if elements is None else mesh.normalize_elements(elements)
        self.nelems = mesh.nelements if elements is None else len(self.tind)

    def _doflocs(self):
        """The dofs' locations x = F_e(X_j) as scikit-fem sets them (dof D[j, e] at F_e of
        the reference location X_j, later j and e winning), F evaluated once per distinct
        X_j (a vector element repeats each point for every component) and read once per
        dof, at its last (j, e)."""
        X, point = np.unique(np.asarray(self.elem.doflocs), axis=0, return_inverse=True)
        x = self.mapping.F(X.T)  # (dim, cells, distinct points)
        D = self.dofs.element_dofs
        last = np.full(self.N, -1)
        last[D.ravel()] = np.arange(D.size)  # writes in order j, then e: the last one stays
        j, e = np.divmod(last, D.shape[1])
        doflocs = x[:, e, point.ravel()[j]]
        doflocs[:, last < 0] = 0.0  # a dof of no element (an unused vertex): at 0, as scikit-fem
        return doflocs

    @property
    def mapping(self):
        """The mesh's mapping: scikit-fem's cache on the mesh, made again when a problem
        has dropped it after its set-up (Problem.release_mappings)."""
        return self.mesh._mapping()

    @mapping.setter
    def mapping(self, value):
        """(AbstractBasis sets the mesh's own mapping, which the getter reads from the mesh.)"""

    @cached_property
    def basis(self):
        return [self.elem.gbasis(self.mapping, self.X, j, tind=self.tind) for j in range(self.Nbfun)]

    @cached_property
    def dx(self):
        return np.abs(self.mapping.detDF(self.X, tind=self.tind)) * np.broadcast_to(self.W, (self.nelems, 1))

    @cached_property
    def value_shape(self):
        """Shape of a basis function's value at a point (from one cell of the mesh; kept: the
        mesh's mapping, which it reads for all cells, may have been released since)."""
        return np.asarray(self.elem.gbasis(self.mapping, self.X, 0, tind=np.zeros(1, dtype=np.int64))[0]).shape[:-2]


def shared_basis(mesh, element, intorder):
    """One scikit-fem basis per mesh, element object and quadrature order (DOFS: one
    point per cell, for the dofs, their locations and the mapping), on this rank's cells
    inside nitsche.partition.local."""
    key = (id(mesh), id(element), intorder, partition.key())
    basis = _BASES.get(key)
    if basis is None:
        if getattr(element, "facet_dofs", 0):  # the dofs on facets number them
            build_facets(mesh)
        if intorder is DOFS:
            basis = DofBasis(mesh, element, elements=partition.cells(mesh))
        else:
            basis = Basis(mesh, element, intorder=intorder, elements=partition.cells(mesh))
        _BASES[key] = basis
    return basis


class Field:
    """The unknown `name` in the finite element space (mesh, element).

    fixed: degrees of freedom held at prescribed values (strong Dirichlet data):
        None, "boundary" (all boundary dofs), the name of a boundary in
        `mesh.boundaries`, a predicate `x -> bool` on boundary facet midpoints,
        an array of dof indices, or, for a vector field, a dict
        {boundary (as above): components held}, components "all", an index
        0..dim-1, a letter "x", "y", "z", or a list of them; e.g.
        {"bottom": "all", "left": "x"} (a roller on the left).
    value: the prescribed values, a number or a function of the dof locations
        `x` (shape (dim, n)); Lagrange elements only for functions (for a vector
        Lagrange element the function returns the components, shape (dim, n)).

    Fields given the same element object on the same mesh share their bases: pass one
    instance to save memory and time.

    dof_basis: a DofBasis, a scikit-fem basis with one quadrature point per cell: the dofs,
    their locations and the mapping, its basis functions tabulated only if read (the
    library tabulates those itself, nitsche.measures); `basis`, the
    scikit-fem basis at the field's quadrature (intorder), is built on first use.
    """

    def __init__(self, name, mesh, element, fixed=None, value=0.0, intorder=None):
        if not isinstance(name, str) or not name.isidentifier():
            raise ValueError(f"field name {name!r} must be a Python identifier (it names a density argument)")
        if name in ("x", "n", "h"):
            raise ValueError(f"field name {name!r} is reserved for the point, normal and mesh size")
        self.name, self.mesh, self.intorder = name, mesh, intorder
        self.held = {}
        element = own_instance(element)  # one instance per mesh (ElementGlobal caches per instance)
        self.element = element
        self.element_with_hessian = with_hessian(element)  # used where a density asks for hess
        self.orders = provided_orders(self.element_with_hessian)
        self.dof_basis = shared_basis(mesh, element, DOFS)
        X, W = get_quadrature(mesh.refdom, 2 * element.maxdeg if intorder is None else intorder)
        self.quadrature = X, W  # the reference points and weights of `basis` (skfem's default)
        self.fixed_dofs = fixed_everywhere(self.dof_basis, self._fixed_dofs(fixed))
        self.fixed_values = self._fixed_values(value)

    @property
    def basis(self):
        """The scikit-fem basis at the field's quadrature (built on first use)."""
        if "_basis" not in self.__dict__:
            self._basis = shared_basis(self.mesh, self.element, self.intorder)
        return self._basis

    @property
    def ndofs(self):
        return self.dof_basis.N

    @property
    def is_lagrange(self):
        e = self.element.elem if isinstance(self.element, ElementVector) else self.element
        return isinstance(e, ElementH1)

    def _fixed_dofs(self, fixed):
        if fixed is None:
            return np.zeros(0, dtype=np.int64)
        if isinstance(fixed, dict):
            held = {where: self._component_dofs(where, which) for where, which in fixed.items()}
        elif isinstance(fixed, str) or callable(fixed):
            held = {fixed: np.asarray(self._facet_dofs(self._boundary(fixed)).all(), dtype=np.int64)}
        else:
            return self._dof_indices(fixed)
        # the dofs each named boundary holds (its reaction), "boundary" meaning all of them
        self.held = {k: d for k, d in held.items() if isinstance(k, str) and k != "boundary"}
        return np.unique(np.concatenate(list(held.values())))

    def _boundary(self, where):
        """Boundary facets: 'boundary' (all), a name in mesh.boundaries, or a predicate."""
        if isinstance(where, str) and where == "boundary":
            return boundary_facets(self.mesh)
        if isinstance(where, str):
            names = sorted((self.mesh.boundaries or {}).keys())
            if where not in names:
                raise ValueError(f"field '{self.name}': unknown boundary {where!r}; "
                                 f"use 'boundary' or one of {names}")
            return self.mesh.boundaries[where]
        if callable(where):
            build_facets(self.mesh)  # the facets as scikit-fem numbers them, by one integer sort
            return np.intersect1d(self.mesh.facets_satisfying(where), boundary_facets(self.mesh))
        raise ValueError(f"field '{self.name}': a fixed boundary is 'boundary', a boundary name "
                         f"or a predicate of x, not {where!r}")

    def _facet_dofs(self, facets):
        """The dofs on the facets, as dof_basis.get_dofs(facets); an element with dofs on
        vertices only takes those of the facets' vertices (scikit-fem's facet-to-edge map,
        built there in 3D, is not needed)."""
        if self.element.edge_dofs == 0 and self.element.facet_dofs == 0:
            return self.dof_basis.get_dofs(nodes=np.unique(self.mesh.facets[:, facets].ravel()))
        return self.dof_basis.get_dofs(facets)

    def _component_dofs(self, where, which):
        """The dofs of the components `which` of a vector field on a boundary."""
        dim = self.mesh.dim()
        if not isinstance(self.element, ElementVector):
            raise ValueError(f"field '{self.name}': components can be fixed for vector fields "
                             "only; give the boundary alone")
        items = list(range(dim)) if isinstance(which, str) and which == "all" else \
            [which] if isinstance(which, (int, str)) else list(which)
        index = []
        for c in items:
            i = "xyz".index(c) if isinstance(c, str) and c in "xyz"[:dim] and len(c) == 1 else c
            if not (isinstance(i, int) and 0 <= i < dim):
                raise ValueError(f"field '{self.name}': component {c!r} on {where!r}: use 'all', "
                                 f"an index 0..{dim - 1} or one of {list('xyz'[:dim])}")
            index.append(i)
        dofs = self._facet_dofs(self._boundary(where))
        return np.concatenate([np.asarray(dofs.all(f"u^{i + 1}"), dtype=np.int64) for i in index])

    def _dof_indices(self, fixed):
        dofs = np.unique(np.asarray(fixed, dtype=np.int64))
        if dofs.size and (dofs.min() < 0 or dofs.max() >= self.ndofs):
            raise ValueError(f"field '{self.name}': fixed dof indices must lie in [0, {self.ndofs})")
        return dofs

    def _fixed_values(self, value):
        if not callable(value):
            return np.full(self.fixed_dofs.size, float(value))
        if self.is_lagrange and isinstance(self.element, ElementVector):
            # value(x) -> (dim, n): component j % dim of dof j (dofs interleaved, as in prolongate)
            x = self.dof_basis.doflocs[:, self.fixed_dofs]
            v = np.asarray(value(x), dtype=float).reshape(self.mesh.dim(), -1)
            return v[self.fixed_dofs % self.mesh.dim(), np.arange(self.fixed_dofs.size)]
        if not self.is_lagrange:
            raise ValueError(f"field '{self.name}': a function as fixed value needs a scalar "
                             "Lagrange element; give a number instead")
        return np.asarray(value(self.dof_basis.doflocs[:, self.fixed_dofs]), dtype=float)

    def interpolate(self, fun):
        """Nodal interpolant of `fun(x)` (Lagrange elements)."""
        if not self.is_lagrange:
            raise ValueError(f"field '{self.name}': nodal interpolation needs a Lagrange element")
        return np.asarray(fun(self.dof_basis.doflocs), dtype=float)

    def prolongate(self, coarse, u):
        """This field's dofs of the coarse field's function `u` (exact for nested Lagrange
        spaces; dofs outside the coarse mesh, as on a refined curved boundary, take the
        extrapolation of the nearest coarse cell)."""
        if not (self.is_lagrange and coarse.is_lagrange):
            return self._prolongate_by_dofs(coarse, u)
        pairs = self._midpoint_pairs(coarse)
        if pairs is not None:  # P1 on nested simplices: no point location
            v = np.asarray(u, dtype=float).reshape(coarse.mesh.p.shape[1], -1)  # (vertices, components)
            return (0.5 * (v[pairs[0]] + v[pairs[1]])).ravel()
        values = probes(coarse.dof_basis, self.dof_basis.doflocs, outside="nearest") @ u
        if isinstance(self.element, ElementVector):  # rows component-major, dofs interleaved
            j = np.arange(self.ndofs)
            values = values.reshape(self.mesh.dim(), -1)[j % self.mesh.dim(), j]
        return values

    def _midpoint_pairs(self, coarse):
        """The coarse vertex pairs (2, N), one per vertex of this mesh, whose midpoints are
        these vertices (a coarse vertex i: the pair (i, i)), when both fields are P1 (scalar
        or vector, dofs numbered by vertex) on triangles or on tetrahedra and every vertex of
        this mesh is a coarse vertex or the midpoint of a coarse edge: this mesh refined by
        scikit-fem (Mesh.refined: the coarse vertices, then the midpoints of the edges, in
        edge order), or matched by coordinates (`midpoint_pairs`, e.g. tensor grids of
        n and 2n cells per side); None otherwise.  There the nodal interpolant of the coarse
        function u is (u_a + u_b) / 2 (a P1 function is linear along each edge)."""
        fine, mesh = self.mesh, coarse.mesh
        if not (type(fine).__name__ == type(mesh).__name__ in ("MeshTri1", "MeshTet1") and
                all(vertex_numbered(f) for f in (self, coarse)) and
                type(self.element) is type(coarse.element)):
            return None
        n = mesh.p.shape[1]
        if mesh.dim() == 2:
            build_facets(mesh)
        pairs = np.concatenate([np.tile(np.arange(n), (2, 1)), mesh.facets if mesh.dim() == 2 else mesh.edges],
                               axis=1)
        if fine.p.shape == (mesh.dim(), pairs.shape[1]) and \
                np.array_equal(fine.p, 0.5 * (mesh.p[:, pairs[0]] + mesh.p[:, pairs[1]])):
            return pairs  # numbered as scikit-fem refines
        return midpoint_pairs(fine.p, mesh.p, pairs)

    # -- Hermite-type elements (BFS, Morley): dofs are derivatives at points ---------
    HERMITE_DOFS = ("u", "u_x", "u_y", "u_xy", "u_n")

    def jets_at(self, u, x):
        """Value (n,), gradient (dim, n) and Hessian (dim, dim, n) of the function with
        dofs u at the points x (dim, n), from the cell that holds each point
        (element-wise for non-conforming elements)."""
        b, elem = self.dof_basis, self.element_with_hessian
        cells = locate(b, x)
        X = reference_coordinates(b.mapping, x[:, :, None], cells)
        out = [0.0, 0.0, 0.0]
        for k in range(b.Nbfun):
            df = elem.gbasis(b.mapping, X, k, tind=cells)[0]
            c = u[b.dofs.element_dofs[k, cells]]
            out[0] = out[0] + c * np.asarray(df)[..., 0]
            out[1] = out[1] + c * np.asarray(df.grad)[..., 0]
            if df.hess is not None:
                out[2] = out[2] + c * np.asarray(df.hess)[..., 0]
        return dict(value=out[0], grad=out[1], hess=None if np.isscalar(out[2]) else out[2])

    def _dof_kinds(self):
        """Name of every global dof (from the element's dofnames) and, for normal
        derivative dofs, the normal the dof is taken along (2, ndofs)."""
        e, b = self.element, self.dof_basis
        names = list(e.dofnames)
        nn, nf = e.nodal_dofs, e.facet_dofs
        if isinstance(e, ElementVector) or e.interior_dofs or e.edge_dofs or \
                len(names) != nn + nf or set(names) - set(self.HERMITE_DOFS) or self.mesh.dim() != 2:
            raise NotImplementedError(
                f"field '{self.name}': prolongation is implemented for Lagrange elements and 2D "
                f"elements with dofs {self.HERMITE_DOFS} (BFS, Morley), not {type(e).__name__}")
        kind = np.empty(self.ndofs, dtype=object)
        for j in range(nn):
            kind[b.nodal_dofs[j]] = names[j]
        for j in range(nf):
            kind[b.facet_dofs[j]] = names[nn + j]
        normal = np.zeros((2, self.ndofs))
        nverts = self.mesh.t.shape[0]
        for k in range(b.Nbfun):
            local = names[k % nn] if k < nverts * nn else names[nn + (k - nverts * nn) % nf]
            if local == "u_n":
                # a Morley-type normal-derivative basis function has zero tangential
                # derivative at its own facet midpoint, so its gradient there is the dof normal
                g = e.gbasis(b.mapping, e.doflocs[k][:, None], k)[0].grad
                normal[:, b.dofs.element_dofs[k]] = np.asarray(g)[:, :, 0]
        return kind, normal

    def _prolongate_by_dofs(self, coarse, u):
        """Apply this field's dof functionals (u, u_x, u_y, u_xy at vertices, u_n at facet
        midpoints) to the coarse function: exact for nested BFS spaces; for Morley (not
        nested) an interpolant, used as the initial guess of the finer level."""
        kind, normal = self._dof_kinds()
        jets = coarse.jets_at(np.asarray(u, dtype=float), self.dof_basis.doflocs)
        v, g, H = jets["value"], jets["grad"], jets["hess"]
        out = np.zeros(self.ndofs)
        for name, val in (("u", v), ("u_x", g[0]), ("u_y", g[1]),
                          ("u_n", np.sum(g * normal, axis=0))):
            sel = kind == name
            out[sel] = val[sel]
        sel = kind == "u_xy"
        if sel.any():
            if H is None:
                raise NotImplementedError(f"field '{coarse.name}': no Hessian for u_xy dofs")
            out[sel] = H[0, 1][sel]
        return out


def fixed_everywhere(basis, dofs):
    """The dofs `dofs` of the basis, and on a rank-local mesh (nitsche.local_mesh) also those
    that another rank holding them fixes: a vertex on the whole mesh's fixed boundary may
    touch this rank's cells at a corner only, its boundary facets on another rank (a flag
    per dof, reduced at each global number's home rank: partition.by_number)."""
    comm = partition.active()
    if comm is None or not hasattr(basis.mesh, "numbering"):
        return dofs
    from .local_mesh import global_dofs
    number, n = global_dofs(basis)
    flag = np.zeros(number.size, np.int8)
    flag[dofs] = 1
    return np.flatnonzero(partition.by_number(comm, number, flag, n, "max"))


def midpoint_pairs(x, p, pairs, rtol=1e-10):
    """For each point of x (dim, N): the vertex pair (a, b) of `pairs` (2, m: (i, i) for a
    vertex p_i, the ends of an edge) whose midpoint it is, to rtol of the extent of p; None
    if a point is none of them."""
    from scipy.spatial import cKDTree
    distance, i = cKDTree((0.5 * (p[:, pairs[0]] + p[:, pairs[1]])).T).query(
        x.T, distance_upper_bound=rtol * np.ptp(p, axis=1).max())
    return pairs[:, i] if np.all(np.isfinite(distance)) else None


def vertex_numbered(field):
    """Whether the field is P1 on triangles or tetrahedra or Q1 on quadrilaterals or
    hexahedra (scalar or vector) with the dofs of vertex i numbered i d .. i d + d - 1 (d
    components)."""
    e = field.element.elem if isinstance(field.element, ElementVector) else field.element
    nodal = field.dof_basis.nodal_dofs
    return type(e) in (ElementTriP1, ElementTetP1, ElementQuad1, ElementHex1) and field.ndofs == nodal.size == field.mesh.p.shape[1] * nodal.shape[0] \
        and np.array_equal(nodal.T.ravel(), np.arange(field.ndofs))


def history(field, name=None):
    """A field of data: the values of `field` at the previous load step (default name
    FIELD_old), on the same mesh and element with all of its dofs prescribed; a density
    names it like any field (e.g. the slip increment (u - u_old) . t of a friction gap) and
    Problem.set_values(name, x_field) moves it to the next step."""
    old = Field(name or f"{field.name}_old", field.mesh, field.element,
                fixed=np.arange(field.ndofs), intorder=field.intorder)
    old.history_of = field.name  # nitsche.path moves it to each step's start
    return old


def coordinates(field, name=None):
    """A field of data: the reference coordinates X on the mesh of a vector Lagrange `field`
    (default name X_FIELD), e.g. the other body's reference point X_m on an interface, whose
    current position is X_m + u(X_m)."""
    return Field(name or f"X_{field.name}", field.mesh, field.element,
                 fixed=np.arange(field.ndofs), value=lambda x: x, intorder=field.intorder)
