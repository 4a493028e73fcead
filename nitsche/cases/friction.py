"""Cattaneo-Mindlin: two elastically similar bodies, a normal load P, then a tangential load
Q < F P, Coulomb friction (plane strain).

Geometry (docs/friction.md): body 1 = (-L, L) x (-L, 0), clamped at the bottom, body 2 =
(-L, L) x (0, L/2) of the same material, with the gap g0(x) = x^2 / (2R) of a cylinder of
radius R on a flat (as in elastic-contact's hertz setup).  On body 1's top (normal n =
(0, 1), tangent t = (-1, 0)):

    g = ((u2 - u1) . n + g0,  ((u2 - u2_old) - (u1 - u1_old)) . t)   (gap, slip increment),
    lambda = (-n . sigma_1 n, -t . sigma_1 n),   alpha = alpha0 h / E,
    K = {(p, q): p >= 0, |q| <= F p}   (Coulomb),

u_old the previous load step (history fields).  Load path (the case's solve): the normal
step, body 2's top moved by (0, -delta) from rest; then the tangential step from that
state, the top moved by (d, -delta), d found by the secant method so that the tangential
force Q = |int lambda_t| is Q_ratio F P (P = int lambda_n).  Elastically similar bodies
do not couple normal and tangential tractions, so Cattaneo and Mindlin's solution holds:
Hertz's pressure p(x) = p0 sqrt(1 - x^2/a^2), a = sqrt(4 P R / (pi E*)), E* = E / (2 (1 -
nu^2)), and the shear q(x) = F p0 (sqrt(1 - x^2/a^2) - (c/a) sqrt(1 - x^2/c^2)) (the
second term for |x| < c only), stick zone |x| < c, c/a = sqrt(1 - Q / (F P)).

friction_law=tresca instead: Tresca's threshold s = F p0 on the whole interface, the top
moved tangentially by d_tresca (full slip where the slip increment is non-zero).
"""
import numpy as np
import jax.numpy as jnp
from skfem import MeshTri, ElementTriP1, ElementTriP2, ElementVector

import nitsche as ni
from nitsche import partition
from nitsche.case import Interval, OneOf, POISSON, POSITIVE, ParameterError
from nitsche.ops import dot, tangent
from nitsche.cases.elastic_contact import elastic, stress
from nitsche.meshes import graded

NAME = "friction"
SUMMARY = "Cattaneo-Mindlin: normal then tangential load with Coulomb friction, plane strain"
PARAMETERS = {
    "E": (1.0, "Young's modulus of both bodies"),
    "nu": (0.3, "Poisson's ratio of both bodies"),
    "mu": (0.3, "Coulomb friction coefficient F"),
    "Q_ratio": (0.5, "tangential load Q / (F P), in [0, 1)"),
    "theta": (1, "Nitsche variant: 1 symmetric, 0 skew-symmetric, -1 non-symmetric"),
    "alpha0": ("auto", "Nitsche parameter (alpha = alpha0 h / E, h = cell diameter)"),
    "R": (4.0, "radius of the parabolic profile g0 = x^2 / (2R)"),
    "delta": (0.01, "downward displacement of body 2's top (the normal load)"),
    "L": (2.0, "half width of the bodies and depth of body 1"),
    "hx": (0.01, "cell width at the contact (|x| < 0.2 L), relative to L"),
    "hy": (0.01, "thickness of the cell layers at the interface (|y| < 0.05 L), relative to L"),
    "growth": (1.3, "ratio of neighbouring cell sizes away from the contact"),
    "steps": (1, "tangential load steps (each from the previous one's state)"),
}
RANGES = {"E": POSITIVE, "nu": POISSON, "mu": POSITIVE, "Q_ratio": Interval(0.0, 1.0, closed_lo=True),
          "R": POSITIVE, "delta": POSITIVE, "L": POSITIVE, "hx": POSITIVE, "hy": POSITIVE,
          "growth": Interval(1.0, closed_lo=True), "steps": Interval(1.0, closed_lo=True),
          "theta": OneOf((1, 0, -1))}
DEGREES = (1, 2)
Q_TOLERANCE = 1e-3  # relative accuracy of the tangential load reached by the secant method
OUTPUTS_FROM_PIECES = True  # the loads summed over the ranks' facets, the interface's points gathered


def check(p):
    if not p.delta < p.L:
        raise ParameterError(f"parameter delta={p.delta!r} (downward displacement of body 2's top) "
                             f"must be below L = {p.L:g}; set --set delta=...")


def build(level, degree, p):
    xs = graded(p.L, 0.2 * p.L, round(0.2 / p.hx), p.growth)
    ys = graded(p.L, 0.05 * p.L, round(0.05 / p.hy), p.growth)
    xs = np.concatenate([-xs[:0:-1], xs])
    m1 = MeshTri.init_tensor(xs, -ys[::-1]).refined(level)
    ys2 = ys[ys <= 0.5 * p.L + 1e-12]
    m2 = MeshTri.init_tensor(xs, ys2).refined(level)
    e = ElementVector(ElementTriP1() if degree == 1 else ElementTriP2())
    u1 = ni.Field("u1", m1, e, fixed=lambda x: x[1] < -p.L + 1e-12)
    u2 = ni.Field("u2", m2, e, fixed=lambda x: x[1] > ys2[-1] - 1e-12)
    u1_old, u2_old = ni.history(u1), ni.history(u2)
    q = 2 * degree
    w = elastic(p.E, p.nu)
    energy = [ni.Integral(lambda u1: w(u1), ni.cells(u1, intorder=q)),
              ni.Integral(lambda u2: w(u2), ni.cells(u2, intorder=q))]
    gamma = ni.interface(u1, lambda x: np.abs(x[1]) < 1e-12, intorder=2 * degree + 2, other=u2,
                         pairing="points")

    def gap(u1, u2, u1_old, u2_old, n, x):
        return jnp.stack([dot(u2 - u1, n) + x[0] ** 2 / (2 * p.R),
                          dot((u2 - u2_old) - (u1 - u1_old), tangent(n))])

    def multiplier(u1, n):
        traction = dot(stress(u1, p.E, p.nu), n)
        return -jnp.stack([dot(n, traction), dot(tangent(n), traction)])

    contact = ni.Coulomb(gap, multiplier, ni.Scaling(p.alpha0, h_power=1, stiffness=p.E), gamma,
                         friction=p.mu, theta=p.theta, name="contact")
    return dict(fields=[u1, u2, u1_old, u2_old], energy=energy, constraints=[contact])


def _move_top(problem, p, d):
    """Body 2's top moved by (d, -delta)."""
    f = problem.by_name["u2"]
    top = f.mesh.facets_satisfying(lambda x: x[1] > f.mesh.p[1].max() - 1e-12, boundaries_only=True)
    dofs = f.dof_basis.get_dofs(top)
    values = np.zeros(f.ndofs)
    values[dofs.all("u^1")], values[dofs.all("u^2")] = d, -p.delta
    problem.set_values("u2", values)


def _step(problem, p, d, x, **options):
    """One load step: the history is x's displacement, the top moved by (d, -delta)."""
    parts = problem.split(x)
    problem.set_values("u1_old", parts["u1"])
    problem.set_values("u2_old", parts["u2"])
    _move_top(problem, p, d)
    return problem.minimize(x, **options)


def loads(problem, result):
    """(P, Q): the normal and tangential forces on the interface (summed over the ranks'
    facets)."""
    v = problem.constraint_values(result.x)["contact"]
    total = partition.summed((v["W"][..., None] * v["multiplier"]).sum((0, 1)))
    return float(total[0]), float(abs(total[1]))


def solve(problem, p, x0=None, **options):
    """The normal step from rest, then the tangential step(s) to Q = Q_ratio F P (the top's
    d by the secant method on Q(d), each trial from the normal state); x0 is not used (the
    load path starts from rest)."""
    rest = problem.initial(None)
    rest[problem.free] = 0.0
    normal = _step(problem, p, 0.0, rest, **options)
    P, _ = loads(problem, normal)
    target = p.Q_ratio * p.mu * P
    trials, path = [(0.0, 0.0, normal)], []

    def tangential(d):
        result, x = None, normal.x
        for k in range(1, int(p.steps) + 1):
            result = _step(problem, p, d * k / int(p.steps), x, **options)
            if not result.converged:
                break
            x = result.x
        trials.append((d, loads(problem, result)[1], result))
        path.append(dict(d=d, Q=trials[-1][1], iterations=result.iterations))
        return result

    if not normal.converged or target == 0.0:
        result = normal
    else:
        d_lo, Q_lo, d = 0.0, 0.0, p.Q_ratio * p.mu * p.delta  # compliances alike: d/delta ~ Q/P
        result = tangential(d)
        d_hi, Q_hi = None, None
        for _ in range(30):
            d_k, Q_k = trials[-1][:2]
            if not result.converged or abs(Q_k - target) <= Q_TOLERANCE * target:
                break
            if Q_k < target:
                d_lo, Q_lo = d_k, Q_k
            else:
                d_hi, Q_hi = d_k, Q_k
            if d_hi is None:  # extrapolate from the origin (Q(d) is concave: stays below)
                d = min(d_k * target / max(Q_k, 1e-300), 4 * d_k)
                d = d if d > d_k * 1.0001 else 2 * d_k
            else:  # regula falsi within the bracket
                d = d_lo + (target - Q_lo) * (d_hi - d_lo) / (Q_hi - Q_lo)
            result = tangential(d)
    problem.load_path = dict(normal_iterations=normal.iterations, normal_load=P,
                             target_tangential_load=target, tangential_trials=path)
    return result


def _zone(x, f):
    """Half the length of the region f <= 0 around the middle of the sorted points x,
    its ends interpolated linearly between the neighbouring points."""
    inside = np.flatnonzero(f <= 0)
    if inside.size == 0:
        return 0.0
    i, j = inside[0], inside[-1]
    left = x[i] if i == 0 else x[i - 1] + (x[i] - x[i - 1]) * f[i - 1] / (f[i - 1] - f[i])
    right = x[j] if j == len(x) - 1 else x[j] + (x[j + 1] - x[j]) * f[j] / (f[j] - f[j + 1])
    return 0.5 * (right - left)


def tractions(problem, result, p):
    """Sorted x, pressure, shear (signed as the load), weights, s = lambda - g/alpha (the
    points of all ranks' contact facets, gathered: a line)."""
    v = problem.constraint_values(result.x)["contact"]
    x, W = partition.gathered(v["x"][..., 0].ravel()), partition.gathered(v["W"].ravel())
    P = partition.gathered(v["multiplier"].reshape(-1, 2))
    s = partition.gathered((v["lam"] - v["g"] / v["alpha"][..., None]).reshape(-1, 2))
    order = np.argsort(x)
    x, W, P, s = x[order], W[order], P[order], s[order]
    sign = np.sign((W * P[:, 1]).sum()) or 1.0
    return x, P[:, 0], sign * P[:, 1], W, s


def cattaneo_mindlin(problem, result, p):
    """The computed stick ratio c/a and half-width a (the ends of the zones where s_n >= 0
    and |s_t| <= F [s_n]_+, interpolated between quadrature points) against Hertz and
    Cattaneo-Mindlin for the computed loads P, Q."""
    x, pn, q, W, s = tractions(problem, result, p)
    P, Q = loads(problem, result)
    a_h = _zone(x, -s[:, 0])
    c_h = _zone(x, np.abs(s[:, 1]) - p.mu * np.maximum(s[:, 0], 0.0) + (s[:, 0] < 0))
    Estar = p.E / (2 * (1 - p.nu ** 2))
    a = np.sqrt(4 * P * p.R / (np.pi * Estar))
    p0 = 2 * P / (np.pi * a)
    ratio = np.sqrt(max(1 - Q / (p.mu * P), 0.0))
    shear = cattaneo_shear(x, P, a_h, ratio, p.mu)
    return dict(normal_load=P, tangential_load=Q, load_ratio=Q / (p.mu * P),
                contact_half_width=a_h, hertz_half_width=float(a), peak_pressure=float(p0),
                stick_half_width=c_h, stick_ratio=c_h / a_h if a_h > 0 else 0.0,
                stick_ratio_reference=float(ratio),
                error_stick_ratio=abs(c_h / a_h - ratio) / ratio if a_h > 0 and ratio > 0 else None,
                error_half_width=abs(a_h - a) / a,
                error_shear_L2=float(np.sqrt((W * (q - shear) ** 2).sum() / (W * shear ** 2).sum()))
                if Q > 0 and a_h > 0 else None)


def cattaneo_shear(x, P, a, ratio, mu):
    """q(x) = F p0 (sqrt(1 - x^2/a^2) - (c/a) sqrt(1 - x^2/c^2)), p0 = 2P / (pi a), c = ratio a
    (the second term for |x| < c): on the computed half-width a (finite bodies shrink it
    below Hertz's)."""
    p0 = 2 * P / (np.pi * max(a, 1e-300))
    c = max(ratio * a, 1e-300)
    return mu * p0 * (np.sqrt(np.maximum(1 - (x / a) ** 2, 0)) - ratio * np.sqrt(np.maximum(1 - (x / c) ** 2, 0)))


def errors(problem, result, p):
    c = cattaneo_mindlin(problem, result, p)
    return {k[6:]: v for k, v in c.items() if k.startswith("error_") and v is not None}


def report(problem, result, p):
    c = cattaneo_mindlin(problem, result, p)
    return dict(cattaneo_mindlin=c, stick_ratio=c["stick_ratio"],
                contact_half_width=c["contact_half_width"],
                load_path=getattr(problem, "load_path", None))


def study_extra(problem, result, row):
    c = cattaneo_mindlin(problem, result, problem.setup.p)
    row.update(stick_ratio=c["stick_ratio"], contact_half_width=c["contact_half_width"])


def figures(problem, result, p, outdir):
    import os
    from nitsche.plot import write_figure  # first: it selects the Agg backend
    import matplotlib.pyplot as plt
    c = cattaneo_mindlin(problem, result, p)
    x, pn, q, W, s = tractions(problem, result, p)
    if outdir is None:  # a rank other than 0 under mpirun: its part is in the data above
        return []
    xs = np.linspace(-1.5 * c["contact_half_width"], 1.5 * c["contact_half_width"], 800)
    a, p0, ratio = c["hertz_half_width"], c["peak_pressure"], c["stick_ratio_reference"]
    P, a_h = c["normal_load"], c["contact_half_width"]
    fig, ax = plt.subplots(figsize=(6.5, 4))
    ax.plot(x, pn, ".", ms=3, label="pressure $\\lambda_n$")
    ax.plot(x, q, ".", ms=3, label="shear $|\\lambda_t|$ (signed)")
    ax.plot(xs, p0 * np.sqrt(np.maximum(1 - (xs / a) ** 2, 0)), "k--", lw=1, label="Hertz")
    ax.plot(xs, cattaneo_shear(xs, P, a_h, ratio, p.mu), "k:", lw=1.2,
            label="Cattaneo-Mindlin (computed a)")
    ax.set_xlim(xs[0], xs[-1])
    ax.set_xlabel("x on the interface")
    ax.set_ylabel("traction")
    ax.set_title(f"F = {p.mu:g}, Q/(F P) = {c['load_ratio']:.3f}: c/a = {c['stick_ratio']:.4f} "
                 f"(exact {ratio:.4f})")
    ax.legend(fontsize=8)
    ax.grid(alpha=0.3)
    path = os.path.join(outdir, "friction_tractions.png")
    fig.tight_layout()
    write_figure(fig, path, dpi=130)
    return [path]


PAPER = [
    dict(command="run", degree=1, level=2, sets={}),
]
