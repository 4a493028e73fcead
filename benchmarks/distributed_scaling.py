"""Strong scaling and memory per rank of the distributed engine: under
`mpirun -n R python benchmarks/distributed_scaling.py CASE LEVEL SOLVER [--local-meshes] [NAME=VALUE ...]`
(the case's parameters, as `nitsche run --set NAME=VALUE`), each
rank builds its part of the case's problem (nitsche.partition; with --local-meshes on the
meshes of its own cells, nitsche.local_mesh) and Newton solves from zero; then every rank
writes its piece of the solution (nitsche.pvtu), and rank 0 rebuilds the whole problem and
writes its VTU (not on local meshes), as `mpirun nitsche run` did before the pieces (and still does for the case's
own figures and report unless --pieces-only).  Rank 0 prints one JSON line: set-up, Newton and
output seconds (wall: the slowest rank's; CPU: each rank's, less moved by other jobs on shared
cores), Newton iterations, energy, the numbers summed (reduced + broadcast) and all-gathered
during Newton, the free dofs each rank holds and owns (the others held are its ghosts, whose
values the scatters move), and each rank's peak
resident memory (MiB) after the imports, the set-up, the solve, the pieces and (rank 0) the
whole problem's VTU; the PETSc options (PETSC_OPTIONS, e.g. "-pc_type redundant" for the
direct solver without MUMPS), whether PETSc has MUMPS, each rank's seconds and count of the
factorizations (PETSc's log events: symbolic, numeric, PCSetUp whole, MatSolve), MUMPS's
ordering, its factor's entries (estimated, actual) and flops, the minimum check's evidence and the
load average before and after."""
import json
import os
import resource
import shutil
import sys
import tempfile
import time

from nitsche import cases
from nitsche.commands import whole
from nitsche.distributed import DistributedProblem
from nitsche.io import write_vtu
from nitsche.pvtu import write_pieces


def peak_mib():
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024


def main(name, level, solver, meshes="whole", sets=()):
    case = cases.get(name)
    p = case.parameters(dict(s.split("=", 1) for s in sets))
    from petsc4py import PETSc  # (its memory counted in the baseline)
    PETSc.Log.begin()
    load = os.getloadavg()[0]
    baseline = peak_mib()
    t, c = time.perf_counter(), time.process_time()
    problem = DistributedProblem.build(lambda: case.problem(level, case.degrees[0], p), meshes=meshes)
    setup, setup_cpu = time.perf_counter() - t, time.process_time() - c
    after_setup = peak_mib()
    c = time.process_time()
    result = problem.minimize(solver=solver)
    newton_cpu = time.process_time() - c
    factorization = factorization_seconds()
    after_solve = peak_mib()
    comm = problem.comm
    folder = comm.bcast(tempfile.mkdtemp() if comm.rank == 0 else None, root=0)
    comm.Barrier()
    t, c = time.perf_counter(), time.process_time()
    write_pieces("solution", problem, result.x, folder)
    pieces, pieces_cpu = time.perf_counter() - t, time.process_time() - c
    after_pieces = peak_mib()
    stats = result.solver_stats
    row = dict(case=name, level=level, sets=list(sets), unknowns=int(problem.unknowns), ranks=comm.size,
               meshes=meshes,
               local_dofs=comm.gather(int(problem.local.ndofs), root=0),
               setup_seconds=comm.allreduce(setup, op=max_op()),
               newton_seconds=comm.allreduce(result.seconds, op=max_op()),
               pieces_seconds=comm.allreduce(pieces, op=max_op()),
               timings=result.timings, iterations=result.iterations, energy=result.energy,
               ksp_iterations=stats["ksp_iterations"], off_rank_entries=stats["off_rank_entries"],
               summed_numbers=stats["summed_numbers"], gathered_numbers=stats["gathered_numbers"],
               fixed=int(problem.fixed.size),
               held_free=comm.gather(int(problem.layout.held.size), root=0),
               owned_free=comm.gather(int(problem.layout.mine.size), root=0),
               setup_cpu_seconds=comm.gather(round(setup_cpu, 2), root=0),
               newton_cpu_seconds=comm.gather(round(newton_cpu, 2), root=0),
               pieces_cpu_seconds=comm.gather(round(pieces_cpu, 2), root=0),
               baseline_mib=comm.gather(round(baseline), root=0),
               setup_peak_mib=comm.gather(round(after_setup), root=0),
               solve_peak_mib=comm.gather(round(after_solve), root=0),
               pieces_peak_mib=comm.gather(round(after_pieces), root=0),
               petsc_options=os.environ.get("PETSC_OPTIONS", ""), solver=result.solver,
               mumps=PETSc.Sys.hasExternalPackage("mumps"), factorization=comm.gather(factorization, root=0),
               negative_pivots=stats["negative_pivots"], lobpcg_steps=stats["lobpcg_steps"],
               **{k: stats[k] for k in ("mumps_ordering", "factor_entries_estimated",
                                        "factor_entries", "factor_flops") if k in stats})
    if comm.rank == 0 and meshes == "whole":
        t, c = time.perf_counter(), time.process_time()
        serial, r = whole(case, problem, result, case.degrees[0], p)
        write_vtu(os.path.join(folder, "whole"), serial, r.x)
        row.update(whole_vtu_seconds=round(time.perf_counter() - t, 2),
                   whole_vtu_cpu_seconds=round(time.process_time() - c, 2),
                   whole_vtu_peak_mib=round(peak_mib()))
    if comm.rank == 0:
        shutil.rmtree(folder)
        row.update(load_average=[round(load, 2), round(os.getloadavg()[0], 2)])
        print(json.dumps(row), flush=True)


def factorization_seconds():
    """{event: [wall seconds, count]} on this rank since PETSc.Log.begin(), of the events that
    occurred: MUMPS's or PETSc's symbolic and numeric factorizations, the whole PCSetUp
    (PCREDUNDANT's: also gathering the matrix on every rank), the solves."""
    from petsc4py import PETSc
    events = ("MatCholFctrSym", "MatCholFctrNum", "MatLUFactorSym", "MatLUFactorNum", "PCSetUp",
              "MatSolve")
    info = {e: PETSc.Log.Event(e).getPerfInfo() for e in events}
    return {e: [round(v["time"], 3), v["count"]] for e, v in info.items() if v["count"]}


def max_op():
    from mpi4py import MPI
    return MPI.MAX


if __name__ == "__main__":
    main(sys.argv[1], int(sys.argv[2]), sys.argv[3] if len(sys.argv) > 3 else "gamg",
         "local" if "--local-meshes" in sys.argv[4:] else "whole", [a for a in sys.argv[4:] if "=" in a])
