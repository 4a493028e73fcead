"""Shallow ironing: a neo-Hookean block pressed into a softer foundation, then dragged along
it with Coulomb friction (large sliding between two deformable bodies, plane strain).

The benchmark of Yang, Laursen and Meng (2005), Code_Aster SSNP153 and Yastrebov's book;
dimensions in mm, forces in N on the 1 mm thick domain.  The foundation (0, 12) x (0, 4),
fixed at its bottom; the block (0.2, 1.4) x (4.5, 5.4) whose lower edge is the circular
arc from (0.2, 4.5) through (0.8, 4.2) to (1.4, 4.5) (radius 0.75, 0.2 above the
foundation at the start).  Both compressible neo-Hookean,

    W(F) = mu/2 (tr(F^T F) - 2 - 2 ln J) + lam/2 (ln J)^2,

nu = 0.32, foundation E = 68.96e7 Pa = 689.6 N/mm^2, block 10 times stiffer.
The block's top is moved down by 1 over the normalized time 0-1, then by 10 sideways
over 1-2.  Contact on the block's arc and leading side (the slave) against the foundation's current top
(pairing='current': closest points, updated at every Newton iterate), Coulomb friction
F = 0.3, in the current configuration:

    g = ((x_s - x_m) . nu,  -((u_1 - u_1old) - (u_2 - u_2old)) . s),
    lambda = -(n_s . P_1 N, s . P_1 N),   alpha = alpha0 h / E_block,

x_s = X + u_1 the slave point, x_m = X_m + u_2(X_m) its closest point on the foundation,
nu = surface_normal(F_2 t) the foundation's current normal there (t its facet's tangent), n_s = cof(F_1) N/|.| the
block's current normal, s = (-n_s,y, n_s,x) its tangent, P_1 N the traction per reference
length (the slip increment is that of the current pair over the step, backward Euler).
contact='two-pass' is the unbiased form of Chouly, Mlika and Renard (2018): the block's arc
and both sides the slave of the foundation's top as above, plus the foundation's top the
slave of the block's current arc and sides (slip_gap with the roles swapped: the block's normal at the closest
point, the foundation's traction the multiplier, each point paired with its closest point
without hysteresis), each pass weighted 1/2, both with alpha = alpha0 h / E_block.
The reactions on the block's top are compared with five published codes (the digitized
curves of the solids4foam repository).
"""
import json
import os

import jax.numpy as jnp
import numpy as np
from skfem import ElementQuad1, ElementQuad2, ElementVector, MeshQuad

import nitsche as ni
from nitsche.case import Interval, OneOf, POISSON, POSITIVE
from nitsche.ops import (current_normal, deformation_gradient, dot, first_piola, lame, neo_hookean,
                         surface_normal, tangent, tangential_coordinates)

NAME = "ironing"
SUMMARY = "shallow ironing: a neo-Hookean block pressed 1 mm and dragged 10 mm on a foundation, Coulomb friction"
PARAMETERS = {
    "E": (689.6, "the foundation's Young's modulus (N/mm^2)"),
    "stiffer": (10.0, "the block's Young's modulus over the foundation's"),
    "nu": (0.32, "Poisson's ratio of both bodies"),
    "F": (0.3, "Coulomb friction coefficient"),
    "depth": (1.0, "the block top's vertical travel (mm), over t = 0..1"),
    "slide": (10.0, "the block top's horizontal travel (mm), over t = 1..2"),
    "end": (1.0, "the normalized time the path ends at: 1 the indentation, 2 with the sliding "
                 "(with contact=two-pass, the default: the one-pass contact stops at t = 1.04, the onset "
                 "of gross slip; the whole path takes about 12 minutes on two cores)"),
    "steps_down": (20, "load steps of the indentation (t = 0..1)"),
    "steps_slide": (50, "load steps of the sliding (t = 1..2)"),
    "alpha0": ("auto", "Nitsche parameter (alpha = alpha0 h / E_block)"),
    "theta": (1, "the Nitsche variant: 1 symmetric, 0 skew, -1 non-symmetric (stable for every alpha0)"),
    "nx": (120, "foundation cells along its length at level 2, the default (and nx/4 across "
                "its height); halved or doubled per level below or above"),
    "nb": (12, "block cells along its arc at level 2 (and nb/2 across its height)"),
    "contact": ("two-pass", "'one-pass': the block's arc and leading side the slave of the foundation's top; "
                            "'two-pass': the unbiased form, each surface (the block's arc and both sides, the "
                            "foundation's top) the slave of the other, each pass weighted 1/2"),
    "damping": (0.0, "diagnostic: numerical damping of the foundation during the sliding (t > 1), "
                     "c/2 |u2 - u2_old|^2 per volume, c = damping E per mm^2 (result.json: "
                     "damping_share_max, the share of the horizontal force it takes)"),
}
RANGES = {"theta": OneOf((1.0, 0.0, -1.0)), "end": Interval(0.0, 2.0, closed_hi=True), "E": POSITIVE, "stiffer": POSITIVE, "nu": POISSON, "F": Interval(0.0, closed_lo=True),
          "depth": Interval(0.0, 2.0, closed_hi=True), "slide": Interval(0.0, 10.5, closed_lo=True, closed_hi=True),
          "steps_down": Interval(1.0, closed_lo=True), "steps_slide": Interval(1.0, closed_lo=True),
          "nx": Interval(4.0, closed_lo=True), "nb": Interval(2.0, closed_lo=True),
          "damping": Interval(0.0, closed_lo=True), "contact": OneOf(("one-pass", "two-pass"))}
DEGREES = (1, 2)
PAPER = [dict(command="run", degree=1, level=2, fast=dict(sets={"steps_down": 10}))]
CENTER, RADIUS = np.array([0.8, 4.95]), 0.75
REFERENCE = os.path.join(os.path.dirname(__file__), "data", "ironing_reference.json")
OUTPUTS_FROM_PIECES = True  # report and figure: the load path's records (the same on every rank)


def cells_at(n, level):
    """n cells at level 2 (the command line's default: the benchmark's mesh), doubled per level."""
    return max(2, round(n * 2.0 ** (level - 2)))


def foundation(nx, level):
    """(0, 12) x (0, 4) in nx x nx/4 quadrilaterals at level 2; 'bottom', 'top'."""
    nx = cells_at(nx, level)
    m = MeshQuad.init_tensor(np.linspace(0, 12, nx + 1), np.linspace(0, 4, max(1, round(nx / 4)) + 1))
    return m.with_boundaries({"bottom": lambda x: x[1] < 1e-9, "top": lambda x: x[1] > 4 - 1e-9})


def block(nb, level):
    """The block: its arc (angles from -143.13 to -36.87 degrees about (0.8, 4.95)) blended
    linearly into its top y = 5.4, nb x nb/2 quadrilaterals at level 2; boundaries 'arc', 'top' and
    'contact' (the arc and the leading side x = 1.4, as in the solids4foam tutorial) and
    'lower' (the arc and both sides)."""
    nb = cells_at(nb, level)
    m = MeshQuad.init_tensor(np.linspace(0, 1, nb + 1), np.linspace(0, 1, max(1, round(nb / 2)) + 1))
    s, r = m.p
    start, end = np.arctan2(-0.45, -0.6), np.arctan2(-0.45, 0.6)
    angle = start + s * (end - start)
    bottom = CENTER[:, None] + RADIUS * np.array([np.cos(angle), np.sin(angle)])
    top = np.array([0.2 + 1.2 * s, np.full_like(s, 5.4)])
    m = MeshQuad(bottom + r * (top - bottom), m.t)
    return m.with_boundaries({"arc": lambda x: x[1] < 4.5, "top": lambda x: x[1] > 5.4 - 1e-9,
                              "contact": lambda x: (x[1] < 4.5) | (x[0] > 1.4 - 1e-9),
                              "lower": lambda x: x[1] < 5.4 - 1e-9})


def build(level, degree, p):
    element = ElementVector(ElementQuad1() if degree == 1 else ElementQuad2())
    mesh1, mesh2 = block(int(p.nb), level), foundation(int(p.nx), level)
    u1 = ni.Field("u1", mesh1, element, fixed={"top": "all"})
    u2 = ni.Field("u2", mesh2, element, fixed={"bottom": "all"})
    u1_old, u2_old, X2, T2 = ni.history(u1), ni.history(u2), ni.coordinates(u2), ni.facet_tangents(u2)
    E1 = p.E * p.stiffer
    law1, law2 = lame(E1, p.nu), lame(p.E, p.nu)
    energy = [ni.Integral(lambda u1: neo_hookean(deformation_gradient(u1), *law1), ni.cells(u1)),
              ni.Integral(lambda u2: neo_hookean(deformation_gradient(u2), *law2), ni.cells(u2))]
    if p.damping > 0:  # c is set per step: 0 during the indentation
        energy.append(ni.Integral(lambda u2, u2_old, c: c / 2 * dot(u2.value - u2_old.value, u2.value - u2_old.value),
                                  ni.cells(u2)))

    two_pass = p.contact == "two-pass"
    half = (lambda x: 0.5) if two_pass else None
    arc = ni.interface(u1, "lower" if two_pass else "contact", other=u2, pairing="current", onto="top",
                       intorder=2 * degree + 2, weight=half)
    scaling = ni.Scaling(p.alpha0, h_power=1, stiffness=E1)
    contact = ni.Coulomb(lambda u1, u2, u1_old, u2_old, X_u2, T_u2, x, n:
                         slip_gap(u1, u1_old, u2, u2_old, X_u2, T_u2, x, n),
                         lambda u1, n: traction(u1, n, law1), scaling, arc, friction=p.F, theta=p.theta)
    fields, constraints = [u1, u2, u1_old, u2_old, X2, T2], [contact]
    if two_pass:
        X1, T1 = ni.coordinates(u1), ni.facet_tangents(u1)
        top = ni.interface(u2, "top", other=u1, pairing="current", onto="lower", intorder=2 * degree + 2,
                           weight=half, hysteresis=0.0)
        # hysteresis 0: at the block's convex vertices a kept facet's extended line would
        # catch the foundation's points (docs/finite_deformation.md)
        constraints.append(ni.Coulomb(lambda u1, u2, u1_old, u2_old, X_u1, T_u1, x, n:
                                      slip_gap(u2, u2_old, u1, u1_old, X_u1, T_u1, x, n),
                                      lambda u2, n: traction(u2, n, law2), scaling, top,
                                      friction=p.F, theta=p.theta, name="contact_foundation"))
        fields += [X1, T1]
    return dict(fields=fields, energy=energy, constraints=constraints, parameters={"c": 0.0})


def slip_gap(slave, slave_old, master, master_old, X_m, t, x, n):
    """The gap of a slave point x_s = x + u_s paired with its closest point x_m = X_m + u_m(X_m)
    on the master's current surface (pairing='current'; one function for both passes of
    contact='two-pass'):

        g = ((x_s - x_m) . nu,  -((u_s - u_s,old) - (u_m - u_m,old)(X_m + t dxi)) . s),

    T = F_m t (t the paired facet's reference tangent, nitsche.facet_tangents), nu =
    surface_normal(T) the master's outward normal, dxi = tangential_coordinates(T, x_s - x_m)
    the closest point's first-order shift (zero where the pairing is current, its derivative
    the linearization of the projection), s = tangent(n_s) with n_s the slave's current
    normal (the slip increment of the current pair over the step, backward Euler)."""
    T = deformation_gradient(master) @ t.value
    d = x + slave.value - X_m.value - master.value
    shift = t.value @ tangential_coordinates(T, d)
    moved = (master.value - master_old.value) + (master.grad - master_old.grad) @ shift
    s = tangent(current_normal(deformation_gradient(slave), n))
    return jnp.stack([dot(d, surface_normal(T)), -dot(slave.value - slave_old.value - moved, s)])


def traction(u, n, law):
    """The multiplier of a slave body (its displacement u, Lame constants law):
    lambda = -(n_s . P N, s . P N), P N its first Piola traction, n_s = cof(F) N/|.| its
    current normal, s = tangent(n_s)."""
    F = deformation_gradient(u)
    t = dot(first_piola(neo_hookean, F, *law), n)
    n_s = current_normal(F, n)
    return -jnp.stack([dot(n_s, t), dot(tangent(n_s), t)])


def path(problem, p):
    """t in (0, 1]: the block's top down by depth t; t in (1, 2]: then sideways by slide (t - 1);
    the listed times up to `end`."""
    f = problem.by_name["u1"]
    top = f.dof_basis.get_dofs(f.mesh.boundaries["top"])

    def press(problem, t):
        values = np.zeros(f.ndofs)
        values[top.all("u^2")] = -p.depth * min(t, 1.0)
        values[top.all("u^1")] = p.slide * max(t - 1.0, 0.0)
        problem.set_values("u1", values)
        problem.set_parameters(c=damping(p) if t > 1.0 + 1e-12 else 0.0)
    down, slide = int(p.steps_down), int(p.steps_slide)
    times = np.concatenate([np.arange(1, down + 1) / down, 1 + np.arange(1, slide + 1) / slide])
    times = np.append(times[times < p.end - 1e-12], p.end)
    return dict(times=times, set_step=press)


def damping(p):
    """c = damping E (N/mm^4): the foundation's resistance c (u2 - u2_old) per volume during
    the sliding, a body force that the reactions on the block's top and the foundation's
    bottom no longer balance (see damping_share; docs/finite_deformation.md)."""
    return float(p.damping) * float(p.E)


def forces(steps):
    """(time, vertical, horizontal) of the accepted steps: the forces the press applies to
    the block's top (-R_y, R_x with R the reaction on the block)."""
    rows = [(s["time"], -s["reactions"]["u1"]["top"]["reaction_y"], s["reactions"]["u1"]["top"]["reaction_x"])
            for s in steps if s["converged"]]
    return np.array(rows).reshape(-1, 3)


def damping_share(steps):
    """Per accepted sliding step (t > 1), the share of the press's horizontal force that the
    numerical damping takes instead of the foundation's support: |R_top,x + R_bottom,x| /
    |R_top,x| (the two reactions balance where there is no damping)."""
    rows = [abs(s["reactions"]["u1"]["top"]["reaction_x"] + s["reactions"]["u2"]["bottom"]["reaction_x"])
            / abs(s["reactions"]["u1"]["top"]["reaction_x"]) for s in steps
            if s["converged"] and s["time"] > 1.0 + 1e-12]
    return np.array(rows)


def reference():
    with open(REFERENCE) as f:
        return json.load(f)


def at(curve, t):
    """A reference curve [[t, F], ...] interpolated at t."""
    c = np.asarray(curve)
    return float(np.interp(t, c[:, 0], c[:, 1]))


def report(problem, result, p):
    """Vertical and horizontal force at t = 1.0, 1.5 and 2.0 beside the published range, and
    the largest share of the horizontal force taken by the numerical damping."""
    steps = problem.path.steps if getattr(problem, "path", None) else []
    F = forces(steps)
    out = {}
    share = damping_share(steps)
    if share.size:
        out["damping_share_max"] = float(share.max())
    ref = reference()["curves"]
    for t in (1.0, 1.5, 2.0):
        if F.size and F[:, 0].max() >= t - 1e-9:
            key = f"{t:.1f}".replace(".", "_")
            out[f"vertical_{key}"] = float(np.interp(t, F[:, 0], F[:, 1]))
            out[f"horizontal_{key}"] = float(np.interp(t, F[:, 0], F[:, 2]))
            for part in ("vertical", "horizontal"):
                values = [at(c[part], t) for c in ref.values()]
                out[f"{part}_{key}_published"] = [min(values), max(values)]
    return out


def figures(problem, result, p, folder):
    """reaction_forces.png: ours beside the five published curves."""
    from nitsche.plot import save_figure  # first: it selects the Agg backend
    import matplotlib.pyplot as plt
    if folder is None:  # a rank other than 0 under mpirun
        return []
    F = forces(problem.path.steps if getattr(problem, "path", None) else [])
    fig, ax = plt.subplots(figsize=(7, 4.5))
    for k, (name, c) in enumerate(reference()["curves"].items()):
        color = f"C{k + 1}"
        for part, style in (("vertical", "-"), ("horizontal", "--")):
            v = np.asarray(c[part])
            ax.plot(v[:, 0], v[:, 1], style, color=color, lw=0.8, label=name if part == "vertical" else None)
    ax.plot(np.r_[0, F[:, 0]], np.r_[0, F[:, 1]], "k-", lw=2, label="nitsche, vertical")
    ax.plot(np.r_[0, F[:, 0]], np.r_[0, F[:, 2]], "k--", lw=2, label="nitsche, horizontal")
    ax.set_xlabel("normalized time")
    ax.set_ylabel("reaction force on the block's top (N)")
    ax.set_xlim(0, 2)
    ax.grid(alpha=0.3)
    ax.legend(fontsize=7, loc="upper left")
    path = os.path.join(folder, "reaction_forces.png")
    return [save_figure(fig, path, "shallow ironing: solid vertical, dashed horizontal")]
