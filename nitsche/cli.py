"""The command line: nitsche list | run CASE | study CASE | paper.

Exit status: 0 converged; 1 Newton did not converge (the outputs say so); 2 a usage
error (bad option, parameter or output folder: one line on stderr, nothing written);
3 the output could not be written (disk full, file-size limit: the folder is as it
was); 130 / 143 interrupted by SIGINT / SIGTERM (the folder is as it was).
"""
import argparse
import math
import os
import signal
import sys
import threading
import warnings

from . import cases as registry, distributed
from .allocator import keep_freed_memory
from .case import ParameterError, parse_assignments
from .output import Interrupted, OutputFolder, raise_interrupted, redeliver_ignored
from .study import Ahead

SOLVERS = ("auto", "cholmod", "superlu", "amg", "gamg", "direct")  # the last two: on MPI ranks
USAGE, WRITE_FAILED = 2, 3


class Parser(argparse.ArgumentParser):
    """argparse with one-line errors (exit 2)."""

    def error(self, message):
        print(f"nitsche: error: {message} (see 'nitsche {self.prog.split()[-1]} --help')"
              if self.prog != "nitsche" else f"nitsche: error: {message}", file=sys.stderr)
        sys.exit(USAGE)


def _common(sp):
    sp.add_argument("case", help="a shipped case (nitsche list) or a case module FILE.py")
    sp.add_argument("--degree", type=int, default=None,
                    help="polynomial degree (default: the case's first, 1 for most cases)")
    sp.add_argument("--set", action="append", default=[], metavar="NAME=VALUE",
                    help="set a case parameter (repeatable); see 'nitsche run CASE --help'")
    sp.add_argument("--out", default=None, help="output folder (default out/CASE)")
    sp.add_argument("--overwrite", action="store_true",
                    help="replace the outputs of an unknown earlier run in the --out folder")
    sp.add_argument("--solver", default="auto", choices=SOLVERS,
                    help="linear solver (under mpirun: auto, gamg or direct, and PETSc options "
                         "such as -ksp_type gmres -ksp_monitor pass through)")
    sp.add_argument("--maxiter", type=int, default=50, help="Newton iteration limit")
    sp.add_argument("--rtol", type=float, default=1e-10, help="Newton relative residual tolerance")
    sp.add_argument("-h", "--help", action="store_true", help="show this help and the case's parameters")


def parser():
    p = Parser(prog="nitsche", description="General Nitsche method for "
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
    run.add_argument("--pieces-only", action="store_true",
                     help="under mpirun: write result.json's common keys and the ranks' pieces of "
                          "the solution (.pvtu) only, not the outputs that need the whole problem "
                          "on rank 0 (the case's errors, report and figures, solution.png)")
    run.add_argument("--local-meshes", action="store_true",
                     help="under mpirun: each rank refines only its own cells of a partitioned "
                          "coarse mesh (meshes of triangles, quadrilaterals, tetrahedra or "
                          "hexahedra that the case refines with nitsche.meshes.refined; an "
                          "interface's other body holds the cells its points reach as ghosts; "
                          "P1/Q1 fields for nested iteration); the outputs are those of "
                          "--pieces-only")
    st = sub.add_parser("study", help="uniform refinement study with nested iteration", add_help=False)
    _common(st)
    st.add_argument("--levels", type=int, default=4, help="number of levels")
    st.add_argument("--start", type=int, default=0, help="first level")
    pa = sub.add_parser("paper", help="reproduce the figures of every case (its PAPER runs) "
                        "into one folder with an index.md")
    pa.add_argument("--out", default=os.path.join("out", "paper"), help="output folder (default out/paper)")
    pa.add_argument("--fast", action="store_true", help="a small version: fewer levels")
    pa.add_argument("--cases", nargs="+", default=None, metavar="CASE", help="only these cases")
    pa.add_argument("--from", dest="source", default=None, metavar="FOLDER",
                    help="the case modules (*.py) in FOLDER instead of the shipped cases")
    pa.add_argument("--overwrite", action="store_true",
                    help="replace the outputs of an unknown earlier run in the --out folder")
    new = sub.add_parser("new", help="write NAME.py, a commented case module to edit "
                         "(then: nitsche run NAME.py)")
    new.add_argument("name", help="the case's name (a Python identifier; the file NAME.py)")
    return p


def show_warning(message, category, filename, lineno, file=None, line=None):
    """A warning (e.g. nitsche.StabilityWarning) as one line, without the Python source."""
    print(f"warning: {message}", file=sys.stderr)


def main(argv=None):
    # the command owns its process: freed arrays stay in the heap for the next Newton step
    # (nitsche.allocator; a library import leaves malloc alone)
    keep_freed_memory()
    args, petsc_options = parser().parse_known_args(argv)
    ranks = None
    if args.command == "run" and distributed.launched_by_mpirun():
        ranks = start_ranks(petsc_options)
    elif args.command in ("study", "paper") and distributed.launched_by_mpirun():
        parser().error(f"'nitsche {args.command}' does not run on MPI ranks (each rank would "
                       "write the same folder): start it without mpirun, or use 'nitsche run'")
    elif petsc_options:
        parser().error(f"unrecognized arguments: {' '.join(petsc_options)} (PETSc options: "
                       "only for 'nitsche run' under mpirun)")
    args.ranks = ranks
    handlers = {}
    if threading.current_thread() is threading.main_thread():
        handlers = {signal.SIGTERM: signal.signal(signal.SIGTERM, raise_interrupted),
                    # a file-size limit: the write fails (EFBIG) instead of killing the process
                    signal.SIGXFSZ: signal.signal(signal.SIGXFSZ, signal.SIG_IGN)}
        unraisable, sys.unraisablehook = sys.unraisablehook, redeliver_ignored
    try:
        with warnings.catch_warnings():
            warnings.showwarning = show_warning
            return _command(args)
    except (KeyboardInterrupt, Interrupted) as e:
        signum = e.signum if isinstance(e, Interrupted) else signal.SIGINT
        print(f"nitsche: interrupted ({signal.Signals(signum).name}); the output folder holds "
              "what it held before", file=sys.stderr)
        return 128 + signum
    finally:
        for signum, handler in handlers.items():
            signal.signal(signum, handler)
        if handlers:
            sys.unraisablehook = unraisable


def start_ranks(petsc_options):
    """Under mpirun: PETSc's options set; ranks other than 0 print nothing (rank 0 reports
    and writes).  The communicator, or a usage error without petsc4py."""
    try:
        comm = distributed.world()
        distributed.set_petsc_options(petsc_options)
    except ImportError as e:
        print(f"nitsche: error: a run under mpirun needs mpi4py and petsc4py ({e}); install "
              "them with 'make petsc'", file=sys.stderr)
        sys.exit(USAGE)
    except ValueError as e:
        print(f"nitsche: error: {e}", file=sys.stderr)
        sys.exit(USAGE)
    if comm.rank > 0:
        sys.stdout = sys.stderr = open(os.devnull, "w")
    report = sys.excepthook

    def abort(*exc):  # an error on one rank ends all (the others would wait in a reduction)
        report(*exc)
        sys.__stderr__.flush()
        comm.Abort(1)
    sys.excepthook = abort
    return comm


def check_options(args):
    """Newton's options and the levels, before anything is solved or written."""
    mpi = distributed.SOLVERS if args.ranks else [s for s in SOLVERS if s not in ("gamg", "direct")]
    if args.solver not in mpi:
        raise ParameterError(f"--solver {args.solver}: " + (
            f"under mpirun the solver is one of {', '.join(mpi)}" if args.ranks else
            "a PETSc solver, for runs under mpirun (mpirun -n N nitsche run ...)"))
    if getattr(args, "pieces_only", False) and not args.ranks:
        raise ParameterError("--pieces-only is for runs under mpirun (mpirun -n N nitsche run "
                             "...); a serial run writes all its outputs")
    if getattr(args, "local_meshes", False) and not args.ranks:
        raise ParameterError("--local-meshes is for runs under mpirun (mpirun -n N nitsche run "
                             "...); a serial run holds the whole mesh")
    if args.maxiter < 0:
        raise ParameterError(f"--maxiter must be >= 0 (Newton iterations), got {args.maxiter}")
    if not (math.isfinite(args.rtol) and 0 < args.rtol < 1):
        raise ParameterError(f"--rtol must lie in (0, 1) (Newton's relative residual), "
                             f"got {args.rtol:g}")
    if args.command == "study":
        if args.levels < 1:
            raise ParameterError(f"--levels must be >= 1, got {args.levels}")
        if args.start < 0:
            raise ParameterError(f"--start must be >= 0 (0 is the coarsest mesh), got {args.start}")


def _command(args):
    try:
        if args.command == "list":
            for name, case in registry.all_cases().items():
                print(f"{name:<16} {case.summary}")
            return 0
        if args.command == "paper":
            from .paper import paper
            return paper(args.out, fast=args.fast, only=args.cases, overwrite=args.overwrite,
                         source=args.source)
        if args.command == "new":
            return new_case(args.name)
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
        check_options(args)
        if args.command == "run":
            case.check_level(args.level, args.degree, p)
        else:
            case.check_level(args.start + args.levels - 1, args.degree, p,
                             option="the finest level (--start + --levels - 1)")
        out = args.out or os.path.join("out", case.name)
        options = dict(solver=args.solver, maxiter=args.maxiter, rtol=args.rtol)
        return execute(case, args, p, out, options)
    except (ParameterError, KeyError, ValueError) as e:
        msg = e.args[0] if isinstance(e, KeyError) else str(e)
        print(f"nitsche: error: {msg}", file=sys.stderr)
        return USAGE


def new_case(name):
    """Write NAME.py from the commented template of a case module."""
    from importlib.resources import files
    if not name.isidentifier():
        raise ParameterError(f"new {name!r}: the name must be a Python identifier "
                             "(letters, digits, _), e.g. my_block")
    path = f"{name}.py"
    if os.path.exists(path):
        raise ParameterError(f"new {name}: {path} exists; choose another name or remove it")
    text = files("nitsche.templates").joinpath("case_template.py").read_text()
    with open(path, "x") as fh:
        fh.write(text.replace("__NAME__", name))
    print(f"wrote {path}: edit build(), then 'nitsche run {path}' or 'nitsche study {path}'")
    return 0


def execute(case, args, p, out, options):
    """Solve into an OutputFolder and commit it; a failed write leaves the folder as it was."""
    from . import commands
    comm = args.ranks
    if comm is not None and comm.rank > 0:
        if not comm.bcast(None, root=0):  # rank 0 could not open the folder (it says why)
            return USAGE
        return follow(case, args, p, options)
    engine = engine_of(args) if comm is not None else None
    opened, folder = False, None
    try:
        folder = OutputFolder(out, overwrite=args.overwrite)
        with folder:
            opened = True
            if comm is not None:  # the other ranks start solving
                comm.bcast(True, root=0)
            if args.command == "run":
                rc = commands.run(case, args.level, args.degree, p, folder, options,
                                  nested=args.nested, verbose=args.verbose,
                                  global_check=args.global_check, engine=engine,
                                  whole_outputs=whole_outputs(args))
            else:
                rc = commands.study(case, args.levels, args.degree, p, folder, options,
                                    start=args.start)
            paths = folder.commit()
    except (KeyboardInterrupt, Interrupted) as e:
        if folder is None or not folder.committed:
            raise
        signum = e.signum if isinstance(e, Interrupted) else signal.SIGINT
        print(f"nitsche: interrupted ({signal.Signals(signum).name}) after the output was "
              f"written: {out} holds this run, whole", file=sys.stderr)
        return 128 + signum
    except OSError as e:
        print(f"nitsche: error: could not write the output into {out}: {e.strerror or e}; "
              "the folder holds what it held before", file=sys.stderr)
        return WRITE_FAILED
    finally:
        if comm is not None and not opened:
            comm.bcast(False, root=0)
    print(commands.written(paths))
    return rc


def engine_of(args):
    """The distributed engine of a run under mpirun: DistributedProblem.build, on rank-local
    meshes with --local-meshes."""
    meshes = "local" if getattr(args, "local_meshes", False) else "whole"
    return lambda make: distributed.DistributedProblem.build(make, meshes=meshes)


def whole_outputs(args):
    """Whether a run under mpirun writes the outputs beyond result.json and the pieces (not
    with --pieces-only, nor on rank-local meshes, where no rank holds the whole mesh)."""
    return not (args.pieces_only or args.local_meshes)


def follow(case, args, p, options):
    """A rank other than 0 of a run under mpirun: its part of the solve and of the outputs
    (its pieces of the solution; rank 0 commits the folder)."""
    from . import commands
    try:
        return commands.run(case, args.level, args.degree, p, None, options, nested=args.nested,
                            global_check=args.global_check, engine=engine_of(args),
                            whole_outputs=whole_outputs(args))
    except OSError:  # a piece could not be written (raised on every rank): rank 0 reports
        return WRITE_FAILED


def entry():
    """The `nitsche` command: main() and the process's exit with its status, at once where
    a chain stopped before its finest level, whose problem a background thread still
    builds (nitsche.study.Ahead, which the interpreter's exit would wait for): the outputs
    are settled by then."""
    code = main()
    if Ahead.running():
        sys.stdout.flush()
        sys.stderr.flush()
        os._exit(code or 0)
    sys.exit(code)


if __name__ == "__main__":
    entry()
