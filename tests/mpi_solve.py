"""Solve shipped cases with nitsche.distributed on the ranks of mpirun (for
test_distributed.py): python mpi_solve.py SOLVER [--local-meshes] CASE:LEVEL ...; rank 0
prints one JSON line per case (energy, Newton iterations, convergence, ranks, the constraint
report, the nested-dissection orderings of the MUMPS PETSc links, each rank's dofs, own
cells and ghost cells)."""
import json
import sys

from nitsche import cases, partition
from nitsche.distributed import DistributedProblem, mumps_has


def main(solver, specs):
    meshes = "local" if "--local-meshes" in specs else "whole"
    for spec in (s for s in specs if s != "--local-meshes"):
        name, level = spec.split(":")
        case = cases.get(name)
        problem = DistributedProblem.build(
            lambda: case.problem(int(level), case.degrees[0], case.parameters({})), meshes=meshes)
        r = problem.minimize(solver=solver)
        dofs = problem.comm.gather(int(problem.local.ndofs), root=0)
        cells = problem.comm.gather(sum(partition.own_cells(f.mesh).size for f in problem.local.fields), root=0)
        ghosts = problem.comm.gather(sum(f.mesh.nelements for f in problem.local.fields), root=0)
        if problem.rank == 0:
            print(json.dumps(dict(case=name, energy=r.energy, iterations=r.iterations,
                                  converged=r.converged, ranks=r.ranks, solver=r.solver,
                                  stats=r.solver_stats, active_count=r.active_count,
                                  max_violation=r.max_violation, constraints=r.constraints,
                                  orderings=[o for o in ("scotch", "pt-scotch") if mumps_has(o)],
                                  local_dofs=dofs, mesh_cells=cells,
                                  ghost_cells=None if ghosts is None else
                                  [g - c for g, c in zip(ghosts, cells)])),
                  flush=True)


if __name__ == "__main__":
    main(sys.argv[1], sys.argv[2:])
