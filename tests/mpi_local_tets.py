"""A 3D obstacle problem on tetrahedra refined rank-locally (for test_distributed.py):
python mpi_local_tets.py DEGREE LEVEL under mpirun builds it with
DistributedProblem.build(..., meshes="local") (nitsche.meshes.refined: each rank refines its
own cells of the partitioned coarse mesh) and solves it with 'direct'; rank 0 prints one
JSON line (energy, Newton iterations, convergence, ranks, each rank's own cells and dofs).
Imported, `obstacle_3d(degree, level)` is the problem (serial: the whole refined mesh)."""
import json
import sys

import numpy as np
from skfem import ElementTetP1, ElementTetP2, MeshTet

import nitsche as ni
from nitsche import partition
from nitsche.meshes import refined
from nitsche.ops import dot, grad, lap


def obstacle_3d(degree, level):
    """u in H^1 of the unit cube, u = 0 on x = 0 and x = 1, minimizing
    int 1/2 |grad u|^2 + 10 u  subject to  u >= psi = -0.02 - 0.2 (x - 1/2)^2 - 0.1 y z."""
    t = np.linspace(0.0, 1.0, 4)
    mesh = refined(MeshTet.init_tensor(t, t, t), level)
    u = ni.Field("u", mesh, ElementTetP1() if degree == 1 else ElementTetP2(),
                 fixed=lambda x: (x[0] < 1e-12) | (x[0] > 1 - 1e-12))

    def psi(x):
        return -0.02 - 0.2 * (x[0] - 0.5) ** 2 - 0.1 * x[1] * x[2]

    contact = ni.Inequality(gap=lambda u, x: u - psi(x), multiplier=lambda u: -lap(u) + 10.0,
                            scaling=ni.Scaling("auto", h_power=2, stiffness=1.0),
                            on=ni.cells(u, intorder=2 * degree + 2), name="contact")
    return ni.Problem([u], lambda u: 0.5 * dot(grad(u), grad(u)) + 10.0 * u.value, [contact])


def main(degree, level):
    from nitsche.distributed import DistributedProblem
    problem = DistributedProblem.build(lambda: obstacle_3d(degree, level), meshes="local")
    r = problem.minimize(solver="direct")
    mesh = problem.local.fields[0].mesh
    cells = problem.comm.gather(int(partition.own_cells(mesh).size), root=0)
    dofs = problem.comm.gather(int(problem.local.ndofs), root=0)
    if problem.rank == 0:
        print(json.dumps(dict(energy=r.energy, iterations=r.iterations, converged=r.converged,
                              ranks=r.ranks, active_count=r.active_count, mesh_cells=cells,
                              local_dofs=dofs, local_meshes=r.solver_stats["local_meshes"],
                              reason=str(r.reason), stats=r.solver_stats)),
              flush=True)


if __name__ == "__main__":
    main(int(sys.argv[1]), int(sys.argv[2]))
