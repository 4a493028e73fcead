"""Jets: a field's value and derivatives at one quadrature point.

A density is a pure JAX function of jets.  `Jet.value`, `.grad`, `.hess` and
`.grad3` are the field and its first three derivatives at the point; a jet
used in arithmetic stands for its value, so `f * u` means `f * u.value`.
"""
import jax.numpy as jnp

ORDERS = ("value", "grad", "hess", "grad3")
DERIVATIVE_NAMES = ("values", "first derivatives", "second derivatives", "third derivatives")


class DerivativeError(ValueError):
    """A density asked for a derivative that the field's element does not provide."""


class Jet:
    """Value and derivatives of the field `name` at one point (only the orders in `parts`)."""

    def __init__(self, name, parts, provided, used=None):
        self.name, self._parts, self._provided, self._used = name, parts, provided, used

    def _get(self, order):
        if order not in self._provided:
            raise DerivativeError(
                f"field '{self.name}': the density asks for {DERIVATIVE_NAMES[order]} "
                f"({ORDERS[order]}), which its element does not provide (it gives "
                f"{', '.join(ORDERS[k] for k in self._provided)}); choose an element that "
                "provides them" + (" (scikit-fem's ElementGlobal elements, e.g. Morley, Argyris, "
                                   "BFS, give grad3 when `element.derivatives = 3` is set on "
                                   "the element instance)" if order == 3 else ""))
        if self._used is not None:
            self._used.add(order)
        return self._parts[order]

    value = property(lambda self: self._get(0))
    grad = property(lambda self: self._get(1))
    hess = property(lambda self: self._get(2))
    grad3 = property(lambda self: self._get(3))

    def __jax_array__(self):
        return jnp.asarray(self.value)

    def __array__(self, *args, **kwargs):
        raise TypeError(f"field '{self.name}': use jax.numpy in densities, not numpy")

    def __getitem__(self, i):
        return self.value[i]

    __add__ = lambda self, o: self.value + o
    __radd__ = lambda self, o: o + self.value
    __sub__ = lambda self, o: self.value - o
    __rsub__ = lambda self, o: o - self.value
    __mul__ = lambda self, o: self.value * o
    __rmul__ = lambda self, o: o * self.value
    __truediv__ = lambda self, o: self.value / o
    __rtruediv__ = lambda self, o: o / self.value
    __pow__ = lambda self, o: self.value ** o
    __neg__ = lambda self: -self.value
