"""Residual terms, the theta variants, Tresca and Coulomb friction (issue 13)."""
import numpy as np
import jax.numpy as jnp
import pytest

import nitsche as ni
from nitsche.cases import block_friction as cases
from nitsche.cases.block_friction import E, energy, gap, multiplier

ALPHA0 = 0.05


def block(law, theta, top=(0.02, -0.03), level=2, alpha0=ALPHA0, threshold=0.01):
    """The block-friction case's problem (an elastic unit square on rigid ground)."""
    return cases.block(law, theta, top, level, alpha0, threshold)


def random_state(problem, seed=0):
    """A random displacement, its history near it (slip increments of stick and slip size)."""
    rng = np.random.default_rng(seed)
    x = problem.initial(None)
    x[problem.free] = 0.03 * rng.standard_normal(problem.free.size)
    u = problem.split(x)["u"]
    problem.set_values("u_old", u + 0.003 * rng.standard_normal(u.size))
    return problem.initial(x)


def fd_jacobian(problem, x, eps=1e-7):
    cols = []
    for j in range(problem.ndofs):
        e = np.zeros(problem.ndofs)
        e[j] = eps
        cols.append((problem.gradient(x + e) - problem.gradient(x - e)) / (2 * eps))
    return np.array(cols).T


@pytest.mark.parametrize("kind,theta", [("inequality", 0), ("inequality", -1), ("tresca", 1),
                                        ("tresca", 0), ("tresca", -1), ("coulomb", 1),
                                        ("coulomb", 0), ("coulomb", -1)])
def test_residual_jacobian_matches_finite_differences(kind, theta):
    problem = block(kind, theta, threshold=0.05)
    assert problem.symmetric == (theta == 1 and kind != "coulomb")
    x = random_state(problem)
    states = problem.constraint_values(x)["contact"].get("state")
    if states is not None:  # the random state mixes stick, slip (and separation)
        assert {1, 2} <= set(np.unique(states))
    A = problem.hessian(x).toarray()
    assert np.abs(A - fd_jacobian(problem, x)).max() <= 1e-7 * np.abs(A).max()
    if theta != 1:
        assert np.abs(A - A.T).max() > 1e-6 * np.abs(A).max()  # non-symmetric indeed


def test_theta_one_residual_is_the_energy_gradient():
    """Tresca with theta = 1 is a functional; the residual r_1 written by hand as a pair
    (c, q) = ((-P(s), alpha (P(s) - lambda)), (g, lambda)) is its gradient."""
    problem = block("tresca", 1)
    u, old = problem.fields
    bottom = problem.constraints[0].on
    threshold = 0.01

    def pairs(u, u_old, n, x, h):
        alpha = ALPHA0 * h / E
        g, lam = gap(u, u_old, n, x), multiplier(u, n)
        s = lam - g / alpha
        t = s[1] * jnp.minimum(1.0, threshold / jnp.maximum(jnp.abs(s[1]), 1e-300))
        P = jnp.stack([jnp.maximum(s[0], 0.0), t])
        return jnp.concatenate([-P, alpha * (P - lam)]), jnp.concatenate([g, lam])

    by_hand = ni.Problem([u, old], [ni.Integral(energy, ni.cells(u)), ni.Residual(pairs, bottom)])
    assert problem.symmetric and not by_hand.symmetric
    for seed in range(3):
        x = random_state(problem, seed)
        by_hand.set_values("u_old", problem.split(x)["u_old"])
        g = problem.gradient(x)
        assert np.abs(by_hand.gradient(x) - g).max() <= 1e-12 * np.abs(g).max()
        A, B = problem.hessian(x), by_hand.hessian(x)
        assert abs(A - B).max() <= 1e-12 * abs(A).max()


@pytest.mark.parametrize("theta", [1, -1])
def test_tresca_full_slip_force_is_threshold_times_length(theta):
    """The top dragged far (full slip): friction force = s x contact length (= 1), the
    top's tangential reaction balancing it."""
    s = 0.01
    problem = block("tresca", theta, top=(0.2, -0.05), threshold=s)
    result = problem.minimize().check()
    rep = result.constraints["contact"]
    assert rep["kind"] == "tresca" and rep["stick_measure"] == 0.0
    assert rep["slip_measure"] + rep["separation_measure"] == pytest.approx(1.0, rel=1e-12)
    assert abs(rep["total_tangential_traction"][0]) == pytest.approx(s * 1.0, rel=1e-10)
    u = problem.by_name["u"]
    top_x = u.fixed_dofs[u.fixed_dofs % 2 == 0] + problem.offsets["u"]
    assert abs(problem.gradient(result.x)[top_x].sum()) == pytest.approx(s, rel=1e-8)
    assert result.solver == ("cholmod" if theta == 1 else "superlu")


@pytest.mark.parametrize("theta", [1, 0, -1])
def test_coulomb_block_converges_with_stick_and_slip(theta):
    problem = block("coulomb", theta)
    result = problem.minimize().check()
    assert result.solver == "superlu" and result.iterations < 30
    rep = result.constraints["contact"]
    assert rep["stick_measure"] + rep["slip_measure"] + rep["separation_measure"] == pytest.approx(1.0)
    assert rep["slip_measure"] > 0


def test_friction_errors_name_the_parameter():
    with pytest.raises(ValueError, match="friction"):
        ni.Coulomb(gap, multiplier, ni.Scaling(0.1, 1), None, friction=-1)
    with pytest.raises(ValueError, match="theta"):
        ni.Inequality(gap, multiplier, ni.Scaling(0.1, 1), None, theta="x")
    with pytest.raises(ValueError, match="gmres"):
        block("tresca", 1).minimize(solver="gmres")
    with pytest.raises(ValueError, match="residual terms"):
        block("coulomb", 1).minimize(solver="cholmod")


def test_gmres_solves_the_non_symmetric_system():
    result = block("coulomb", -1).minimize(solver="gmres").check()
    assert result.solver == "gmres"


def test_cattaneo_mindlin_stick_ratio(tmp_path):
    """nitsche run friction: c/a within a few per cent of sqrt(1 - Q/(F P)) (level 1: 2.1 %),
    the half-width within 3 % of Hertz's, the tangential load at Q_ratio F P."""
    import json
    from nitsche.cli import main
    out = tmp_path / "run"
    assert main(["run", "friction", "--level", "1", "--no-nested", "--out", str(out)]) == 0
    data = json.loads((out / "result.json").read_text())
    cm = data["cattaneo_mindlin"]
    assert data["stick_ratio"] == cm["stick_ratio"] and data["contact_half_width"] > 0
    assert cm["load_ratio"] == pytest.approx(0.5, rel=2e-3)
    assert abs(data["stick_ratio"] - cm["stick_ratio_reference"]) <= 0.03 * cm["stick_ratio_reference"]
    assert cm["error_half_width"] < 0.035
    rep = data["constraints"]["contact"]
    assert rep["kind"] == "coulomb" and rep["stick_measure"] > 0 and rep["slip_measure"] > 0
    assert data["solver"] == "superlu"
    assert (out / "friction_tractions.png").exists()


def test_vector_multiplier_stability_limits():
    """The tangential component adds to B: the global limit is at most the frictionless one."""
    friction, frictionless = block("coulomb", -1), block("inequality", 1)
    assert friction.stability_limits()["contact"] <= frictionless.stability_limits()["contact"]
    assert 0 < friction.alpha0_limits["contact"] <= frictionless.alpha0_limits["contact"]


def test_the_theta_study_is_a_figure_of_the_block_friction_case(tmp_path):
    """`nitsche run block-friction --set theta_study=true` (the paper index's entry) writes the
    sweep: theta = -1 converges for every alpha0 and stays accurate; theta = 1 fails or
    degrades beyond its stability limit (frictionless)."""
    import json
    from nitsche.cli import main
    assert main(["run", "block-friction", "--level", "1", "--set", "theta_study=true",
                 "--out", str(tmp_path)]) == 0
    rows = json.loads((tmp_path / "theta_study.json").read_text())["rows"]
    assert (tmp_path / "theta_study.png").stat().st_size > 10000
    assert len(rows) == 2 * 3 * 9
    minus = [r for r in rows if r["theta"] == -1]
    assert all(r["converged"] for r in minus)
    assert max(r["error"] for r in minus) < 3 * min(r["error"] for r in minus)
    plus = {r["alpha0"]: r for r in rows if r["theta"] == 1 and r["law"] == "inequality"}
    assert not plus[400]["converged"] or plus[400]["error"] > 2 * plus[1 / 400]["error"]
