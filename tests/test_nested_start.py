"""A nested level's first Newton step with the coarser level's active set, and the last step
factored so that the minimum check needs no factorization of its own."""
import numpy as np
import pytest

from nitsche.case import Case
from nitsche.cases import obstacle, two_membrane
from nitsche.linalg import HAVE_CHOLMOD, Cholmod
from nitsche.newton import factor_last
from nitsche.study import prolongate


def chain(module, level, **sets):
    """(coarse problem, its solution to 1e-12, the fine problem, the prolongated start)."""
    case = Case(module)
    p = case.parameters({k: str(v) for k, v in sets.items()})
    coarse, fine = case.problem(level - 1, 1, p), case.problem(level, 1, p)
    x = coarse.minimize(rtol=1e-12).x
    return coarse, fine, prolongate(coarse, x, fine)


def test_the_predicted_system_with_the_same_alpha_is_newtons():
    """kappa = 1 (ratio 1): the predicted density's active set is J_h's own, so its energy,
    gradient and Hessian are J_h's at any x."""
    _, fine, x0 = chain(two_membrane, 2)
    rng = np.random.default_rng(3)
    for x in (x0, x0 + 0.02 * rng.standard_normal(x0.size)):
        E, g, A = fine.newton_system(x)
        Ep, gp, Ap = fine.predicted_system(x, 1.0)
        assert abs(Ep - E) <= 1e-14 * abs(E)
        assert np.abs(gp - g).max() <= 1e-13 * np.abs(g).max()
        assert abs(Ap - A).max() <= 1e-13 * abs(A).max()


def test_the_predicted_active_set_is_the_coarser_levels():
    """Two membranes (P1, alpha = alpha0 h^2): the coarse solution interpolated penetrates by
    4x the fine alpha's depth, so J_h's own active set there misses points of the coarse
    contact set; the predicted density (kappa = 2^2) keeps them: its Hessian differs from
    J_h's, and the first step with it leaves a residual below a fifth of Newton's own."""
    _, fine, x0 = chain(two_membrane, 3)
    A, Ap = fine.newton_system(x0)[2], fine.predicted_system(x0, 2.0)[2]
    assert (Ap - A).diagonal().min() >= -1e-12 and (Ap - A).diagonal().max() > 0  # points added
    plain, predicted = fine.minimize(x0), fine.minimize(x0, coarse_ratio=2.0)
    assert plain.converged and predicted.converged
    assert predicted.residuals[1] < 0.2 * plain.residuals[1], (predicted.residuals, plain.residuals)
    assert predicted.iterations < plain.iterations
    assert abs(predicted.energy - plain.energy) <= 1e-12 * abs(plain.energy)


def test_the_obstacles_start_is_not_made_worse():
    """The obstacle (P1, flat obstacle): the contact pressure is about f everywhere on the
    contact set, so the start already has the fine active set; the prediction keeps it."""
    _, fine, x0 = chain(obstacle, 3)
    plain, predicted = fine.minimize(x0), fine.minimize(x0, coarse_ratio=2.0)
    assert predicted.converged and predicted.iterations <= plain.iterations
    assert abs(predicted.energy - plain.energy) <= 1e-12 * abs(plain.energy)


def test_factor_last_extrapolates_the_residuals_quadratically():
    class P:
        symmetric = True
    lin = Cholmod() if HAVE_CHOLMOD else type("L", (), {"checks_by_factor": True})()
    assert not factor_last(P, lin, True, [1e-4], 1e-10)  # no rate yet
    assert factor_last(P, lin, True, [1.2e-4, 2.8e-7], 1e-10)  # 2.8e-7^3 / 1.2e-4^2 = 1.5e-12
    assert not factor_last(P, lin, True, [2.2e-3, 1.2e-4], 1e-10)  # 3.6e-7
    assert not factor_last(P, lin, False, [1.2e-4, 2.8e-7], 1e-10)  # no minimum check: CG
    assert not factor_last(P, object(), True, [1.2e-4, 2.8e-7], 1e-10)  # a solver that cannot reuse


@pytest.mark.skipif(not HAVE_CHOLMOD, reason="scikit-sparse is not installed")
def test_the_minimum_check_after_a_factored_last_step_costs_no_factorization(monkeypatch):
    """Two membranes from the coarser level's solution: the last step is factored, and the
    minimum check at the solution (the same active set) reuses that factorization."""
    _, fine, x0 = chain(two_membrane, 4)
    counts = []
    check = Cholmod.is_positive_definite

    def counted(self, A):
        before = self.factorizations
        try:
            return check(self, A)
        finally:
            counts.append(self.factorizations - before)
    monkeypatch.setattr(Cholmod, "is_positive_definite", counted)
    result = fine.minimize(x0, coarse_ratio=2.0, solver="cholmod")
    assert result.converged and counts == [0], (counts, result.residuals)
