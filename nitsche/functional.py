"""The ingredients of a constrained problem and the Nitsche functional built from them.

For a constraint g(u) >= 0 (or = 0) on a measure S with multiplier lambda(u)
and scaling alpha = alpha0 h^k / stiffness, the engine adds to the energy

    int_S  -1/2 alpha lambda^2 + 1/2 alpha P(lambda - g / alpha)^2,

P = [.]_+ for an inequality and the identity for an equality; a penalty
constraint has lambda = 0, i.e. int_S P(-g)^2 / (2 alpha).  The discrete
multiplier (contact force) is lambda_N = P(lambda - g / alpha).
"""
import copy
import inspect
import math

import jax.numpy as jnp

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


class Scaling:
    """alpha = alpha0 * h^h_power / stiffness, constant on each cell (h: cell diameter)."""

    def __init__(self, alpha0, h_power, stiffness=1.0):
        if not (isinstance(alpha0, str) and alpha0 == "auto"):
            try:
                alpha0 = float(alpha0)
            except (TypeError, ValueError):
                raise ValueError(f"alpha0 must be a positive number or 'auto', not {alpha0!r}")
            if not alpha0 > 0 or alpha0 == float("inf"):
                raise ValueError(f"alpha0 must be a positive finite number (got {alpha0}); "
                                 "use alpha0='auto' for a safe fraction of the stability limit")
        self.alpha0 = alpha0
        self.h_power = _number(h_power, "h_power", "the power k of h in alpha = alpha0 h^k / "
                               "stiffness", lambda k: k >= 0, "a finite number >= 0")
        self.stiffness = float(_number(stiffness, "stiffness", "the stiffness in alpha = alpha0 "
                                       "h^k / stiffness", lambda s: s > 0, "a positive finite number"))

    def resolved(self, alpha0):
        """A copy with alpha0 given (the resolution of alpha0='auto' by one Problem)."""
        return Scaling(alpha0, self.h_power, self.stiffness)

    @property
    def is_auto(self):
        return isinstance(self.alpha0, str)

    def relative(self, h):
        """alpha / alpha0 = h^k / stiffness."""
        return h ** self.h_power / self.stiffness

    def __call__(self, h):
        if self.is_auto:
            raise RuntimeError("alpha0='auto' must be resolved (Problem does this) before use")
        return self.alpha0 * self.relative(h)

    def __repr__(self):
        return f"Scaling(alpha0={self.alpha0}, h_power={self.h_power}, stiffness={self.stiffness})"


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

    def with_scaling(self, scaling):
        """The same constraint with another scaling (e.g. alpha0='auto' resolved)."""
        other = copy.copy(self)
        other.scaling = scaling
        return other

    @property
    def kind(self):
        if self.multiplier is None:
            return "penalty"
        return "inequality" if self.inequality else "equality"

    def _parts(self):
        gap, multiplier, scaling = self.gap, self.multiplier, self.scaling
        gn, mn = self.gap_names, self.multiplier_names
        alpha0, k, stiffness = scaling.alpha0, scaling.h_power, scaling.stiffness

        def parts(args):
            alpha = alpha0 * args["h"] ** k / stiffness
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

    def multiplier_square(self):
        """1/2 (alpha/alpha0) lambda^2: its Hessian is the B of the stability eigenproblem."""
        multiplier, scaling, mn = self.multiplier, self.scaling, self.multiplier_names
        k, stiffness = scaling.h_power, scaling.stiffness

        def density(args):
            lam = call(multiplier, mn, args)
            return 0.5 * args["h"] ** k / stiffness * lam ** 2
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
