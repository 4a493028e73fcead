"""Rigid obstacles as signed distance functions, and frictionless contact with them in the
current configuration.

An obstacle is a JAX function phi(y) of a point y: positive outside the obstacle, zero on
its surface, negative inside (a signed distance, |grad phi| = 1 near the surface; any
function with grad phi != 0 on its zero set will do).  A moving obstacle takes run-time
parameters after the point, phi(y, s, ...) (`translated`), so that a whole load path
compiles once.

A body point X with displacement u is at y = X + u(X) and the obstacle pushes it along
n = grad phi(y) / |grad phi(y)|.  The constraint and its multiplier are

    g(u)      = phi(X + u(X)) >= 0,
    lambda(u) = n . P(F) N,       P = dW/dF (first Piola-Kirchhoff),

N the body's outward normal in the reference configuration: lambda is the contact
pressure per reference area.  At a solution the traction is P N = lambda_N n, since
dJ[v] = int P N . v on the boundary and Dg[v] = n . v; hence lambda(u) = lambda_N there
(consistency), and lambda_N >= 0 pushes the body off the obstacle.
"""
import inspect

import jax
import jax.numpy as jnp

from .ops import axisymmetric_deformation_gradient, deformation_gradient, first_piola


def plane(point, normal):
    """phi(y) = (y - point) . m, m = normal / |normal|: the half-space on the side of the
    plane (a line in 2D) through `point` opposite to `normal`."""
    point, m = jnp.asarray(point, float), jnp.asarray(normal, float)
    m = m / jnp.linalg.norm(m)
    return lambda y: jnp.dot(y - point, m)


def sphere(center, radius):
    """phi(y) = |y - center| - radius: a ball (in 2D a disk; in axisymmetric (r, z)
    coordinates with the center on the axis r = 0, the ball of revolution)."""
    center = jnp.asarray(center, float)
    return lambda y: jnp.linalg.norm(y - center) - radius


circle = sphere


def cylinder(point, axis, radius):
    """phi(y) = |(I - a a^T)(y - point)| - radius, a = axis / |axis|: the infinite solid
    circular cylinder about the line through `point` along `axis` (3D)."""
    point, a = jnp.asarray(point, float), jnp.asarray(axis, float)
    a = a / jnp.linalg.norm(a)

    def phi(y):
        d = y - point
        return jnp.linalg.norm(d - jnp.dot(d, a) * a) - radius
    return phi


def translated(phi, direction):
    """psi(y, s) = phi(y - s direction): the obstacle phi moved by s times `direction`
    (s a run-time parameter of the problem, e.g. an indentation depth)."""
    direction = jnp.asarray(direction, float)
    return lambda y, s: phi(y - s * direction)


def normal(phi, y, *parameters):
    """n = grad phi(y) / |grad phi(y)|: the unit normal pointing out of the obstacle."""
    g = jax.grad(phi)(y, *parameters)
    return g / jnp.linalg.norm(g)


def contact(obstacle, W, field="u", parameters=(), axisymmetric=False):
    """(gap, multiplier) of frictionless contact of the displacement field named `field`
    with the rigid obstacle phi(y, *parameters), for ni.Inequality on boundary facets:

        gap(u, x, ...)           = phi(x + u, ...)
        multiplier(u, x, n, ...) = n_phi . P(F) n,   n_phi = normal(phi, x + u, ...),

    P = first_piola(W, F), W(F) the energy density, x and n the reference point and
    outward normal.  `parameters`: the names of the problem's run-time parameters that
    phi takes after the point, in order.  axisymmetric: x = (r, z) and F the 3x3
    axisymmetric deformation gradient (the hoop stretch 1 + u_r/r; the measures carry
    the weight 2 pi r); otherwise F = I + grad u."""
    parameters = tuple(parameters)
    clash = {field, "x", "n"} & set(parameters)
    if clash:
        raise ValueError(f"parameter names {sorted(clash)} clash with the field or x, n")

    def place(args):
        return args["x"] + args[field].value, [args[k] for k in parameters]

    def gap(**args):
        y, s = place(args)
        return obstacle(y, *s)

    def multiplier(**args):
        u, x, N = args[field], args["x"], args["n"]
        F = axisymmetric_deformation_gradient(u, x) if axisymmetric else deformation_gradient(u)
        d = N.shape[0]  # the in-plane block: N and n_phi have no hoop component
        y, s = place(args)
        return jnp.dot(normal(obstacle, y, *s), jnp.dot(first_piola(W, F)[:d, :d], N))
    return (named(gap, (field, "x") + parameters),
            named(multiplier, (field, "x", "n") + parameters))


def named(density, names):
    """The density density(**args) declaring the arguments `names` (the engine passes a
    density the fields, parameters and x, n, h it names)."""
    kind = inspect.Parameter.KEYWORD_ONLY
    density.__signature__ = inspect.Signature([inspect.Parameter(k, kind) for k in names])
    return density
