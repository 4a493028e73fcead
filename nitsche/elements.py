"""Element-wise second derivatives for scikit-fem's Lagrange (H1) elements.

scikit-fem's P1/P2/Q1 elements give values and gradients only.  For affine
cells the physical Hessian is

    hess_x phi = invDF^T  hess_xi phi  invDF,

and the reference Hessian of a basis function that is a polynomial of degree
at most three in each variable is given *exactly* (up to round-off) by
central second differences, so any such element gains `hess` without a
hand-written table.
"""
import copy

import numpy as np
from skfem import ElementVector
from skfem.element import ElementGlobal
from skfem.mapping import MappingAffine
from skfem.element import ElementH1, DiscreteField

STEP = 0.5  # central-difference step on the reference element (exact for cubics)


def reference_hessian(element, X, i):
    """d^2 phi_i / dxi_a dxi_b at reference points X, shape (dim, dim, *X.shape[1:])."""
    dim = X.shape[0]
    out = np.empty((dim, dim) + X.shape[1:])
    shift = [STEP * np.eye(dim)[a].reshape((dim,) + (1,) * (X.ndim - 1)) for a in range(dim)]
    phi = lambda Y: element.lbasis(Y, i)[0]
    for a in range(dim):
        for b in range(a, dim):
            if a == b:
                d = (phi(X + shift[a]) - 2 * phi(X) + phi(X - shift[a])) / STEP**2
            else:
                d = (phi(X + shift[a] + shift[b]) - phi(X + shift[a] - shift[b])
                     - phi(X - shift[a] + shift[b]) + phi(X - shift[a] - shift[b])) / (4 * STEP**2)
            out[a, b] = out[b, a] = d
    out[np.abs(out) < 1e-9] = 0.0  # round-off of exact zeros (e.g. every P1 Hessian)
    return out


def _gbasis_with_hessian(self, mapping, X, i, tind=None):
    (field,) = super(type(self), self).gbasis(mapping, X, i, tind)
    invDF = mapping.invDF(X, tind)
    if not isinstance(mapping, MappingAffine) and \
            np.ptp(invDF, axis=-1).max() > 1e-10 * np.abs(invDF).max():
        raise ValueError(
            f"{type(self).__bases__[0].__name__}: element-wise second derivatives need affine "
            "cells (triangles, tetrahedra, parallelograms); this mesh has curved or "
            "non-parallelogram cells")
    ref = reference_hessian(self, X if X.ndim == 3 else X[:, None, :], i)
    if X.ndim == 2:
        ref = np.broadcast_to(ref, ref.shape[:2] + (invDF.shape[2], ref.shape[-1]))
    if not ref.any():  # degree-one elements
        hess = np.zeros((X.shape[0],) * 2 + invDF.shape[2:])
    else:
        hess = np.einsum('iaeq,ijeq,jbeq->abeq', invDF, ref, invDF, optimize=True)
    return (DiscreteField(value=np.asarray(field), grad=field.grad, hess=hess),)


def has_zero_hessian(element):
    """True for wrapped elements whose reference Hessians vanish (degree one on simplices)."""
    if not getattr(element, "provides_hessian", False):
        return False
    X = np.full((element.dim, 1), 0.25)
    return not any(reference_hessian(element, X, i).any() for i in range(len(element.doflocs)))


_CACHE = {}


def with_hessian(element):
    """Return `element` able to give `hess`: H1 elements are wrapped, others returned as is."""
    if isinstance(element, ElementVector) or not isinstance(element, ElementH1):
        return element
    cls = type(element)
    if cls not in _CACHE:  # (setdefault: one class per element class, whichever thread makes it)
        _CACHE.setdefault(cls, type(cls.__name__, (cls,), {"gbasis": _gbasis_with_hessian,
                                                           "provides_hessian": True}))
    wrapped = _CACHE[cls].__new__(_CACHE[cls])
    wrapped.__dict__.update(element.__dict__)
    return wrapped


def own_instance(element):
    """A fresh instance of an element that caches mesh data on itself, for one mesh.

    scikit-fem's ElementGlobal (Morley, Argyris, BFS, ...) caches its inverse
    Vandermonde matrices on the instance for the first mesh it sees, so an object
    shared between meshes silently gives wrong bases; a copy without the cache is
    made per field.  The copy keeps the instance's `derivatives` (scikit-fem
    computes third derivatives, grad3, only when `element.derivatives = 3` is set
    before the element is used).  Other elements are returned as they are."""
    if not isinstance(element, ElementGlobal):
        return element
    own = copy.copy(element)
    for cached in ("V", "_pbasis"):
        own.__dict__.pop(cached, None)
    return own


def provided_orders(element):
    """Derivative orders an element gives at quadrature points: 0 value, 1 grad, 2 hess, 3 grad3."""
    if isinstance(element, ElementVector):
        return (0, 1)
    if getattr(element, "provides_hessian", False):
        return (0, 1, 2)
    if hasattr(element, "derivatives"):  # scikit-fem's ElementGlobal
        return tuple(range(min(int(element.derivatives), 3) + 1))
    return (0, 1)
