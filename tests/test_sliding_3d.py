"""Contact paired in the current configuration in 3D (pairing='current'): closest points on
triangles and bilinear quadrilaterals against dense sampling, the k-d tree search against
all facets, the hysteresis, the paired facet's tangents, and a neo-Hookean block pressed
onto a softer one and slid sideways (a path that compiles once, balances its forces at
every step, converges quadratically once the pairing settles, and whose contact Jacobian
matches central differences)."""
import numpy as np
import pytest
from skfem import ElementHex1, ElementHex2, ElementTetP1, ElementVector, MeshHex, MeshHex2, MeshTet

import nitsche as ni
from nitsche import assembly
from nitsche.newton import forcing
from nitsche.ops import (current_normal, deformation_gradient, dot, first_piola, lame, neo_hookean,
                         surface_normal, tangential_coordinates)
from nitsche.projection import closest_facets, on_facets, shape_functions, within
from nitsche.sliding import HYSTERESIS
from sliding_checks import jacobian_against_finite_differences

SAMPLES = 201  # per side of the dense sampling of a facet's reference coordinates


def sampled_distance(x, v):
    """The distance of each point x (P, 3) to its facet v (P, vertices, 3) by dense sampling:
    an upper bound within sqrt(2) diam(v) / (SAMPLES - 1) of the exact one."""
    r, s = (a.ravel() for a in np.meshgrid(np.linspace(0, 1, SAMPLES), np.linspace(0, 1, SAMPLES)))
    eta = np.stack([r, s], 1)[r + s <= 1 + 1e-12] if v.shape[1] == 3 else np.stack([r, s], 1)
    N, _ = shape_functions(v.shape[1], eta)
    return np.array([np.sqrt((((N @ vp) - xp) ** 2).sum(1)).min() for xp, vp in zip(x, v)])


def distance(x, v, eta):
    N, _ = shape_functions(v.shape[1], eta)
    return np.sqrt(((x - np.einsum("pi,pik->pk", N, v)) ** 2).sum(1))


@pytest.mark.parametrize("vertices", [3, 4])
def test_closest_points_on_triangles_and_bilinear_quadrilaterals(vertices):
    """Random facets (the quadrilaterals twisted out of plane) and points all around them, so
    that interiors, edges and vertices are all nearest somewhere: the closest point is never
    farther than the best sampled one, and nearer by less than the sampling's resolution."""
    rng = np.random.default_rng(vertices)
    unit = np.array([[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0]], float)
    unit = unit[[0, 1, 3]] if vertices == 3 else unit
    v = unit + 0.3 * rng.standard_normal((200, vertices, 3))
    x = rng.uniform(-1.0, 2.0, (200, 3))
    eta, _ = on_facets(x, v)
    assert within(eta, vertices, 1e-14).all()
    d, sampled = distance(x, v, eta), sampled_distance(x, v)
    assert np.all(d <= sampled + 1e-12)
    diam = np.sqrt(((v[:, :, None] - v[:, None]) ** 2).sum(-1)).max(axis=(1, 2))
    assert np.all(sampled - d < np.sqrt(2) * diam / (SAMPLES - 1))
    inside = within(eta, vertices, -1e-9)  # in the interior, on an edge, at a vertex
    edge = ~inside & ~np.any([np.abs(eta - c).max(1) < 1e-12 for c in unit[:, :2]], axis=0)
    assert inside.sum() > 10 and edge.sum() > 10 and (~inside & ~edge).sum() > 10


@pytest.mark.parametrize("mesh", ["tet", "hex"])
def test_the_tree_search_finds_the_closest_facet_of_all(mesh):
    """Points near a wavy surface of a tetrahedral or hexahedral mesh: the facet and distance
    of closest_facets (k-d tree candidates) are those of the search over every facet."""
    grid = [np.linspace(0, 1, 7), np.linspace(0, 1, 6), np.linspace(0, 0.3, 2)]
    m = MeshTet.init_tensor(*grid) if mesh == "tet" else MeshHex.init_tensor(*grid)
    top = m.facets_satisfying(lambda p: p[2] > 0.3 - 1e-9, boundaries_only=True)
    p = m.p.copy()
    p[2] += 0.05 * np.sin(5 * p[0]) * np.cos(4 * p[1]) + 0.02 * np.random.default_rng(0).standard_normal(p.shape[1])
    v = p.T[m.facets[:, top].T]
    x = np.random.default_rng(1).uniform([-0.2, -0.2, 0.1], [1.2, 1.2, 0.6], (300, 3))
    facet, eta = closest_facets(x, v, candidates=2)
    every = [distance(x, np.repeat(v[f:f + 1], len(x), 0), on_facets(x, np.repeat(v[f:f + 1], len(x), 0))[0])
             for f in range(len(v))]
    assert np.allclose(distance(x, v[facet], eta), np.min(every, axis=0), rtol=0, atol=1e-12)


def test_a_point_keeps_its_facet_within_the_hysteresis():
    """Two triangles sharing the edge x = 1 of the plane z = 0: a point above the second,
    just past the edge, stays on the first while it projects within HYSTERESIS of it."""
    v = np.array([[[0, 0, 0], [1, 0, 0], [0, 1, 0]], [[1, 0, 0], [1, 1, 0], [0, 1, 0]]], float)
    near = np.array([[0.5 + 0.5 * HYSTERESIS, 0.5, 0.3]])  # past the shared edge r + s = 1
    assert closest_facets(near, v)[0].tolist() == [1]
    facet, eta = closest_facets(near, v, previous=np.array([0]), margin=HYSTERESIS)
    assert facet.tolist() == [0] and eta.sum() == pytest.approx(1.0)  # on the shared edge
    far = np.array([[0.5 + 1.5 * HYSTERESIS, 0.5, 0.3]])
    assert closest_facets(far, v, previous=np.array([0]), margin=HYSTERESIS)[0].tolist() == [1]


def box(x, y, z, tets=False):
    m = MeshTet.init_tensor(x, y, z) if tets else MeshHex.init_tensor(x, y, z)
    return m.with_boundaries({"bottom": lambda p: p[2] < z[0] + 1e-9, "top": lambda p: p[2] > z[-1] - 1e-9})


E1, E2, NU = 10.0, 1.0, 0.3
DOWN, SIDE = 0.07, 0.1  # the block's top: down (t = 0..1), then sideways along x (t = 1..2)


def two_blocks(tets=True):
    """A neo-Hookean block (0.6, 1.4)^2 x (0.52, 0.92) (Q1) 0.02 above a ten times softer
    one (0, 2)^2 x (0, 0.5) (P1 tetrahedra or Q1), clamped at its bottom; frictionless contact
    of the block's bottom with the other's current top, the normal gap of the closest point
    with its first-order shift,

        g = (d - T dxi) . nu,  d = x_s - x_m,  T = F_2 t,  dxi = (T^T T)^-1 T^T d,
        nu = t_1 x t_2 / |.|,  lambda = -n_s . P_1 N."""
    m2 = box(np.linspace(0, 2, 6), np.linspace(0, 2, 6), np.linspace(0, 0.5, 2), tets)
    m1 = box(np.linspace(0.6, 1.4, 3), np.linspace(0.6, 1.4, 3), np.linspace(0.52, 0.92, 2))
    u1 = ni.Field("u1", m1, ElementVector(ElementHex1()), fixed={"top": "all"}, intorder=2)
    u2 = ni.Field("u2", m2, ElementVector(ElementTetP1() if tets else ElementHex1()),
                  fixed={"bottom": "all"}, intorder=2)
    X2, T2 = ni.coordinates(u2), ni.facet_tangents(u2)
    law1, law2 = lame(E1, NU), lame(E2, NU)
    energy = [ni.Integral(lambda u1: neo_hookean(deformation_gradient(u1), *law1), ni.cells(u1)),
              ni.Integral(lambda u2: neo_hookean(deformation_gradient(u2), *law2), ni.cells(u2))]

    def gap(u1, u2, X_u2, T_u2, x):
        T = deformation_gradient(u2) @ T_u2.value
        d = x + u1.value - X_u2.value - u2.value
        return dot(d - T @ tangential_coordinates(T, d), surface_normal(T))

    def multiplier(u1, n):
        F1 = deformation_gradient(u1)
        return -dot(current_normal(F1, n), dot(first_piola(neo_hookean, F1, *law1), n))

    on = ni.interface(u1, "bottom", other=u2, pairing="current", onto="top", intorder=2)
    contact = ni.Inequality(gap, multiplier, ni.Scaling("auto", 1, E1), on, name="contact")
    return ni.Problem([u1, u2, X2, T2], energy, [contact])


def move(problem, t):
    u1 = problem.by_name["u1"]
    top = u1.basis.get_dofs(u1.mesh.boundaries["top"])
    values = np.zeros(u1.ndofs)
    values[top.all("u^3")] = -DOWN * min(t, 1.0)
    values[top.all("u^1")] = SIDE * max(t - 1.0, 0.0)
    problem.set_values("u1", values)


@pytest.fixture(scope="module")
def pressed_and_slid():
    problem = two_blocks()
    problem.minimize()  # the rest state: compiles every kernel
    compiled = len(assembly._COMPILED)
    path = ni.path(problem, [0.5, 1.0, 1.5, 2.0], move, quiet=True)
    return problem, path, compiled


def test_the_path_compiles_once_and_re_pairs_every_iterate(pressed_and_slid):
    problem, path, compiled = pressed_and_slid
    assert path.converged, path.reason
    assert len(assembly._COMPILED) == compiled
    assert problem.constraints[0].on.pairings >= sum(s["iterations"] for s in path.steps)
    assert all(s["contact_measure"] > 0.3 for s in path.steps)  # the block's bottom is 0.64


def test_forces_balance_between_the_bodies_at_every_step(pressed_and_slid):
    problem, path, _ = pressed_and_slid
    for s in path.steps:
        top, bottom = s["reactions"]["u1"]["top"], s["reactions"]["u2"]["bottom"]
        scale = abs(top["reaction_z"])
        assert scale > 0.01
        for k in ("reaction_x", "reaction_y", "reaction_z"):
            assert abs(top[k] + bottom[k]) < 1e-6 * scale, (s["time"], k)


def test_newton_converges_quadratically_once_the_pairing_settles(pressed_and_slid):
    """r_k+1 <= C r_k^2 + eta_k r_k near the solution, eta_k = forcing(r_k, rtol) the accuracy
    the inexact Newton method asks of its linear solves (loose at the last step, where
    r_k^2 is below rtol)."""
    problem, path, _ = pressed_and_slid
    for result in path.results[2:]:  # the sliding steps
        r = result.residuals
        tail = [(a, b) for a, b in zip(r, r[1:]) if 1e-12 < a < 1e-3]
        assert tail and all(b < 100 * a ** 2 + forcing(a, 1e-10) * a for a, b in tail), r


def test_the_contact_jacobian_against_central_differences(pressed_and_slid):
    problem, path, _ = pressed_and_slid
    jacobian_against_finite_differences(problem, path, rtol=1e-6)


def tangents_at_the_pairing(on, T_field):
    """The values (E, Q, dim, dim - 1) of a facet_tangents field as the interface tabulates it."""
    T, dofs = on.tabulation(T_field, [0])
    values = np.zeros(T_field.ndofs)
    values[T_field.fixed_dofs] = T_field.fixed_values
    dim = T_field.mesh.dim()
    return np.einsum("eqck,ek->eqc", T, values[dofs]).reshape(*T.shape[:2], dim, dim - 1)


@pytest.mark.parametrize("lower", ["quadrilaterals 2D", "tetrahedra", "hexahedra"])
def test_facet_tangents_are_the_paired_facets_outward_tangents(lower):
    """On an undeformed lower body (its top z = 0.5, or y = 0.5 in 2D): the tangents lie in
    the top, rot(t) (2D) or t_1 x t_2 (3D) is the outward normal e_z times the facet's
    measure (the reference facet has measure 1, or 1/2 for a triangle; for the squares of
    the hexahedra this holds only with their vertices in turn), and X_m is below the point."""
    from skfem import ElementQuad1, MeshQuad
    dim = 2 if lower.endswith("2D") else 3
    if dim == 2:
        m2 = MeshQuad.init_tensor(np.linspace(0, 2, 6), np.linspace(0, 0.5, 2))
        m1 = MeshQuad.init_tensor(np.linspace(0.6, 1.4, 4), np.linspace(0.52, 0.92, 2))
        boundaries = {"bottom": lambda p: p[1] < 0.52 + 1e-9, "top": lambda p: p[1] > 0.5 - 1e-9}
        m1, m2 = m1.with_boundaries(boundaries), m2.with_boundaries(boundaries)
        e1 = e2 = ElementVector(ElementQuad1())
    else:
        tets = lower == "tetrahedra"
        m2 = box(np.linspace(0, 2, 6), np.linspace(0, 2, 6), np.linspace(0, 0.5, 2), tets=tets)
        m1 = box(np.linspace(0.6, 1.4, 4), np.linspace(0.6, 1.4, 4), np.linspace(0.52, 0.92, 2))
        e1, e2 = ElementVector(ElementHex1()), ElementVector(ElementTetP1() if tets else ElementHex1())
    u1, u2 = ni.Field("u1", m1, e1), ni.Field("u2", m2, e2)
    on = ni.interface(u1, "bottom", other=u2, pairing="current", onto="top")
    t = tangents_at_the_pairing(on, ni.facet_tangents(u2))
    assert np.allclose(t[..., dim - 1, :], 0.0)
    if dim == 2:
        normal = np.stack([-t[..., 1, 0], t[..., 0, 0]], -1)
        size = 0.4  # the segments' length
    else:
        normal = np.cross(t[..., 0], t[..., 1])
        size = 0.4 * 0.4  # the squares' area, twice the triangles'
    assert np.allclose(normal[..., :dim - 1], 0.0) and np.allclose(normal[..., dim - 1], size)
    X_s = np.moveaxis(np.asarray(on.points), 0, -1)
    X_m = np.moveaxis(on.X_m, 0, -1)
    assert np.allclose(X_m[..., :dim - 1], X_s[..., :dim - 1]) and np.allclose(X_m[..., dim - 1], 0.5)


def test_the_current_normal_of_the_paired_facets(pressed_and_slid):
    """At the slid solution: ops.surface_normal(F_2 t) at the paired points is the unit normal
    of the current (flat) facet through its moved vertices, pointing up."""
    problem, path, _ = pressed_and_slid
    from nitsche.quantities import quantity
    x = path.at(problem, len(path.steps) - 1)
    problem.update_pairing(x)
    on = problem.constraints[0].on
    on.attach(problem.by_name["u1"])  # the quadrature (the problem released its bases)
    u2 = problem.by_name["u2"]
    current = (u2.mesh.p + problem.split(x)["u2"][u2.basis.nodal_dofs]).T[on.segments[on.facet]]
    expected = np.cross(current[:, 1] - current[:, 0], current[:, 2] - current[:, 0])
    expected *= np.sign(expected[:, 2:]) / np.linalg.norm(expected, axis=1, keepdims=True)
    for k in range(3):
        nu, _, _ = quantity(problem, x, lambda u2, T_u2: surface_normal(deformation_gradient(u2) @ T_u2.value)[k],
                            on=on)
        assert np.allclose(nu.ravel(), expected[:, k], atol=1e-12)
    assert np.ptp(expected[:, 2]) > 1e-4  # the facets are tilted differently


def test_unsupported_facets_and_tangents_elsewhere_say_what_to_do():
    m2 = MeshHex2.from_mesh(MeshHex.init_tensor(*[np.linspace(0, 1, 3)] * 3))  # curved faces
    m2 = m2.with_boundaries({"top": lambda p: p[2] > 1 - 1e-9})
    m1 = box(np.linspace(0.2, 0.8, 3), np.linspace(0.2, 0.8, 3), np.linspace(1.1, 1.5, 2))
    u1 = ni.Field("u1", m1, ElementVector(ElementHex1()))
    u2 = ni.Field("u2", m2, ElementVector(ElementHex2()))
    with pytest.raises(ValueError, match="mesh of degree one"):
        ni.interface(u1, "bottom", other=u2, pairing="current", onto="top")
    u3 = ni.Field("u3", box(*[np.linspace(0, 1, 3)] * 3), ElementVector(ElementHex1()))
    with pytest.raises(ValueError, match="selects no facet"):
        ni.interface(u1, "bottom", other=u3, pairing="current", onto=lambda p: p[2] > 2)
    T1 = ni.facet_tangents(u1)
    with pytest.raises(ValueError, match="pairing='current'"):
        ni.Problem([u1, T1], [ni.Integral(lambda u1, T_u1: T_u1.value[0, 0] * u1.value[0],
                                          ni.facets(u1, "bottom"))])
