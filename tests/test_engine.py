"""The engine: exact derivatives of J_h, Newton's report, clear errors."""
import jax.numpy as jnp
import numpy as np
import pytest
from skfem import CellBasis, MeshTri, ElementTriP1, ElementTriP2, ElementTriMorley

import nitsche as ni
from nitsche.ops import dot, grad, lap


def problem(kind, where, degree, alpha0=0.05):
    mesh = MeshTri.init_symmetric().refined(2)
    u = ni.Field("u", mesh, ElementTriP1() if degree == 1 else ElementTriP2(),
                 fixed=None if where == "facets" else "boundary")
    energy = lambda u, x: 0.5 * dot(grad(u), grad(u)) - (1 + x[0]) * u
    if where == "facets":
        on = ni.facets(u)
        lam = lambda u, n: dot(grad(u), n)
        scaling = ni.Scaling(alpha0, 1)
    else:
        on = ni.cells(u, intorder=4)
        lam = lambda u: -lap(u) - 1.0
        scaling = ni.Scaling(alpha0 / 10, 2)
    gap = lambda u, x: u - 0.05 * jnp.sin(3 * x[0]) + 0.02
    c = {"equality": lambda: ni.Equality(gap, lam, scaling, on),
         "inequality": lambda: ni.Inequality(gap, lam, scaling, on),
         "penalty": lambda: ni.Penalty(gap, scaling, on)}[kind]()
    return ni.Problem([u], energy, [c], alpha0_limits={c.name: 1e9})


@pytest.mark.parametrize("kind", ["equality", "inequality", "penalty"])
@pytest.mark.parametrize("where", ["cells", "facets"])
@pytest.mark.parametrize("degree", [1, 2])
def test_gradient_and_hessian_match_finite_differences(kind, where, degree):
    p = problem(kind, where, degree)
    rng = np.random.default_rng(0)
    x = p.initial(0.1 * rng.standard_normal(p.ndofs))
    v = np.zeros(p.ndofs)
    v[p.free] = rng.standard_normal(p.free.size)
    g = p.gradient(x)
    H = p.hessian(x)
    eps = 1e-6
    fd_g = (p.energy(x + eps * v) - p.energy(x - eps * v)) / (2 * eps)
    assert fd_g == pytest.approx(g @ v, rel=1e-6, abs=1e-9)
    # the generalized Hessian: exact where the active set does not change in (x - eps v, x + eps v)
    fd_H = (p.gradient(x + eps * v) - p.gradient(x - eps * v)) / (2 * eps)
    assert np.allclose(fd_H, H @ v, rtol=1e-5, atol=1e-6 * np.abs(H @ v).max())
    assert abs(H - H.T).max() <= 1e-12 * abs(H).max()
    if kind == "inequality":  # the test exercises both active and inactive points
        vals = p.constraint_values(x)["inequality" if False else "contact"]
        active = vals["lam"] - vals["g"] / vals["alpha"] > 0
        assert active.any() and (~active).any()


def test_newton_converges_and_reports():
    p = problem("inequality", "cells", 2)
    r = p.minimize()
    assert r.converged and r.iterations >= 1
    assert r.residuals[-1] <= 1e-10
    assert r.active_count > 0 and r.max_violation >= 0
    assert "converged" in r.report()


def test_iteration_limit_is_reported_not_silent():
    p = problem("inequality", "cells", 2)
    r = p.minimize(maxiter=1)
    assert not r.converged
    assert "iteration limit" in r.reason
    with pytest.raises(ni.NotConverged):
        r.check()


def test_bad_alpha0_is_a_clear_error():
    for bad in (0.0, -1.0, float("nan"), "big"):
        with pytest.raises(ValueError, match="alpha0"):
            ni.Scaling(bad, 1)


def test_unknown_field_name_is_a_clear_error():
    mesh = MeshTri().refined(2)
    u = ni.Field("u", mesh, ElementTriP1(), fixed="boundary")
    with pytest.raises(ValueError, match=r"unknown argument.*\['w'\].*fields \['u'\]"):
        ni.Problem([u], lambda w: dot(grad(w), grad(w)))


@pytest.mark.parametrize("gap,lam,part", [
    (lambda w: w, lambda u: -lap(u), "gap"),
    (lambda u: u, lambda w: -lap(w), "multiplier"),
])
def test_unknown_name_in_a_constraint_names_gap_or_multiplier(gap, lam, part):
    mesh = MeshTri().refined(2)
    u = ni.Field("u", mesh, ElementTriP2(), fixed="boundary")
    c = ni.Inequality(gap, lam, ni.Scaling(0.005, 2), ni.cells(u), name="support")
    with pytest.raises(ValueError, match=rf"^the {part} of constraint 'support': "
                                         r"unknown argument\(s\) \['w'\]; .*fields \['u'\]"):
        ni.Problem([u], lambda u: dot(grad(u), grad(u)), [c])


def test_missing_derivative_is_a_clear_error():
    mesh = MeshTri().refined(2)
    u = ni.Field("u", mesh, ElementTriMorley(), fixed="boundary")
    with pytest.raises(ni.DerivativeError, match="third derivatives"):
        ni.Problem([u], lambda u: jnp.sum(u.grad3 ** 2))


def test_normal_on_cells_is_a_clear_error():
    mesh = MeshTri().refined(2)
    u = ni.Field("u", mesh, ElementTriP1(), fixed="boundary")
    with pytest.raises(ValueError, match="normal"):
        ni.Problem([u], lambda u, n: dot(grad(u), n))


def test_non_finite_initial_energy_is_a_clear_error():
    mesh = MeshTri().refined(2)
    u = ni.Field("u", mesh, ElementTriP1(), fixed="boundary")
    p = ni.Problem([u], lambda u: jnp.log(u.value - 1.0) + dot(grad(u), grad(u)))
    with pytest.raises(ValueError, match="not finite"):
        p.minimize()


def test_stability_limit_of_p2_cell_laplacian_and_warning():
    """methods.md: the P2 cell-Laplacian limit is about 0.0105 with h = diameter."""
    from nitsche.case import Case
    import nitsche.cases.obstacle as obstacle
    case = Case(obstacle)
    limits = case.alpha0_limits(2, case.parameters())
    assert 0.008 < limits["contact"] < 0.013
    with pytest.warns(ni.StabilityWarning, match="exceeds the stability limit"):
        case.problem(0, 2, case.parameters({"alpha0": "0.1"}), limits)


def test_stability_limit_of_boundary_flux():
    """methods.md: Dirichlet flux term, P1 limit 0.35 - 0.5, P2 0.095 - 0.137."""
    from nitsche.case import Case
    import nitsche.cases.dirichlet as dirichlet
    case = Case(dirichlet)
    assert 0.3 < case.alpha0_limits(1, case.parameters())["dirichlet"] < 0.55
    assert 0.08 < case.alpha0_limits(2, case.parameters())["dirichlet"] < 0.14


def test_p2_hessian_is_exact():
    """Element-wise second derivatives of P2 reproduce a quadratic's Hessian."""
    mesh = MeshTri().refined(3)
    u = ni.Field("u", mesh, ElementTriP2())
    x = u.interpolate(lambda x: 3 * x[0] ** 2 - 2 * x[0] * x[1] + 5 * x[1] ** 2 + x[0])
    h = CellBasis(mesh, u.element_with_hessian).interpolate(x).hess
    assert np.allclose(h[0, 0], 6) and np.allclose(h[0, 1], -2) and np.allclose(h[1, 1], 10)


def test_compiled_kernels_follow_parameter_changes():
    """Kernels are reused across levels, but a changed parameter value recompiles."""
    from types import SimpleNamespace
    mesh = MeshTri().refined(3)
    p = SimpleNamespace(f=1.0)
    energies = []
    for f in (1.0, 2.0):
        p.f = f
        u = ni.Field("u", mesh, ElementTriP1(), fixed="boundary")
        r = ni.Problem([u], lambda u: 0.5 * dot(grad(u), grad(u)) - p.f * u).minimize().check()
        energies.append(r.energy)
    assert energies[1] == pytest.approx(4 * energies[0], rel=1e-12)  # J scales with f^2


def test_quadratic_terms_are_recognized():
    """Quadratic densities (also through nested jit calls such as jnp.trace) are assembled
    once; the Nitsche inequality term is not quadratic."""
    from skfem import ElementVector
    mesh = MeshTri().refined(2)
    u = ni.Field("u", mesh, ElementVector(ElementTriP1()), fixed="boundary")
    energy = lambda u: jnp.trace(ni.ops.sym_grad(u)) ** 2 + ni.ops.ddot(u.grad, u.grad)
    p = ni.Problem([u], energy)
    assert p.energy_terms[0].is_quadratic
    q = problem("inequality", "cells", 2)
    assert q.energy_terms[0].is_quadratic and not q.constraint_terms[0].is_quadratic
    assert problem("equality", "facets", 1).constraint_terms[0].is_quadratic


def test_factor_reuse_solves_later_newton_steps_by_preconditioned_cg():
    from nitsche.linalg import HAVE_CHOLMOD
    if not HAVE_CHOLMOD:
        pytest.skip("scikit-sparse is not installed")
    mesh = MeshTri.init_symmetric().refined(5)
    u = ni.Field("u", mesh, ElementTriP1(), fixed="boundary")
    obstacle = lambda x: 0.2 - 2 * dot(x - 0.5, x - 0.5)
    contact = ni.Inequality(lambda u, x: u - obstacle(x), lambda u: -lap(u),
                            ni.Scaling(0.1, 2), ni.cells(u, intorder=4))
    p = ni.Problem([u], lambda u: 0.5 * dot(grad(u), grad(u)), [contact])
    reused = p.minimize(solver="cholmod")
    direct = p.minimize(solver="superlu")
    assert reused.converged and direct.converged
    stats = reused.solver_stats
    assert stats["factorizations"] < reused.iterations and len(stats["cg_iterations"]) >= 1
    assert reused.active_count == direct.active_count
    assert np.abs(reused.x - direct.x).max() <= 1e-8 * np.abs(direct.x).max()


def test_pcg_reports_negative_curvature():
    from nitsche.linalg import IndefiniteHessian, pcg
    A = np.diag([1.0, -1.0])
    with pytest.raises(IndefiniteHessian):
        pcg(A, np.array([1.0, 1.0]), lambda r: r, 1e-12, 10)
    x, its = pcg(np.diag([1.0, 2.0]), np.array([1.0, 1.0]), lambda r: r, 1e-12, 10)
    assert np.allclose(x, [1.0, 0.5]) and its <= 2
    x, its = pcg(np.diag([1.0, 2.0]), np.zeros(2), lambda r: r, 1e-12, 10)
    assert not x.any() and its == 0


def test_non_finite_gap_at_the_initial_guess_names_the_gap():
    mesh = MeshTri().refined(2)
    u = ni.Field("u", mesh, ElementTriP1(), fixed="boundary")
    contact = ni.Inequality(lambda u: jnp.sqrt(u.value - 1.0), lambda u: -lap(u),
                            ni.Scaling(0.1, 2), ni.cells(u), name="support")
    p = ni.Problem([u], lambda u: 0.5 * dot(grad(u), grad(u)) - u, [contact])
    with pytest.raises(ValueError, match="gap g of constraint 'support'"):
        p.minimize()


def test_uncoupled_field_blocks_are_found_and_the_two_field_hessian_is_exact():
    mesh = MeshTri.init_symmetric().refined(2)
    e = ElementTriP2()
    u1 = ni.Field("u1", mesh, e, fixed="boundary")
    u2 = ni.Field("u2", mesh, e, fixed="boundary")
    energy = lambda u1, u2: 0.5 * dot(grad(u1), grad(u1)) + dot(grad(u2), grad(u2)) - u1 + u2
    contact = ni.Inequality(lambda u1, u2: u2 + 0.01 - u1, lambda u1: 1.0 + lap(u1),
                            ni.Scaling(0.002, 2), ni.cells(u1, intorder=4))
    p = ni.Problem([u1, u2], energy, [contact], alpha0_limits={"contact": 1.0})
    (energy_term,), (contact_term,) = p.energy_terms, p.constraint_terms
    assert energy_term.coupling == ((True, False), (False, True))
    assert contact_term.coupling == ((True, True), (True, True))
    rng = np.random.default_rng(1)
    x = p.initial(0.05 * rng.standard_normal(p.ndofs))
    v = np.zeros(p.ndofs)
    v[p.free] = rng.standard_normal(p.free.size)
    eps = 1e-6
    fd = (p.gradient(x + eps * v) - p.gradient(x - eps * v)) / (2 * eps)
    Hv = p.hessian(x) @ v
    assert np.allclose(fd, Hv, rtol=1e-5, atol=1e-6 * np.abs(Hv).max())


def test_the_readme_example_runs_and_converges():
    import pathlib
    text = (pathlib.Path(__file__).parents[1] / "README.md").read_text()
    code = text.split("```python")[1].split("```")[0]
    scope = {}
    exec(compile(code, "README.md", "exec"), scope)
    result = scope["result"]
    assert result.converged and result.active_count > 0
    assert result.max_violation < 1e-2


def test_a_cell_measure_takes_its_fields_quadrature_also_for_tabulations_from_a_basis():
    """P2 Hessians (lap u) are tabulated from a scikit-fem basis; with the field's own
    quadrature order (intorder=5, 7 points) that basis uses the same points as the
    weights: the same J_h as with the order given to the measure."""
    mesh = MeshTri().refined(2)

    def solve(field_order, measure_order):
        u = ni.Field("u", mesh, ElementTriP2(), fixed="boundary", intorder=field_order)
        c = ni.Inequality(gap=lambda u: u + 0.01, multiplier=lambda u: -lap(u) - 1.0,
                          scaling=ni.Scaling(0.01, h_power=2, stiffness=1.0),
                          on=ni.cells(u, intorder=measure_order), name="c")
        p = ni.Problem([u], lambda u: 0.5 * dot(grad(u), grad(u)) - u, [c])
        assert all(t.nq == 7 for t in p.assembler.terms)
        return p.minimize().check().energy

    assert solve(5, None) == pytest.approx(solve(5, 5), rel=1e-13)


@pytest.mark.parametrize("inequality", [True, False])
@pytest.mark.parametrize("shift", [-0.3, 0.0, 0.5])  # violated somewhere, touching, nowhere
def test_constraint_report_locates_the_largest_violation_as_the_full_arrays_did(inequality, shift):
    """report_constraints finds the most violated point without full-size temporaries:
    the same point, violation, limit and flag as max(-g, 0) (|g| for equalities) and
    alpha lambda over all points (the first point when nothing is violated)."""
    from types import SimpleNamespace
    from nitsche.problem import report_constraints
    rng = np.random.default_rng(5)
    g = rng.random((40, 6)) + shift
    if shift == 0.0:
        g[7, 1] = 0.0  # touching: no violation
    lam, alpha, W = rng.normal(size=(40, 6)), rng.random((40, 6)) * 1e-2, rng.random((40, 6))
    values = {"c": dict(g=g, lam=lam, alpha=alpha, multiplier=np.maximum(lam - g / alpha, 0), W=W)}
    c = SimpleNamespace(name="c", kind="inequality" if inequality else "equality",
                        inequality=inequality, gap_names=["u"],
                        projection=SimpleNamespace(frictional=False))
    alpha0, u = rng.random(40) * 1e-2, rng.normal(size=10)
    rep = report_constraints([c], values, {"u": u}, {"c": alpha0}, {"c": np.ones(40)})["c"]
    violation = np.maximum(-g, 0.0) if inequality else np.abs(g)  # the full arrays, as before
    worst = np.unravel_index(np.argmax(violation), violation.shape)
    assert (worst == (0, 0)) == (inequality and shift >= 0)
    limit = min(0.5, 50 * float(alpha0[worst[0]])) * float(np.abs(u).max())
    consistency = 2 * float(np.abs((alpha * lam)[worst]))
    assert rep["max_violation"] == float(violation[worst]) and rep["violation_limit"] == limit
    assert rep["infeasible"] == bool(violation[worst] > limit and violation[worst] > consistency)


@pytest.mark.parametrize("inequality", [True, False])
@pytest.mark.parametrize("shift", [-0.3, 0.0, 0.5])  # violated somewhere, touching, nowhere
def test_constraint_report_from_pieces_equals_the_whole_report(inequality, shift):
    """report_constraints on pieces of the elements (as MPI ranks hold them: one without
    elements, each knowing part of the dofs) with their statistics gathered equals the
    report on all elements: counts, maxima, the most violated point, its limit and flag
    exactly, the sums to 1e-14, alpha0's statistics exactly."""
    from types import SimpleNamespace
    from nitsche.problem import constraint_statistics, report_constraints
    rng = np.random.default_rng(7)
    g = rng.random((40, 6)) + shift
    g[3, 2] = g[31, 4] = g.min() if shift < 0 else g[3, 2]  # a tie across pieces: the first wins
    lam, alpha, W = rng.normal(size=(40, 6)), rng.random((40, 6)) * 1e-2, rng.random((40, 6))
    values = dict(g=g, lam=lam, alpha=alpha, multiplier=np.maximum(lam - g / alpha, 0), W=W)
    c = SimpleNamespace(name="c", kind="inequality" if inequality else "equality",
                        inequality=inequality, gap_names=["u"],
                        projection=SimpleNamespace(frictional=False))
    alpha0, limits, u = rng.random(40) * 1e-2, rng.random(40), rng.normal(size=10)
    whole = report_constraints([c], {"c": values}, {"u": u}, {"c": alpha0}, {"c": limits})["c"]
    cuts = [slice(0, 0), slice(0, 17), slice(17, 40)]  # rank 0 without elements
    known = [u * (np.arange(10) < 3), u * (np.arange(10) >= 3), u * (np.arange(10) >= 8)]
    pieces = [constraint_statistics(c, {k: a[s] for k, a in values.items()}, {"u": uk},
                                    alpha0[s], limits[s]) for s, uk in zip(cuts, known)]
    for rank, (s, uk) in enumerate(zip(cuts, known)):
        part = report_constraints([c], {"c": {k: a[s] for k, a in values.items()}}, {"u": uk},
                                  {"c": alpha0[s]}, {"c": limits[s]}, gather=lambda _: pieces)["c"]
        assert part.keys() == whole.keys()
        for k, v in whole.items():
            assert part[k] == (pytest.approx(v, rel=1e-14) if k in ("contact_measure", "total_multiplier")
                               else v), (rank, k)
    if inequality and shift < 0:
        assert whole["active_count"] > 0 and whole["max_violation"] == -g[3, 2]
