"""What `nitsche run` and `nitsche study` do, as library functions: solve a case, then
write its outputs (result.json or study.json, VTU, figures) into an entered
nitsche.output.OutputFolder, which the caller commits.

Return codes: 0 converged; 1 Newton did not converge (the outputs say so: a nested run
writes its finest converged level, a study the levels it finished).
"""
import contextlib
import dataclasses
import os
import sys
import time

from . import partition
from .allocator import freed_memory_returned
from .io import write_json, write_pvd, write_vtu
from .pvtu import write_pieces
from .quantities import evaluate
from .reactions import reactions
from .study import StudyFailed, dofs, run_study, solve_nested, table, unknowns


def solve(case, level, degree, p, options, nested=True, verbose=False, engine=None):
    """Solve `case` at `level` (nested: levels 0..level, each from the previous one; a case
    with a load path solves its path at `level` only); engine: build -> the problem to
    minimize, build() making the case's problem (nitsche.distributed.DistributedProblem.build
    on MPI ranks).  Returns (problem, result, Newton iterations per level, failure)."""
    options = dict(options)
    if verbose:
        options["progress"] = lambda it, res, E: print(f"  Newton {it:3d}  residual {res:.3e}  "
                                                       f"J_h {E:.12g}", file=sys.stderr)
    if nested and not case.has_path:
        return solve_nested(case, level, degree, p, options, progress=True, engine=engine)
    problem = (engine or (lambda build: build()))(lambda: case.problem(level, degree, p))
    result = case.solve(problem, None, **options)
    its, failure = [result.iterations], None
    if not result.converged:
        failure = dict(level=level, reason=result.reason)
    steps = getattr(problem, "path", None)
    if steps is not None:
        failure = None if steps.converged else dict(level=level, reason=steps.reason)
        its = [s["iterations"] for s in steps.steps]
    return problem, result, its, failure


# what Case.solve (a load path) and the cases' solve hooks attach to the problem they solve,
# for the output hooks: carried to the problem the outputs are computed on
SOLVE_RECORDS = ("path", "load_path")


def whole(case, problem, result, degree, p):
    """The whole problem of a distributed one (rank 0 builds it for the outputs that are
    the case's own code on a whole problem: its set-up and memory are the serial ones) and
    the result on it."""
    serial = case.problem(problem.setup.level, degree, p)
    serial.set_state(problem.state()[:2])  # (its alpha0 is its own: the ranks' are rank-local)
    carry(problem, serial)
    if hasattr(serial, "path"):  # the steps' states without the ranks' alpha0
        serial.path = dataclasses.replace(serial.path, states=[s[:2] for s in serial.path.states])
    if serial.sliding:  # built paired at rest: paired at the solution (nitsche.sliding)
        serial.update_pairing(result.x)
    return serial, dataclasses.replace(result, problem=serial)


def part(problem, result):
    """This rank's part of a distributed problem (its cells' elements: the outputs from the
    pieces, Case.outputs_from_pieces) and the result on it (x whole)."""
    carry(problem, problem.local)
    return problem.local, dataclasses.replace(result, problem=problem.local)


def carry(source, target):
    """The solve's records (SOLVE_RECORDS) of the problem `source` onto `target`."""
    for name in SOLVE_RECORDS:
        if name in vars(source):
            setattr(target, name, vars(source)[name])


def run(case, level, degree, p, out, options, nested=True, verbose=False, global_check=False,
        engine=None, whole_outputs=True):
    """Solve (see solve) and write the outputs; global_check: also the global alpha0
    limits and the stability ratio (J_h convex if <= 1).  With an engine (MPI ranks) it is
    collective, `out` None on the ranks other than 0: result.json's common keys come from
    the ranks (energy, constraint report, reactions from the summed gradient, alpha0 limits
    reduced) and the solution is a .pvtu of the ranks' pieces (nitsche.pvtu); the outputs
    that are the case's own code (its errors, report and figures, solution.png) are
    computed by every rank on its part where the case says they can be
    (Case.outputs_from_pieces, and no global_check), otherwise on the whole problem, which
    rank 0 then builds (so also declared quantities and global_check); whole_outputs False
    leaves them all out.
    result.json's `seconds` is the solve (wall), `output_seconds` what follows it up to
    result.json (errors, reactions, VTU, figures), `cpu_seconds` the CPU time of both."""
    t0, c0 = time.perf_counter(), time.process_time()
    problem, result, its, failure = solve(case, level, degree, p, options, nested, verbose, engine)
    seconds = time.perf_counter() - t0
    with freed_memory_returned():  # the outputs run once (nitsche.allocator)
        rank = problem.rank if engine else 0
        reached = problem.setup.level
        if failure and reached < level:
            print(f"nitsche: Newton failed at level {failure['level']} ({failure['reason']}): "
                  f"levels {failure['level']}..{level} were not solved; the report and the files "
                  f"are those of level {reached}, the finest converged one", file=sys.stderr)
        print(f"{case.name}: level {reached}, degree {degree}, {dofs(problem)} dofs "
              f"({unknowns(problem)} unknowns); Newton iterations per level {its}")
        print(result.report())
        data = dict(case=case.name, level=level, level_reached=reached, degree=degree,
                    dofs=int(dofs(problem)), unknowns=int(unknowns(problem)),
                    converged=result.converged and failure is None, reason=result.reason,
                    level_converged=result.converged, failure=failure,
                    newton_iterations=result.iterations, residuals=result.residuals,
                    nested_iterations=its,
                    energy=result.energy, active_count=result.active_count,
                    contact_measure=result.contact_measure, max_violation=result.max_violation,
                    feasible=result.feasible, seconds=seconds, solve_seconds=result.seconds, timings=result.timings,
                    solver=result.solver, solver_stats=result.solver_stats, ranks=result.ranks,
                    minimum=result.minimum, parameters=vars(p),
                    alpha0_limits=problem.alpha0_limits, constraints=result.constraints,
                    reactions=problem.reactions(result.x) if engine else reactions(problem, result.x))
        if failure and reached < level:
            data["reason"] = f"level {failure['level']}: {failure['reason']}"
        vtu = solution_writer(problem, out) if engine else \
            lambda prefix, x, vertex_data=None: out.adopt(write_vtu(out.stage_prefix(prefix), problem, x,
                                                                    vertex_data))
        steps = getattr(problem, "path", None)
        if steps is not None:
            data.update(steps=steps.steps, step_cuts=steps.cuts, path_seconds=steps.seconds)
            write_path(steps, out, vtu, lambda k: steps.at(problem, k),
                       f"{case.name}, level {reached}, P{degree}")
        pieces = contextlib.nullcontext()
        if engine:
            vtu("solution", result.x)
            from_pieces = problem.comm.bcast(  # rank 0's decision: every rank must take it
                whole_outputs and case.outputs_from_pieces and not global_check, root=0)
            if rank > 0 and not from_pieces:
                return 0 if data["converged"] else 1
            data.update(whole_problem_outputs=whole_outputs, outputs_from_pieces=from_pieces)
            if not whole_outputs:
                data.update(output_seconds=time.perf_counter() - t0 - seconds,
                            cpu_seconds=time.process_time() - c0)
                write_json(out.stage("result.json"), data)
                return 0 if data["converged"] else 1
            if from_pieces:  # every rank its part, the hooks' integrals reduced over the ranks
                pieces = partition.local(problem.comm)
                problem, result = part(problem, result)
            else:
                problem, result = whole(case, problem, result, degree, p)
        with pieces:
            return outputs(case, problem, result, p, out, data, vtu, global_check, engine,
                           f"{case.name}, level {reached}, P{degree}", t0 + seconds, c0)


def outputs(case, problem, result, p, out, data, vtu, global_check, engine, title, t_solved, c0):
    """The outputs that are the case's own code (errors, report, declared quantities,
    figures), solution.png and the global check, and then result.json: on the whole problem
    (serial, or rank 0 with the problem rebuilt), or, inside nitsche.partition.local, on
    every rank with its part (out None on ranks other than 0, which write nothing)."""
    errors = case.errors(problem, result, p)
    for k, v in errors.items():
        print(f"  error {k}: {v:.6e}")
    data["errors"] = errors
    if global_check:  # J_h is convex if the ratio is at most 1
        data.update(alpha0_global_limits=problem.stability_limits(),
                    alpha0_stability_ratio=problem.stability_ratio())
    extra = getattr(case.module, "report", None)
    if extra:
        data.update(extra(problem, result, p))
    problem.release()  # what only Newton's matrices use (built again if a hook below asks)
    declared = getattr(case.module, "quantities", None)  # quantities(p) -> {name: density}
    found = evaluate(problem, result.x, declared(p)) if declared else {}
    data["quantities"] = {k: s for k, (s, _, _) in found.items()}
    if not engine:  # (on MPI ranks the pieces are written: without the declared quantities)
        vtu("solution", result.x, {k: (m, v) for k, (_, m, v) in found.items()})
    from .plot import plot_solution  # (matplotlib loaded for the figures, not through the solve)
    png = plot_solution(problem, result, None if out is None else out.stage("solution.png"), title)
    hook = getattr(case.module, "figures", None)  # figures(problem, result, p, folder) -> paths
    figures = hook(problem, result, p, None if out is None else out.staging) if hook else []
    if out is None:
        return 0 if data["converged"] else 1
    out.adopt([png] + list(figures))
    data.update(output_seconds=time.perf_counter() - t_solved, cpu_seconds=time.process_time() - c0)
    write_json(out.stage("result.json"), data)
    return 0 if data["converged"] else 1


def solution_writer(dp, out):
    """vtu(prefix, x) on MPI ranks (collective): the pieces of x and their .pvtu into rank
    0's staging folder, all adopted there; returns the .pvtu names (on rank 0)."""
    staging = dp.comm.bcast(out.staging if dp.rank == 0 else None, root=0)

    def vtu(prefix, x, vertex_data=None):
        pieces, collections = write_pieces(prefix, dp, x, staging)
        if dp.rank > 0:
            return []
        out.adopt(pieces)
        return out.adopt(collections)
    return vtu


def write_path(steps, out, vtu, at, title):
    """A load path's VTU series solution_NNNN.vtu (one per accepted step, solution_NNNN_i.vtu
    per mesh i of several; .pvtu on MPI ranks), their collection solution.pvd (ParaView:
    time = the step's time) and the reactions against time, reactions.png; at(k) sets the
    problem to accepted step k and returns its solution (the problem is left at the last
    accepted step).  vtu(prefix, x) writes and adopts, returning the names; out is None on
    MPI ranks other than 0."""
    series = []
    for k, record in enumerate(steps.steps[:len(steps.results)]):
        series.append((record["time"], vtu(f"solution_{k + 1:04d}", at(k))))
    if out is not None:
        out.adopt([write_pvd(out.stage("solution.pvd"), series)])
        from .plot import plot_path
        out.adopt([plot_path(steps.steps, out.stage("reactions.png"), title)])


def study(case, levels, degree, p, out, options, start=0):
    """A refinement study of `levels` levels from `start`; study.json and figures."""
    failure = None
    try:
        rows = run_study(case, levels, degree, p, start=start, newton_options=options)
    except StudyFailed as e:
        print(f"\nnitsche: study stopped: {e}", file=sys.stderr)
        rows, failure = e.rows, dict(level=e.level, reason=e.reason)
    if rows:
        print(table(rows))
    data = dict(case=case.name, degree=degree, parameters=vars(p),
                expected_rate=case.rate.get(degree), levels=rows, failure=failure)
    if rows:
        from .plot import plot_convergence
        out.adopt([plot_convergence(rows, out.stage("convergence.png"), data["expected_rate"],
                                    f"{case.name}, P{degree}")])
        hook = getattr(case.module, "study_figures", None)  # study_figures(rows, p, degree, folder)
        if hook:
            out.adopt(hook(rows, p, degree, out.staging))
    write_json(out.stage("study.json"), data)
    return 0 if failure is None else 1


def written(paths):
    """The one-line summary of the files a command wrote."""
    names = sorted(paths, key=lambda q: os.path.basename(q) not in ("result.json", "study.json"))
    return "wrote " + ", ".join(os.path.normpath(q) for q in names)
