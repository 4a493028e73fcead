"""Newton's method on MPI ranks with PETSc: the serial engine on a partition of the elements.

Every rank builds the whole Problem (mesh, terms, alpha0: the set-up is replicated) and
holds the whole dof vector x; the work of each Newton step is divided:

- the cells of each mesh are partitioned among the R ranks (METIS on the graph of cells
  sharing a facet, through pymetis), and each element of a term goes to the rank of the
  cell that owns it; rank r evaluates its share J_h^r, grad J_h^r and the element
  Hessians with the same compiled kernels (Term, Assembler on its elements);
- J_h = sum_r J_h^r and grad J_h = sum_r grad J_h^r are reduced on rank 0 and broadcast,
  so that every rank holds the same bits and takes the same decisions;
- the Hessian on the free dofs is a PETSc AIJ matrix: its COO pattern (each rank's
  free-free entries, off-rank ones included) is set once per mesh, its values each step;
  a free dof is owned by the lowest rank among the elements that hold it;
- the Newton systems are solved by a PETSc KSP, the step gathered on every rank.

Newton itself is nitsche.newton.newton, unchanged: the same stopping test, line search and
result; `ranks` is R.
"""
import copy
import os

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla

from .assembly import Assembler
from .linalg import (AMG_THRESHOLD_3D, IndefiniteHessian, NotSolved, lowest_eigenvalue,
                     near_nullspace, positive_diagonal)

SOLVERS = ("auto", "gamg", "direct")
MPI_ENVIRONMENT = ("OMPI_COMM_WORLD_SIZE", "PMI_SIZE", "PMIX_RANK")  # Open MPI, MPICH, PMIx


def launched_by_mpirun():
    """Whether this process was started by mpirun / mpiexec (then `nitsche run` is distributed)."""
    return any(k in os.environ for k in MPI_ENVIRONMENT)


def world():
    from mpi4py import MPI
    return MPI.COMM_WORLD


def set_petsc_options(tokens):
    """PETSc options from command-line tokens, e.g. ['-ksp_type', 'gmres', '-ksp_view']:
    a token after an option is its value unless it is itself an option (a number is a value)."""
    from petsc4py import PETSc
    options, i = PETSc.Options(), 0
    while i < len(tokens):
        name = tokens[i]
        if not name.startswith("-") or _is_number(name):
            raise ValueError(f"PETSc option expected (-name [value]), got {name!r}")
        value = tokens[i + 1] if i + 1 < len(tokens) and (
            not tokens[i + 1].startswith("-") or _is_number(tokens[i + 1])) else None
        options.setValue(name.lstrip("-"), value)
        i += 1 if value is None else 2


def _is_number(s):
    try:
        float(s)
        return True
    except ValueError:
        return False


def element_ranks(terms, free, ranks):
    """The rank of each element of each term: a k-way METIS partition (pymetis) of the graph
    whose vertices are the cells of all meshes, two cells joined when elements they own share
    a free dof (neighbours in a mesh, and across meshes the cells an interface or a membrane
    couples, which thereby land on one rank)."""
    offsets, n = {}, 0
    for t in terms:
        mesh = t.measure.mesh
        if id(mesh) not in offsets:
            offsets[id(mesh)], n = n, n + mesh.t.shape[1]
    vertices = [offsets[id(t.measure.mesh)] + t.cells for t in terms]
    if ranks == 1:
        return [np.zeros(v.size, np.int64) for v in vertices]
    import pymetis
    isfree = np.zeros(1 + max(int(t.global_dofs.max()) for t in terms), bool)
    isfree[free] = True
    rows = np.concatenate([np.repeat(v, t.global_dofs.shape[1]) for v, t in zip(vertices, terms)])
    dofs = np.concatenate([t.global_dofs.ravel() for t in terms])
    keep = isfree[dofs]
    M = sp.csr_matrix((np.ones(keep.sum()), (rows[keep], dofs[keep])), shape=(n, isfree.size))
    graph = (M @ M.T).tocsr()
    graph.setdiag(0)
    graph.eliminate_zeros()
    part = np.asarray(pymetis.part_graph(ranks, xadj=graph.indptr, adjncy=graph.indices)[1])
    return [part[v] for v in vertices]


def restrict(term, elements):
    """The term on some of its elements: the same compiled kernels (same chunk and
    tabulation shapes); a quadratic term already assembled keeps its element parts."""
    part = copy.copy(term)
    part.nel = elements.size
    part.dofs = [d[elements] for d in term.dofs]
    part.field_dofs = [d[elements] for d in term.field_dofs]
    part.global_dofs = term.global_dofs[elements]
    part.cells = term.cells[elements]
    if hasattr(term, "_parts"):
        part._parts = tuple(a[elements] for a in term._parts)
        return part
    part.T = [T if T.shape[0] == 1 else T[elements] for T in term.T]
    part.J = [J if J is None or J.shape[0] == 1 else J[elements] for J in term.J]
    part.W, part.x, part.n = term.W[elements], term.x[elements], term.n[elements]
    part.h, part.alpha0 = term.h[elements], term.alpha0[elements]
    return part


class DistributedProblem:
    """A Problem whose Newton steps are divided among the ranks of an MPI communicator (see
    the module docstring); what is not defined here is the serial problem's."""

    def __init__(self, problem, comm=None):
        self.serial, self.comm = problem, comm or world()
        self.ranks, self.rank = self.comm.size, self.comm.rank
        terms = problem.assembler.terms
        self.element_ranks = self.comm.bcast(element_ranks(terms, problem.free, self.ranks)
                                             if self.rank == 0 else None)
        self.terms = terms
        self.local = {id(t): restrict(t, np.flatnonzero(r == self.rank))
                      for t, r in zip(terms, self.element_ranks) if (r == self.rank).any()}
        self.local_assembler = Assembler(list(self.local.values()), problem.ndofs) \
            if self.local else None
        self.assembler = SummedAssembler(self)
        self.layout = Layout(self)
        self.matrix = self.layout.matrix()

    def __getattr__(self, name):
        return getattr(self.serial, name)

    def summed(self, a):
        """sum over ranks of a (a number or an array), reduced on rank 0 and broadcast."""
        from mpi4py import MPI
        a = np.ascontiguousarray(np.atleast_1d(a), dtype=float)
        total = np.empty_like(a)
        self.comm.Reduce(a, total, op=MPI.SUM, root=0)
        self.comm.Bcast(total, root=0)
        return total

    def energy(self, x):
        """J_h(x)."""
        E = self.local_assembler.energy(x) if self.local_assembler is not None else 0.0
        return float(self.summed(E)[0])

    def gradient(self, x):
        """The gradient of J_h at x (all dofs)."""
        return self.assembler.gradient(x)[1]

    def newton_system(self, x):
        """J_h(x), its gradient on the free dofs and the PETSc Hessian on them (as a
        DistributedMatrix)."""
        E, g, data = self.assembler.evaluate(x)
        self.layout.set_values(data)
        return E, g[self.serial.free], self.matrix

    def minimize(self, x0=None, solver="auto", **options):
        """Newton's method (nitsche.newton.newton) with a PETSc solver: 'gamg' (CG + GAMG),
        'direct' (LU) or 'auto' (as the serial 'auto': AMG in 3D above AMG_THRESHOLD_3D
        unknowns, else direct); PETSc options (-ksp_type ...) override their settings."""
        from .newton import newton
        return newton(self, x0, solver=KrylovSolver(solver, self), **options)


class SummedAssembler:
    """The serial Assembler's evaluations (of all terms or of the given serial terms) as sums
    over the ranks of their local assemblies; the Hessian data stays this rank's (on its
    local pattern)."""

    def __init__(self, dp):
        self.dp, self.terms = dp, dp.terms

    def evaluate(self, x, terms=None, hessian=True):
        dp = self.dp
        mine = None if terms is None else [dp.local[id(t)] for t in terms if id(t) in dp.local]
        if dp.local_assembler is None or mine == []:
            E, g, data = 0.0, np.zeros(dp.serial.ndofs), np.zeros(0) if hessian else None
        else:
            E, g, data = dp.local_assembler.evaluate(x, mine, hessian)
        return float(dp.summed(E)[0]), dp.summed(g), data

    def gradient(self, x, terms=None):
        """J(x) and its gradient, summed over the ranks."""
        return self.evaluate(x, terms, hessian=False)[:2]


class Layout:
    """The free dofs numbered rank after rank for PETSc (order[k]: the serial free index of
    PETSc's dof k) and the COO pattern of each rank's free-free Hessian entries."""

    def __init__(self, dp):
        problem = dp.serial
        owner = np.full(problem.ndofs, dp.ranks - 1)
        for t, r in zip(dp.terms, dp.element_ranks):
            np.minimum.at(owner, t.global_dofs.ravel(), np.repeat(r, t.global_dofs.shape[1]))
        free_owner = owner[problem.free]
        self.order = np.argsort(free_owner, kind="stable")
        self.counts = np.bincount(free_owner, minlength=dp.ranks)
        self.start = int(self.counts[:dp.rank].sum())
        self.mine = self.order[self.start: self.start + self.counts[dp.rank]]
        self.n, self.comm = problem.free.size, dp.comm
        number = -np.ones(problem.ndofs, np.int64)
        number[problem.free[self.order]] = np.arange(self.n)
        a = dp.local_assembler
        if a is None:
            self.keep, self.rows, self.cols = np.zeros(0, np.int64), np.zeros(0), np.zeros(0)
            return
        rows = number[np.repeat(np.arange(problem.ndofs), np.diff(a.indptr))]
        cols = number[a.indices]
        self.keep = np.flatnonzero((rows >= 0) & (cols >= 0))
        self.rows, self.cols = rows[self.keep], cols[self.keep]

    def matrix(self):
        """The PETSc matrix, its pattern set once (values: set_values)."""
        from petsc4py import PETSc
        local = int(self.counts[self.comm.rank])
        A = PETSc.Mat().create(comm=self.comm)
        A.setSizes(((local, self.n), (local, self.n)))
        A.setType(PETSc.Mat.Type.AIJ)
        A.setPreallocationCOO(self.rows.astype(PETSc.IntType), self.cols.astype(PETSc.IntType))
        self.A = A
        return DistributedMatrix(A, self)

    def set_values(self, data):
        """The matrix values from this rank's CSR data (entries of all ranks summed)."""
        from petsc4py import PETSc
        self.A.setValuesCOO(np.ascontiguousarray(data[self.keep], dtype=PETSc.ScalarType),
                            addv=PETSc.InsertMode.INSERT_VALUES)

    def vector(self, v=None):
        """A PETSc vector, this rank's entries from the replicated free vector v (or zero)."""
        x = self.A.createVecRight()
        x.setArray(np.zeros(x.getLocalSize()) if v is None else v[self.mine])
        return x

    def gather(self, x):
        """A PETSc vector as a replicated free vector (serial numbering) on every rank."""
        local = np.ascontiguousarray(x.getArray(readonly=True))
        whole = np.empty(self.n)
        self.comm.Allgatherv(local, [whole, self.counts])
        out = np.empty(self.n)
        out[self.order] = whole
        return out


class DistributedMatrix:
    """The PETSc Hessian seen by the serial Newton: A @ v and A.diagonal() on replicated
    free vectors."""

    def __init__(self, mat, layout):
        self.mat, self.layout = mat, layout

    def __matmul__(self, v):
        y = self.layout.vector()
        self.mat.mult(self.layout.vector(v), y)
        return self.layout.gather(y)

    def diagonal(self):
        return self.layout.gather(self.mat.getDiagonal())


class KrylovSolver:
    """PETSc's solvers behind the interface of nitsche.linalg's (solve, is_positive_definite,
    stats).  'gamg': CG preconditioned by GAMG (smoothed aggregation) with the near-nullspace
    of nitsche.linalg.near_nullspace (rigid-body modes), to Newton's forcing tolerance;
    'direct': LU by MUMPS when PETSc has it, else each rank a sequential LU of the whole
    matrix (PCREDUNDANT).  PETSc options (-ksp_type, -pc_type ...) are applied last."""

    def __init__(self, name, dp, rtol=1e-10, maxiter=2000):
        from petsc4py import PETSc
        if name not in SOLVERS:
            raise ValueError(f"solver must be one of {', '.join(SOLVERS)} on MPI ranks, not {name!r}")
        if name == "auto":
            name = "gamg" if dp.serial.dim == 3 and dp.serial.free.size > AMG_THRESHOLD_3D else "direct"
        self.name, self.dp, self.rtol = f"petsc-{name}", dp, rtol
        ksp = PETSc.KSP().create(comm=dp.comm)
        ksp.setOperators(dp.layout.A)
        pc = ksp.getPC()
        if name == "gamg":
            ksp.setType("cg")
            pc.setType("gamg")
            ksp.setTolerances(atol=0.0, max_it=maxiter)
        elif PETSc.Sys.hasExternalPackage("mumps"):
            ksp.setType("preonly")
            pc.setType("lu")
            pc.setFactorSolverType("mumps")
        else:
            ksp.setType("preonly")
            pc.setType("redundant")  # PCREDUNDANT's own solver: LU
        self.ksp, self.kind, self.iterations = ksp, name, []

    def prepare(self, problem):
        """The near-nullspace of GAMG: rigid-body modes of the vector fields, constants."""
        if self.kind != "gamg":
            return
        from petsc4py import PETSc
        B = np.linalg.qr(near_nullspace(self.dp.serial))[0]
        vectors = [self.dp.layout.vector(b) for b in B.T]
        self.dp.layout.A.setNearNullSpace(PETSc.NullSpace().create(vectors=vectors, comm=self.dp.comm))

    def solve(self, A, b, rtol=0.0):
        from petsc4py import PETSc
        positive_diagonal(A)
        if self.kind == "gamg":
            self.ksp.setTolerances(rtol=max(rtol, self.rtol))
        self.ksp.setFromOptions()
        x = self.dp.layout.vector()
        self.ksp.solve(self.dp.layout.vector(b), x)
        reason = self.ksp.getConvergedReason()
        self.iterations.append(self.ksp.getIterationNumber())
        R = PETSc.KSP.ConvergedReason
        if reason in (R.DIVERGED_INDEFINITE_MAT, R.DIVERGED_INDEFINITE_PC,
                      R.DIVERGED_PCSETUP_FAILED):
            raise IndefiniteHessian(f"PETSc KSP: {reason_name(reason)}")
        if reason < 0:
            raise NotSolved(f"PETSc KSP ({self.ksp.getType()}, {self.ksp.getPC().getType()}): "
                            f"{reason_name(reason)}")
        dx = self.dp.layout.gather(x)
        if not np.all(np.isfinite(dx)):
            raise IndefiniteHessian("singular Newton matrix")
        return dx

    def is_positive_definite(self, A):
        """As AMGCG's: a positive diagonal, and LOBPCG preconditioned by this solver's
        preconditioner estimates the smallest eigenvalue above 0 (evidence, not proof; with
        the LU preconditioner it converges at once)."""
        try:
            positive_diagonal(A)
        except IndefiniteHessian:
            return False
        self.ksp.setUp()
        pc, layout = self.ksp.getPC(), self.dp.layout

        def precondition(v):
            y = layout.vector()
            pc.apply(layout.vector(np.ravel(v)), y)
            return layout.gather(y)
        n = layout.n
        operator = spla.LinearOperator((n, n), matvec=lambda v: A @ np.ravel(v), dtype=float)
        return bool(lowest_eigenvalue(operator, spla.LinearOperator((n, n), matvec=precondition,
                                                                    dtype=float)) > 0)

    def stats(self):
        return dict(ranks=self.dp.ranks, ksp_iterations=list(self.iterations))


def reason_name(reason):
    from petsc4py import PETSc
    names = {v: k for k, v in vars(PETSc.KSP.ConvergedReason).items() if isinstance(v, int)}
    return names.get(reason, str(reason))
