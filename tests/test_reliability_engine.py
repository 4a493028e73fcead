"""Honest results from the API (issue 10): compiled kernels follow everything a density
reads, non-finite ingredients are errors that name them, the scaling is honoured and not
mutated, stability limits for normals, constant multipliers and singular energies,
reproducible eigenvalue estimates."""
import warnings

import jax.numpy as jnp
import numpy as np
import pytest
import scipy.sparse as sp
from skfem import MeshTri, ElementTriP1, ElementTriP2

import nitsche as ni
from nitsche import assembly, stability
from nitsche.assembly import fingerprint
from nitsche.conditioning import condition_number
from nitsche.ops import dot, grad, lap

STIFFNESS = 1.0  # module globals read by the densities below, changed by the tests
SOURCE = np.array([1.0])


def flux(u, n):
    """A helper the multiplier calls: the global it reads must key the kernel too."""
    return STIFFNESS * dot(grad(u), n)


energy_of_globals = lambda u: 0.5 * STIFFNESS * dot(grad(u), grad(u)) - u.value * SOURCE[0]


def poisson(level=3):
    mesh = MeshTri().refined(level)
    return ni.Field("u", mesh, ElementTriP1(), fixed="boundary")


# -- 1. compiled kernels ---------------------------------------------------------------

def test_a_module_global_read_by_the_energy_recompiles_and_an_unchanged_one_does_not():
    global STIFFNESS
    energies = []
    for STIFFNESS in (1.0, 4.0):
        energies.append(ni.Problem([poisson()], energy_of_globals).minimize().check().energy)
    fresh = ni.Problem([poisson()], lambda u: 0.5 * 4.0 * dot(grad(u), grad(u)) - u).minimize()
    assert energies[1] == pytest.approx(fresh.energy, rel=1e-12)
    assert energies[1] == pytest.approx(energies[0] / 4, rel=1e-12)  # u = u_1 / k, J = J_1 / k
    compiled, seconds = len(assembly._COMPILED), assembly.compile_seconds[0]
    again = ni.Problem([poisson()], energy_of_globals).minimize().check()
    assert again.energy == energies[1]
    assert len(assembly._COMPILED) == compiled and assembly.compile_seconds[0] == seconds
    STIFFNESS = 1.0


def dirichlet_by_nitsche(alpha0="auto"):
    """Pure Neumann Poisson with u = 0 by Nitsche on all boundary facets; the multiplier
    -k du/dn uses the normal and, through flux(), the global k."""
    u = ni.Field("u", MeshTri().refined(2), ElementTriP1())
    c = ni.Equality(lambda u: u.value, lambda u, n: -flux(u, n), ni.Scaling(alpha0, 1),
                    ni.facets(u), name="dirichlet")
    return ni.Problem([u], energy_of_globals, [c])


def test_stability_limits_follow_globals_read_by_called_functions_and_work_with_normals():
    global STIFFNESS
    limits, local = [], []
    for STIFFNESS in (1.0, 4.0):
        p = dirichlet_by_nitsche()
        local.append(p.alpha0_limits["dirichlet"])  # the smallest element-local limit
        # after the Problem released its measures' bases (item 4: AttributeError 'normals')
        limits.append(p.stability_limits()["dirichlet"])
        assert local[-1] <= limits[-1] * (1 + 1e-10)
    STIFFNESS = 1.0
    assert 0.3 < limits[0] < 0.55
    assert limits[1] == pytest.approx(limits[0] / 4, rel=1e-8)  # B ~ k^2, K ~ k
    assert local[1] == pytest.approx(local[0] / 4, rel=1e-8)


def test_fingerprint_of_recursive_functions_and_of_arrays_read_as_globals():
    namespace = {}
    exec("def even(n):\n    return True if n == 0 else odd(n - 1)\n"
         "def odd(n):\n    return False if n == 0 else even(n - 1) and LEVEL > 0\n"
         "LEVEL = 1", namespace)
    key = fingerprint(namespace["even"])
    assert key == fingerprint(namespace["even"])
    namespace["LEVEL"] = 2
    assert fingerprint(namespace["even"]) != key
    before = fingerprint(energy_of_globals)
    SOURCE[0] = 2.0  # changed in place: arrays are keyed by value
    try:
        assert fingerprint(energy_of_globals) != before
    finally:
        SOURCE[0] = 1.0
    assert fingerprint(energy_of_globals) == before


# -- 2. non-finite ingredients ---------------------------------------------------------

def obstacle_problem(gap=None, multiplier=None, alpha0=0.1, energy=None):
    u = poisson()
    psi = lambda x: jnp.where(x[0] > 0.75, jnp.nan, -0.1)
    contact = ni.Inequality(gap or (lambda u, x: u - psi(x)), multiplier or (lambda u: -lap(u) - 1.0),
                            ni.Scaling(alpha0, 2), ni.cells(u), name="contact")
    energy = energy or (lambda u: 0.5 * dot(grad(u), grad(u)) + u)
    return ni.Problem([u], energy, [contact], alpha0_limits={"contact": 1.0})


def test_a_nan_gap_is_an_error_that_names_it():
    """Today [lambda - NaN/alpha]_+ = 0 switches the constraint off there and Newton
    reports convergence with max_violation NaN."""
    p = obstacle_problem()
    x = p.initial(None)
    message = r"the gap g of constraint 'contact' is NaN at \d+ of \d+ quadrature points, e\.g\. x = \(0\.[89]"
    with pytest.raises(ValueError, match=message):
        p.check_finite(x)
    with pytest.raises(ValueError, match=message):
        p.constraint_values(x)
    with pytest.raises(ValueError, match="gap g of constraint 'contact' is NaN"):
        p.minimize()


def test_a_nan_gap_makes_j_h_nan_where_the_projection_would_hide_it():
    """[lambda - NaN/alpha]_+ = 0 would switch the constraint off (J_h finite); the density's
    check makes J_h NaN there (Newton's first system then names the gap), without a
    derivative: the gradient stays that of the other parts."""
    p = obstacle_problem()
    x = p.initial(None)
    E, g = p.assembler.gradient(x)
    assert np.isnan(E) and np.isnan(p.energy(x)) and np.all(np.isfinite(g))
    finite = obstacle_problem(gap=lambda u, x: u - jnp.where(x[0] > 0.75, 0.5, -0.1))
    assert np.isfinite(finite.energy(x))


def test_a_nan_multiplier_is_an_error_that_names_it():
    p = obstacle_problem(gap=lambda u: u.value + 0.1,
                         multiplier=lambda u, x: -lap(u) + jnp.where(x[1] < 0.2, jnp.nan, 0.0))
    with pytest.raises(ValueError, match="the multiplier lambda of constraint 'contact' is NaN"):
        p.check_finite(p.initial(None))


def test_overflow_with_finite_ingredients_says_which_term_and_why():
    tiny = obstacle_problem(gap=lambda u: u.value - 0.1, alpha0=1e-300)  # active: g < 0
    x = tiny.initial(None)
    tiny.check_finite(x)  # every ingredient is finite
    assert tiny.non_finite(x).startswith("constraint 'contact': alpha (g/alpha)^2 overflows")
    assert "alpha0 too small" in tiny.non_finite(x)
    with pytest.raises(ValueError, match="alpha0 too small"):
        tiny.minimize()
    load = obstacle_problem(gap=lambda u: u.value + 0.1, multiplier=lambda u: -lap(u) - 1e300)
    assert "alpha lambda^2 overflows (|lambda| up to 1.0e+300)" in load.non_finite(x)
    assert obstacle_problem(gap=lambda u: u.value + 0.1).non_finite(x) == "J_h and its gradient are finite"
    big = obstacle_problem(gap=lambda u: u.value + 0.1,
                           energy=lambda u: 1e300 * dot(grad(u), grad(u)) ** 2)
    x[big.free] = 1e40
    assert big.non_finite(x) == "the energy density overflows: check the magnitudes of the loads/parameters"


# -- 3. the scaling ----------------------------------------------------------------------

def test_a_fractional_h_power_is_honoured_and_a_bad_one_refused():
    u = poisson(2)
    c = ni.Inequality(lambda u: u.value + 0.1, lambda u: -lap(u), ni.Scaling(0.01, 1.5, 2.0),
                      ni.cells(u), name="contact")
    p = ni.Problem([u], lambda u: 0.5 * dot(grad(u), grad(u)), [c], alpha0_limits={"contact": 1.0})
    h = p.constraint_terms[0].h
    alpha = p.constraint_values(p.initial(None))["contact"]["alpha"]
    assert np.allclose(alpha, (0.01 * h ** 1.5 / 2.0)[:, None], rtol=1e-14)
    for bad in (-1, float("nan"), float("inf"), "two"):
        with pytest.raises(ValueError, match="h_power"):
            ni.Scaling(0.1, bad)


def test_auto_alpha0_is_resolved_per_problem_without_changing_the_users_scaling():
    u = ni.Field("u", MeshTri().refined(3), ElementTriP2(), fixed="boundary")
    scaling = ni.Scaling("auto", 2)
    contact = ni.Inequality(lambda u: u.value + 0.01, lambda u: -lap(u) - 1.0, scaling,
                            ni.cells(u), name="contact")
    energy = lambda u: 0.5 * dot(grad(u), grad(u)) + u
    first = ni.Problem([u], energy, [contact])
    assert scaling.alpha0 == "auto" and contact.scaling is scaling
    resolved = first.alpha0["contact"]
    assert np.allclose(resolved, np.minimum(0.5 * first.limits["contact"], 0.1))
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # today: "alpha0 = ... exceeds ...; use alpha0='auto'"
        second = ni.Problem([u], energy, [contact], alpha0_limits={"contact": 0.5 * resolved.min()})
    assert scaling.alpha0 == "auto"
    assert np.allclose(second.alpha0["contact"], 0.25 * resolved.min())
    result = second.minimize().check()
    assert result.constraints["contact"]["alpha0"] == pytest.approx(0.25 * resolved.min())


# -- 4. and 5. normals, constant multipliers -------------------------------------------------

def test_a_constraint_with_a_normal_multiplier_serves_a_second_problem():
    """Its facet measure's bases were released by the first Problem (today AttributeError
    on 'normals'), its Scaling('auto') is resolved again (today the first alpha0 is kept)."""
    first = dirichlet_by_nitsche()
    (c,) = first.constraints
    user = ni.Equality(c.gap, c.multiplier, ni.Scaling("auto", 1), c.on, name="dirichlet")
    limits = [ni.Problem(first.fields, energy_of_globals, [user]).alpha0_limits["dirichlet"]
              for _ in range(2)]
    assert limits[0] == limits[1] == pytest.approx(first.alpha0_limits["dirichlet"], rel=1e-10)
    assert user.scaling.alpha0 == "auto"


def constant_multiplier_problem(multiplier):
    u = poisson(2)
    contact = ni.Inequality(lambda u, x: u - 0.05 * jnp.sin(3 * x[0]) + 0.02, multiplier,
                            ni.Scaling("auto", 2), ni.cells(u, intorder=4), name="contact")
    return ni.Problem([u], lambda u: 0.5 * dot(grad(u), grad(u)) - u, [contact])


@pytest.mark.parametrize("multiplier", [lambda: 2.0, lambda x: 1.0 + x[0] ** 2])
def test_a_constant_multiplier_is_accepted_with_exact_derivatives(multiplier):
    p = constant_multiplier_problem(multiplier)
    assert p.alpha0_limits == {"contact": np.inf} and p.stability_limits() == {"contact": np.inf}
    assert np.all(p.alpha0["contact"] == 0.1)
    rng = np.random.default_rng(2)
    x = p.initial(0.1 * rng.standard_normal(p.ndofs))
    v = p.constraint_values(x)["contact"]
    # J_h = J + sum W (-1/2 alpha q^2 + 1/2 alpha [q - g/alpha]_+^2): the first part is constant
    nitsche = np.sum(v["W"] * (-0.5 * v["alpha"] * v["lam"] ** 2
                               + 0.5 * v["alpha"] * np.maximum(v["lam"] - v["g"] / v["alpha"], 0) ** 2))
    J = p.assembler.energy(x, terms=p.energy_terms)
    assert p.energy(x) == pytest.approx(J + nitsche, rel=1e-12)
    assert v["active"].any() and (~v["active"]).any()
    d = np.zeros(p.ndofs)
    d[p.free] = rng.standard_normal(p.free.size)
    eps = 1e-6
    assert (p.energy(x + eps * d) - p.energy(x - eps * d)) / (2 * eps) == pytest.approx(p.gradient(x) @ d, rel=1e-6)
    Hd = p.hessian(x) @ d
    fd = (p.gradient(x + eps * d) - p.gradient(x - eps * d)) / (2 * eps)
    assert np.allclose(fd, Hd, rtol=1e-5, atol=1e-6 * np.abs(Hd).max())
    assert p.minimize().check().active_count > 0


# -- 6. singular energy Hessians ----------------------------------------------------------

def neumann_problem(alpha0):
    """No Dirichlet condition: K is singular on constants, where lambda = u is not zero."""
    u = ni.Field("u", MeshTri().refined(2), ElementTriP1())
    contact = ni.Inequality(lambda u: u.value - 0.1, lambda u: u.value, ni.Scaling(alpha0, 1),
                            ni.facets(u, lambda x: x[1] < 1e-9), name="contact")
    return ni.Problem([u], lambda u: 0.5 * dot(grad(u), grad(u)) - u, [contact])


def test_auto_alpha0_on_a_singular_energy_hessian_is_a_clear_error():
    """The element-local check: on every cell lambda = u sees the constants, where the
    cell's energy vanishes.  The global diagnostic says the same of the whole mesh."""
    with pytest.raises(ValueError, match="alpha0='auto' for constraint 'contact': on 4 of its "
                                         "elements the energy of the cell does not bound the "
                                         "multiplier.*give alpha0 as a number"):
        neumann_problem("auto")
    with pytest.warns(ni.StabilityWarning, match="not checked against a stability limit"):
        p = neumann_problem(0.1)
    assert p.alpha0_limits["contact"] == 0
    with pytest.raises(ValueError, match="no stability limit of alpha0: the energy Hessian"):
        p.stability_limits()


@pytest.mark.parametrize("dense_limit", [0, 3000])
def test_largest_generalized_eigenvalue_tells_a_singular_k_from_a_harmless_kernel(dense_limit, monkeypatch):
    monkeypatch.setattr(stability, "DENSE_LIMIT", dense_limit)
    K = sp.diags([0.0, 1.0, 2.0, 3.0, 4.0, 5.0]).tocsr()
    harmless = sp.diags([0.0, 3.0, 2.0, 0.0, 0.0, 1.0]).tocsr()  # B = 0 on the kernel of K
    assert stability.largest_generalized_eigenvalue(harmless, K) == pytest.approx(3.0, rel=1e-3)
    for B, K_ in [(sp.diags([1.0, 0, 0, 0, 0, 0]).tocsr(), K),  # B > 0 on the kernel
                  (harmless, sp.csr_matrix((6, 6))),  # K = 0
                  (harmless, sp.diags([1.0, -3.0, 1.0, 1.0, 1.0, 1.0]).tocsr())]:  # indefinite
        with pytest.raises(stability.SingularEnergy):
            stability.largest_generalized_eigenvalue(B, K_)


# -- 7. reproducible estimates ------------------------------------------------------------

def test_arpack_estimates_are_reproducible():
    n = 400
    A = sp.diags([-np.ones(n - 1), 2.0 + np.linspace(0, 1, n), -np.ones(n - 1)], [-1, 0, 1]).tocsr()
    runs = [condition_number(A, dense_limit=10, tol=1e-2) for _ in range(3)]
    assert runs[0] == runs[1] == runs[2]
    N = A + sp.diags([0.5 * np.ones(n - 1)], [1])
    assert condition_number(N, dense_limit=10, tol=1e-2) == condition_number(N, dense_limit=10, tol=1e-2)


def test_the_condition_number_is_that_of_the_non_zero_entries_and_leaves_the_matrix_alone():
    """A Newton matrix's structure holds exact zeros (inactive terms): nonzero_entries is
    the matrix without them (as eliminate_zeros, also for empty rows and an empty matrix),
    copies only the non-zero entries and leaves its argument as it was."""
    from nitsche.conditioning import nonzero_entries
    n = 300
    A = sp.diags([-np.ones(n - 1), 2.0 + np.linspace(0, 1, n), -np.ones(n - 1)], [-1, 0, 1]).tocsr()
    Z = A.copy()
    Z.data[np.random.default_rng(0).random(Z.nnz) < 0.3] = 0.0  # explicit zeros,
    Z.data[Z.indptr[7]:Z.indptr[9]] = 0.0  # rows 7 and 8 with nothing but zeros
    before = (Z.data.copy(), Z.indices.copy(), Z.indptr.copy())
    B, C = nonzero_entries(Z), Z.copy()
    C.eliminate_zeros()
    assert B.nnz == C.nnz < Z.nnz and np.array_equal(B.indptr, C.indptr)
    assert np.array_equal(B.indices, C.indices) and np.array_equal(B.data, C.data)
    assert all(np.array_equal(a, b) for a, b in zip(before, (Z.data, Z.indices, Z.indptr)))
    assert nonzero_entries(sp.csr_matrix((4, 4))).indptr.tolist() == [0] * 5
    full = A.copy()
    full.data[::7] = 0.0
    kept = full.copy()
    kept.eliminate_zeros()
    assert condition_number(full, dense_limit=10, tol=1e-2) == condition_number(kept, dense_limit=10, tol=1e-2)


def test_a_global_limit_of_a_multiplier_not_differentiable_at_the_start_is_a_clear_error():
    """|grad u| has no derivative at u = 0 (JAX gives NaN): the global stability limit
    (--global-check) names the constraint instead of failing inside the eigensolver."""
    u = poisson()
    c = ni.Inequality(lambda u: u.value + 1.0, lambda u: jnp.sqrt(dot(grad(u), grad(u))),
                      ni.Scaling(0.1, 1), ni.cells(u), name="rooted")
    problem = ni.Problem([u], lambda u: 0.5 * dot(grad(u), grad(u)) - u, [c])
    with pytest.raises(ValueError, match="constraint 'rooted'.*not finite at the initial state"):
        problem.stability_limits()
