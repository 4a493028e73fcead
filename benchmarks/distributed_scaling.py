"""Strong scaling and memory per rank of the distributed engine: under
`mpirun -n R python benchmarks/distributed_scaling.py CASE LEVEL SOLVER`, each rank builds its
part of the case's problem (nitsche.partition) and Newton solves from zero; rank 0 prints
one JSON line: set-up and Newton seconds (wall: the slowest rank's; CPU: each rank's, less
moved by other jobs on shared cores), Newton iterations, energy, and each rank's peak
resident memory (MiB) after the imports, after the set-up and after the solve."""
import json
import resource
import sys
import time

from nitsche import cases
from nitsche.distributed import DistributedProblem


def peak_mib():
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024


def main(name, level, solver):
    case = cases.get(name)
    p = case.parameters({})
    from petsc4py import PETSc  # noqa: F401 (its memory counted in the baseline)
    baseline = peak_mib()
    t, c = time.perf_counter(), time.process_time()
    problem = DistributedProblem.build(lambda: case.problem(level, case.degrees[0], p))
    setup, setup_cpu = time.perf_counter() - t, time.process_time() - c
    after_setup = peak_mib()
    c = time.process_time()
    result = problem.minimize(solver=solver)
    newton_cpu = time.process_time() - c
    comm = problem.comm
    row = dict(case=name, level=level, unknowns=int(problem.free.size), ranks=comm.size,
               setup_seconds=comm.allreduce(setup, op=max_op()),
               newton_seconds=comm.allreduce(result.seconds, op=max_op()),
               timings=result.timings, iterations=result.iterations, energy=result.energy,
               ksp_iterations=result.solver_stats["ksp_iterations"],
               off_rank_entries=result.solver_stats["off_rank_entries"],
               setup_cpu_seconds=comm.gather(round(setup_cpu, 2), root=0),
               newton_cpu_seconds=comm.gather(round(newton_cpu, 2), root=0),
               baseline_mib=comm.gather(round(baseline), root=0),
               setup_peak_mib=comm.gather(round(after_setup), root=0),
               peak_mib=comm.gather(round(peak_mib()), root=0))
    if comm.rank == 0:
        print(json.dumps(row), flush=True)


def max_op():
    from mpi4py import MPI
    return MPI.MAX


if __name__ == "__main__":
    main(sys.argv[1], int(sys.argv[2]), sys.argv[3] if len(sys.argv) > 3 else "gamg")
