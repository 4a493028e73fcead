"""Refinement studies with nested iteration and successive-difference rates.

Level k starts Newton from the previous level's solution interpolated to the
fine space, I u_{k-1}.  The successive difference E_k = |u_k - I u_{k-1}|_E
(energy norm of J) satisfies E_k <= C h_k^r (1 + 2^r), so the rate is
log2(E_{k-1} / E_k); errors against an exact solution are added where the case
has one.
"""
import sys
import time

import numpy as np

from .norms import energy_norm, rates
from .newton import NotConverged


def prolongate(coarse, x, fine):
    """The coarse problem's solution x as a dof vector of the fine problem."""
    parts = coarse.split(x)
    return fine.join({f.name: f.prolongate(coarse.by_name[f.name], parts[f.name])
                      for f in fine.fields})


def mesh_size(problem):
    from .measures import cell_diameters
    return float(cell_diameters(problem.fields[0].mesh).max())


def solve_nested(case, level, degree, p, newton_options=None, first=0, progress=False):
    """Solve levels first .. level, each from the previous solution; returns the finest
    (problem, result) and the Newton iterations of every level."""
    prev, its = None, []
    for k in range(first, level + 1):
        problem = case.problem(k, degree, p)
        result = problem.minimize(prolongate(*prev, problem) if prev else None,
                                  **(newton_options or {}))
        its.append(result.iterations)
        if progress:
            print(f"[level {k}/{level}] {problem.free.size} unknowns: {result.iterations} Newton "
                  f"iterations, {result.seconds:.2f} s", file=sys.stderr, flush=True)
        if not result.converged:
            break
        prev = (problem, result.x)
    return problem, result, its


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
        problem = case.problem(level, degree, p)
        if progress:
            print(f"[{i + 1}/{levels}] level {level}: {problem.free.size} unknowns ...",
                  end="", file=out, flush=True)
        x0 = prolongate(*prev, problem) if prev else None
        result = problem.minimize(x0, **(newton_options or {}))
        if not result.converged:
            raise NotConverged(f"level {level}: {result.reason}")
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
    for key in [k for k in rows[0] if k.startswith("error_")] + ["difference"]:
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
