"""Semismooth Newton's method with a backtracking line search on J_h."""
import time
from dataclasses import dataclass, field

import numpy as np

from .linalg import IndefiniteHessian, make_solver
from . import assembly


ENERGY_ROUNDOFF = 1e-9  # relative change of J_h below which a full step is judged by the residual
STAGNATION_STEP = 1e-8  # relative Newton step accepted as converged once the residual stagnates
FORCING_MAX = 1e-2      # the loosest relative accuracy asked of an iterative linear solve


def forcing(residual, rtol):
    """Relative accuracy of the linear solve at relative residual r (inexact Newton):
    eta = min(1e-2, max(r, rtol / (10 r))), so that |grad| falls like r^2 and the last
    step is solved no more accurately than the stopping test needs."""
    return min(FORCING_MAX, max(residual, 0.1 * rtol / residual))


class NotConverged(RuntimeError):
    """Raised by Result.check() when Newton's method did not converge."""


@dataclass
class Result:
    """What a Newton run did: solution, convergence, constraint report and timings."""
    x: np.ndarray
    converged: bool
    reason: str
    iterations: int
    residuals: list
    energy: float
    active_count: int = 0
    contact_measure: float = 0.0
    max_violation: float = 0.0
    seconds: float = 0.0
    timings: dict = field(default_factory=dict)
    solver: str = ""
    solver_stats: dict = field(default_factory=dict)
    constraints: dict = field(default_factory=dict)
    problem: object = None

    def field(self, name):
        """The dof vector of one field."""
        return self.problem.split(self.x)[name]

    def __getitem__(self, name):
        return self.field(name)

    def check(self):
        if not self.converged:
            raise NotConverged(f"Newton's method did not converge: {self.reason}")
        return self

    def report(self):
        lines = [f"Newton: {'converged' if self.converged else 'NOT CONVERGED'} ({self.reason}) "
                 f"in {self.iterations} iterations, solver {self.solver}",
                 "  residuals: " + " ".join(f"{r:.2e}" for r in self.residuals),
                 f"  energy J_h = {self.energy:.12g}",
                 f"  active points {self.active_count}, contact measure {self.contact_measure:.6g}, "
                 f"largest violation {self.max_violation:.3e}",
                 "  seconds: " + ", ".join(f"{k} {v:.3f}" for k, v in self.timings.items())
                 + f", total {self.seconds:.3f}",
                 "  linear solver: " + ", ".join(f"{k.replace('_', ' ')} {v}"
                                                 for k, v in self.solver_stats.items())]
        return "\n".join(lines)


def newton(problem, x0=None, rtol=1e-10, maxiter=50, solver="auto", progress=None):
    """Minimize J_h from x0 (fixed dofs are set to their values).

    Stops when |grad J_h|_free <= rtol * |grad J_h(x_ref)|_free, x_ref = the
    initial guess with all free dofs zero, or when a full Newton step is below
    round-off.  Each step solves H dx = -grad on the free dofs (to the relative
    accuracy `forcing`: exactly by a fresh factorization, or by CG preconditioned
    with an earlier one) and backtracks (Armijo) on J_h.  Never returns silently unconverged: see Result.converged.
    """
    t_start = time.perf_counter()
    c0 = assembly.compile_seconds[0]
    timings = {"assembly": 0.0, "solve": 0.0, "line_search": 0.0}
    x = problem.initial(x0)
    free = problem.free
    lin = make_solver(solver, free.size, problem.dim)
    if hasattr(lin, "prepare"):  # e.g. AMG: near-nullspace from the fields
        lin.prepare(problem)
    E0, g0 = problem.assembler.gradient(x)
    if not (np.isfinite(E0) and np.all(np.isfinite(g0))):
        raise ValueError(f"J_h or its gradient is not finite at the initial guess (J_h = {E0}): "
                         f"{problem.non_finite(x)}; check the densities (log, sqrt, division) "
                         "and the initial guess x0")
    x_ref = problem.initial(np.zeros(problem.ndofs))
    x_ref[free] = 0.0
    ref = np.linalg.norm(problem.gradient(x_ref)[free])
    if not (np.isfinite(ref) and ref > 0):  # e.g. a density undefined at zero: scale by x0
        ref = np.linalg.norm(g0[free]) or 1.0
    residuals, reason, converged, it, E = [], "", False, 0, np.nan
    for it in range(maxiter + 1):
        t = time.perf_counter()
        E, g, A = problem.newton_system(x)
        timings["assembly"] += time.perf_counter() - t
        if not np.isfinite(E) or not np.all(np.isfinite(g)):
            reason = "the energy or its gradient is not finite"
            break
        res = np.linalg.norm(g)
        residuals.append(res / ref)
        if progress:
            progress(it, res / ref, E)
        if res <= rtol * ref:
            converged, reason = True, f"relative residual {res / ref:.1e} <= {rtol:.0e}"
            break
        if it == maxiter:
            reason = f"reached the iteration limit {maxiter} with relative residual {res / ref:.1e}"
            break
        t = time.perf_counter()
        try:
            dx = lin.solve(A, -g, rtol=forcing(res / ref, rtol))
        except IndefiniteHessian as e:
            reason = ("the Hessian is not positive definite (alpha0 above the stability limit, "
                      f"or a singular problem): {e}")
            break
        timings["solve"] += time.perf_counter() - t
        slope = float(g @ dx)
        if not slope < 0:
            reason = "the Newton direction is not a descent direction: the Hessian is indefinite"
            break
        if (len(residuals) > 1 and residuals[-1] > 0.5 * residuals[-2]
                and np.linalg.norm(dx) <= STAGNATION_STEP * max(np.linalg.norm(x[free]), 1e-300)):
            # the residual no longer falls and the step is far below the discretization error:
            # round-off floor (e.g. third-derivative multipliers, alpha ~ h^3, on fine meshes,
            # where J_h itself is only known to ~1e-10 and a line search cannot resolve it)
            x = x.copy()
            x[free] += dx
            converged, reason = True, (f"residual stagnated at round-off ({res / ref:.1e}), "
                                       f"Newton step below {STAGNATION_STEP:.0e} of the solution")
            it += 1
            residuals.append(np.linalg.norm(problem.gradient(x)[free]) / ref)
            break
        t = time.perf_counter()
        step, xn = 1.0, x.copy()
        for _ in range(40):
            xn[free] = x[free] + step * dx
            En = problem.energy(xn)
            if np.isfinite(En) and En <= E + 1e-4 * step * slope + 1e-14 * abs(E):
                break
            if step == 1.0 and np.isfinite(En) and abs(En - E) <= ENERGY_ROUNDOFF * abs(E) \
                    and np.linalg.norm(problem.gradient(xn)[free]) < res:
                break  # J_h is flat to round-off here (1/alpha ~ h^-4): judge the step by the residual
            step *= 0.5
        else:
            reason = "the line search found no decrease of J_h"
            timings["line_search"] += time.perf_counter() - t
            break
        timings["line_search"] += time.perf_counter() - t
        x = xn
        if step == 1.0 and np.linalg.norm(dx) <= 1e-13 * max(np.linalg.norm(x[free]), 1e-300):
            converged, reason = True, "full Newton step below round-off"
            it += 1
            residuals.append(np.linalg.norm(problem.gradient(x)[free]) / ref)
            break
    timings["compile"] = assembly.compile_seconds[0] - c0
    seconds = time.perf_counter() - t_start
    report = problem.constraint_report(x)
    return Result(x=x, converged=converged, reason=reason, iterations=it, residuals=residuals,
                  energy=problem.energy(x), seconds=seconds, timings=timings, solver=lin.name,
                  solver_stats=lin.stats(),
                  constraints=report, problem=problem,
                  active_count=sum(r["active_count"] for r in report.values()),
                  contact_measure=sum(r["contact_measure"] for r in report.values()
                                      if r["kind"] != "equality"),
                  max_violation=max([r["max_violation"] for r in report.values()], default=0.0))
