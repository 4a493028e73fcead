"""The minimum check of nitsche.distributed on the ranks of mpirun (for test_distributed.py):
python mpi_minimum.py; rank 0 prints one JSON line per problem with Newton's verdict, the
check's LOBPCG estimates and steps, MUMPS's negative pivots, whether PETSc has MUMPS, the
numbers all-gathered during Newton's method and the smallest eigenvalue and the number of
negative eigenvalues of the whole problem's Hessian at the result (dense, on rank 0).

- `saddle`: (u^2 - 1)^2 + |grad u|^2 from u = 0, a stationary point whose Hessian
  -4 M + 2 K has a positive diagonal but a negative eigenvalue (the constant): the check
  must fail there, by the inertia of MUMPS's L D L^T or by LOBPCG (the diagonal passes);
- `well`: the same from u = 0.2, converged to the well u = 1 (positive definite);
- `saddle-redundant`, `well-redundant`: the same with -pc_type redundant (PETSc's LU on
  every rank: LOBPCG, with or without MUMPS);
- `obstacle`: the shipped case at level 2, P2 elements (lambda = f + lap u depends on u, so
  J_h is not certified convex and the Hessian is checked), with GAMG (a preconditioner that
  is not exact);
- `obstacle-p1`: the same with P1 elements, whose J_h is certified convex on every rank
  (Problem.convex): no eigenvalue estimate."""
import json

import numpy as np
from mpi4py import MPI
from petsc4py import PETSc
from skfem import ElementTriP1, MeshTri

import nitsche as ni
from nitsche import cases
from nitsche.distributed import DistributedProblem, set_petsc_options
from nitsche.ops import dot, grad


def double_well():
    u = ni.Field("u", MeshTri().refined(3), ElementTriP1())
    return ni.Problem([u], lambda u: (u.value ** 2 - 1) ** 2 + dot(grad(u), grad(u)))


def spectrum(problem, x):
    """The smallest eigenvalue of the Hessian on the free dofs and the number of its
    negative ones (dense)."""
    H = problem.hessian(x)[problem.free][:, problem.free].toarray()
    eigenvalues = np.linalg.eigvalsh(H)
    return float(eigenvalues[0]), int((eigenvalues < 0).sum())


def main():
    comm = MPI.COMM_WORLD
    obstacle = cases.get("obstacle")
    make_obstacle = lambda: obstacle.problem(2, 2, obstacle.parameters({}))  # noqa: E731
    make_obstacle_p1 = lambda: obstacle.problem(2, 1, obstacle.parameters({}))  # noqa: E731
    runs = [("saddle", double_well, "direct", 0.0, []), ("well", double_well, "direct", 0.2, []),
            ("saddle-redundant", double_well, "direct", 0.0, ["-pc_type", "redundant"]),
            ("well-redundant", double_well, "direct", 0.2, ["-pc_type", "redundant"]),
            ("obstacle", make_obstacle, "gamg", None, []),
            ("obstacle-p1", make_obstacle_p1, "gamg", None, [])]
    for name, make, solver, start, options in runs:
        set_petsc_options(options)
        dp = DistributedProblem.build(make, comm)
        x0 = None if start is None else np.full(dp.ndofs, start)
        r = dp.minimize(x0=x0, solver=solver)
        PETSc.Options().delValue("pc_type")
        if dp.rank == 0:
            stats = r.solver_stats
            lowest, negative = spectrum(make(), r.x)
            print(json.dumps(dict(problem=name, ranks=r.ranks, converged=r.converged,
                                  reason=r.reason, minimum=r.minimum, estimates=stats["lobpcg_estimates"],
                                  steps=stats["lobpcg_steps"],
                                  negative_pivots=stats["negative_pivots"],
                                  mumps=PETSc.Sys.hasExternalPackage("mumps"),
                                  gathered_numbers=stats["gathered_numbers"],
                                  lowest=lowest, negative=negative)), flush=True)


if __name__ == "__main__":
    main()
