"""Kirchhoff plates: the local BFS element, Morley/BFS prolongation, third derivatives,
plate energies against exact solutions, and the cases plate-plate (6.3) and
plate-unilateral (6.4)."""
import itertools

import jax.numpy as jnp
import numpy as np
import pytest
from numpy.polynomial import polynomial as P
from skfem import (Basis, CellBasis, FacetBasis, MeshQuad, MeshTri, ElementTriMorley,
                   ElementTriP2)

import nitsche as ni
from nitsche.bfs import ElementQuadBFSLocal
from nitsche.case import Case
from nitsche.cases import plate_plate, plate_unilateral
from nitsche.ops import hess, tangent
from nitsche.study import run_study

# a bicubic sum_k a_k(x) b_k(y): exactly representable by BFS
BICUBIC = [([0.1, -0.5, 0.3, 1.0], [0.2, 1.0, -2.0, 0.7]), ([1.0, 2.0, 0.0, -1.0], [0.5, 0.0, 1.0, 1.0])]


def bicubic(x, y, dx=0, dy=0):
    return sum(P.polyval(x, P.polyder(a, dx)) * P.polyval(y, P.polyder(b, dy)) for a, b in BICUBIC)


def bfs_dofs(basis):
    u = np.zeros(basis.N)
    for j, (dx, dy) in enumerate([(0, 0), (1, 0), (0, 1), (1, 1)]):
        u[basis.nodal_dofs[j]] = bicubic(*basis.mesh.p, dx, dy)
    return u


def max_errors(f, xq):
    """Largest error of value, Hessian and third derivatives against the bicubic."""
    err = [np.abs(f.value - bicubic(*xq)).max()]
    for k in (2, 3):
        part = f.hess if k == 2 else f.grad3
        err.append(max(np.abs(part[i] - bicubic(*xq, i.count(0), i.count(1))).max()
                       for i in itertools.product(range(2), repeat=k)))
    return err


def test_local_bfs_reproduces_a_bicubic_to_round_off_at_h_1_128():
    """scikit-fem's global-monomial BFS has Hessian errors ~1e-2 here; the local one is at
    round-off (the dofs' own rounding, amplified by 1/h^2 and 1/h^3)."""
    mesh = MeshQuad().refined(7)
    b = Basis(mesh, ElementQuadBFSLocal(), intorder=4)
    u = bfs_dofs(b)
    ev, eh, e3 = max_errors(b.interpolate(u), b.global_coordinates().value)
    assert ev < 1e-13 and eh < 1e-8 and e3 < 1e-5
    fb = FacetBasis(mesh, ElementQuadBFSLocal(), facets=mesh.boundary_facets())
    ev, eh, e3 = max_errors(fb.interpolate(u), fb.global_coordinates().value)
    assert ev < 1e-13 and eh < 1e-8 and e3 < 1e-5


def test_local_bfs_rejects_non_rectangles():
    mesh = MeshQuad().refined(1)
    mesh = MeshQuad(mesh.p + 0.05 * np.array([[0.0], [1.0]]) * mesh.p[0] ** 2, mesh.t)
    with pytest.raises(ValueError, match="axis-parallel"):
        Basis(mesh, ElementQuadBFSLocal())


def test_bfs_prolongation_is_exact():
    coarse = ni.Field("u", MeshQuad().refined(2), ElementQuadBFSLocal())
    fine = ni.Field("u", MeshQuad().refined(3), ElementQuadBFSLocal())
    uc = np.random.default_rng(1).standard_normal(coarse.ndofs)
    uf = fine.prolongate(coarse, uc)
    pts = np.random.default_rng(2).uniform(0.01, 0.99, (2, 50))
    jc, jf = coarse.jets_at(uc, pts), fine.jets_at(uf, pts)
    for k in ("value", "grad", "hess"):
        assert np.allclose(jc[k], jf[k], atol=1e-10 * np.abs(jc[k]).max())


def test_morley_prolongation_is_a_close_interpolant():
    u_exact = lambda x: np.sin(np.pi * x[0]) ** 2 * np.sin(np.pi * x[1]) ** 2
    coarse = ni.Field("u", MeshTri().refined(4), ElementTriMorley())
    fine = ni.Field("u", MeshTri().refined(5), ElementTriMorley())
    # coarse dofs from the function itself (vertex values, normal derivatives by differences)
    uc = coarse.prolongate(fine, fine.prolongate(coarse, np.zeros(coarse.ndofs)))
    assert np.allclose(uc, 0)
    kind, normal = coarse._dof_kinds()
    x = coarse.basis.doflocs
    uc = np.where(kind == "u", u_exact(x), 0.0)
    e = 1e-6
    dn = (u_exact(x + e * normal) - u_exact(x - e * normal)) / (2 * e)
    uc = np.where(kind == "u_n", dn, uc)
    uf = fine.prolongate(coarse, uc)
    vf = uf[fine.basis.nodal_dofs[0]]
    assert np.abs(vf - u_exact(fine.mesh.p)).max() < 0.02


def test_element_instances_are_not_shared_between_meshes():
    """ElementGlobal caches its Vandermonde inverse per instance (methods.md, pitfall 2)."""
    e = ElementTriMorley()
    a = ni.Field("a", MeshTri().refined(2), e)
    b = ni.Field("b", MeshTri().refined(3), e)
    ref = Basis(MeshTri().refined(3), ElementTriMorley())
    x = np.random.default_rng(0).standard_normal(ref.N)
    assert a.ndofs != b.ndofs
    assert np.allclose(CellBasis(b.mesh, b.element).interpolate(x).hess, ref.interpolate(x).hess)


def test_third_derivatives_and_their_error():
    mesh = MeshTri().refined(2)
    with pytest.raises(ni.DerivativeError, match=r"third derivatives.*derivatives = 3"):
        ni.Problem([ni.Field("u", mesh, ElementTriP2())], lambda u: jnp.sum(u.grad3 ** 2))
    e = ElementTriMorley()
    e.derivatives = 3  # scikit-fem's switch for grad3
    u = ni.Field("u", mesh, e)
    assert 3 in u.orders
    p = ni.Problem([u], lambda u: 0.5 * jnp.sum(u.hess ** 2) + 0.0 * jnp.sum(u.grad3))
    assert np.isfinite(p.energy(np.ones(p.ndofs)))


def test_tangent_is_the_normal_rotated():
    assert np.allclose(tangent(jnp.array([1.0, 0.0])), [0.0, 1.0])


def navier_simply_supported(x, y, D, q, terms=99):
    """Deflection of the simply supported unit square plate under the load q (Navier)."""
    w = 0.0
    for m in range(1, terms, 2):
        for n in range(1, terms, 2):
            w += np.sin(m * np.pi * x) * np.sin(n * np.pi * y) / (m * n * (m * m + n * n) ** 2)
    return 16 * q / (np.pi ** 6 * D) * w


def test_bfs_plate_energy_simply_supported_against_navier():
    """The plate energy of plate-unilateral, no constraint, simply supported: u = 0 and the
    tangential derivatives fixed on the boundary; centre deflection 0.00406 q/D."""
    D, nu, q = 1.0, 0.3, 1.0
    out = []
    for level in (2, 3):
        mesh = MeshQuad().refined(level)
        b = Basis(mesh, ElementQuadBFSLocal())
        fixed = np.concatenate([b.get_dofs(lambda x: np.isclose(x[0], 0) | np.isclose(x[0], 1))
                                .nodal[k] for k in ("u", "u_y")] +
                               [b.get_dofs(lambda x: np.isclose(x[1], 0) | np.isclose(x[1], 1))
                                .nodal[k] for k in ("u", "u_x")])
        u = ni.Field("u", mesh, ElementQuadBFSLocal(), fixed=fixed)

        def energy(u):
            H = hess(u)
            lap = H[0, 0] + H[1, 1]
            return D * (0.5 * lap ** 2 + (1 - nu) * (H[0, 1] ** 2 - H[0, 0] * H[1, 1])) - q * u
        r = ni.minimize(energy, [u]).check()
        centre = r.x[u.basis.nodal_dofs[0]][np.argmin(np.hypot(*(mesh.p - 0.5)))]
        out.append(centre)
    exact = navier_simply_supported(0.5, 0.5, D, q)
    assert abs(exact - 0.00406235) < 1e-7
    errs = [abs(c - exact) / exact for c in out]
    assert errs[1] < 1e-4 and errs[1] < errs[0] / 8  # fourth order in the deflection


def test_morley_plate_energy_clamped_manufactured():
    """Clamped plate u = x^2 (1-x)^2 y^2 (1-y)^2, f = D lap^2 u: broken energy error O(h)."""
    D, nu = 2.0, 0.3
    X = lambda t: t ** 2 * (1 - t) ** 2
    X2 = lambda t: 2 - 12 * t + 12 * t ** 2
    X1 = lambda t: 2 * t - 6 * t ** 2 + 4 * t ** 3
    errors = []
    for level in (3, 4):
        mesh = MeshTri().refined(level)
        u = ni.Field("u", mesh, ElementTriMorley(), fixed="boundary")

        def energy(u, x):
            H = hess(u)
            f = D * (24 * X(x[1]) + 2 * X2(x[0]) * X2(x[1]) + 24 * X(x[0]))
            return plate_plate.bending(H, D, nu) - f * u
        r = ni.Problem([u], ni.Integral(energy, ni.cells(u, intorder=6))).minimize().check()
        cb = CellBasis(mesh, u.element, intorder=4)
        H = cb.interpolate(r.x).hess
        x, y = cb.global_coordinates().value
        He = np.array([[X2(x) * X(y), X1(x) * X1(y)], [X1(x) * X1(y), X(x) * X2(y)]])
        norm = np.sqrt(np.sum(2 * plate_plate.bending(He, D, nu) * cb.dx))
        errors.append(np.sqrt(np.sum(2 * plate_plate.bending(H - He, D, nu) * cb.dx)) / norm)
    rate = np.log2(errors[0] / errors[1])
    assert errors[1] < 0.35 and 0.85 < rate < 1.2  # measured 0.59, 0.30 (relative), rate 0.96


@pytest.fixture(scope="module")
def unilateral():
    case = Case(plate_unilateral)
    p = case.parameters()
    limits = case.alpha0_limits(3, p)  # the global check on level 1
    from nitsche.study import solve_nested
    problem, result, its, failure = solve_nested(case, 2, 3, p)
    return case, p, limits, problem, result.check(), its


def test_plate_unilateral_alpha0_auto_is_below_the_stability_limit(unilateral):
    """methods.md: C_I ~ 8.2e2 with h = side, alpha0 < 1.2e-3; with h = diameter the
    limit is 1.2e-3 / 2^1.5 ~ 4.3e-4 (global).  The rigid modes of K are regularized.
    'auto' takes half of the element-local limits, which lie below the global one."""
    case, p, limits, problem, result, its = unilateral
    assert 3.5e-4 < limits["support"] < 5.5e-4
    local = problem.limits["support"]
    assert 0.5 * limits["support"] < local.min() <= limits["support"]
    assert problem.alpha0["support"] == pytest.approx(0.5 * local)
    assert max(its[1:]) <= 4  # nested iteration


def test_plate_unilateral_reaction_balance_corners_and_signs(unilateral):
    case, p, limits, problem, result, its = unilateral
    q = plate_unilateral.support_quantities(problem, result, p)
    assert q["reaction_balance"] == pytest.approx(1.0, abs=1e-10)  # exact: constants in V_h
    assert all(7.3e-4 < c < 7.8e-4 for c in q["corner_lift"])    # corners lift off
    assert all(0.45 < s < 0.6 for s in q["lifted_length"])          # lifted part of each edge
    assert q["min_shear_reaction"] > -0.02 * q["max_shear_reaction"]  # -V(u_h) >= 0 up to consistency
    assert q["max_penetration"] < 1e-6


def test_plate_plate_contact_no_penetration():
    case = Case(plate_plate)
    p = case.parameters()
    limits = case.alpha0_limits(2, p)
    assert limits["contact"] == np.inf and np.all(case.problem(0, 2, p).alpha0["contact"] == 0.1)
    from nitsche.study import solve_nested
    problem, result, its, failure = solve_nested(case, 3, 2, p)
    result.check()
    rep = plate_plate.report(problem, result, p)
    assert 0.005 < rep["contact_area"] < 0.05
    assert rep["max_penetration"] < 1e-4
    assert rep["centre_u1"] - rep["centre_u2"] > p.d  # pushed together, slight penetration only
    coarse = case.problem(2, 2, p, limits)
    xc = coarse.minimize().check().x
    assert 0 < plate_plate.difference(coarse, xc, problem, result.x) < 0.2


def test_cli_run_writes_plate_figures(tmp_path):
    from nitsche.cli import main
    assert main(["run", "plate-unilateral", "--degree", "3", "--level", "1",
                 "--out", str(tmp_path / "pu")]) == 0
    assert (tmp_path / "pu" / "plate_unilateral.png").exists()
    assert main(["run", "plate-plate", "--degree", "2", "--level", "2",
                 "--out", str(tmp_path / "pp")]) == 0
    assert (tmp_path / "pp" / "plate_plate.png").exists()


def test_paper_lists():
    for m in (plate_plate, plate_unilateral):
        assert {d["command"] for d in m.PAPER} == {"study", "run"}
        assert all(d["degree"] in m.DEGREES for d in m.PAPER)


@pytest.mark.slow
def test_plate_plate_study_rate_is_linear():
    case = Case(plate_plate)
    rows = run_study(case, 6, 2, case.parameters(), progress=False)
    assert abs(rows[-1]["rate"] - 1.0) < 0.15 and abs(rows[-2]["rate"] - 1.0) < 0.15
    area = [r["contact_area"] for r in rows]
    assert abs(area[-1] - area[-2]) < abs(area[-2] - area[-3])  # contact area converges
    assert rows[-1]["max_penetration"] < rows[-2]["max_penetration"] < 1e-4


@pytest.mark.slow
def test_plate_unilateral_study_rate_and_lifted_corners():
    case = Case(plate_unilateral)
    rows = run_study(case, 6, 3, case.parameters(), progress=False)
    # mean rate over the finest four levels: the mean of the step rates r_k = log2(E_(k-1) / E_k)
    # of levels k = 2..5, i.e. log2(E_1 / E_5) / 4 (docs/plates.md; measured 1.74)
    rates = [r["rate"] for r in rows[-4:]]
    assert np.mean(rates) >= 1.7, rates
    lifted = [r["lifted_length"] for r in rows[-3:]]
    assert np.ptp(lifted) < 0.03 and all(0.45 < s < 0.6 for s in lifted)
    assert all(abs(r["reaction_balance"] - 1) < 1e-8 for r in rows)
