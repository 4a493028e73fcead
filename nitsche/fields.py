"""Fields: named unknowns, each on its own scikit-fem basis."""
import numpy as np
from skfem import Basis, ElementVector
from skfem.element import ElementH1

from .elements import with_hessian, provided_orders
from .locate import probes


class Field:
    """The unknown `name` in the finite element space (mesh, element).

    fixed: degrees of freedom held at prescribed values (strong Dirichlet data):
        None, "boundary" (all boundary dofs), the name of a boundary in
        `mesh.boundaries`, a predicate `x -> bool` on boundary facet midpoints,
        or an array of dof indices.
    value: the prescribed values, a number or a function of the dof locations
        `x` (shape (dim, n)); Lagrange elements only for functions (for a vector
        Lagrange element the function returns the components, shape (dim, n)).
    """

    def __init__(self, name, mesh, element, fixed=None, value=0.0, intorder=None):
        if not isinstance(name, str) or not name.isidentifier():
            raise ValueError(f"field name {name!r} must be a Python identifier (it names a density argument)")
        if name in ("x", "n", "h"):
            raise ValueError(f"field name {name!r} is reserved for the point, normal and mesh size")
        self.name, self.mesh = name, mesh
        self.element = element
        self.element_with_hessian = with_hessian(element)  # used where a density asks for hess
        self.orders = provided_orders(self.element_with_hessian)
        self.basis = Basis(mesh, element, intorder=intorder)
        self.fixed_dofs = self._fixed_dofs(fixed)
        self.fixed_values = self._fixed_values(value)

    @property
    def ndofs(self):
        return self.basis.N

    @property
    def is_lagrange(self):
        e = self.element.elem if isinstance(self.element, ElementVector) else self.element
        return isinstance(e, ElementH1)

    def _fixed_dofs(self, fixed):
        if fixed is None:
            return np.zeros(0, dtype=np.int64)
        if isinstance(fixed, str) and fixed == "boundary":
            return np.asarray(self.basis.get_dofs().all(), dtype=np.int64)
        if isinstance(fixed, str):
            names = sorted((self.mesh.boundaries or {}).keys())
            if fixed not in names:
                raise ValueError(f"field '{self.name}': unknown boundary {fixed!r}; "
                                 f"use 'boundary' or one of {names}")
            return np.asarray(self.basis.get_dofs(fixed).all(), dtype=np.int64)
        if callable(fixed):
            facets = self.mesh.facets_satisfying(fixed, boundaries_only=True)
            return np.asarray(self.basis.get_dofs(facets).all(), dtype=np.int64)
        dofs = np.unique(np.asarray(fixed, dtype=np.int64))
        if dofs.size and (dofs.min() < 0 or dofs.max() >= self.ndofs):
            raise ValueError(f"field '{self.name}': fixed dof indices must lie in [0, {self.ndofs})")
        return dofs

    def _fixed_values(self, value):
        if not callable(value):
            return np.full(self.fixed_dofs.size, float(value))
        if self.is_lagrange and isinstance(self.element, ElementVector):
            # value(x) -> (dim, n): component j % dim of dof j (dofs interleaved, as in prolongate)
            x = self.basis.doflocs[:, self.fixed_dofs]
            v = np.asarray(value(x), dtype=float).reshape(self.mesh.dim(), -1)
            return v[self.fixed_dofs % self.mesh.dim(), np.arange(self.fixed_dofs.size)]
        if not self.is_lagrange:
            raise ValueError(f"field '{self.name}': a function as fixed value needs a scalar "
                             "Lagrange element; give a number instead")
        return np.asarray(value(self.basis.doflocs[:, self.fixed_dofs]), dtype=float)

    def interpolate(self, fun):
        """Nodal interpolant of `fun(x)` (Lagrange elements)."""
        if not self.is_lagrange:
            raise ValueError(f"field '{self.name}': nodal interpolation needs a Lagrange element")
        return np.asarray(fun(self.basis.doflocs), dtype=float)

    def prolongate(self, coarse, u):
        """This field's dofs of the coarse field's function `u` (exact for nested Lagrange spaces)."""
        if not (self.is_lagrange and coarse.is_lagrange):
            raise NotImplementedError(
                f"field '{self.name}': prolongation is implemented for Lagrange elements only")
        values = probes(coarse.basis, self.basis.doflocs) @ u
        if isinstance(self.element, ElementVector):  # rows component-major, dofs interleaved
            j = np.arange(self.ndofs)
            values = values.reshape(self.mesh.dim(), -1)[j % self.mesh.dim(), j]
        return values
