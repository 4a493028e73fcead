"""Refinement studies with nested iteration and successive-difference rates.

Level k starts Newton from the previous level's solution interpolated to the
fine space, I u_{k-1}.  The successive difference E_k = |u_k - I u_{k-1}|_E
(energy norm of J) satisfies E_k <= C h_k^r (1 + 2^r), so the rate is
log2(E_{k-1} / E_k); errors against an exact solution are added where the case
has one.
"""
import dataclasses
import sys
import threading
import time

import numpy as np

from .allocator import release_freed_memory
from .norms import energy_norm, rates
from .newton import RTOL, NotConverged


def prolongate(coarse, x, fine):
    """The coarse problem's solution x as a dof vector of the fine problem: each field's
    Field.prolongate, or the fine problem's own prolongate_field where it has one (a
    distributed problem on rank-local meshes)."""
    parts = coarse.split(x)
    field = getattr(fine, "prolongate_field", None) or (lambda f, c, u: f.prolongate(c, u))
    return fine.join({f.name: field(f, coarse.by_name[f.name], parts[f.name]) for f in fine.fields})


def unknowns(problem):
    """The whole problem's free dofs (a distributed problem's: all ranks')."""
    return getattr(problem, "unknowns", problem.free.size)


def dofs(problem):
    """The whole problem's dofs (a distributed problem's: all ranks')."""
    return getattr(problem, "whole_ndofs", problem.ndofs)


def mesh_size(problem):
    from .measures import cell_diameters
    return float(cell_diameters(problem.fields[0].mesh).max())


class StudyFailed(NotConverged):
    """A level of a study did not converge (or ran out of memory): the rows of the
    levels finished before it are kept."""

    def __init__(self, level, reason, rows):
        super().__init__(f"level {level}: {reason}")
        self.level, self.reason, self.rows = level, reason, with_rates(rows)


COARSE_RTOL = 1e-6  # the relative residual of the coarser levels of `nitsche run`'s chain (nested)
COARSE_REDUCTION = 1e-2  # or their first residual's reduction by this factor, whichever comes first
AHEAD_MEMORY = 0.5  # the finest level built ahead (solve_nested) while its estimated memory is below this share
FAILURES = (MemoryError, ValueError, ArithmeticError, np.linalg.LinAlgError)  # of a finer level


class Ahead:
    """make() run in a background thread from now on; value() waits for it and returns what
    it returned or raises what it raised.  Not a daemon thread: the interpreter's exit waits
    for it (a daemon thread still inside JAX's or NumPy's native code when the interpreter
    finalizes is unwound there and aborts the process, SIGABRT instead of the exit status)."""

    NAME = "nitsche-ahead"  # its threads' name

    def __init__(self, make):
        self._outcome = None
        self._thread = threading.Thread(target=self._run, args=(make,), name=self.NAME)
        self._thread.start()

    @staticmethod
    def running():
        """Whether an Ahead's thread is still at work (e.g. a chain stopped on a coarser level)."""
        return any(t.name == Ahead.NAME and t.is_alive() for t in threading.enumerate())

    def _run(self, make):
        try:
            self._outcome = (True, make())
        except BaseException as e:  # noqa: BLE001 -- handed to value()'s caller
            self._outcome = (False, e)

    def value(self):
        self._thread.join()
        done, value = self._outcome
        self._outcome = None  # (not held here once handed over)
        if not done:
            raise value
        return value


def nested(make_problem, levels, solve=None, coarse_rtol=None, coarse_reduction=None, ahead=False,
           **newton_options):
    """Nested iteration for any problem: for each k in `levels`, minimize J_h of
    make_problem(k) from the previous level's solution prolongated to it (I u_{k-1}), by
    solve(problem, x0, **newton_options) (default Problem.minimize; a case's load path).
    Yields (k, problem, result); stops after a level that does not converge.  I u_{k-1}
    differs from the prescribed values only by interpolation: it is not lifted (lift=False,
    which saves a factorization per level) unless newton_options say so.  Only the last
    level's minimum is checked (newton's minimum_check, one factorization per level):
    a coarser level is the next one's starting guess, and so, coarse_rtol given, is solved
    only to the relative residual max(rtol, coarse_rtol) (COARSE_RTOL: far below the
    interpolation error of I u_{k-1}, which the finer level's Newton steps remove), and,
    coarse_reduction given, a level after the first only until its residual is that
    fraction of its first one (newton's reduction: level k starts from the interpolation
    error of I u_{k-1}, level k + 1 from that of I u_k, measured the same (two membranes'
    P1 fields: 1.1, 1.1) or 4x smaller (the obstacle: 8.8e-4, 2.2e-4); COARSE_REDUCTION
    leaves on level k 25-100x less than level k + 1 starts from; the first level starts
    from x0 or zero, not from an interpolation error).  ahead: the last level's problem is
    built in a background thread (Ahead) from the start, beside the coarser levels' set-up
    and solves (make_problem must then be safe to call from two threads at once: no MPI
    collectives, as in a distributed set-up, and no shared mutable state)."""
    newton_options.setdefault("lift", False)
    prev, solve, levels = None, solve or (lambda problem, x0, **o: problem.minimize(x0, **o)), list(levels)
    check = newton_options.pop("minimum_check", True)
    rtol = newton_options.pop("rtol", RTOL)
    finest = Ahead(lambda: make_problem(levels[-1])) if ahead and len(levels) > 1 else None
    for k in levels:
        problem = finest.value() if finest and k == levels[-1] else make_problem(k)
        x0 = prolongate(prev[0], prev[1].x, problem) if prev else None
        prev = result = None  # not held here through this solve (solve_nested drops its own)
        last = k == levels[-1]
        reduced = coarse_reduction and x0 is not None and not last
        coarse = dict(reduction=coarse_reduction) if reduced else {}
        result = solve(problem, x0, minimum_check=check and last,
                       rtol=rtol if last or coarse_rtol is None else max(rtol, coarse_rtol),
                       **coarse, **newton_options)
        yield k, problem, result
        if not result.converged:
            return
        prev = (problem, result)


def solve_nested(case, level, degree, p, newton_options=None, first=0, progress=False,
                 engine=None):
    """Solve the case's levels first .. level by nested iteration (engine: build -> the
    problem to minimize, build() making the case's problem, e.g.
    nitsche.distributed.DistributedProblem.build; the case's problem by default).

    Returns (problem, result, iterations per level, failure): the finest level's problem
    and result, or, when a level fails (Newton, or an error such as MemoryError on a finer
    level), those of the finest converged level and failure = dict(level, reason); a
    failure on the first level returns its unconverged result (an error there is raised).
    The levels below `level` are solved to COARSE_RTOL only, those after the first also
    only to COARSE_REDUCTION of their first residual (nested's coarse_rtol and
    coarse_reduction), unless the options' rtol is looser.  A converged coarser level keeps
    its result without its problem, which is built again only if a finer level fails, so
    that its memory is not held through the finer solves; it is then solved on to the
    options' rtol and checked.  Serial (no engine), the finest level's problem is built in
    a background thread beside the coarser levels (nested's ahead), unless its estimated
    memory is above AHEAD_MEMORY of the machine's (then the two would hold more at once
    than the finest solve alone)."""
    from .case import machine_memory
    ahead = engine is None and level > first and \
        case.memory_need(level, degree, p) <= AHEAD_MEMORY * machine_memory()
    prev, its = None, []
    engine = engine or (lambda build: build())
    build = lambda k: engine(lambda: case.problem(k, degree, p))  # noqa: E731

    def converged_level():
        """The finest converged level's problem (built again) and result: Newton's method
        from its solution on to the full tolerance and the minimum check (a coarser level
        of the chain was solved to COARSE_RTOL only, unchecked)."""
        k, result = prev
        problem = build(k)
        return problem, case.solve(problem, result.x, **(newton_options or {}))
    try:
        for k, problem, result in nested(build, range(first, level + 1), case.solve, COARSE_RTOL,
                                         COARSE_REDUCTION, ahead=ahead, **(newton_options or {})):
            its.append(result.iterations)
            if progress:
                print(f"[level {k}/{level}] {unknowns(problem)} unknowns: {result.iterations} "
                      f"Newton iterations, {result.seconds:.2f} s", file=sys.stderr, flush=True)
            if not result.converged:
                failure = dict(level=k, reason=result.reason)
                return (*converged_level(), its, failure) if prev else (problem, result, its, failure)
            if k == level:
                release_freed_memory()  # the solve's factor and temporaries, kept for the next
                return problem, result, its, None  # Newton step, back to the system
            prev = (k, dataclasses.replace(result, problem=None))
            problem = result = None
    except FAILURES as e:
        if prev is None:
            raise
        reason = "out of memory" if isinstance(e, MemoryError) else f"{type(e).__name__}: {e}"
        return (*converged_level(), its, dict(level=first + len(its), reason=reason))
    raise ValueError(f"no level to solve: first level {first} > level {level}")


def alpha0_summary(problem):
    """alpha0 and its stability limit per constraint with a multiplier: min / median / max
    over the elements (flat keys, e.g. contact_alpha0_min)."""
    out = {}
    for c in problem.constraints:
        if c.multiplier is None:
            continue
        for what, v in (("alpha0", problem.alpha0[c.name]), ("alpha0_limit", problem.limits[c.name])):
            for stat, fn in (("min", np.min), ("median", np.median), ("max", np.max)):
                out[f"{c.name}_{what}_{stat}"] = float(fn(v))
    return out


def run_study(case, levels, degree, p, start=0, progress=True, newton_options=None):
    """Solve levels start .. start+levels-1; returns the list of rows (dicts).

    A case's optional hook study_extra(problem, result, row) adds its own quantities."""
    extra = getattr(case.module, "study_extra", None)
    rows, prev = [], None
    out = sys.stderr
    for i, level in enumerate(range(start, start + levels)):
        t0 = time.perf_counter()
        try:
            problem = case.problem(level, degree, p)
            if progress:
                print(f"[{i + 1}/{levels}] level {level}: {problem.free.size} unknowns ...",
                      end="", file=out, flush=True)
            x0 = prolongate(*prev, problem) if prev else None
            result = case.solve(problem, x0, **(newton_options or {}))
        except FAILURES as e:
            if not rows:
                raise
            raise StudyFailed(level, "out of memory" if isinstance(e, MemoryError)
                              else f"{type(e).__name__}: {e}", rows)
        if not result.converged:
            raise StudyFailed(level, result.reason, rows)
        row = dict(level=level, h=mesh_size(problem), dofs=int(problem.ndofs),
                   unknowns=int(problem.free.size), newton_iterations=result.iterations,
                   energy=result.energy, active_count=result.active_count,
                   contact_measure=result.contact_measure, max_violation=result.max_violation,
                   seconds=time.perf_counter() - t0, compile_seconds=result.timings["compile"])
        row.update(alpha0_summary(problem))
        if x0 is not None:
            # a case may define the successive difference itself (non-nested spaces, e.g. Morley)
            difference = getattr(case.module, "difference", None)
            row["difference"] = (difference(*prev, problem, result.x) if difference
                                 else energy_norm(problem, result.x - x0))
        row.update({f"error_{k}": v for k, v in case.errors(problem, result, p).items()})
        if extra:
            extra(problem, result, row)
        rows.append(row)
        prev = (problem, result.x)
        if progress:
            print(f" {result.iterations} Newton its, {row['seconds']:.2f} s", file=out, flush=True)
    return with_rates(rows)


def with_rates(rows):
    """rows with the rate of each error column and of the successive difference."""
    for key in [k for k in (rows[0] if rows else ()) if k.startswith("error_")] + ["difference"]:
        vals = [r.get(key) for r in rows]
        for r, rate in zip(rows, rates([v if v is not None else np.nan for v in vals])):
            if r.get(key) is not None:
                r[f"rate_{key}" if key != "difference" else "rate"] = \
                    rate if rate is not None and np.isfinite(rate) else None
    return rows


def table(rows):
    """The study as a text table."""
    keys = ["level", "h", "dofs", "newton_iterations", "difference", "rate"]
    keys += [k for k in rows[0] if k.startswith("error_") or k.startswith("rate_error")]
    keys += ["active_count", "max_violation", "seconds"]
    head = " ".join(f"{k:>12}" for k in keys)
    lines = [head]
    for r in rows:
        cells = []
        for k in keys:
            v = r.get(k)
            cells.append(f"{'-':>12}" if v is None else f"{v:>12d}" if isinstance(v, int)
                         else f"{v:>12.4g}")
        lines.append(" ".join(cells))
    return "\n".join(lines)
