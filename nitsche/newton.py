"""Semismooth Newton's method with a backtracking line search on J_h (on the residual norm
for problems with residual terms: Coulomb friction, theta != 1)."""
import numbers
import time
import warnings
from dataclasses import dataclass, field

import numpy as np
import scipy.sparse as sp

from .linalg import IndefiniteHessian, NotSolved, make_solver
from . import assembly


ENERGY_ROUNDOFF = 1e-9  # relative change of J_h below which a full step is judged by the residual
STAGNATION_STEP = 1e-8  # relative Newton step accepted as converged once the residual stagnates
FORCING_MAX = 1e-2      # the loosest relative accuracy asked of an iterative linear solve
ROUNDOFF = 1e-13        # relative accuracy of a gradient summed from terms (about 500 machine epsilons)
RTOL = 1e-10           # the default relative residual of the stopping test
SOLVE_FAILURE = 0.5     # a Newton step with |A dx + g| above this fraction of |g| was not solved
SHIFT_START = 1e-4      # the first relative diagonal shift tried on an indefinite Newton matrix
DIVERGED = 1e3         # after convexified steps, a residual this many times the first one: diverged
SHIFT_MAX = 1e8         # shifts beyond this: the Newton matrix is hopeless (a NaN, a huge negative entry)
UNBOUNDED = ("J_h looks unbounded below or singular (a field or rigid-body mode without support, "
             "a load no support balances, a non-convex energy, or alpha0 above its stability "
             "limit): add supports, balance the loads, start nearer a minimum (x0) or lower alpha0")


def norm(problem, v):
    """The Euclidean norm of a free vector: problem.norm where the problem has its own (a
    distributed one sums over its ranks, nitsche.distributed)."""
    own = getattr(problem, "norm", None)
    return own(v) if own else np.linalg.norm(v)


def dot(problem, a, b):
    """a . b of free vectors: problem.dot where the problem has its own (see norm)."""
    own = getattr(problem, "dot", None)
    return own(a, b) if own else float(a @ b)


def free_part(problem, x):
    """The free vector of a dof vector x, x[free]: problem.free_part where the problem has
    its own (a distributed one: the free dofs the rank holds, nitsche.distributed)."""
    own = getattr(problem, "free_part", None)
    return own(x) if own else x[problem.free]


def with_free(problem, x, v):
    """A copy of the dof vector x with the free vector v on its free dofs: problem.with_free
    where the problem has its own (see free_part)."""
    own = getattr(problem, "with_free", None)
    if own:
        return own(x, v)
    y = x.copy()
    y[problem.free] = v
    return y


def energy_search(problem, x, dx, E, res, slope, system_at=None):
    """x + step dx, step = 1, 1/2, ... the first with Armijo's decrease of J_h (or, at the full
    step, J_h flat to round-off and the residual smaller): (step, x + step dx, system), None
    if 40 halvings fail.  system_at given, the full step's J_h comes from system_at(x + dx)
    (Newton's system there: J_h, gradient, Hessian), returned as `system` for the next
    Newton step, which most often starts there (else, and without it, system is None)."""
    xf, step = free_part(problem, x), 1.0
    for _ in range(40):
        xn = with_free(problem, x, xf + step * dx)
        system = system_at(xn) if system_at and step == 1.0 else None
        En = system[0] if system else problem.energy(xn)
        if np.isfinite(En) and En <= E + 1e-4 * step * slope + 1e-14 * abs(E):
            return step, xn, system
        if step == 1.0 and np.isfinite(En) and abs(En - E) <= ENERGY_ROUNDOFF * abs(E) \
                and norm(problem, system[1] if system else free_part(problem, problem.gradient(xn))) < res:
            return step, xn, system  # J_h flat to round-off here (1/alpha ~ h^-4): the step judged by the residual
        step *= 0.5
    return None


energy_search.merit = "J_h"


def residual_search(problem, x, dx, E, res, slope, system_at=None):
    """x + step dx, step = 1, 1/2, ... the first with |r| <= (1 - 1e-4 step) |r(x)| (r the
    residual on the free dofs): (step, x + step dx, None), None if 40 halvings fail
    (system_at: unused, the trial residuals need no Jacobian)."""
    xf, step = free_part(problem, x), 1.0
    for _ in range(40):
        xn = with_free(problem, x, xf + step * dx)
        rn = norm(problem, free_part(problem, problem.gradient(xn)))
        if np.isfinite(rn) and rn <= (1 - 1e-4 * step) * res:
            return step, xn, None
        step *= 0.5
    return None


residual_search.merit = "the residual norm"


def diagonal_shift(A):
    """tau -> A + tau D, D = diag|A| floored at 1e-12 of its largest entry; a matrix with its
    own `shifted` (the distributed one: its PETSc values, in place) shifts itself."""
    if hasattr(A, "shifted"):
        return A.shifted
    d = np.abs(A.diagonal())
    D = sp.diags(np.maximum(d, 1e-12 * d.max()), format="csc")

    def shifted(tau):
        M = (A + tau * D).tocsc()
        M.sort_indices()
        return M
    return shifted


def convexified_step(lin, A, g, shift):
    """Inertia correction of an indefinite Newton matrix: dx = -(A + tau D)^-1 g (see
    diagonal_shift), for the first tau = shift, 10 shift, ... up to SHIFT_MAX with
    A + tau D positive definite: the Newton step of a convex model of J_h, a descent
    direction that the line search then shortens.  Returns (dx, tau, A + tau D)."""
    shifted = diagonal_shift(A)
    tau = shift
    while tau <= SHIFT_MAX:
        M = shifted(tau)
        if lin.is_positive_definite(M):
            return lin.solve(M, -g, rtol=0.0), tau, M
        tau *= 10.0
    raise IndefiniteHessian(f"A + tau diag|A| is indefinite for every tau up to {SHIFT_MAX:.0e}")


def lifted(problem, x0, plain, lin):
    """problem.lift(x0) with the Newton solver, or `plain` (x0 with the prescribed values
    set) where the linearization at x0 cannot be solved or the lifted start is not finite."""
    try:
        with np.errstate(all="ignore"):
            x = problem.lift(x0, lambda A, b: lin.solve(A, b, rtol=1e-8))
    except RuntimeError:  # IndefiniteHessian, NotSolved, a singular factor
        return plain
    return x if np.all(np.isfinite(x)) and np.isfinite(problem.energy(x)) else plain


def check_options(rtol, maxiter, reduction=None):
    """maxiter an integer >= 0, rtol and reduction (None or) in (0, 1): a ValueError naming
    the option otherwise."""
    if isinstance(maxiter, bool) or not isinstance(maxiter, numbers.Integral) or maxiter < 0:
        raise ValueError(f"maxiter (the Newton iteration limit) must be an integer >= 0, not {maxiter!r}")
    given = [("rtol", rtol, "relative residual tolerance", "1e-10")]
    given += [("reduction", reduction, "residual reduction", "1e-2")] if reduction is not None else []
    for name, value, what, example in given:
        if isinstance(value, bool) or not isinstance(value, numbers.Real) or not 0 < value < 1:
            raise ValueError(f"{name} (Newton's {what}) must be a number in (0, 1), "
                             f"e.g. {example}, not {value!r}")


def residual_scale(problem, x_ref, rtol):
    """The reference residual of the stopping test |grad J_h|_free <= rtol * ref:

        ref = max(|grad J_h(x_ref)|, ROUNDOFF / rtol * S),   S = sum_t |grad J_t(x_ref)|,

    J_t the terms of J_h (energy terms, constraints), all on the free dofs.  The first
    is the usual scale; the second makes a gradient at round-off of the terms it sums
    (|grad| <= ROUNDOFF * S) converged, e.g. where the terms cancel at x_ref because it
    is the solution (two membranes with d = 0).  None if neither is finite and positive."""
    a = problem.assembler
    grads = [free_part(problem, a.gradient(x_ref, [t])[1]) for t in a.terms]
    S = sum(norm(problem, g) for g in grads)
    ref = max(norm(problem, sum(grads)), ROUNDOFF / rtol * S) if grads else 0.0
    return ref if np.isfinite(ref) and ref > 0 else None


def forcing(residual, rtol):
    """Relative accuracy of the linear solve at relative residual r (inexact Newton):
    eta = min(1e-2, max(r, rtol / (10 r))), so that |grad| falls like r^2 and the last
    step is solved no more accurately than the stopping test needs."""
    return min(FORCING_MAX, max(residual, 0.1 * rtol / residual))


class NotConverged(RuntimeError):
    """Raised by Result.check() when Newton's method did not converge."""


class FeasibilityWarning(UserWarning):
    """A constraint is violated far beyond the discretization level: it looks infeasible
    (see Problem.constraint_report)."""


@dataclass
class Result:
    """What a Newton run did: solution, convergence, constraint report and timings.
    feasible: no constraint looks infeasible (the reports' `infeasible` flags)."""
    x: np.ndarray
    converged: bool
    reason: str
    iterations: int
    residuals: list
    energy: float
    active_count: int = 0
    contact_measure: float = 0.0
    max_violation: float = 0.0
    feasible: bool = True
    seconds: float = 0.0
    timings: dict = field(default_factory=dict)
    solver: str = ""
    solver_stats: dict = field(default_factory=dict)
    constraints: dict = field(default_factory=dict)
    problem: object = None
    ranks: int = 1  # MPI ranks of the run (nitsche.distributed)
    shifts: list = field(default_factory=list)  # tau of each step taken on A + tau diag|A|
    # how the stationary point is known to be a minimum: "J_h convex" (Problem.convex),
    # "Hessian positive definite" (the solver's test), "not checked", or "" (not converged)
    minimum: str = ""

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
                 f"  energy J_h = {self.energy:.12g}"
                 + (f", {len(self.shifts)} convexified steps (J_h not convex there)" if self.shifts else ""),
                 f"  active points {self.active_count}, contact measure {self.contact_measure:.6g}, "
                 f"largest violation {self.max_violation:.3e}"
                 + ("" if self.feasible else ", INFEASIBLE: " + ", ".join(
                     n for n, r in self.constraints.items() if r["infeasible"])),
                 "  seconds: " + ", ".join(f"{k} {v:.3f}" for k, v in self.timings.items())
                 + f", total {self.seconds:.3f}",
                 "  linear solver: " + ", ".join(f"{k.replace('_', ' ')} {v}"
                                                 for k, v in self.solver_stats.items())]
        return "\n".join(lines)


def newton(problem, x0=None, rtol=RTOL, maxiter=50, solver="auto", progress=None, lift=True,
           minimum_check=True, reduction=None):
    """Minimize J_h from x0 (fixed dofs are set to their values; lift: where x0's differ
    from the prescribed ones, the increment is carried into the interior first, see
    Problem.lift, unless that start is not finite); for a problem with
    residual terms (problem.symmetric False) solve r(x) = 0 instead: LU (or GMRES-ILU)
    steps, backtracking until |r| falls by (1 - 1e-4 step), no minimum check.

    Stops when |grad J_h|_free <= rtol * ref (see residual_scale; x_ref = the initial
    guess with all free dofs zero), or when a full Newton step is below round-off;
    reduction given, already when |grad J_h|_free <= reduction * |grad J_h(x0)|_free (a
    coarser level of a nested chain: a fraction of the interpolation error it starts from).
    Each step solves H dx = -grad on the free dofs (to the relative accuracy `forcing`:
    exactly by a fresh factorization, or by CG preconditioned with an earlier one) and
    backtracks (Armijo) on J_h.  A stationary point is reported converged only if it is
    a minimum: J_h convex (Problem.convex, certified term by term: no factorization), or
    else the Hessian on the free dofs positive definite there (the solver's
    is_positive_definite: CHOLMOD a Cholesky factor of that matrix, SuperLU the pivots
    of its symmetric LU, AMG an LOBPCG estimate); Result.minimum says which; minimum_check=False skips that check (a
    coarse level of a nested chain, only a starting guess for the next level, whose own
    check decides).  Never returns silently unconverged:
    see Result.converged; Result.feasible says whether a constraint looks infeasible.
    """
    check_options(rtol, maxiter, reduction)
    t_start = time.perf_counter()
    c0 = assembly.compile_seconds[0]
    timings = {"assembly": 0.0, "solve": 0.0, "line_search": 0.0, "minimum_check": 0.0}
    convex = problem.symmetric and getattr(problem, "convex", False)

    def linear_solver():
        lin = make_solver(solver, problem.free.size, problem.dim, problem.symmetric)
        if hasattr(lin, "prepare"):  # e.g. AMG: near-nullspace from the fields
            lin.prepare(problem)
        if hasattr(lin, "keep_factored"):  # a certified convex J_h needs no positive definite test
            lin.keep_factored = not convex
        if hasattr(lin, "prune"):  # a Problem's Newton matrices hold their significant entries only
            lin.prune = not getattr(problem, "pruned", False)
        return lin
    lin = linear_solver()
    x = problem.initial(x0)
    if lift and x0 is not None and problem.moved(x0) is not None:
        t = time.perf_counter()
        x = lifted(problem, x0, x, lin)
        timings["lift"] = time.perf_counter() - t
    x_ref = with_free(problem, problem.initial(np.zeros(problem.ndofs)), 0.0)
    ref = residual_scale(problem, x_ref, rtol)  # None: scaled by the initial gradient (below)
    residuals, reason, converged, it, E = [], "", False, 0, np.nan
    shift, shifts = SHIFT_START, []  # inertia correction: the next shift, and those taken
    sliding = getattr(problem, "sliding", None)

    def system_at(y):
        """Newton's system at y (J_h, gradient, Hessian), its time counted as assembly."""
        t = time.perf_counter()
        system = problem.newton_system(y)
        timings["assembly"] += time.perf_counter() - t
        return system
    system = None  # Newton's system at x where the line search assembled it
    for it in range(maxiter + 1):
        t = time.perf_counter()
        if sliding and problem.update_pairing(x):  # a new matrix structure
            lin = linear_solver()
        timings["assembly"] += time.perf_counter() - t
        A = M = None  # the last step's matrices are not held through this assembly
        E, g, A = system or system_at(x)
        system = None
        if it == 0 and not (np.isfinite(E) and np.all(np.isfinite(g))):
            raise ValueError(f"J_h or its gradient is not finite at the initial guess (J_h = {E}): "
                             f"{problem.non_finite(x)}; check the densities (log, sqrt, division) "
                             "and the initial guess x0")
        if ref is None:  # e.g. a density undefined at zero, or nothing but zeros: scale by x0
            ref = norm(problem, g) or 1.0
        if not np.isfinite(E) or not np.all(np.isfinite(g)):
            reason = (f"J_h or its gradient became non-finite at iteration {it} "
                      f"(largest |x| {np.abs(x).max():.3g}; {problem.non_finite(x)}): {UNBOUNDED}")
            break
        res = norm(problem, g)
        residuals.append(res / ref)
        if progress:
            progress(it, res / ref, E)
        if it == 0:  # the stopping test's relative residual
            tol = max(rtol, reduction * residuals[0]) if reduction else rtol
        if res <= tol * ref:
            converged, reason = True, f"relative residual {res / ref:.1e} <= " + (
                f"{rtol:.0e}" if tol == rtol else f"{tol:.1e} ({reduction:.0e} of the first)")
            break
        if shifts and res / ref > DIVERGED * max(residuals[0], 1.0):
            reason = (f"Newton diverged on a non-convex J_h: the residual grew to {res / ref:.1e} "
                      f"along convexified steps by iteration {it}: {UNBOUNDED}")
            break
        if it == maxiter:
            reason = f"reached the iteration limit {maxiter} with relative residual {res / ref:.1e}"
            break
        t = time.perf_counter()
        convexified = False
        try:
            dx, M = lin.solve(A, -g, rtol=forcing(res / ref, tol)), A
            convexified = problem.symmetric and not dot(problem, g, dx) < 0
        except IndefiniteHessian as e:
            if not problem.symmetric:
                reason = f"the Newton system could not be solved at iteration {it} ({e}): {UNBOUNDED}"
                timings["solve"] += time.perf_counter() - t
                break
            convexified = True
        except NotSolved as e:
            reason = f"the Newton system could not be solved at iteration {it} ({e}): {UNBOUNDED}"
            timings["solve"] += time.perf_counter() - t
            break
        if convexified:  # J_h is not convex here: the step of a convex model instead
            try:
                dx, tau, M = convexified_step(lin, A, g, shift)
            except (IndefiniteHessian, NotSolved) as e:
                reason = (f"the Hessian of J_h is not positive definite at iteration {it} and no "
                          f"diagonal shift helps ({e}): {UNBOUNDED}")
                timings["solve"] += time.perf_counter() - t
                break
            shift, shifts = max(SHIFT_START, tau / 10), shifts + [tau]
        timings["solve"] += time.perf_counter() - t
        solve_residual = norm(problem, M @ dx + g) / res
        if not solve_residual <= SOLVE_FAILURE:
            reason = (f"the Newton matrix is singular to working precision at iteration {it} "
                      f"(step {norm(problem, dx):.3g}, relative residual of its solve "
                      f"{solve_residual:.2g}): {UNBOUNDED}")
            break
        slope = dot(problem, g, dx)
        if problem.symmetric and not slope < 0:
            reason = f"the Newton direction is not a descent direction at iteration {it}: {UNBOUNDED}"
            break
        if (not convexified and len(residuals) > 1 and residuals[-1] > 0.5 * residuals[-2]
                and norm(problem, dx) <= STAGNATION_STEP * max(norm(problem, free_part(problem, x)), 1e-300)):
            # the residual no longer falls and the step is far below the discretization error:
            # round-off floor (e.g. third-derivative multipliers, alpha ~ h^3, on fine meshes,
            # where J_h itself is only known to ~1e-10 and a line search cannot resolve it)
            x = with_free(problem, x, free_part(problem, x) + dx)
            converged, reason = True, (f"residual stagnated at round-off ({res / ref:.1e}), "
                                       f"Newton step below {STAGNATION_STEP:.0e} of the solution")
            it += 1
            residuals.append(norm(problem, free_part(problem, problem.gradient(x))) / ref)
            break
        t, assembled = time.perf_counter(), timings["assembly"]
        search = energy_search if problem.symmetric else residual_search
        A = M = None  # (not held through the search's assembly at the full step)
        found = search(problem, x, dx, E, res, slope, None if sliding else system_at)
        timings["line_search"] += time.perf_counter() - t - (timings["assembly"] - assembled)
        if found is None:
            reason = (f"the line search found no decrease of {search.merit} at iteration {it} "
                      f"(Newton step {norm(problem, dx):.3g}): {UNBOUNDED}")
            break
        step, x, system = found
        found = None  # (the system is held by `system` alone: not through the next step's search)
        if not convexified and step == 1.0 and norm(problem, dx) <= 1e-13 * max(norm(problem, free_part(problem, x)), 1e-300):
            converged, reason = True, "full Newton step below round-off"
            it += 1
            E, g, A = system or system_at(x)  # (the minimum checked at x)
            residuals.append(norm(problem, g) / ref)
            break
    if shifts and not converged:
        reason += (f" (the Hessian of J_h was not positive definite at {len(shifts)} iterations, "
                   f"which took shifted steps)")
    minimum = ""
    if converged and problem.symmetric and minimum_check:
        t = time.perf_counter()
        if convex:
            minimum = "J_h convex"
        elif lin.is_positive_definite(A):
            minimum = "Hessian positive definite"
        else:
            converged, reason = False, (
                f"stationary point that is not a minimum: the Hessian of J_h on the free dofs is "
                f"not positive definite there ({reason}); start elsewhere (x0), or, if J_h should "
                "be convex, check the supports and that alpha0 is below its stability limit")
        timings["minimum_check"] = time.perf_counter() - t
    elif converged:
        minimum = "not checked" if problem.symmetric else "not a minimization (a residual)"
    timings["compile"] = assembly.compile_seconds[0] - c0
    seconds = time.perf_counter() - t_start
    solver_name, solver_stats = lin.name, lin.stats()
    lin = A = M = None  # the factor and the matrices are not held through the report
    report = problem.constraint_report(x)
    infeasible = [name for name, r in report.items() if r["infeasible"]]
    for name in infeasible if converged else ():
        r = report[name]
        warnings.warn(f"constraint '{name}' looks infeasible: its largest violation "
                      f"{r['max_violation']:.3g} exceeds {r['violation_limit']:.3g} (min(1/2, 50 alpha0) "
                      "times the size of its fields), far beyond the discretization level; check "
                      "its data (e.g. an obstacle above the boundary values, a gap that cannot close)",
                      FeasibilityWarning)
    return Result(x=x, converged=converged, reason=reason, iterations=it, residuals=residuals,
                  energy=problem.energy(x), seconds=seconds, timings=timings, solver=solver_name,
                  solver_stats=solver_stats, minimum=minimum,
                  constraints=report, problem=problem, ranks=getattr(problem, "ranks", 1), shifts=shifts,
                  active_count=sum(r["active_count"] for r in report.values()),
                  contact_measure=sum(r["contact_measure"] for r in report.values()
                                      if r["kind"] != "equality"),
                  max_violation=max([r["max_violation"] for r in report.values()], default=0.0),
                  feasible=not infeasible)
