"""Where the distributed solve reaches its peak resident memory on each rank, phase by phase:
under `mpirun -n R python benchmarks/distributed_memory_phases.py CASE LEVEL [SOLVER]`, a
thread per rank samples VmRSS every 5 ms (benchmarks/memory_phases.py's sampler and labels)
while each rank builds its part of the problem and Newton solves from zero; rank 0 prints one
JSON line: per rank, VmHWM after the set-up and after the solve, and the highest sample of
each phase (set-up; Newton: evaluate, matrix values, KSP solve, line search, minimum check,
constraint report, the result's all-gather), highest first, and the resident memory at the
start of each Newton iteration (its growth over the iterations) and the CPU seconds of the
solve (newton_cpu_s, process time); with PETSc's allocations
traced (PETSC_OPTIONS=-malloc_debug) also what PETSc holds then (PetscMallocGetCurrentUsage),
to tell PETSc's objects from the rest of the heap.  A diagnostic: the seconds are not
timings."""
import ctypes
import json
import os
import sys
import threading
import time

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from memory_phases import label, sampler, samples, stack, status  # noqa: E402


def petsc_mib():
    """The memory PETSc's allocations hold now (MiB; 0 unless PETSc traces them)."""
    with open("/proc/self/maps") as fh:  # the libpetsc petsc4py loaded
        path = next(line.split()[-1] for line in fh if "/libpetsc.so" in line)
    lib = ctypes.CDLL(path)
    used = ctypes.c_double()
    lib.PetscMallocGetCurrentUsage(ctypes.byref(used))
    return used.value / 2 ** 20


def main(name, level, solver):
    threading.Thread(target=sampler, args=(None,), daemon=True).start()
    from petsc4py import PETSc  # noqa: F401 (its memory counted in the imports)
    from nitsche import assembly, cases, distributed, newton
    for owner, fn, what in [
            (distributed.DistributedProblem, "build", "set-up"), (newton, "newton", "newton"),
            (assembly.Assembler, "evaluate", "evaluate"),
            (distributed.Layout, "assembled", "gradient sum"),
            (distributed.Layout, "set_values", "matrix values"),
            (distributed.KrylovSolver, "prepare", "near-nullspace"),
            (distributed.KrylovSolver, "solve", "KSP solve"),
            (distributed.DistributedMatrix, "__matmul__", "A v"),
            (newton, "energy_search", "line search"),
            (distributed.KrylovSolver, "is_positive_definite", "minimum check"),
            (distributed.DistributedProblem, "constraint_report", "constraint report"),
            (distributed.DistributedProblem, "whole", "all-gather")]:
        label(owner, fn, what)
    iterations = []  # (VmRSS, PETSc's) at each Newton system
    system = distributed.DistributedProblem.newton_system

    def traced(self, x):
        iterations.append((round(status("VmRSS")), round(petsc_mib(), 1)))
        return system(self, x)
    distributed.DistributedProblem.newton_system = traced
    case = cases.get(name)
    p = case.parameters({})
    stack[:] = ["run"]
    imports = status("VmHWM")
    problem = distributed.DistributedProblem.build(lambda: case.problem(level, case.degrees[0], p))
    after_setup = status("VmHWM")
    cpu = time.process_time()
    result = problem.minimize(solver=solver)
    cpu = time.process_time() - cpu
    after_solve = status("VmHWM")
    peaks = {}
    for _, rss, where, _ in list(samples):
        peaks[where] = max(rss, peaks.get(where, 0.0))
    row = dict(ranks=problem.ranks, newton_cpu_s=round(cpu, 2), imports_mib=round(imports), setup_mib=round(after_setup),
               solve_mib=round(after_solve), end_rss_mib=round(status("VmRSS")),
               end_petsc_mib=round(petsc_mib(), 1),
               rss_petsc_per_iteration=iterations,
               phases={w: round(r) for w, r in sorted(peaks.items(), key=lambda kv: -kv[1])})
    rows = problem.comm.gather(row, root=0)
    if problem.rank == 0:
        print(json.dumps(dict(case=name, level=level, solver=solver, unknowns=int(problem.free.size),
                              iterations=result.iterations, energy=result.energy,
                              load=os.getloadavg(), rows=rows)), flush=True)


if __name__ == "__main__":
    main(sys.argv[1], int(sys.argv[2]), sys.argv[3] if len(sys.argv) > 3 else "gamg")
