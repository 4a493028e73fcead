"""A check shared by the tests of contact pairing in the current configuration."""
import numpy as np


def jacobian_against_finite_differences(problem, path, rtol):
    """At the path's last state, paired anew there: the Hessian applied to three random
    free directions against central differences of the gradient, to rtol relative."""
    x = path.at(problem, len(path.steps) - 1)
    problem.update_pairing(x)
    A = problem.hessian(x)
    rng = np.random.default_rng(0)
    free = problem.free
    for _ in range(3):
        v = np.zeros(problem.ndofs)
        v[free] = rng.standard_normal(free.size)
        v *= 1e-6 / np.abs(v).max()
        fd = (problem.gradient(x + v) - problem.gradient(x - v)) / 2
        assert np.linalg.norm((A @ v - fd)[free]) < rtol * np.linalg.norm(fd[free])
