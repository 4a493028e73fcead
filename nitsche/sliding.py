"""Contact pairing in the current configuration (large sliding between deformable bodies).

The contact surface of body 1 keeps its own quadrature points X_s.  At every Newton iterate
each point's current position x_s = X_s + u_1(X_s) is projected onto the current surface of
body 2, the facets `onto` with their vertices moved by u_2 (a polyline in 2D; flat
triangles or bilinear quadrilaterals in 3D, nitsche.projection):

    xi = argmin_{y on the current facets} |x_s - y|,

and body 2's fields are evaluated at the reference point X_m of that closest point (the
same position on the facet's reference vertices); a point keeps its facet while its
projection lies near it (HYSTERESIS), so that it does not flip between two facets at a
vertex from one iterate to the next.  A density reads body 2 there like any
field on an interface: e.g. the normal gap (x_s - x_m) . nu with x_m = X_m + u_2(X_m)
(X_m from nitsche.coordinates(u_2)) and nu the current normal of body 2 (from the paired
facet's tangents, facet_tangents(u_2)).  The pairing is
held fixed within a Newton step and its line search, and updated before the next one: the
derivative of X_m in u is left out of the Newton matrix, so the convergence is fast but
not quadratic while the pairing still moves, and quadratic once it has settled.
"""
import numpy as np

from skfem import ElementHex1, ElementTetP1

from .fields import coordinates
from .measures import Interface, facets, select_facets, tabulate_at
from .projection import closest_facets, shape_functions


FLAT_FACETED = (ElementTetP1, ElementHex1)  # 3D meshes with flat triangles or bilinear quadrilaterals
HYSTERESIS = 0.25  # a point keeps its facet while its projection lies within this share beyond it


class Sliding(Interface):
    """An interface measure on body 1's facets whose points are paired with body 2's current
    surface `onto` (see the module docstring).  pair(u_1, u_2) updates the pairing from dof
    vectors of the two displacement fields; every quadrature point has its own slot of body
    2's cells, so the tabulations keep their shapes (and the compiled kernels) across pairings."""

    def __init__(self, base, mine, other, onto, hysteresis=HYSTERESIS):
        super().__init__(base)
        self.hysteresis = hysteresis
        if other.mesh.dim() == 3 and other.mesh.elem not in FLAT_FACETED:
            raise ValueError(f"pairing='current' projects onto flat triangles (MeshTet1) and bilinear "
                             f"quadrilaterals (MeshHex1); the other body's {type(other.mesh).__name__} "
                             "has other facets: give it a mesh of degree one (the field may be of "
                             "degree two)")
        self.mine, self.other = mine, other
        facets_ = select_facets(other.mesh, onto)
        if np.size(facets_) == 0:
            raise ValueError(f"onto={onto!r} selects no facet of the other body: check the boundary")
        self.segments = other.mesh.facets[:, facets_].T  # (S, 2) vertex indices; in 3D (S, 3 or 4)
        self.segment_cells = other.mesh.f2t[0, facets_]
        self.orientation = outward(other.mesh, self.segments, self.segment_cells)
        X = np.asarray(base.points, dtype=float)  # (dim, E, Q)
        self.shape = X.shape[1:]
        self.X_s = X.reshape(X.shape[0], -1).T
        cells = np.repeat(np.asarray(base.cells)[:, None], self.shape[1], axis=1)
        # (the cells' numbers are the whole mesh's: the dof numbering, not a rank's basis)
        self._own = (tabulate_at(mine, [0], cells, X), mine.dof_basis.dofs.element_dofs[:, cells])
        self.pairings = 0
        self.pair(np.zeros(mine.ndofs), np.zeros(other.ndofs))

    def current_points(self, u1):
        """x_s = X_s + u_1(X_s), shape (P, dim)."""
        T, dofs = self._own  # T (E, Q, dim, k), dofs (k, E, Q)
        return self.X_s + np.einsum("eqck,keq->eqc", T, u1[dofs]).reshape(self.X_s.shape)

    def pair(self, u1, u2):
        """Pair every point with the closest point of body 2's current surface (u1, u2: the
        dof vectors of the two fields): segments in 2D, triangles or bilinear quadrilaterals in
        3D (nitsche.projection), a point keeping its facet while its unclipped projection
        lies within the hysteresis of it."""
        p = self.other.mesh.p
        current = (p + u2[self.other.dof_basis.nodal_dofs]).T[self.segments]  # (S, vertices, dim)
        self.facet, self.eta = closest_facets(self.current_points(u1), current,
                                              getattr(self, "facet", None), self.hysteresis)
        N, _ = shape_functions(self.segments.shape[1], self.eta)
        X_m = np.einsum("pi,pik->kp", N, p.T[self.segments[self.facet]])
        self.X_m = X_m.reshape(p.shape[0], *self.shape)
        self.other_cells = self.segment_cells[self.facet].reshape(self.shape)
        self._other.clear()
        self._tabulated = {}  # ids of (basis, element) -> (orders, T, dofs) of this pairing
        self.pairings += 1

    def tabulation(self, field, orders):
        """Body 2's fields at the paired points; a field of facet_tangents: the reference
        tangents of the paired facets, t_a = dX/deta_a = sum_i dN_i/deta_a(eta) X_i (X_i the
        facet's vertices, the field's values there), the first one signed so that rot(t_1)
        (2D) or t_1 x t_2 (3D) is body 2's outward normal."""
        if getattr(field, "tangents_of", None) is None:
            return self._other_tabulation(field, orders) if not self._mine(field) \
                else super().tabulation(field, orders)
        if field.mesh is not self.other.mesh:
            raise ValueError(f"facet tangents '{field.name}' belong to another body than the one "
                             "this interface is paired with (other=...)")
        if list(orders) != [0]:
            raise ValueError(f"facet tangents '{field.name}' are data: a density reads their value only")
        vertices, (E, Q) = self.segments.shape[1], self.shape
        dim, m = self.other.mesh.dim(), self.eta.shape[1]
        _, dN = shape_functions(vertices, self.eta)  # (P, vertices, m)
        dN[:, :, 0] *= self.orientation[self.facet][:, None]
        T = np.einsum("pia,cd->pcaid", dN, np.eye(dim)).reshape(E, Q, dim * m, vertices * dim)
        dofs = field.dof_basis.nodal_dofs[:, self.segments[self.facet]]  # (dim, P, vertices)
        dofs = dofs.transpose(1, 2, 0).reshape(E, Q * vertices * dim)
        slots = np.zeros((E, Q, dim * m, Q, vertices * dim))
        slots[:, np.arange(Q), :, np.arange(Q)] = T.transpose(1, 0, 2, 3)
        return slots.reshape(E, Q, dim * m, -1), np.ascontiguousarray(dofs)

    def _other_tabulation(self, field, orders):
        """Body 2's tabulation at the paired points, made once per pairing for the fields
        that share a basis and element (u_2, its previous step's values, its coordinates):
        the rows of the requested orders are taken from one made for orders it holds."""
        key = (id(field.dof_basis), id(field.element))  # (the fields keep both alive)
        made = self._tabulated.get(key)
        if made is None or not set(orders) <= set(made[0]):
            wanted = sorted(set(orders) | set(made[0] if made else ()))
            self._tabulated[key] = made = (wanted, *super().tabulation(field, wanted))
        made_orders, T, dofs = made
        sizes = [int(np.prod(s, dtype=int)) for s in self.shapes(field, made_orders)]
        spans = {o: (start, start + size) for o, start, size in zip(made_orders, np.cumsum([0] + sizes), sizes)}
        rows = np.concatenate([np.arange(*spans[o]) for o in orders])
        return (T if len(rows) == T.shape[2] and np.array_equal(rows, np.arange(T.shape[2]))
                else np.ascontiguousarray(T[:, :, rows])), dofs

    def shapes(self, field, orders):
        if getattr(field, "tangents_of", None) is None:
            return super().shapes(field, orders)
        dim = self.other.mesh.dim()
        return [(dim, dim - 1) + (dim,) * o for o in orders]

    def reachable(self, field):
        """The dofs of a field on the other body that this interface's elements can hold
        under any pairing: those of its cells along `onto` (none of a field on this body:
        the elements keep those of their own cells); a distributed problem holds them all
        (nitsche.distributed.Layout)."""
        if field.mesh is self.mesh:
            return np.zeros(0, np.int64)
        return field.dof_basis.dofs.element_dofs[:, self.segment_cells].ravel()

    def other_points(self, field):
        return self.X_m

    def _located(self, field):
        """Body 2's cells of the paired points, one slot per quadrature point."""
        E, Q = self.shape
        slots = np.broadcast_to(np.arange(Q), (E, Q))
        return self.X_m, self.other_cells, slots, self.other_cells


def outward(mesh, vertices, cells):
    """+1 or -1 per facet (its vertices (S, v), owning cells (S,)): the sign of its first
    reference tangent dX/deta_1 at the centre that makes rot(t_1) (2D) or t_1 x t_2 (3D)
    point out of the cell."""
    v = mesh.p.T[vertices]  # (S, v, dim)
    centre = 1 / 3 if vertices.shape[1] == 3 else 0.5
    _, dN = shape_functions(vertices.shape[1], np.full((len(v), mesh.dim() - 1), centre))
    t = np.einsum("sia,sik->ska", dN, v)
    n = np.stack([-t[:, 1, 0], t[:, 0, 0]], 1) if mesh.dim() == 2 else np.cross(t[:, :, 0], t[:, :, 1])
    out = v.mean(axis=1) - mesh.p[:, mesh.t[:, cells]].mean(axis=1).T
    return np.where((n * out).sum(1) >= 0, 1.0, -1.0)


def facet_tangents(field, name=None):
    """A field of data: on an interface with pairing='current' onto the body of `field`, the
    reference tangents of the paired facet at X_m, value shape (dim, dim - 1) (columns t_a;
    default name T_FIELD).  With F_2 = I + grad u_2 there, T = F_2 t are the current tangents,
    ops.surface_normal(T) body 2's current outward normal and ops.tangential_coordinates(T,
    x_s - x_m) the first-order shift dxi of the closest point (docs/finite_deformation.md)."""
    t = coordinates(field, name or f"T_{field.name}")
    t.tangents_of = field.name
    return t


def sliding(field, where, other, onto, intorder=None, weight=None, hysteresis=None):
    """The interface measure of nitsche.measures.interface(..., pairing='current');
    hysteresis: the share of a facet beyond it within which a point keeps it (default
    HYSTERESIS; 0 pairs every point with its closest point)."""
    if onto is None:
        raise ValueError("pairing='current' needs the other body's contact surface: onto=<boundary name>")
    hysteresis = HYSTERESIS if hysteresis is None else float(hysteresis)
    if not hysteresis >= 0:
        raise ValueError(f"hysteresis must be a share of a facet >= 0, not {hysteresis!r}")
    return Sliding(facets(field, where, intorder=intorder, weight=weight), field, other, onto, hysteresis)
