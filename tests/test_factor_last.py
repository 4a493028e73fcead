"""The likely last Newton step factored where the minimum check would factor anyway, so that
the check reuses that factorization instead of the last CG solve."""
import pytest

from nitsche.case import Case
from nitsche.cases import obstacle, two_membrane
from nitsche.linalg import HAVE_CHOLMOD, Cholmod
from nitsche.newton import factor_last
from nitsche.study import prolongate


def test_factor_last_extrapolates_the_residuals_quadratically():
    class P:
        symmetric = True

    class Solver:
        def __init__(self, factors):
            self.check_factors = lambda A: factors
    lin = Solver(True)
    assert not factor_last(P, lin, None, True, [1e-4], 1e-10)  # no rate yet
    assert factor_last(P, lin, None, True, [1.2e-4, 2.8e-7], 1e-10)  # 2.8e-7^3 / 1.2e-4^2 = 1.5e-12
    assert not factor_last(P, lin, None, True, [2.2e-3, 1.2e-4], 1e-10)  # 3.6e-7
    assert not factor_last(P, lin, None, False, [1.2e-4, 2.8e-7], 1e-10)  # no minimum check: CG
    assert not factor_last(P, Solver(False), None, True, [1.2e-4, 2.8e-7], 1e-10)  # the check is free
    assert not factor_last(P, object(), None, True, [1.2e-4, 2.8e-7], 1e-10)  # a solver without it


@pytest.mark.skipif(not HAVE_CHOLMOD, reason="scikit-sparse is not installed")
@pytest.mark.parametrize("module,level,factorizations", [(obstacle, 4, 2), (two_membrane, 4, 1)])
def test_the_minimum_check_after_the_last_step_costs_no_factorization(monkeypatch, module, level,
                                                                       factorizations):
    """From the coarser level's solution: the obstacle's active set loses points on the way
    (the check would factor), so its last step is factored and the check reuses it; the two
    membranes' only gains points (the first factorization serves the check): one
    factorization, the last step by CG."""
    case = Case(module)
    p = case.parameters({})
    coarse, fine = case.problem(level - 1, 1, p), case.problem(level, 1, p)
    x0 = prolongate(coarse, coarse.minimize(rtol=1e-6).x, fine)
    counts = []
    check = Cholmod.is_positive_definite

    def counted(self, A):
        before = self.factorizations
        try:
            return check(self, A)
        finally:
            counts.append(self.factorizations - before)
    monkeypatch.setattr(Cholmod, "is_positive_definite", counted)
    result = fine.minimize(x0, solver="cholmod", lift=False)
    assert result.converged and counts == [0], (counts, result.residuals)
    assert result.solver_stats["factorizations"] == factorizations, result.solver_stats
