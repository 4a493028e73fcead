"""Solve shipped cases with nitsche.distributed on the ranks of mpirun (for
test_distributed.py): python mpi_solve.py SOLVER CASE:LEVEL ...; rank 0 prints one JSON line
per case (energy, Newton iterations, convergence, ranks, the constraint report, the
nested-dissection orderings of the MUMPS PETSc links)."""
import json
import sys

from nitsche import cases
from nitsche.distributed import DistributedProblem, mumps_has


def main(solver, specs):
    for spec in specs:
        name, level = spec.split(":")
        case = cases.get(name)
        problem = DistributedProblem.build(
            lambda: case.problem(int(level), case.degrees[0], case.parameters({})))
        r = problem.minimize(solver=solver)
        if problem.rank == 0:
            print(json.dumps(dict(case=name, energy=r.energy, iterations=r.iterations,
                                  converged=r.converged, ranks=r.ranks, solver=r.solver,
                                  stats=r.solver_stats, active_count=r.active_count,
                                  max_violation=r.max_violation, constraints=r.constraints,
                                  orderings=[o for o in ("scotch", "pt-scotch") if mumps_has(o)])),
                  flush=True)


if __name__ == "__main__":
    main(sys.argv[1], sys.argv[2:])
