"""A load-path case on MPI ranks against the serial engine: CPU time and peak memory per rank,
the steps' Newton iterations and energies.

    python benchmarks/distributed_path.py OUT.json CASE LEVEL SOLVER [NAME=VALUE ...]            # serial
    mpirun -n R python benchmarks/distributed_path.py OUT.json CASE LEVEL SOLVER [NAME=VALUE ...]

Serially (no mpirun) the case's problem is built and its path solved with SOLVER (superlu: an
exact LU, as PETSc's); under mpirun each rank builds its part (nitsche.distributed) and the
path is solved with SOLVER (direct, gamg or auto).  One row per run is appended to OUT.json
(a list): unknowns, ranks (0: serial), set-up and path CPU seconds and the peak resident
memory (MiB) after the imports, the set-up and the path of each rank, the path's wall
seconds, per accepted step (time, Newton iterations, energy, cuts), whether a rank's Hessian
pattern grew (pairings in the current configuration), every Newton run of the path, failed
attempts included (`attempts`: Newton iterations, converged, energy, residual per iterate), the
load average before and after; under mpirun also PETSC_OPTIONS (e.g. "-pc_type redundant")
and each rank's factorization seconds and counts (distributed_scaling.factorization_seconds)."""
import json
import os
import resource
import sys
import time

from nitsche import cases
from nitsche.distributed import launched_by_mpirun


def peak_mib():
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024


def main(out, name, level, solver, sets):
    case = cases.get(name)
    p = case.parameters(dict(kv.split("=") for kv in sets))
    load = os.getloadavg()
    comm = None
    if launched_by_mpirun():
        from mpi4py import MPI
        from petsc4py import PETSc  # (its memory counted in the baseline)
        PETSc.Log.begin()
        comm = MPI.COMM_WORLD
    baseline = peak_mib()
    c = time.process_time()
    if comm is None:
        problem = case.problem(level, case.degrees[0], p)
        local = problem
    else:
        from nitsche.distributed import DistributedProblem
        problem = DistributedProblem.build(lambda: case.problem(level, case.degrees[0], p), comm)
        local = problem.local
    setup_cpu, after_setup, entries = time.process_time() - c, peak_mib(), local.assembler.nnz
    attempts, minimize = [], problem.minimize

    def recorded(*args, **kwargs):
        result = minimize(*args, **kwargs)
        attempts.append([result.iterations, bool(result.converged), float(result.energy),
                         [float(r) for r in result.residuals]])
        return result
    problem.minimize = recorded
    c, t = time.process_time(), time.perf_counter()
    case.solve(problem, None, solver=solver)
    path_cpu, wall, after_path = time.process_time() - c, time.perf_counter() - t, peak_mib()

    def each(v):
        return [v] if comm is None else comm.gather(v, root=0)
    grew = local.assembler.nnz > entries
    row = dict(case=name, level=level, solver=solver, parameters=dict(kv.split("=") for kv in sets),
               unknowns=int(problem.free.size), ranks=0 if comm is None else comm.size,
               setup_cpu_seconds=each(round(setup_cpu, 2)), path_cpu_seconds=each(round(path_cpu, 2)),
               path_wall_seconds=each(round(wall, 2)), baseline_mib=each(round(baseline)),
               setup_peak_mib=each(round(after_setup)), path_peak_mib=each(round(after_path)),
               pattern_grew=each(bool(grew)), converged=bool(problem.path.converged),
               steps=[[s["time"], s["iterations"], s["energy"], s["cuts"]] for s in problem.path.steps],
               attempts=attempts,
               load_average=[round(a, 2) for a in (load[0], os.getloadavg()[0])])
    if comm is not None:
        from distributed_scaling import factorization_seconds
        row.update(petsc_options=os.environ.get("PETSC_OPTIONS", ""),
                   factorization=comm.gather(factorization_seconds(), root=0))
    if comm is None or comm.rank == 0:
        rows = json.load(open(out)) if os.path.exists(out) else []
        with open(out, "w") as f:
            json.dump(rows + [row], f, indent=1)
        print(json.dumps(row), flush=True)


if __name__ == "__main__":
    main(sys.argv[1], sys.argv[2], int(sys.argv[3]), sys.argv[4], sys.argv[5:])
