"""The command line: nitsche list | run CASE | study CASE."""
import argparse
import os
import sys
import time
import warnings

from . import cases as registry
from .case import ParameterError, parse_assignments


def _common(sp):
    sp.add_argument("case")
    sp.add_argument("--degree", type=int, default=None,
                    help="polynomial degree (default: the case's first, 1 for most cases)")
    sp.add_argument("--set", action="append", default=[], metavar="NAME=VALUE",
                    help="set a case parameter (repeatable); see 'nitsche run CASE --help'")
    sp.add_argument("--out", default=None, help="output folder (default out/CASE)")
    sp.add_argument("--solver", default="auto", help="linear solver: auto, cholmod, superlu, amg")
    sp.add_argument("--maxiter", type=int, default=50, help="Newton iteration limit")
    sp.add_argument("--rtol", type=float, default=1e-10, help="Newton relative residual tolerance")
    sp.add_argument("-h", "--help", action="store_true", help="show this help and the case's parameters")


def parser():
    p = argparse.ArgumentParser(prog="nitsche", description="General Nitsche method for "
                                "constrained problems of solid mechanics")
    sub = p.add_subparsers(dest="command", required=True)
    sub.add_parser("list", help="list the cases")
    run = sub.add_parser("run", help="solve one case at one level", add_help=False)
    _common(run)
    run.add_argument("--level", type=int, default=2, help="uniform refinements of the base mesh")
    run.add_argument("--verbose", action="store_true", help="print every Newton iteration")
    run.add_argument("--no-nested", dest="nested", action="store_false",
                     help="start Newton from zero instead of solving the coarser levels first")
    run.add_argument("--global-check", action="store_true",
                     help="diagnostic: also solve the global eigenproblems of alpha0 (sparse LU; "
                          "result.json: alpha0_global_limits, alpha0_stability_ratio)")
    st = sub.add_parser("study", help="uniform refinement study with nested iteration", add_help=False)
    _common(st)
    st.add_argument("--levels", type=int, default=4, help="number of levels")
    st.add_argument("--start", type=int, default=0, help="first level")
    pa = sub.add_parser("paper", help="reproduce the figures of every case (its PAPER runs) "
                        "into one folder with an index.md")
    pa.add_argument("--out", default=os.path.join("out", "paper"), help="output folder (default out/paper)")
    pa.add_argument("--fast", action="store_true", help="a small version: fewer levels")
    pa.add_argument("--cases", nargs="+", default=None, metavar="CASE", help="only these cases")
    return p


def show_warning(message, category, filename, lineno, file=None, line=None):
    """A warning (e.g. nitsche.StabilityWarning) as one line, without the Python source."""
    print(f"warning: {message}", file=sys.stderr)


def main(argv=None):
    args = parser().parse_args(argv)
    with warnings.catch_warnings():
        warnings.showwarning = show_warning
        return _command(args)


def _command(args):
    try:
        if args.command == "list":
            for name, case in registry.all_cases().items():
                print(f"{name:<16} {case.summary}")
            return 0
        if args.command == "paper":
            from .paper import paper
            return paper(args.out, fast=args.fast, only=args.cases)
        case = registry.get(args.case)
        if args.help:
            parser()._subparsers._group_actions[0].choices[args.command].print_help()
            print()
            print(case.help())
            return 0
        p = case.parameters(parse_assignments(args.set))
        if args.degree is None:  # e.g. Morley (2) or BFS (3) plates have one element only
            args.degree = case.degrees[0]
        case.check_degree(args.degree)
        out = args.out or os.path.join("out", case.name)
        os.makedirs(out, exist_ok=True)
        options = dict(solver=args.solver, maxiter=args.maxiter, rtol=args.rtol)
        if args.command == "run":
            return _run(case, args, p, out, options)
        return _study(case, args, p, out, options)
    except (ParameterError, KeyError, ValueError) as e:
        msg = e.args[0] if isinstance(e, KeyError) else str(e)
        print(f"nitsche: error: {msg}", file=sys.stderr)
        return 2


def _run(case, args, p, out, options):
    from .io import write_json, write_vtu
    from .plot import plot_solution
    from .study import solve_nested
    t0 = time.perf_counter()
    if args.verbose:
        options["progress"] = lambda it, res, E: print(f"  Newton {it:3d}  residual {res:.3e}  "
                                                       f"J_h {E:.12g}", file=sys.stderr)
    if args.nested:
        problem, result, its = solve_nested(case, args.level, args.degree, p, options,
                                            progress=True)
    else:
        problem = case.problem(args.level, args.degree, p)
        result = problem.minimize(**options)
        its = [result.iterations]
    seconds = time.perf_counter() - t0
    reached = args.level - (args.level + 1 - len(its) if args.nested else 0)
    if reached < args.level:
        print(f"nitsche: Newton failed at level {reached}: levels {reached + 1}..{args.level} "
              "were not solved; the report and the files are those of level "
              f"{reached}", file=sys.stderr)
    print(f"{case.name}: level {reached}, degree {args.degree}, {problem.ndofs} dofs "
          f"({problem.free.size} unknowns); Newton iterations per level {its}")
    print(result.report())
    errors = case.errors(problem, result, p)
    for k, v in errors.items():
        print(f"  error {k}: {v:.6e}")
    data = dict(case=case.name, level=args.level, level_reached=reached, degree=args.degree,
                dofs=int(problem.ndofs),
                unknowns=int(problem.free.size), converged=result.converged, reason=result.reason,
                newton_iterations=result.iterations, residuals=result.residuals,
                nested_iterations=its,
                energy=result.energy, active_count=result.active_count,
                contact_measure=result.contact_measure, max_violation=result.max_violation,
                seconds=seconds, solve_seconds=result.seconds, timings=result.timings,
                solver=result.solver, solver_stats=result.solver_stats, parameters=vars(p),
                alpha0_limits=problem.alpha0_limits,
                constraints=result.constraints, errors=errors)
    if args.global_check:  # J_h is convex if the ratio is at most 1
        data.update(alpha0_global_limits=problem.global_limits(),
                    alpha0_stability_ratio=problem.stability_ratio())
    extra = getattr(case.module, "report", None)
    if extra:
        data.update(extra(problem, result, p))
    write_json(os.path.join(out, "result.json"), data)
    paths = write_vtu(os.path.join(out, "solution"), problem, result.x)
    figs = [plot_solution(problem, result, os.path.join(out, "solution.png"),
                          f"{case.name}, level {reached}, P{args.degree}")]
    hook = getattr(case.module, "figures", None)
    if hook:
        figs += hook(problem, result, p, out)
    print(f"wrote {os.path.join(out, 'result.json')}, {', '.join(paths + figs)}")
    return 0 if result.converged else 1


def _study(case, args, p, out, options):
    from .io import write_json
    from .plot import plot_convergence
    from .study import run_study, table
    from .newton import NotConverged
    try:
        rows = run_study(case, args.levels, args.degree, p, start=args.start, newton_options=options)
    except NotConverged as e:
        print(f"\nnitsche: study stopped: {e}", file=sys.stderr)
        return 1
    print(table(rows))
    rate = case.rate.get(args.degree)
    write_json(os.path.join(out, "study.json"), dict(case=case.name, degree=args.degree,
                                                    parameters=vars(p), expected_rate=rate,
                                                    levels=rows))
    fig = plot_convergence(rows, os.path.join(out, "convergence.png"), rate,
                           f"{case.name}, P{args.degree}")
    hook = getattr(case.module, "study_figures", None)  # optional: study_figures(rows, p, degree, out)
    figs = [fig] + (hook(rows, p, args.degree, out) if hook else [])
    print(f"wrote {os.path.join(out, 'study.json')}, {', '.join(figs)}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
