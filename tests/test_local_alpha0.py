"""alpha0 from element-local stability limits (nitsche.stability): bounds against the
global eigenvalue check, convexity of J_h, a graded Hertz problem, the reports."""
import json

import jax.numpy as jnp
import meshio
import numpy as np
import pytest
from skfem import ElementTriP1, ElementTriP2, ElementVector, MeshTri

import nitsche as ni
import nitsche.assembly
import nitsche.stability
from nitsche.cases import elastic_contact, get
from nitsche.cli import main
from nitsche.ops import dot, grad, sym_grad


def flux_problem(mesh, element, alpha0, vector=False):
    """Laplace (or plane-strain elasticity) with a unilateral flux constraint on the whole
    boundary, no fixed dofs; the gap u + 1 > 0 at u = 0 keeps every point inactive there, so
    the Hessian of J_h at u = 0 is K - sum_T alpha_T B_T."""
    u = ni.Field("u", mesh, ElementVector(element) if vector else element)
    if vector:
        mu, lam = 0.5, 1.0

        def stress(u):
            eps = sym_grad(u)
            return 2 * mu * eps + lam * (eps[0, 0] + eps[1, 1]) * jnp.eye(2)
        energy = lambda u: 0.5 * jnp.sum(stress(u) * sym_grad(u))
        gap = lambda u, n: dot(u, n) + 1.0
        multiplier = lambda u, n: -dot(n, dot(stress(u), n))
    else:
        energy = lambda u: 0.5 * dot(grad(u), grad(u))
        gap = lambda u: u + 1.0
        multiplier = lambda u, n: dot(grad(u), n)
    c = ni.Inequality(gap=gap, multiplier=multiplier, scaling=ni.Scaling(alpha0, 1),
                      on=ni.facets(u, intorder=4), name="contact")
    return ni.Problem([u], energy, [c])


def smallest_hessian_eigenvalue(problem):
    """Smallest eigenvalue of the Hessian of J_h at u = 0 (free dofs), relative to its largest."""
    w = np.linalg.eigvalsh(problem.newton_system(problem.initial(None))[2].toarray())
    return w[0] / w[-1]


CASES = [("dirichlet", 1, 1), ("dirichlet", 2, 1), ("signorini", 2, 1), ("obstacle", 2, 0),
         ("elastic-contact", 1, 0), ("elastic-contact", 2, 0), ("plate-unilateral", 3, 0)]


@pytest.mark.parametrize("name,degree,level", CASES)
def test_local_limits_are_below_the_global_one_and_keep_J_h_convex(name, degree, level):
    """Summing the local inequalities: one alpha0 below every local limit is below the global
    limit, and alpha0_T just below each local limit keeps B_alpha <= K (ratio <= 1)."""
    case = get(name)
    problem = case.problem(level, degree, case.parameters({"alpha0": "0.999*limit"}))
    limits = problem.stability_limits()
    for c in problem.constraints:
        if c.multiplier is not None and np.isfinite(limits[c.name]):
            assert problem.limits[c.name].min() <= limits[c.name] * (1 + 1e-9)
    # several constraints share cells (signorini: contact and Dirichlet flux): each alone
    single = [ni.Problem(problem.fields, problem.integrals, [c]) for c in problem.constraints]
    for p in single:
        assert p.stability_ratio() <= 1 + 1e-6
    assert case.problem(level, degree, case.parameters()).stability_ratio() <= 1 + 1e-6  # 'auto'


@pytest.mark.parametrize("element,vector", [(ElementTriP1(), False), (ElementTriP2(), False),
                                            (ElementTriP1(), True), (ElementTriP2(), True)])
def test_one_cell_local_limit_is_sharp(element, vector):
    """On one cell the local eigenproblem is the global one: the Hessian of J_h is positive
    semidefinite just below the limit and indefinite just above."""
    mesh = MeshTri.init_refdom()
    below = flux_problem(mesh, element, "0.99*limit", vector)
    limit = below.limits["contact"]
    assert np.isfinite(limit).all()
    assert limit.min() == pytest.approx(below.stability_limits()["contact"], rel=1e-6)
    assert smallest_hessian_eigenvalue(below) > -1e-10
    with pytest.warns(ni.StabilityWarning):
        above = flux_problem(mesh, element, "1.01*limit", vector)
    assert smallest_hessian_eigenvalue(above) < -1e-6


@pytest.mark.parametrize("element,vector", [(ElementTriP2(), False), (ElementTriP1(), True)])
def test_small_mesh_convex_below_local_limits_indefinite_somewhat_above(element, vector):
    mesh = MeshTri.init_symmetric().refined(1)
    below = flux_problem(mesh, element, "0.999*limit", vector)
    ratio = below.stability_limits()["contact"] / below.limits["contact"].min()
    assert 1 <= ratio < 2  # the local limits are not far below the global one
    assert smallest_hessian_eigenvalue(below) > -1e-10
    with pytest.warns(ni.StabilityWarning):
        above = flux_problem(mesh, element, "2*limit", vector)
    assert smallest_hessian_eigenvalue(above) < -1e-6


def graded_hertz(alpha0_limits=None):
    case = get("elastic-contact")
    p = case.parameters({"setup": "hertz", "hx": "0.0025", "hy": "0.0025", "growth": "1.5"})
    return case.problem(0, 1, p, alpha0_limits), p


def test_graded_hertz_pressure_is_smooth_and_within_5_percent():
    """Cells 0.005 x 0.005 at the contact, growing by 1.5: the contact facets far from the
    contact sit on flat cells (aspect about 100).  One alpha0 for all (half the global limit,
    the previous 'auto') is set by those cells; the local limits are not."""
    problem, p = graded_hertz()
    limits = problem.limits["contact"]
    assert limits.max() > 50 * limits.min()  # the flat cells' limits are much smaller
    result = problem.minimize().check()
    hz = elastic_contact.hertz_comparison(problem, result, p)
    assert hz["error_peak_pressure"] < 0.05 and hz["error_pressure_L2"] < 0.05  # measured 0.044, 0.042
    x, lam, _ = elastic_contact.pressure(problem, result)
    jumps = np.abs(np.diff(lam[x < 0.8 * hz["half_width"]])) / hz["peak_pressure"]
    assert jumps.max() < 0.15  # no checkerboard (measured 0.07)

    uniform, _ = graded_hertz({"contact": problem.stability_limits()["contact"]})
    other = uniform.minimize().check()
    hu = elastic_contact.hertz_comparison(uniform, other, p)
    assert hu["error_peak_pressure"] > 0.3  # measured 0.86: checkerboard
    assert result.iterations <= other.iterations  # measured 10 against 18


def test_alpha0_forms_and_the_scaling_is_not_changed():
    mesh = MeshTri.init_symmetric().refined(2)
    h = nitsche.measures.cell_diameters(mesh)
    auto = flux_problem(mesh, ElementTriP2(), "auto")
    limit = auto.limits["contact"]
    assert auto.alpha0["contact"] == pytest.approx(np.minimum(0.5 * limit, 0.1))
    assert auto.constraints[0].scaling.alpha0 == "auto"  # resolved per Problem, not in the Scaling
    assert flux_problem(mesh, ElementTriP2(), "0.3*limit").alpha0["contact"] == pytest.approx(0.3 * limit)
    assert np.all(flux_problem(mesh, ElementTriP2(), 0.02).alpha0["contact"] == 0.02)
    by_cell = flux_problem(mesh, ElementTriP2(), lambda x, h: 0.01 + 0.01 * (x[0] > 0.5))
    t = by_cell.constraint_terms[0]
    assert by_cell.alpha0["contact"] == pytest.approx(np.where(t.x[:, :, 0].mean(1) > 0.5, 0.02, 0.01))
    assert t.h == pytest.approx(h[t.cells])
    for bad in ("0.3 * lim", "-1*limit", "fast"):
        with pytest.raises(ValueError, match="alpha0"):
            ni.Scaling(bad, 1)


def test_alpha0_is_kernel_data_not_a_compiled_constant():
    mesh = MeshTri.init_symmetric().refined(2)
    first = flux_problem(mesh, ElementTriP2(), 0.011)
    first.newton_system(first.initial(None))
    compiled = len(nitsche.assembly._COMPILED)
    other = flux_problem(mesh, ElementTriP2(), 0.012)
    other.newton_system(other.initial(None))
    assert len(nitsche.assembly._COMPILED) == compiled


def test_result_json_and_vtu_report_alpha0_per_element(tmp_path):
    assert main(["run", "signorini", "--level", "1", "--degree", "2", "--out", str(tmp_path)]) == 0
    data = json.loads((tmp_path / "result.json").read_text())
    for name in ("contact", "dirichlet"):
        c = data["constraints"][name]
        assert c["alpha0"] == c["alpha0_min"] <= c["alpha0_median"] <= c["alpha0_max"]
        assert c["alpha0_limit_min"] <= c["alpha0_limit_median"] <= c["alpha0_limit_max"]
        assert c["alpha0_min"] == pytest.approx(0.5 * c["alpha0_limit_min"])
        assert data["alpha0_limits"][name] == c["alpha0_limit_min"]
    cells = meshio.read(tmp_path / "solution.vtu").cell_data
    a = np.concatenate(cells["contact_alpha0"])
    assert np.nanmin(a) == pytest.approx(data["constraints"]["contact"]["alpha0_min"])
    assert np.isnan(a).any()  # cells without a contact facet


def test_limits_do_not_depend_on_the_level():
    """Shape, not size: the same limits on levels 0 and 4, also for Hermite (BFS) dofs whose
    scales differ by powers of h (the kernel regularization is relative to each dof's scale)."""
    case = get("plate-unilateral")
    coarse, fine = (case.problem(k, 3, case.parameters()).limits["support"] for k in (0, 4))
    assert fine.min() == pytest.approx(coarse.min(), rel=1e-6)  # corner cells: two facets
    assert fine.max() == pytest.approx(coarse.max(), rel=1e-6)


def test_fraction_of_the_limit_and_the_global_check_on_the_command_line(tmp_path):
    assert main(["run", "dirichlet", "--level", "1", "--degree", "2", "--out", str(tmp_path),
                 "--set", "alpha0=0.3*limit", "--global-check"]) == 0
    data = json.loads((tmp_path / "result.json").read_text())
    assert data["alpha0_limits"]["dirichlet"] <= data["alpha0_global_limits"]["dirichlet"]
    assert 0 < data["alpha0_stability_ratio"] < 0.3 + 1e-6  # 0.3 of every local limit
    c = data["constraints"]["dirichlet"]
    assert c["alpha0_min"] == pytest.approx(0.3 * c["alpha0_limit_min"])
    assert c["alpha0_max"] == pytest.approx(0.3 * c["alpha0_limit_max"])


def test_cells_in_chunks_give_the_same_limits(monkeypatch):
    """Several elements per cell (the corners of the plate) across chunk boundaries."""
    case = get("plate-unilateral")
    problem = case.problem(1, 3, case.parameters())
    monkeypatch.setattr(nitsche.stability, "BATCH_ENTRIES", 3000)  # about 3 cells per chunk
    assert problem.local_limits()["support"] == pytest.approx(problem.limits["support"], rel=1e-12)


def test_a_multiplier_the_cell_energy_does_not_bound_has_no_limit():
    """A multiplier of a field without energy (v): B_C does not vanish on the kernel of K_C.
    'auto' is an error; a given number is not checked (a warning says so; limit 0)."""
    mesh = MeshTri.init_symmetric().refined(1)
    u, v = ni.Field("u", mesh, ElementTriP2()), ni.Field("v", mesh, ElementTriP2())
    energy = lambda u, v: 0.5 * dot(grad(u), grad(u)) + 0.0 * v
    c = ni.Inequality(gap=lambda u: u + 1.0, multiplier=lambda v, n: dot(grad(v), n),
                      scaling=ni.Scaling("auto", 1), on=ni.facets(u), name="contact")
    with pytest.raises(ValueError, match="does not bound the multiplier"):
        ni.Problem([u, v], energy, [c])
    c.scaling = ni.Scaling(0.01, 1)
    with pytest.warns(ni.StabilityWarning, match="not checked against a stability limit on 8 of"):
        ni.Problem([u, v], energy, [c])
