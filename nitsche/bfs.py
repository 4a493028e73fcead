"""The Bogner-Fox-Schmit element in local coordinates (axis-parallel rectangles).

scikit-fem's ElementQuadBFS builds each cell's basis from global monomials
x^i y^j (i, j <= 3) and inverts a Vandermonde matrix; its condition number grows
like (|x| / h)^6 and the Hessians lose digits on fine meshes (1e-3 relative
error at h = 1/128).  This element has the same degrees of freedom in the same
layout, u, u_x, u_y, u_xy at the four vertices of every cell (so scikit-fem's
Basis, FacetBasis and dof numbering work unchanged), but evaluates the
tensor-product Hermite cubics in coordinates local to the cell:

    eta = sigma (x - x_v) / h_x in [0, 1],  sigma = +1 / -1 at the low / high end,
    value function   V(eta) = 1 - 3 eta^2 + 2 eta^3          (V = 1, V' = 0 at the vertex)
    slope function   S(eta) = sigma h_x (eta - 2 eta^2 + eta^3)  (S = 0, dS/dx = 1 at the vertex)

and d^k/dx^k = (sigma / h_x)^k d^k/deta^k.  The basis function of vertex v and
dof (u, u_x, u_y, u_xy) is V V, S V, V S, S S in (x, y).  Values, gradients,
Hessians and third derivatives are exact up to round-off at any mesh size.
"""
import itertools

import numpy as np
from skfem.element import Element, DiscreteField
from skfem.refdom import RefQuad

# d^k/deta^k of V and of eta - 2 eta^2 + eta^3, k = 0..3
_V = (lambda e: 1 - 3 * e ** 2 + 2 * e ** 3, lambda e: -6 * e + 6 * e ** 2,
      lambda e: -6 + 12 * e, lambda e: 12 + 0 * e)
_S = (lambda e: e - 2 * e ** 2 + e ** 3, lambda e: 1 - 4 * e + 3 * e ** 2,
      lambda e: -4 + 6 * e, lambda e: 6 + 0 * e)


class ElementQuadBFSLocal(Element):
    """Bogner-Fox-Schmit (C^1 bicubic Hermite) element, evaluated in local coordinates.

    Same dofs and layout as skfem.ElementQuadBFS; valid on axis-parallel rectangles
    (a ValueError otherwise).  Provides value, grad, hess and grad3."""

    nodal_dofs = 4
    maxdeg = 3          # bicubic: tensor-product quadrature of order 2 * 3 integrates mass exactly
    derivatives = 3     # orders provided at quadrature points (read by nitsche.elements)
    dofnames = ['u', 'u_x', 'u_y', 'u_xy']
    doflocs = np.array([[0., 0.]] * 4 + [[1., 0.]] * 4 + [[1., 1.]] * 4 + [[0., 1.]] * 4)
    refdom = RefQuad

    def _geometry(self, mesh, tind):
        """Low corner (2, E), sides (2, E) and the end (0 low, 1 high) of each vertex (4, 2, E)."""
        p = mesh.p[:, mesh.t[:, tind]]  # (2, 4, E)
        lo, hi = p.min(axis=1), p.max(axis=1)
        side = hi - lo
        at_hi = np.abs(p - hi[:, None]) <= 1e-10 * side[:, None]
        at_lo = np.abs(p - lo[:, None]) <= 1e-10 * side[:, None]
        if not np.all(at_hi ^ at_lo):
            raise ValueError("ElementQuadBFSLocal needs axis-parallel rectangular cells")
        return lo, side, np.moveaxis(at_hi, 1, 0).astype(int)

    def gbasis(self, mapping, X, i, tind=None):
        mesh = mapping.mesh
        if tind is None:
            tind = np.arange(mesh.t.shape[1])
        if not 0 <= i < 16:
            self._index_error()
        vertex, kind = divmod(i, 4)
        lo, side, end = self._geometry(mesh, tind)
        x = np.asarray(mapping.F(X, tind=tind))  # (2, E, Q)
        one_d = []
        for a, slope in ((0, kind in (1, 3)), (1, kind in (2, 3))):
            sigma = 1.0 - 2.0 * end[vertex, a]                      # (E,)
            corner = lo[a] + end[vertex, a] * side[a]
            eta = sigma[:, None] * (x[a] - corner[:, None]) / side[a][:, None]
            scale = sigma / side[a]                                 # d eta / dx
            fns = _S if slope else _V
            pre = sigma * side[a] if slope else np.ones_like(side[a])
            one_d.append([(pre * scale ** k)[:, None] * fns[k](eta) for k in range(4)])
        fx, fy = one_d

        def deriv(index):
            nx = sum(1 for d in index if d == 0)
            return fx[nx] * fy[len(index) - nx]

        parts = []
        for k in range(4):
            out = np.empty((2,) * k + x.shape[1:])
            for index in itertools.product(range(2), repeat=k):
                out[index] = deriv(index)
            parts.append(out)
        return (DiscreteField(value=parts[0], grad=parts[1], hess=parts[2], grad3=parts[3]),)
