"""The ingredients of a constrained problem and the Nitsche functional built from them.

For a constraint g(u) >= 0 (or = 0) on a measure S with multiplier lambda(u)
and scaling alpha = alpha0 h^k / stiffness (alpha0 one value per element, passed to
the compiled kernels as data like h), the engine adds to the energy

    int_S  -1/2 alpha lambda^2 + 1/2 alpha P(lambda - g / alpha)^2,

P = [.]_+ for an inequality and the identity for an equality; a penalty
constraint has lambda = 0, i.e. int_S P(-g)^2 / (2 alpha).  The discrete
multiplier (contact force) is lambda_N = P(lambda - g / alpha).

In general g and lambda have several components (normal, tangential) and P is the
projection onto a closed convex set K (the constraint's kind): R_+ (inequality), R
(equality), R_+ x B(0, s) (Tresca friction, threshold s), or the Coulomb set
{(p, t): p >= 0, |t| <= F p} reached through the normal part, P(s) = ([s_n]_+,
P_B(F [s_n]_+)(s_t)).  With phi(s) = 1/2 |s|^2 - 1/2 dist(s, K)^2 (grad phi = P) the
density is -1/2 alpha |lambda|^2 + alpha phi(lambda - g/alpha) and its derivative in a
direction v is the residual

    r_theta(u; v) = int_S -P(s) . Dg[v] + theta alpha (P(s) - lambda) . Dlambda[v],

s = lambda - g/alpha, theta = 1 (symmetric: the energy's gradient), 0 (skew-symmetric)
or -1 (non-symmetric, stable for every alpha0; Chouly, Hild, Renard).  A constraint
without a potential (Coulomb) or with theta != 1 enters as this residual.
"""
import inspect
import math
from typing import Callable, NamedTuple

import jax
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
    residual = False

    def __init__(self, density, on):
        self.density, self.on = density, on
        self.names = argument_names(density, "the energy density")

    def pointwise(self):
        density, names = self.density, self.names
        return lambda args: call(density, names, args)


class Residual:
    """int_on c(u) . Dq(u)[v]: a term of the residual given by a density returning the pair
    (c, q) of arrays of one shape (the test function enters through the jets of q; an
    energy density w is the case c = 1, q = w)."""
    residual = True

    def __init__(self, density, on):
        self.density, self.on = density, on
        self.names = argument_names(density, "the residual density")

    pointwise = Integral.pointwise


def _ball(t, radius):
    """(P_B(t), Huber potential) for the ball B(0, radius): t min(1, radius/|t|) and
    1/2 |t|^2 inside, radius |t| - radius^2/2 outside (safe derivatives at t = 0)."""
    t2 = jnp.sum(t * t)
    inside = t2 <= radius ** 2
    norm = jnp.sqrt(jnp.where(inside, 1.0, t2))
    return (jnp.where(inside, t, radius * t / norm),
            jnp.where(inside, 0.5 * t2, radius * norm - 0.5 * radius ** 2))


def nan_unless_finite(*values):
    """0 where every value is finite, NaN otherwise, and no derivative: added to a
    constraint's density, J_h (or the residual) is not finite where g, lambda or alpha
    is not, which the projection could hide ([lambda - NaN/alpha]_+ = 0 would switch the
    constraint off there); Newton's method then names the ingredient (Problem.non_finite)."""
    finite = jnp.all(jnp.stack([jnp.all(jnp.isfinite(v)) for v in values]))
    return jax.lax.stop_gradient(jnp.where(finite, 0.0, jnp.nan))


class Projection(NamedTuple):
    """The projection P onto the constraint's set K and, where it has one, its potential
    phi (grad phi = P); for vectors the first component is the normal one.  A value (a
    tuple): densities that read it are keyed by what it holds, also across processes."""
    kind: str
    project: Callable
    potential: Callable = None
    friction: float = None
    threshold: float = None

    @property
    def frictional(self):
        return self.kind in ("tresca", "coulomb")

    @property
    def convex(self):
        """Whether phi is convex: the potential of the projection onto a convex set (grad phi
        = P is monotone): R_+ (inequality), R (equality), R_+ x a ball (Tresca)."""
        return self.potential is not None and self.kind in ("inequality", "equality", "tresca")

    def radius(self, P):
        """The radius of the tangential ball at the projected value P (frictional kinds)."""
        return self.threshold if self.kind == "tresca" else self.friction * P[..., 0]


INEQUALITY = Projection("inequality", plus, lambda s: 0.5 * jnp.sum(plus(s) ** 2))
EQUALITY = Projection("equality", lambda s: s, lambda s: 0.5 * jnp.sum(s ** 2))


def tresca_ball(threshold):
    """K = R_+ x B(0, threshold): P(s) = ([s_n]_+, P_B(s_t)), phi = 1/2 [s_n]_+^2 + Huber(s_t)."""
    threshold = _number(threshold, "threshold", "the Tresca friction bound s", lambda s: s >= 0,
                        "a number >= 0")

    def project(s):
        return jnp.concatenate([plus(s[:1]), _ball(s[1:], threshold)[0]])

    def potential(s):
        return 0.5 * plus(s[0]) ** 2 + _ball(s[1:], threshold)[1]
    return Projection("tresca", project, potential, threshold=threshold)


def coulomb_cone(friction):
    """P(s) = ([s_n]_+, P_B(F [s_n]_+)(s_t)) (no potential: a residual form)."""
    friction = _number(friction, "friction", "the Coulomb friction coefficient F", lambda f: f >= 0,
                       "a number >= 0")

    def project(s):
        pn = plus(s[:1])
        return jnp.concatenate([pn, _ball(s[1:], friction * pn[0])[0]])
    return Projection("coulomb", project, friction=friction)


class Constraint:
    """g(u) in K (inequality g >= 0, equality g = 0, or a frictional set for g = (normal,
    tangential)) on a measure, with its multiplier lambda(u) (None for a penalty
    constraint), its scaling and theta (1, 0, -1: the symmetric, skew-symmetric and
    non-symmetric Nitsche variants)."""

    def __init__(self, gap, multiplier, scaling, on, inequality=True, name=None, theta=1,
                 projection=None):
        if not isinstance(scaling, Scaling):
            raise TypeError("scaling must be nitsche.Scaling(alpha0, h_power, stiffness)")
        self.gap, self.multiplier, self.scaling, self.on = gap, multiplier, scaling, on
        self.projection = projection or (INEQUALITY if inequality else EQUALITY)
        self.inequality = self.projection is not EQUALITY
        self.theta = _number(theta, "theta", "the Nitsche variant: 1 symmetric, 0 skew-symmetric, "
                             "-1 non-symmetric", lambda t: True, "a finite number (1, 0 or -1)")
        self.name = name or ("contact" if self.inequality else "equality")
        self.gap_names = argument_names(gap, "the gap g")
        self.multiplier_names = argument_names(multiplier, "the multiplier") \
            if multiplier is not None else ()
        self.names = tuple(dict.fromkeys(self.gap_names + self.multiplier_names))

    @property
    def kind(self):
        if self.multiplier is None and not self.projection.frictional:
            return "penalty"
        return self.projection.kind

    @property
    def residual(self):
        """True when the constraint enters as a residual (no potential, or theta != 1 with a
        multiplier), False when it is a term of the energy J_h."""
        return self.projection.potential is None or (self.multiplier is not None and self.theta != 1)

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
        """The Nitsche density -1/2 alpha |lambda|^2 + alpha phi(lambda - g/alpha), or, for a
        residual constraint, the pair (c, q) = ((-P(s), theta alpha (P(s) - lambda)), (g, lambda))
        of r_theta(u; v) = int c . Dq[v]; NaN where g, lambda or alpha is not finite."""
        parts, projection, theta = self._parts(), self.projection, self.theta

        def density(args):
            g, lam, alpha = parts(args)
            return (-0.5 * alpha * jnp.sum(lam ** 2) + alpha * projection.potential(lam - g / alpha)
                    + nan_unless_finite(g, lam, alpha))

        def pairs(args):
            g, lam, alpha = (jnp.atleast_1d(v) for v in parts(args))
            P = projection.project(lam - g / alpha)
            c = jnp.concatenate([-P, theta * alpha * (P - lam)]) + nan_unless_finite(g, lam, alpha)
            return c, jnp.concatenate([g, lam])
        return pairs if self.residual else density

    def gap_pointwise(self):
        """g at a point, as a density of the constraint's jets."""
        gap, gn = self.gap, self.gap_names
        return lambda args: call(gap, gn, args)

    def values(self):
        """(g, lambda, alpha, P(lambda - g/alpha)) at a point: for reports, tractions and
        active sets (g, lambda, P vectors for a frictional constraint)."""
        parts, projection = self._parts(), self.projection

        def values(args):
            g, lam, alpha = parts(args)
            P = projection.project(jnp.atleast_1d(lam - g / alpha))
            return g, lam, alpha, P.reshape(jnp.shape(lam))
        return values

    def scaled_multiplier(self):
        """sqrt(alpha) lambda with the element's alpha0 (1: sqrt(alpha/alpha0) lambda, whose
        Gram matrix sum_q W D(.)^T D(.) is the B of the stability eigenproblems)."""
        multiplier, scaling, mn = self.multiplier, self.scaling, self.multiplier_names
        k, stiffness = scaling.h_power, scaling.stiffness

        def density(args):
            return jnp.sqrt(args[ALPHA0] * args["h"] ** k / stiffness) * call(multiplier, mn, args)
        return density


def Equality(gap, multiplier, scaling, on, name=None, theta=1):
    """Nitsche's method for g(u) = 0 (e.g. Dirichlet data)."""
    return Constraint(gap, multiplier, scaling, on, inequality=False, name=name, theta=theta)


def Inequality(gap, multiplier, scaling, on, name=None, theta=1):
    """Nitsche's method for g(u) >= 0 (contact, obstacle, unilateral support)."""
    return Constraint(gap, multiplier, scaling, on, inequality=True, name=name, theta=theta)


def Penalty(gap, scaling, on, inequality=True, name=None):
    """The penalty method: int P(-g)^2 / (2 alpha), no multiplier terms."""
    return Constraint(gap, None, scaling, on, inequality=inequality, name=name)


def Tresca(gap, multiplier, scaling, on, threshold, theta=1, name="contact"):
    """Contact with Tresca friction: g = (g_n, g_t) (normal gap, tangential slip increment),
    lambda = (lambda_n, lambda_t) (pressure, tangential traction), K = R_+ x B(0, threshold);
    a functional for theta = 1 (the Huber potential of the ball)."""
    return Constraint(gap, multiplier, scaling, on, name=name, theta=theta,
                      projection=tresca_ball(threshold))


def Coulomb(gap, multiplier, scaling, on, friction, theta=1, name="contact"):
    """Contact with Coulomb friction (coefficient F): as Tresca with the threshold
    F [s_n]_+ (the discrete pressure); always a residual (no potential)."""
    return Constraint(gap, multiplier, scaling, on, name=name, theta=theta,
                      projection=coulomb_cone(friction))
