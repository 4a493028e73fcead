"""Quasi-static load paths: a problem solved step by step, each step from the previous one.

At time t the prescribed data are set (the run-time parameter `t` and/or set_step(problem,
t)), history fields (ni.history) take the previous step's solution, and Newton starts from
the previous solution with the increment of the prescribed values lifted into the
interior (Problem.lift: H_ff dx_f = -H_fc dx_fixed) and, where run-time parameters
changed, the first-order change of the solution added (`predicted`, a tangent
predictor).  A step whose Newton run fails is halved, down to min_step times its
nominal length (interfaces paired in the current configuration paired again at the
accepted solution from the accepted step's closest facets first, not from the failed
attempt's); after two successes in a row the step
doubles again (up to the next listed time).  A step whose Newton run met a non-convex J_h
(Result.shifts: convexified steps) and failed, for the second time since alpha0 last changed,
is retried with alpha0 halved on every constraint: the stability limits of alpha0 are those of the reference configuration, and a
deformed one may need less (at most ALPHA0_HALVINGS times along a path).
"""
import sys
import time
from dataclasses import dataclass, field

import numpy as np

from .newton import free_part, norm, with_free
from .reactions import reactions

COMPONENTS = ("reaction_x", "reaction_y", "reaction_z")
ALPHA0_HALVINGS = 6


@dataclass
class Path:
    """What a load path did: per accepted step its record (`steps`), Result and problem
    state; the last attempted Result; whether every listed time was reached."""
    steps: list = field(default_factory=list)
    results: list = field(default_factory=list)
    states: list = field(default_factory=list)
    converged: bool = True
    reason: str = ""
    result: object = None
    seconds: float = 0.0

    def at(self, problem, k):
        """Set the problem to accepted step k's data and return its solution."""
        problem.set_state(self.states[k])
        return self.results[k].x

    @property
    def cuts(self):
        return sum(s["cuts"] for s in self.steps)


def step_reactions(problem, x):
    """{field: {boundary: {reaction_x: .., reaction_y: ..}}}: nitsche.reactions.reactions by
    component name (history fields, all of whose dofs are data, are left out)."""
    history = {f.name for f in problem.fields if getattr(f, "history_of", None)}
    return {name: {region: dict(zip(COMPONENTS, R)) for region, R in regions.items()}
            for name, regions in reactions(problem, x).items() if name not in history}


def predicted(problem, x, before, lin, eps=1e-3):
    """x, the solution at the parameter values `before` ({name: value}), plus the tangent
    predictor of the change to the present values p:

        H_ff dx_f = -(grad_f J_h(x; before + eps (p - before)) - grad_f J_h(x; before)) / eps,

    H the Hessian at x before the change (positive definite at a minimum): the first-order
    change of the solution with the active sets of x (points that come into contact are
    left to Newton).  x itself where no parameter changed, where the system cannot be solved
    (lin: a nitsche.linalg solver) or where the prediction does not lower J_h (the
    residual's norm for a problem with residual terms)."""
    after = problem.state()[0]
    if after == before:
        return x
    try:
        problem.set_parameters(**before)
        _, g0, H = problem.newton_system(x)
        problem.set_parameters(**{k: v + eps * (after[k] - v) for k, v in before.items()})
        g1 = free_part(problem, problem.gradient(x))
        problem.set_parameters(**after)
        moved = with_free(problem, x, free_part(problem, x) + lin.solve(H, -(g1 - g0) / eps, rtol=1e-8))
    except RuntimeError:  # IndefiniteHessian, NotSolved, a singular factor
        problem.set_parameters(**after)
        return x
    def merit(z):  # J_h, or the residual's norm where J_h has residual terms
        return problem.energy(z) if problem.symmetric else norm(problem, free_part(problem, problem.gradient(z)))
    with np.errstate(all="ignore"):
        return moved if merit(moved) < merit(x) else x


def path(problem, times, set_step=None, parameter="t", x0=None, start=0.0, min_step=1 / 64,
         quiet=False, **newton_options):
    """Solve `problem` at each of the increasing `times` from `start` (x0: the solution at
    start; default the rest state, zero free dofs).  At time t the parameter named
    `parameter` (if the problem has it) is set to t and set_step(problem, t) is called (e.g.
    Problem.set_values of a moved boundary).  Steps are cut in half on failure, down to
    min_step times the listed interval, and regrow after two successes.  One line per step
    on stderr unless quiet; each step lifts (newton_options' `lift` is ignored).  Returns
    a Path; each record: step, time, increment, iterations, converged, cuts,
    contact_measure, reactions, energy, seconds, alpha0_scale (alpha0 relative to the
    problem's initial one)."""
    newton_options.pop("lift", None)
    times = np.asarray(times, dtype=float).ravel()
    if times.size == 0 or not np.all(np.diff(np.concatenate([[start], times])) > 0):
        raise ValueError(f"times must increase from start = {start:g}, got {times.tolist()}")
    if not 0 < min_step <= 1:
        raise ValueError(f"min_step (the smallest step, relative to the listed one) must be in (0, 1], not {min_step!r}")
    history = [f for f in problem.fields if getattr(f, "history_of", None) in problem.by_name]
    lin = problem.linear_solver(newton_options.get("solver", "auto"))  # the predictor's

    def set_time(t):
        if parameter in problem.parameters:
            problem.set_parameters(**{parameter: t})
        if set_step is not None:
            set_step(problem, t)

    t0 = time.perf_counter()
    set_time(start)
    x = problem.initial(x0)
    if x0 is None:
        x[problem.free] = 0.0
    out, t, previous, solved_at = Path(), start, start, problem.state()[0]
    accepted = problem.paired_facets()  # an attempt that fails starts the next one from these
    dt, successes, cuts, alpha0_scale, nonconvex = None, 0, 0, 1.0, 0
    for target in times:
        nominal = target - previous
        while t < target - 1e-12 * nominal:
            h = target - t if dt is None else min(dt, target - t)
            parts = problem.split(x)
            for f in history:
                problem.set_values(f.name, parts[f.history_of])
            set_time(t + h)
            if problem.sliding:  # a pairing may have grown the pattern: a solver for the present one
                lin = problem.linear_solver(newton_options.get("solver", "auto"))
            try:
                result = problem.minimize(predicted(problem, x, solved_at, lin), lift=True,
                                          **newton_options)
                reason = result.reason
            except ValueError as e:  # e.g. J_h not finite at the start: an inverted element
                result, reason = None, str(e)
            out.result = result or out.result
            if result is not None and result.converged:
                t, x, solved_at = t + h, result.x, problem.state()[0]
                accepted = problem.paired_facets()
                out.results.append(result)
                out.states.append(problem.state())
                out.steps.append(dict(step=len(out.steps) + 1, time=t, increment=h,
                                      iterations=result.iterations, converged=True, cuts=cuts,
                                      contact_measure=result.contact_measure,
                                      reactions=step_reactions(problem, x), energy=result.energy,
                                      seconds=result.seconds, alpha0_scale=alpha0_scale))
                if not quiet:
                    print(f"step {len(out.steps)}: t = {t:.6g} (+{h:.3g}{f', {cuts} cuts' if cuts else ''}): "
                          f"{result.iterations} Newton iterations, contact measure "
                          f"{result.contact_measure:.4g}", file=sys.stderr, flush=True)
                successes, cuts = successes + 1, 0
                if dt is not None and successes >= 2:
                    dt, successes = (None if 2 * dt >= nominal else 2 * dt), 0
                continue
            nonconvex += bool(result is not None and result.shifts)
            if accepted:  # paired again at the accepted x from its facets, not the failed attempt's
                problem.set_paired_facets(accepted)
                problem.update_pairing(x)
            if nonconvex >= 2 and alpha0_scale > 0.5 ** ALPHA0_HALVINGS and problem.scale_alpha0(0.5):
                alpha0_scale, nonconvex = alpha0_scale / 2, 0
                if not quiet:
                    print(f"step {len(out.steps) + 1}: t = {t + h:.6g} failed on a non-convex J_h "
                          f"({reason}); alpha0 halved (now {alpha0_scale:g} of its initial value)",
                          file=sys.stderr, flush=True)
                continue
            cuts, successes, dt = cuts + 1, 0, h / 2
            if not quiet:
                print(f"step {len(out.steps) + 1}: t = {t + h:.6g} failed ({reason}); "
                      f"step cut to {dt:.3g}", file=sys.stderr, flush=True)
            if dt < min_step * nominal:
                out.converged = False
                out.reason = (f"Newton failed at t = {t + h:.6g} with steps down to {h:.3g} "
                              f"(min_step {min_step:g} of {nominal:.3g}): {reason}")
                out.steps.append(dict(step=len(out.steps) + 1, time=t + h, increment=h,
                                      iterations=result.iterations if result else 0,
                                      converged=False, cuts=cuts, reason=reason))
                if out.states:  # the problem back at the last accepted step
                    problem.set_state(out.states[-1])
                out.seconds = time.perf_counter() - t0
                return out
        previous = target
    out.seconds = time.perf_counter() - t0
    out.reason = f"{len(out.steps)} steps to t = {t:.6g}, {out.cuts} cuts"
    return out
