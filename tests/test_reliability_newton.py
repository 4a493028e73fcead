"""Newton's honesty: checked options, minima only, round-off scales, unbounded problems."""
import numpy as np
import pytest
import scipy.sparse as sp
from skfem import MeshTri, ElementTriP1, ElementTriP2

import nitsche as ni
from nitsche.linalg import HAVE_CHOLMOD, Cholmod, IndefiniteHessian, semidefinite_difference
from nitsche.ops import dot, grad, lap

SOLVERS = ["cholmod", "superlu", "amg"] if HAVE_CHOLMOD else ["superlu", "amg"]


def membrane(fixed="boundary"):
    return ni.Field("u", MeshTri().refined(3), ElementTriP1(), fixed=fixed)


def two_membranes(d):
    """Two membranes pressed together by f1 = 1, f2 = -1 across the gap d (the case's J_h, P1)."""
    mesh = MeshTri().refined(2)
    u1 = ni.Field("u1", mesh, ElementTriP1(), fixed="boundary")
    u2 = ni.Field("u2", mesh, ElementTriP1(), fixed="boundary")
    energy = lambda u1, u2: (0.5 * dot(grad(u1), grad(u1)) + dot(grad(u2), grad(u2)) - u1 + u2)
    contact = ni.Inequality(lambda u1, u2: u2 + d - u1, lambda u1: 1.0 + lap(u1),
                            ni.Scaling(0.1, 2), ni.cells(u1, intorder=4))
    return ni.Problem([u1, u2], energy, [contact], alpha0_limits={"contact": np.inf})


# -- 1. options --------------------------------------------------------------------

@pytest.mark.parametrize("option,value", [("maxiter", -1), ("maxiter", 2.5), ("maxiter", True),
                                          ("rtol", 10.0), ("rtol", 0.0), ("rtol", 1.0),
                                          ("rtol", float("nan")), ("rtol", "1e-8"),
                                          ("solver", "magic"), ("solver", None),
                                          ("reduction", 1.0), ("reduction", "0.1")])
def test_bad_newton_options_are_one_line_errors_naming_the_option(option, value):
    p = ni.Problem([membrane()], lambda u: 0.5 * dot(grad(u), grad(u)) - u)
    with pytest.raises(ValueError, match=rf"^{option} .*must be") as e:
        p.minimize(**{option: value})
    assert "\n" not in str(e.value)


def test_good_newton_options_still_run():
    p = ni.Problem([membrane()], lambda u: 0.5 * dot(grad(u), grad(u)) - u)
    assert p.minimize(maxiter=np.int64(5), rtol=0.5).converged
    r = p.minimize(maxiter=0)
    assert not r.converged and "iteration limit 0" in r.reason


def test_a_reduction_stops_at_that_fraction_of_the_first_residual():
    """newton(reduction=q) stops at the first residual <= q r_0, or at rtol where that comes
    first, and says which."""
    p = two_membranes(d=0.05)
    full = p.minimize()
    for q in (1e-1, 1e-3):
        r = p.minimize(reduction=q)
        assert r.converged and r.residuals[-1] <= q * r.residuals[0] < r.residuals[-2], r.residuals
        assert r.iterations < full.iterations and "of the first" in r.reason
    assert p.minimize(reduction=1e-12).iterations == full.iterations  # rtol comes first


# -- 2. a converged minimization is a minimum -------------------------------------------

@pytest.mark.parametrize("solver", SOLVERS)
def test_a_double_well_started_at_its_saddle_is_not_converged(solver):
    u = membrane(fixed=None)
    energy = lambda u: (u.value ** 2 - 1) ** 2 + 1e-3 * dot(grad(u), grad(u))
    r = ni.minimize(energy, [u], solver=solver)  # u = 0: grad J = 0, Hessian -4 M + 2e-3 K
    assert r.iterations == 0 and not r.converged
    assert r.reason.startswith("stationary point that is not a minimum")
    assert "start elsewhere" in r.reason
    with pytest.raises(ni.NotConverged):
        r.check()
    # from a point off the saddle Newton finds a minimum (u = +-1) and says so
    u = membrane(fixed=None)
    r = ni.minimize(energy, [u], x0=np.full(u.ndofs, 0.8), solver=solver)
    assert r.converged and np.allclose(r.x, 1.0)


@pytest.mark.parametrize("solver", SOLVERS)
def test_an_indefinite_hessian_takes_convexified_steps_to_a_minimum(solver):
    """From u = 0.2 (J'' = 12 u^2 - 4 < 0 on the whole mesh) Newton's own step points to the
    saddle; shifted steps A + tau diag|A| (inertia correction) reach the well at u = 1."""
    u = membrane(fixed=None)
    energy = lambda u: (u.value ** 2 - 1) ** 2 + 1e-3 * dot(grad(u), grad(u))
    r = ni.minimize(energy, [u], x0=np.full(u.ndofs, 0.2), solver=solver)
    assert r.converged and np.allclose(r.x, 1.0), r.reason
    assert len(r.shifts) >= 1 and all(t > 0 for t in r.shifts)
    assert "convexified steps" in r.report()
    # a convex problem takes none
    assert ni.minimize(lambda u: 0.5 * dot(grad(u), grad(u)) - u, [membrane()], solver=solver).shifts == []


@pytest.mark.skipif(not HAVE_CHOLMOD, reason="scikit-sparse is not installed")
def test_cholmod_rejects_an_indefinite_matrix_also_in_simplicial_ldlt():
    A = sp.csc_matrix(np.array([[-2.0, 0.5], [0.5, 1.0]]))
    with pytest.raises(IndefiniteHessian):
        Cholmod().solve(A, np.ones(2))
    assert not Cholmod().is_positive_definite(A)


@pytest.mark.skipif(not HAVE_CHOLMOD, reason="scikit-sparse is not installed")
def test_positive_definiteness_from_the_factor_or_a_new_factorization():
    n = 200
    F = sp.diags([np.full(n - 1, -1.0), np.full(n, 2.1), np.full(n - 1, -1.0)], [-1, 0, 1]).tocsc()
    lin = Cholmod()
    lin.solve(F, np.ones(n))
    assert lin.is_positive_definite(F) and lin.factorizations == 1  # the factor of F itself
    for shift in (-0.05, -3.0):
        A = (F + sp.diags(np.where(np.arange(n) == 20, shift, 0.0))).tocsc()
        assert lin.is_positive_definite(A) == (np.linalg.eigvalsh(A.toarray()).min() > 0)
    assert lin.factorizations == 2  # -0.05: factored; -3.0: the factorization failed


@pytest.mark.skipif(not HAVE_CHOLMOD, reason="scikit-sparse is not installed")
def test_a_semidefinite_change_of_the_factored_matrix_needs_no_factorization():
    """A = F + D: with D positive semidefinite (rank-one changes, as a point entering the
    active set makes) A is positive definite without a new factorization; an indefinite D
    (however small its negative part) is decided by factoring A."""
    n, rng = 300, np.random.default_rng(4)
    F = sp.diags([np.full(n - 1, -1.0), np.full(n, 2.001), np.full(n - 1, -1.0)], [-1, 0, 1]).tocsc()
    F.sort_indices()  # as the engine's patterns
    lin = Cholmod()
    lin.solve(F, np.ones(n))

    def changed(signs):  # F + sum_i s_i w_i w_i^T, w_i on 3 neighbouring dofs (F's pattern)
        D = sp.csc_matrix((n, n))
        for s in signs:
            i = rng.integers(1, n - 2)
            w = sp.csc_matrix((rng.normal(size=2), ([i, i + 1], [0, 0])), shape=(n, 1))
            D = D + s * (w @ w.T)
        A = (F + D).tocsc()
        A.sort_indices()  # as the engine's patterns
        return A
    for signs, factors in (([1.0] * 5, 0), ([1.0] * 5 + [-1e-9], 1), ([1.0, -5.0], 1)):
        before = lin.factorizations
        A = changed(signs)
        assert A.nnz == F.nnz  # the same pattern
        assert lin.is_positive_definite(A) == (np.linalg.eigvalsh(A.toarray()).min() > 0)
        assert lin.factorizations - before <= factors
    assert semidefinite_difference(F.copy(), F) and not semidefinite_difference(F - 1e-8 * sp.eye(n, format="csc"), F)
    assert not semidefinite_difference(sp.eye(n, format="csc"), F)  # another pattern, a large change
    w = sp.csc_matrix(([1.0, 1.0], ([0, 5], [0, 0])), shape=(n, 1))  # (0, 5): outside F's pattern
    for sign in (1.0, -1e-3):  # a pattern grown by a small change: tested, as on one pattern
        G = (F + sign * (w @ w.T)).tocsc()
        G.sort_indices()
        assert G.nnz > F.nnz and semidefinite_difference(G, F) == (sign > 0)
        assert not semidefinite_difference(G, F, zero=True)


def obstacle_problem(element=ElementTriP1(), energy=None, gap=None, multiplier="lap", theta=1,
                     measure=None):
    """A membrane over the obstacle psi = -0.05 under the load f = -1 (P1: J_h convex)."""
    u = ni.Field("u", MeshTri().refined(3), element, fixed="boundary")
    energy = energy or (lambda u: 0.5 * dot(grad(u), grad(u)) + u)
    lam = {"lap": lambda u: -1.0 - lap(u), "none": None, "value": lambda u: -u.value}[multiplier]
    gap = gap or (lambda u: u + 0.05)
    contact = ni.Inequality(gap, lam, ni.Scaling(0.1, 2), measure or ni.cells(u), theta=theta) \
        if lam is not None else ni.Penalty(gap, ni.Scaling(0.1, 2), measure or ni.cells(u))
    return ni.Problem([u], energy, [contact], alpha0_limits={"contact": np.inf})


def test_convexity_is_certified_term_by_term():
    """Problem.convex: convex quadratic energy terms (d2w/dz2 one positive semidefinite
    matrix, weights >= 0) and constraints with D lambda = 0 and an affine gap.  Anything it
    cannot show is not certified (and then the Hessian is checked)."""
    assert obstacle_problem().convex  # lambda = -1 - lap u, lap of P1 = 0
    assert obstacle_problem(multiplier="none").convex  # a penalty
    assert not obstacle_problem(ElementTriP2()).convex  # lap of P2 depends on u
    assert not obstacle_problem(multiplier="value").convex  # D lambda != 0
    assert not obstacle_problem(gap=lambda u: u + 0.05 - u.value ** 2).convex  # g not affine
    assert not obstacle_problem(theta=0).convex  # a residual
    assert not obstacle_problem(energy=lambda u: 0.5 * dot(grad(u), grad(u)) - 2 * u.value ** 2).convex
    assert not obstacle_problem(energy=lambda u: 0.5 * dot(grad(u), grad(u)) + u.value ** 4).convex
    # a coefficient varying in x: D differs from point to point (not shown, conservatively)
    assert not obstacle_problem(energy=lambda u, x: (1 + x[0] ** 2) * dot(grad(u), grad(u))).convex
    # a quadrature with a negative weight: element Hessians need not be semidefinite
    u = ni.Field("u", MeshTri().refined(2), ElementTriP1(), fixed="boundary")
    X = np.array([[1 / 3, 0.2, 0.6, 0.2], [1 / 3, 0.2, 0.2, 0.6]])
    negative = ni.measures.Cells(u.mesh, quadrature=(X, np.array([-27, 25, 25, 25]) / 96))
    negative.attach(u)
    assert not ni.Problem([u], ni.Integral(lambda u: dot(grad(u), grad(u)), negative)).convex
    assert ni.Problem([u], ni.Integral(lambda u: dot(grad(u), grad(u)), ni.cells(u))).convex


@pytest.mark.parametrize("solver", SOLVERS)
def test_a_convex_j_h_is_a_minimum_without_the_hessians_test(solver, monkeypatch):
    """A converged run of a certified convex J_h says so (Result.minimum) and takes no
    factorization for it; the same run with the certificate withheld tests the Hessian,
    which is indeed positive definite there (dense eigenvalues), and reaches the same x."""
    p = obstacle_problem()
    r = p.minimize(solver=solver)
    assert r.converged and r.minimum == "J_h convex" and r.constraints["contact"]["active_count"] > 0
    H = p.hessian(r.x)[p.free][:, p.free].toarray()
    assert np.linalg.eigvalsh(H)[0] > 0
    monkeypatch.setattr(ni.Problem, "convex", property(lambda self: False))
    q = obstacle_problem()
    checked = q.minimize(solver=solver)
    assert checked.converged and checked.minimum == "Hessian positive definite"
    assert np.array_equal(checked.x, r.x) and checked.iterations == r.iterations
    if solver == "cholmod":
        assert checked.solver_stats["factorizations"] >= r.solver_stats["factorizations"]
    assert p.minimize(minimum_check=False).minimum == "not checked"


# -- 3. the solution is the initial guess ------------------------------------------------

def test_a_problem_solved_by_its_initial_guess_converges():
    p = two_membranes(d=0.0)  # the loads cancel across the contact: u1 = u2 = 0
    r = p.minimize()
    assert r.converged and r.iterations <= 1, r.reason
    assert np.abs(r.x).max() <= 1e-12


def test_the_stopping_test_of_a_normal_problem_is_unchanged():
    from nitsche.newton import residual_scale
    p = two_membranes(d=0.05)
    x_ref = p.initial(None)
    assert residual_scale(p, x_ref, 1e-10) == pytest.approx(np.linalg.norm(p.gradient(x_ref)[p.free]))
    r = p.minimize()
    assert r.converged and r.residuals[0] == pytest.approx(1.0) and r.residuals[-1] <= 1e-10


# -- 4. infeasible constraints -------------------------------------------------------------

def obstacle_above_the_boundary(degree, level=1, psi=0.3):
    """A membrane fixed at u = 0 on the boundary of (-2, 2)^2 over the obstacle psi > 0."""
    mesh = MeshTri.init_symmetric().scaled((4, 4)).translated((-2, -2)).refined(level + 2)
    u = ni.Field("u", mesh, ElementTriP1() if degree == 1 else ElementTriP2(), fixed="boundary")
    contact = ni.Inequality(lambda u: u - psi, lambda u: -lap(u), ni.Scaling("auto", 2),
                            ni.cells(u, intorder=2 * degree + 2))
    return ni.Problem([u], lambda u: 0.5 * dot(grad(u), grad(u)), [contact])


@pytest.mark.parametrize("degree", [1, 2])
def test_an_obstacle_above_the_boundary_values_is_flagged_infeasible(degree):
    p = obstacle_above_the_boundary(degree)
    with pytest.warns(ni.FeasibilityWarning, match="constraint 'contact' looks infeasible"):
        r = p.minimize()
    assert r.converged and not r.feasible and "INFEASIBLE: contact" in r.report()
    c = r.constraints["contact"]
    assert c["infeasible"] and c["max_violation"] > c["violation_limit"] > 0
    assert c["max_violation"] > 0.5 * 0.3  # psi - u = 0.3 at the boundary: not shrinking with h


def test_a_feasible_obstacle_is_not_flagged():
    p = obstacle_above_the_boundary(2, psi=-0.1)  # below the boundary values: no contact
    r = p.minimize()
    assert r.converged and r.feasible and not r.constraints["contact"]["infeasible"]


@pytest.mark.parametrize("name,degree", [("obstacle", 1), ("obstacle", 2), ("signorini", 1),
                                         ("signorini", 2), ("two-membrane", 2),
                                         ("elastic-contact", 1), ("dirichlet", 1)])
def test_the_shipped_cases_are_feasible_at_every_level(name, degree):
    import importlib
    import warnings
    from nitsche.case import Case
    case = Case(importlib.import_module("nitsche.cases." + name.replace("-", "_")))
    p = case.parameters()
    limits = case.alpha0_limits(degree, p)
    with warnings.catch_warnings():
        warnings.simplefilter("error", ni.FeasibilityWarning)
        results = [r for _, _, r in ni.nested(lambda k: case.problem(k, degree, p, limits), range(4))]
    assert len(results) == 4 and all(r.converged and r.feasible for r in results)
    for r in results[1:]:
        for c in r.constraints.values():  # with a margin: the largest violation is far below the limit
            assert not c["infeasible"] and c["max_violation"] < 0.5 * c["violation_limit"]


# -- 5. unbounded problems ------------------------------------------------------------------

@pytest.mark.parametrize("solver", SOLVERS)
@pytest.mark.parametrize("fixed,energy", [
    (None, lambda u: 0.5 * dot(grad(u), grad(u)) - u),   # no support: the constant is free
    ("boundary", lambda u: -u.value ** 4 - u),            # unbounded below, singular at 0
])
def test_an_unbounded_problem_says_it_looks_unbounded(solver, fixed, energy):
    r = ni.minimize(energy, [membrane(fixed)], solver=solver)
    assert not r.converged
    assert "looks unbounded below or singular" in r.reason
    assert "add supports" in r.reason
