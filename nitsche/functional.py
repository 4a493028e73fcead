"""The ingredients of a constrained problem and the Nitsche functional built from them.

For a constraint g(u) >= 0 (or = 0) on a measure S with multiplier lambda(u)
and scaling alpha = alpha0 h^k / stiffness (alpha0 one value per element, passed to
the compiled kernels as data like h), the engine adds to the energy

    int_S  -1/2 alpha lambda^2 + 1/2 alpha P(lambda - g / alpha)^2,

P = [.]_+ for an inequality and the identity for an equality; a penalty
constraint has lambda = 0, i.e. int_S P(-g)^2 / (2 alpha).  The discrete
multiplier (contact force) is lambda_N = P(lambda - g / alpha).
"""
import inspect
import math

import jax.numpy as jnp
import numpy as np

from .ops import plus

RESERVED = ("x", "n", "h")


def argument_names(fn, what):
    """Names of the arguments of a density (fields by name, and x, n, h)."""
    try:
        params = inspect.signature(fn).parameters.values()
    except (TypeError, ValueError):
        raise TypeError(f"{what} must be a Python function of named fields (and x, n, h)")
    if any(p.kind in (p.VAR_POSITIONAL, p.VAR_KEYWORD) for p in params):
        raise TypeError(f"{what}: name each argument (a field name, or x, n, h); *args is not allowed")
    return tuple(p.name for p in params)


def call(fn, names, args):
    """Call a density with the arguments it names."""
    return fn(**{k: args[k] for k in names})


def _number(value, name, meaning, valid, expected):
    """value as an int if it is integral (h^2 stays an exact square), else a float;
    ValueError naming the parameter unless valid(value) and finite."""
    try:
        number = float(value)
    except (TypeError, ValueError):
        number = float("nan")
    if not (math.isfinite(number) and valid(number)):
        raise ValueError(f"{name} ({meaning}) must be {expected}, got {value!r}")
    return int(number) if number.is_integer() else number


AUTO_FRACTION = 0.5  # alpha0='auto' takes this fraction of each element's stability limit ...
AUTO_CAP = 0.1       # ... and at most this (the value where the multiplier term is stable for all alpha0)
ALPHA0 = "alpha0 of the element"  # the key under which a density receives alpha0: data, like h


class Scaling:
    """alpha = alpha0 h^k / stiffness on each element (h: cell diameter, k = h_power), with

        alpha0 = a positive number      the same on every element,
                 'auto'                 min(1/2 limit_T, 0.1),
                 'F*limit' ('0.3*limit') F limit_T (0.1 where limit_T is infinite),
                 a function alpha0(x, h) of the elements' centroids x (dim, elements) and
                                         cell diameters h (elements,),

    limit_T the element's stability limit (nitsche.stability).  The Scaling keeps what the
    user gave; each Problem resolves it to one alpha0 per element."""

    def __init__(self, alpha0, h_power, stiffness=1.0):
        if isinstance(alpha0, str) and alpha0.strip() == "auto":
            alpha0 = "auto"
        self.fraction = _fraction(alpha0)
        if self.fraction is None and not callable(alpha0):
            try:
                alpha0 = float(alpha0)
            except (TypeError, ValueError):
                raise ValueError(f"alpha0 must be a positive number, 'auto', 'F*limit' or a function "
                                 f"alpha0(x, h), not {alpha0!r}")
            if not alpha0 > 0 or alpha0 == float("inf"):
                raise ValueError(f"alpha0 must be a positive finite number (got {alpha0}); "
                                 "use alpha0='auto' for a safe fraction of the stability limit")
        self.alpha0 = alpha0
        self.h_power = _number(h_power, "h_power", "the power k of h in alpha = alpha0 h^k / "
                               "stiffness", lambda k: k >= 0, "a finite number >= 0")
        self.stiffness = float(_number(stiffness, "stiffness", "the stiffness in alpha = alpha0 "
                                       "h^k / stiffness", lambda s: s > 0, "a positive finite number"))

    @property
    def needs_limit(self):
        """alpha0 is a fraction of the stability limit ('auto' or 'F*limit')."""
        return self.fraction is not None

    def per_element(self, limit, x, h):
        """alpha0 on each element from its stability limit, centroid x (dim, elements) and
        cell diameter h."""
        if self.alpha0 == "auto":
            return np.minimum(AUTO_FRACTION * limit, AUTO_CAP)
        if self.needs_limit:
            return np.where(np.isfinite(limit), self.fraction * limit, AUTO_CAP)
        if callable(self.alpha0):
            a = np.broadcast_to(np.asarray(self.alpha0(x, h), dtype=float), h.shape).copy()
            if not np.all(np.isfinite(a) & (a > 0)):
                raise ValueError("the function alpha0(x, h) must return positive finite values")
            return a
        return np.full(h.shape, self.alpha0)

    def __repr__(self):
        return f"Scaling(alpha0={self.alpha0!r}, h_power={self.h_power}, stiffness={self.stiffness})"


def _fraction(alpha0):
    """F of 'F*limit' (1/2 for 'auto'); None for other values."""
    if not isinstance(alpha0, str):
        return None
    if alpha0 == "auto":
        return AUTO_FRACTION
    head, star, tail = alpha0.partition("*")
    try:
        fraction = float(head) if star and tail.strip() == "limit" else None
    except ValueError:
        fraction = None
    if fraction is None or not 0 < fraction < float("inf"):
        raise ValueError(f"alpha0 must be a positive number, 'auto', 'F*limit' with F > 0 "
                         f"(e.g. '0.3*limit') or a function alpha0(x, h), not {alpha0!r}")
    return fraction


class Integral:
    """int_on density(fields..., x, n, h): one term of the energy J."""

    def __init__(self, density, on):
        self.density, self.on = density, on
        self.names = argument_names(density, "the energy density")

    def pointwise(self):
        density, names = self.density, self.names
        return lambda args: call(density, names, args)


class Constraint:
    """g(u) >= 0 (inequality) or g(u) = 0 (equality) on a measure, with its
    multiplier lambda(u) (None for a penalty constraint) and its scaling."""

    def __init__(self, gap, multiplier, scaling, on, inequality, name=None):
        if not isinstance(scaling, Scaling):
            raise TypeError("scaling must be nitsche.Scaling(alpha0, h_power, stiffness)")
        self.gap, self.multiplier, self.scaling, self.on = gap, multiplier, scaling, on
        self.inequality = bool(inequality)
        self.name = name or ("contact" if inequality else "equality")
        self.gap_names = argument_names(gap, "the gap g")
        self.multiplier_names = argument_names(multiplier, "the multiplier") \
            if multiplier is not None else ()
        self.names = tuple(dict.fromkeys(self.gap_names + self.multiplier_names))

    @property
    def kind(self):
        if self.multiplier is None:
            return "penalty"
        return "inequality" if self.inequality else "equality"

    def _parts(self):
        gap, multiplier, scaling = self.gap, self.multiplier, self.scaling
        gn, mn = self.gap_names, self.multiplier_names
        k, stiffness = scaling.h_power, scaling.stiffness

        def parts(args):
            alpha = args[ALPHA0] * args["h"] ** k / stiffness
            g = call(gap, gn, args)
            lam = call(multiplier, mn, args) if multiplier is not None else jnp.zeros_like(g)
            return g, lam, alpha
        return parts

    def pointwise(self):
        """The Nitsche density -1/2 alpha lambda^2 + 1/2 alpha P(lambda - g/alpha)^2."""
        parts, P = self._parts(), (plus if self.inequality else (lambda s: s))

        def density(args):
            g, lam, alpha = parts(args)
            return -0.5 * alpha * lam ** 2 + 0.5 * alpha * P(lam - g / alpha) ** 2
        return density

    def values(self):
        """(g, lambda, alpha) at a point: for reports, contact pressure and active sets."""
        return self._parts()

    def scaled_multiplier(self):
        """sqrt(alpha) lambda with the element's alpha0 (1: sqrt(alpha/alpha0) lambda, whose
        Gram matrix sum_q W D(.)^T D(.) is the B of the stability eigenproblems)."""
        multiplier, scaling, mn = self.multiplier, self.scaling, self.multiplier_names
        k, stiffness = scaling.h_power, scaling.stiffness

        def density(args):
            return jnp.sqrt(args[ALPHA0] * args["h"] ** k / stiffness) * call(multiplier, mn, args)
        return density


def Equality(gap, multiplier, scaling, on, name=None):
    """Nitsche's method for g(u) = 0 (e.g. Dirichlet data)."""
    return Constraint(gap, multiplier, scaling, on, inequality=False, name=name)


def Inequality(gap, multiplier, scaling, on, name=None):
    """Nitsche's method for g(u) >= 0 (contact, obstacle, unilateral support)."""
    return Constraint(gap, multiplier, scaling, on, inequality=True, name=name)


def Penalty(gap, scaling, on, inequality=True, name=None):
    """The penalty method: int P(-g)^2 / (2 alpha), no multiplier terms."""
    return Constraint(gap, None, scaling, on, inequality=inequality, name=name)
