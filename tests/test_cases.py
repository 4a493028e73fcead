"""The paper's cases of sections 2, 3 and 5.1: rates, constraints, exact solutions."""
import numpy as np
import pytest

from nitsche.cases import get
from nitsche.study import run_study


def study(name, degree, levels, **sets):
    case = get(name)
    return run_study(case, levels, degree, case.parameters(sets), progress=False)


@pytest.mark.parametrize("degree", [1, 2])
def test_dirichlet_rates(degree):
    rows = study("dirichlet", degree, 5 if degree == 1 else 4)
    assert abs(rows[-1]["rate_error_energy"] - degree) < 0.1
    assert abs(rows[-1]["rate_error_L2"] - (degree + 1)) < 0.1
    assert abs(rows[-1]["rate"] - degree) < 0.1  # successive differences agree
    assert all(r["newton_iterations"] == 1 for r in rows)  # a quadratic functional


def test_obstacle_against_exact_solution_p1():
    rows = study("obstacle", 1, 5)
    errs = [r["error_H1"] for r in rows]
    assert all(b < a for a, b in zip(errs, errs[1:]))
    assert abs(rows[-1]["rate_error_H1"] - 1.0) < 0.1
    # contact area -> pi r*^2 = 1.53044
    assert abs(rows[-1]["contact_measure"] - 1.53044) < 0.1
    assert max(r["newton_iterations"] for r in rows) <= 6


def test_obstacle_against_exact_solution_p2():
    rows = study("obstacle", 2, 4)
    errs = [r["error_H1"] for r in rows]
    assert all(b < a for a, b in zip(errs, errs[1:]))
    rates = [r["rate_error_H1"] for r in rows[1:]]
    assert np.mean(rates) > 1.3  # H^{5/2-eps} regularity: about 1.5
    assert rows[-1]["max_violation"] < 1e-3


def test_signorini_active_set_and_violation():
    rows = study("signorini", 1, 5)
    assert all(r["active_count"] > 0 for r in rows)
    case = get("signorini")
    p = case.parameters()
    problem = case.problem(3, 1, p, case.alpha0_limits(1, p))
    res = problem.minimize().check()
    contact = res.constraints["contact"]
    assert contact["active_count"] > 0
    # the exact contact zone is x < 1/2: the active points lie there
    v = problem.constraint_values(res.x)["contact"]
    xa = v["x"][..., 0][v["multiplier"] > 1e-8]
    assert xa.max() < 0.5 + 1e-9
    errs = [r["error_H1"] for r in rows]
    assert abs(rows[-1]["rate_error_H1"] - 1.0) < 0.1
    assert all(b < a for a, b in zip(errs, errs[1:]))


def test_signorini_violation_shrinks_with_h():
    case = get("signorini")
    p = case.parameters()
    viol, limits = [], case.alpha0_limits(2, p)
    for level in range(1, 5):
        problem = case.problem(level, 2, p, limits)
        res = problem.minimize().check()
        viol.append(res.constraints["contact"]["max_violation"])
    assert all(b <= a for a, b in zip(viol, viol[1:]))
    assert viol[-1] < viol[0] / 8


def test_nested_iteration_keeps_newton_iterations_bounded():
    rows = study("obstacle", 2, 5)
    its = [r["newton_iterations"] for r in rows]
    assert max(its[2:]) <= 6, its


@pytest.mark.slow
@pytest.mark.parametrize("name,degree,levels", [("obstacle", 1, 7), ("obstacle", 2, 6),
                                                ("dirichlet", 2, 6), ("signorini", 2, 6)])
def test_full_studies(name, degree, levels):
    rows = study(name, degree, levels)
    rate = get(name).rate[degree]
    key = "rate_error_H1"
    assert np.mean([r[key] for r in rows[-3:]]) > rate - 0.2
