"""Contact pairing in the current configuration (large sliding between deformable bodies).

The contact surface of body 1 keeps its own quadrature points X_s.  At every Newton iterate
each point's current position x_s = X_s + u_1(X_s) is projected onto the current surface of
body 2, the facets `onto` with their vertices moved by u_2 (a polyline in 2D):

    xi = argmin_{y on the current facets} |x_s - y|,

and body 2's fields are evaluated at the reference point X_m of that closest point (the
same position on the facet's reference vertices); a point keeps its facet while its
projection lies near it (HYSTERESIS), so that it does not flip between two facets at a
vertex from one iterate to the next.  A density reads body 2 there like any
field on an interface: e.g. the normal gap (x_s - x_m) . nu with x_m = X_m + u_2(X_m)
(X_m from nitsche.coordinates(u_2)) and nu the current normal of body 2.  The pairing is
held fixed within a Newton step and its line search, and updated before the next one: the
derivative of X_m in u is left out of the Newton matrix, so the convergence is fast but
not quadratic while the pairing still moves, and quadratic once it has settled.
"""
import numpy as np

from .measures import Interface, facets, select_facets, tabulate_at


HYSTERESIS = 0.25  # a point keeps its segment while its projection lies within this share beyond it


def closest_points(x, a, b, previous=None):
    """For points x (P, 2) and segments a -> b (S, 2): the nearest segment s (P,) and the
    parameter t in [0, 1] of the nearest point a_s + t (b_s - a_s) on it.  previous: the
    points' segments so far, kept while the unclipped projection onto them lies in
    [-HYSTERESIS, 1 + HYSTERESIS] (so that a point near a vertex does not flip between its
    two segments from one Newton iterate to the next)."""
    d = b - a
    t = np.einsum("psk,sk->ps", x[:, None, :] - a[None], d) / np.maximum((d * d).sum(1), 1e-300)
    rows = np.arange(len(x))
    keep = np.zeros(len(x), bool) if previous is None else \
        (t[rows, previous] >= -HYSTERESIS) & (t[rows, previous] <= 1 + HYSTERESIS)
    t = np.clip(t, 0.0, 1.0)
    gap = x[:, None, :] - (a[None] + t[..., None] * d[None])
    s = np.where(keep, previous if previous is not None else 0, np.argmin((gap * gap).sum(-1), axis=1))
    return s, t[rows, s]


class Sliding(Interface):
    """An interface measure on body 1's facets whose points are paired with body 2's current
    surface `onto` (see the module docstring).  pair(u_1, u_2) updates the pairing from dof
    vectors of the two displacement fields; every quadrature point has its own slot of body
    2's cells, so the tabulations keep their shapes (and the compiled kernels) across pairings."""

    def __init__(self, base, mine, other, onto):
        super().__init__(base)
        if other.mesh.dim() != 2:
            raise ValueError("pairing='current' projects onto the other body's current surface in "
                             "2D only (a polyline); for 3D use pairing='points' or 'supermesh'")
        self.mine, self.other = mine, other
        facets_ = select_facets(other.mesh, onto)
        self.segments = other.mesh.facets[:, facets_].T  # (S, 2) vertex indices
        self.segment_cells = other.mesh.f2t[0, facets_]
        X = np.asarray(base.points, dtype=float)  # (2, E, Q)
        self.shape = X.shape[1:]
        self.X_s = X.reshape(2, -1).T
        cells = np.repeat(np.asarray(base.cells)[:, None], self.shape[1], axis=1)
        self._own = (tabulate_at(mine, [0], cells, X), mine.basis.element_dofs[:, cells])
        self.pairings = 0
        self.pair(np.zeros(mine.ndofs), np.zeros(other.ndofs))

    def current_points(self, u1):
        """x_s = X_s + u_1(X_s), shape (P, 2)."""
        T, dofs = self._own  # T (E, Q, 2, k), dofs (k, E, Q)
        return self.X_s + np.einsum("eqck,keq->eqc", T, u1[dofs]).reshape(-1, 2)

    def pair(self, u1, u2):
        """Pair every point with the closest point of body 2's current surface (u1, u2: the
        dof vectors of the two fields)."""
        vertex_dofs = self.other.basis.nodal_dofs  # (2, vertices): the two components
        p = self.other.mesh.p
        current = p + u2[vertex_dofs]
        a, b = current[:, self.segments[:, 0]].T, current[:, self.segments[:, 1]].T
        s, t = closest_points(self.current_points(u1), a, b, getattr(self, "segment", None))
        self.segment = s
        A, B = p[:, self.segments[s, 0]], p[:, self.segments[s, 1]]
        X_m = (A + t * (B - A)).reshape(2, *self.shape)
        self.X_m, self.other_cells = X_m, self.segment_cells[s].reshape(self.shape)
        self._other.clear()
        self.pairings += 1

    def other_points(self, field):
        return self.X_m

    def _located(self, field):
        """Body 2's cells of the paired points, one slot per quadrature point."""
        E, Q = self.shape
        slots = np.broadcast_to(np.arange(Q), (E, Q))
        return self.X_m, self.other_cells, slots, self.other_cells


def sliding(field, where, other, onto, intorder=None, weight=None):
    """The interface measure of nitsche.measures.interface(..., pairing='current')."""
    if onto is None:
        raise ValueError("pairing='current' needs the other body's contact surface: onto=<boundary name>")
    return Sliding(facets(field, where, intorder=intorder, weight=weight), field, other, onto)
