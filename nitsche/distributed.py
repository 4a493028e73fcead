"""Newton's method on MPI ranks with PETSc: the serial engine on rank-local problems.

Each rank builds its own problem inside nitsche.partition.local (DistributedProblem.build):
the bases, measures and terms of its own cells only (a METIS partition of each mesh; an
element belongs to the rank of the cell that owns it), so the set-up and its memory are
divided among the ranks; the meshes stay whole on every rank unless they are rank-local
(build(..., meshes="local"): nitsche.local_mesh, dofs numbered by global_numbers).

- a free dof is owned by the lowest rank among the elements that hold it; the free dofs a
  rank's elements hold are its owned dofs and its ghosts;
- the free vectors of Newton's method (x's free part, the gradient's, the step, A v) are,
  on each rank, arrays of its held free dofs in its local numbering (Layout.held: the owned
  dofs first, in PETSc's order, then the ghosts), which newton takes and gives back through
  free_part(x) and with_free(x, v): the gradient is summed by a PETSc scatter that adds the
  ghosts' values to their owners' and sends the sums back (Layout.assembled), the step and
  A v are scattered from the PETSc vector to the held dofs (Layout.held_values, the
  scatter's own array); norms and dot products sum the owned entries (the first ones) over
  the ranks (newton.norm, newton.dot), J_h is summed; so only scalars, the ghosts' values
  and the fixed dofs' gradient entries (the reactions) travel, and every rank holds the
  same bits of every number it decides on; x itself and the gradient keep the serial
  length (the local assembler's dof numbering);
- the Hessian on the free dofs is a PETSc AIJ matrix: its COO pattern (each rank's
  free-free entries, those of rows another rank owns included) is set once per mesh, its
  values each step; the Newton systems are solved by a PETSc KSP;
- an interface paired in the current configuration (nitsche.sliding) is paired on each
  rank for its own points; the rank holds the dofs of the other body's cells along the
  surface (ghosts: the current surface and any cell a pairing reaches), and a pairing that
  grows a rank's pattern gives every rank a new PETSc matrix on the grown one;
- the whole free vector is all-gathered for the result (once per solve); the minimum check
  at convergence is the inertia of MUMPS's L D L^T ('direct' where PETSc has MUMPS), else
  LOBPCG on the PETSc vectors (lowest_eigenvalue: products, the preconditioner and
  reductions of a few numbers); the constraint report is the serial
  engine's (problem.report_constraints) on each rank's elements, combined from a few
  numbers per rank (alpha0's medians by a distributed selection, order_statistics);
- petsc4py keeps the parallel PETSc objects Python drops until PETSc.garbage_cleanup:
  it runs once per Newton system (collect).

Newton itself is nitsche.newton.newton, unchanged but for the norms, dot products and free
parts it asks of the problem: the same stopping test, line search and result; `ranks` is R.
"""
import os
import warnings

import numpy as np

from . import partition
from .linalg import AMG_THRESHOLD_3D, IndefiniteHessian, NotSolved, near_nullspace
from .problem import report_constraints

SOLVERS = ("auto", "gamg", "direct")
# set by Open MPI's and MPICH's launchers for their processes (not PMIX_RANK: a process whose
# parent initialized MPI by itself, as a singleton, inherits that one)
MPI_ENVIRONMENT = ("OMPI_COMM_WORLD_SIZE", "PMI_SIZE")


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


class DistributedProblem:
    """A problem whose Newton steps are divided among the ranks of an MPI communicator (see
    the module docstring): `local` is this rank's part, built inside
    nitsche.partition.local(comm); what is not defined here is the local problem's."""

    def __init__(self, local, comm=None):
        self.local, self.comm = local, comm or world()
        self.ranks, self.rank = self.comm.size, self.comm.rank
        if getattr(local, "partition", None) != (self.rank, self.ranks):
            raise ValueError("a DistributedProblem needs this rank's part of the problem: build it "
                             "inside nitsche.partition.local(comm), e.g. DistributedProblem.build(make)")
        from mpi4py import MPI
        self.alpha0_limits = {k: self.comm.allreduce(v, op=MPI.MIN)
                              for k, v in local.alpha0_limits.items()}
        self.elements = self.comm.allgather([t.nel for t in local.assembler.terms])  # per rank, per term
        self.assembler = SummedAssembler(self)
        self.summed_numbers = 0  # numbers reduced on rank 0 and broadcast (the O(N) traffic)
        self.layout = Layout(self)
        self.matrix = self.layout.matrix()
        self.off_rank_entries = self.comm.allreduce(self.layout.off_rank)
        self.straddling = self.comm.allreduce(sum(
            int((self.layout.owner[t.global_dofs] != self.rank).any(axis=1).sum())
            for t in local.constraint_terms))  # constraint elements holding another rank's dofs
        self.owned_fixed = self.layout.owner[local.fixed] == self.rank
        self.layout.owner = None  # (a rank per dof) read by the set-up only
        self.fixed_fields = [f.name for f in local.fields  # fields with fixed dofs on any rank
                             if self.comm.allreduce(int(f.fixed_dofs.size))]
        meshes = {id(f.mesh): f.mesh for f in local.fields}.values()
        self.local_meshes = sum(hasattr(m, "numbering") for m in meshes)  # rank-local ones

    @classmethod
    def build(cls, make, comm=None, meshes="whole"):
        """The problem make() (e.g. lambda: case.problem(level, degree, p)) built on every
        rank from its own cells, distributed; meshes "local": the meshes that make refines
        (nitsche.meshes.refined) hold only this rank's cells (nitsche.local_mesh)."""
        comm = comm or world()
        with partition.local(comm, meshes):
            problem = cls(make(), comm)
        if meshes == "local" and not problem.local_meshes and problem.rank == 0:
            warnings.warn("local meshes asked for, but the problem's meshes are whole on every "
                          "rank: a case's meshes are rank-local where it refines them with "
                          "nitsche.meshes.refined", stacklevel=2)
        return problem

    def __getattr__(self, name):
        return getattr(self.local, name)

    @property
    def convex(self):
        """Problem.convex of every rank's part (one decision, taken by all ranks at once)."""
        if "_convex" not in self.__dict__:
            from mpi4py import MPI
            self._convex = bool(self.comm.allreduce(int(self.local.convex), op=MPI.MIN))
        return self._convex

    def summed(self, a):
        """sum over ranks of a (a number or an array), reduced on rank 0 and broadcast."""
        from mpi4py import MPI
        a = np.ascontiguousarray(np.atleast_1d(a), dtype=float)
        self.summed_numbers += a.size
        total = np.empty_like(a)
        self.comm.Reduce(a, total, op=MPI.SUM, root=0)
        self.comm.Bcast(total, root=0)
        return total

    def norm(self, v):
        """|v| of a free vector (this rank's held free dofs, Layout.held): its owned entries'
        squares summed over the ranks (newton.norm)."""
        return float(np.sqrt(self.dot(v, v)))

    def dot(self, a, b):
        """a . b of free vectors, over the ranks' owned entries (the first Layout.owned of
        each; newton.dot)."""
        n = self.layout.owned
        return float(self.summed(np.dot(a[:n], b[:n]))[0])

    def free_part(self, x):
        """The free vector of the dof vector x: its entries on this rank's held free dofs
        (Layout.held's order; newton.free_part)."""
        return x[self.layout.dofs]

    def with_free(self, x, v):
        """A copy of the dof vector x with the free vector v on this rank's held free dofs
        (newton.with_free)."""
        y = np.array(x, dtype=float)
        y[self.layout.dofs] = v
        return y

    def whole(self, x):
        """x (valid on the dofs this rank's elements hold) with every free dof's value: an
        all-gather, for the result and the outputs, unless every rank's elements hold all of
        its free dofs (rank-local meshes; one rank)."""
        x = np.array(x, dtype=float)
        if not self.layout.complete:  # (on rank-local meshes every free dof is held)
            x[self.local.free] = self.layout.gather(
                self.layout.vector(self.free_part(x)))[self.layout.global_free]
        return x

    @property
    def unknowns(self):
        """The whole problem's free dofs (all ranks')."""
        return self.layout.n

    @property
    def whole_ndofs(self):
        """The whole problem's dofs (all ranks')."""
        return self.layout.whole_ndofs

    def reactions(self, x):
        """nitsche.reactions.reactions of the whole problem: each rank's sums over the fixed
        dofs it owns (where the gradient is the ranks' sum), summed over the ranks."""
        from .reactions import reactions
        g = self.gradient(x)
        g[self.local.fixed[~self.owned_fixed]] = 0.0
        mine = reactions(self.local, x, gradient=g, fields=self.fixed_fields)
        flat = [v for regions in mine.values() for values in regions.values() for v in values]
        total = iter(self.summed(np.array(flat, dtype=float)).tolist())
        return {f: {r: [next(total) for _ in values] for r, values in regions.items()}
                for f, regions in mine.items()}

    def prolongate_field(self, fine, coarse, u):
        """The fine field's dofs of the coarse field's function u (nested iteration,
        study.prolongate): Field.prolongate on a whole mesh; on a rank-local mesh, for P1 and
        Q1 fields, the mean of the values at each vertex's parents (local_mesh.Numbering:
        the coarse vertices whose mean it is: an edge's midpoint, a face's or cell's centre): from the rank's own coarse values where
        every rank's coarse mesh holds its fine vertices' parents (the fine mesh refined from
        it), else from the coarse field all-gathered by global number (the coarser levels,
        each partitioned by itself)."""
        from mpi4py import MPI
        from .fields import vertex_numbered
        from .local_mesh import global_dofs, parent_mean
        if not hasattr(fine.mesh, "numbering"):
            return fine.prolongate(coarse, u)
        if not (vertex_numbered(fine) and vertex_numbered(coarse)):
            raise ValueError(f"field '{fine.name}': nested iteration on rank-local meshes "
                             "prolongates P1 and Q1 fields only: run with --no-nested or whole "
                             "meshes")
        d = fine.dof_basis.nodal_dofs.shape[0]  # components
        parents, held = fine.mesh.numbering.parents, coarse.mesh.numbering.vertices
        order = np.argsort(held)
        at = np.minimum(np.searchsorted(held, parents, sorter=order), max(held.size - 1, 0))
        mine = held.size > 0 and bool((held[order[at]] == parents).all())
        if self.comm.allreduce(mine, op=MPI.LAND):
            v = np.asarray(u, dtype=float).reshape(-1, d)[order[at]]  # (parents, vertices, components)
            return parent_mean(v).ravel()
        number, n = global_dofs(coarse.dof_basis)
        values = np.empty(n)
        values[np.concatenate(self.comm.allgather(number))] = \
            np.concatenate(self.comm.allgather(np.asarray(u, dtype=float)))
        self.layout.gathered_numbers += n
        return parent_mean(values.reshape(-1, d)[parents]).ravel()

    def energy(self, x):
        """J_h(x)."""
        return float(self.summed(self.local.assembler.energy(x))[0])

    def gradient(self, x):
        """The gradient of J_h at x (a dof vector): on the fixed dofs and the free dofs this
        rank's elements hold (zero on the other free dofs)."""
        return self.assembler.gradient(x)[1]

    def newton_system(self, x):
        """J_h(x), its gradient on this rank's held free dofs (free_part) and the PETSc
        Hessian on the free dofs (as a DistributedMatrix); first the last step's PETSc
        vectors are destroyed (collect)."""
        self.collect()
        E, g, data = self.assembler.evaluate(x)
        self.layout.set_values(data)
        return E, self.free_part(g), self.matrix

    def update_pairing(self, x):
        """Problem.update_pairing of this rank's interface points (each rank pairs its own
        against the other body's current surface, whose dofs it holds: Layout); True on
        every rank where one rank's pattern grew, the PETSc matrix then on the grown one."""
        from mpi4py import MPI
        grew = self.comm.allreduce(bool(self.local.update_pairing(x)), op=MPI.LOR)
        if grew:
            self.layout.grown(self.local)
        return grew

    def linear_solver(self, name="auto"):
        """A PETSc solver of the Newton matrix (KrylovSolver): a load path's predictor."""
        return KrylovSolver(name, self)

    def collect(self):
        """Destroy the PETSc objects Python dropped (collective): petsc4py defers the
        destruction of parallel objects to PETSc.garbage_cleanup, so without it the
        vectors of every solve, product and minimum check stay allocated on 2+ ranks
        (measured: 1.5 MiB per Newton iteration per rank at 130k unknowns)."""
        from petsc4py import PETSc
        PETSc.garbage_cleanup(self.comm)

    def lift(self, x0, solve):
        """Problem.lift: H_ff dx_f = -H_fc d with the summed Hessian."""
        x0 = np.asarray(x0, dtype=float)
        d, x = self.local.moved(x0), self.local.initial(x0)
        if d is None:
            return x
        _, _, data = self.assembler.evaluate(x0)
        self.layout.set_values(data)
        step = np.zeros(self.local.ndofs)
        step[self.local.fixed] = d
        rhs = self.layout.assembled(self.free_part(self.local.assembler.matrix(data) @ step))
        x[self.layout.dofs] += solve(self.matrix, -rhs)
        return x

    def non_finite(self, x):
        """Problem.non_finite: the reasons of the ranks that have one."""
        return "; ".join(dict.fromkeys(self.comm.allgather(self.local.non_finite(x))))

    def constraint_values(self, x):
        """Problem.constraint_values of all ranks' elements (concatenated, rank after rank):
        every quadrature point's values on every rank (the report does not gather them)."""
        parts = self.comm.allgather(self.local.constraint_values(x))
        return {name: {k: None if parts[0][name][k] is None else
                       np.concatenate([p[name][k] for p in parts]) for k in parts[0][name]}
                for name in parts[0]}

    def constraint_report(self, x):
        """Problem.constraint_report of the whole problem, the same on every rank: each rank's
        counts, sums, maxima and most violated point over its elements (with the fields'
        size max |u| on its held dofs) gathered and combined (problem.report_constraints);
        alpha0 and its limits per element are gathered for their medians."""
        held = np.zeros_like(x)
        held[self.local.fixed] = x[self.local.fixed]
        held[self.layout.dofs] = self.free_part(x)
        return report_constraints(self.local.constraints, self.local.constraint_values(x),
                                  self.local.split(held), self.local.alpha0, self.local.limits,
                                  gather=self.statistics)

    def statistics(self, s):
        """Every rank's constraint_statistics s, rank after rank (report_constraints' gather),
        their scalars all-gathered; alpha0 and its limits per element stay on the ranks: the
        first piece carries their (min, median, max) over all elements (order_statistics),
        the others none, so constraint_summary's min, median and max of the concatenation
        are the whole problem's, bit for bit."""
        s = dict(s)
        arrays = {k: s.pop(k) for k in ("alpha0", "limits")}
        pieces = self.comm.allgather(s)
        for k, a in arrays.items():
            summary = order_statistics(self.comm, a)
            for i, piece in enumerate(pieces):
                piece[k] = summary if i == 0 else summary[:0]
        return pieces

    def minimize(self, x0=None, solver="auto", **options):
        """Newton's method (nitsche.newton.newton) with a PETSc solver: 'gamg' (CG + GAMG),
        'direct' (LU) or 'auto' (as the serial 'auto': AMG in 3D above AMG_THRESHOLD_3D
        unknowns, else direct); PETSc options (-ksp_type ...) override their settings."""
        from .newton import newton
        result = newton(self, x0, solver=KrylovSolver(solver, self), **options)
        result.x = self.whole(result.x)
        self.collect()
        return result


def order_statistics(comm, a):
    """[min, median, max] of the ranks' arrays a together (np.median's: the mean of the two
    middle values of an even count), exactly, without gathering them: each order statistic
    is found by bisection on the ordered 64-bit keys of the doubles (kth_smallest)."""
    from mpi4py import MPI
    keys = np.sort(ordered_keys(np.asarray(a, float).ravel()))
    n = comm.allreduce(keys.size)
    if n == 0:
        raise ValueError("order statistics of no values")
    at = [0, (n - 1) // 2, n // 2, n - 1]
    lo = comm.allreduce(int(keys[0]) if keys.size else np.iinfo(np.int64).max, op=MPI.MIN)
    hi = comm.allreduce(int(keys[-1]) if keys.size else np.iinfo(np.int64).min, op=MPI.MAX)
    v = [float(ordered_keys(np.array([kth_smallest(comm, keys, k, lo, hi)]), inverse=True)[0])
         for k in at[1:3]]
    first, last = (float(ordered_keys(np.array([k]), inverse=True)[0]) for k in (lo, hi))
    return np.array([first, v[0] if n % 2 else np.mean(v), last])


def ordered_keys(a, inverse=False):
    """The doubles a as int64 keys in the same order (and back: inverse): the sign bit
    flips the other bits of negative numbers."""
    if inverse:
        b = np.asarray(a, np.int64)
        return (b ^ ((b >> 63) & np.int64(0x7FFFFFFFFFFFFFFF))).view(np.float64)
    b = np.ascontiguousarray(a, np.float64).view(np.int64)
    return b ^ ((b >> 63) & np.int64(0x7FFFFFFFFFFFFFFF))


def kth_smallest(comm, keys, k, lo, hi):
    """The k-th smallest (from 0) of the ranks' sorted keys, all in [lo, hi]: the least key
    K with more than k keys <= K, by bisection (one reduction of a count per step)."""
    while lo < hi:
        mid = lo + (hi - lo) // 2
        if comm.allreduce(int(np.searchsorted(keys, mid, side="right"))) > k:
            hi = mid
        else:
            lo = mid + 1
    return lo


def global_numbers(problem):
    """The global number of each of the problem's dofs and the whole problem's count: each
    field's (local_mesh.global_dofs: on a whole mesh its own dofs), the fields one after
    the other."""
    from .local_mesh import global_dofs
    parts, total = [], 0
    for f in problem.fields:
        number, n = global_dofs(f.dof_basis)
        parts.append(number + total)
        total += n
    return np.concatenate(parts), total


class SummedAssembler:
    """The Assembler's evaluations (of all terms or of the given ones) as sums over the
    ranks of their local assemblies: J summed over the ranks (NaN on every rank where one
    rank's gradient is not finite), the gradient summed on the dofs this rank's elements
    hold (free: Layout.assembled; fixed: a reduction of those alone) and zero on the other
    free dofs; the Hessian data stays this rank's (on its local pattern).  The sums replace
    the local gradient's entries in place (it is zero on the free dofs the rank does not
    hold)."""

    def __init__(self, dp):
        self.dp, self.terms = dp, dp.local.assembler.terms

    def evaluate(self, x, terms=None, hessian=True):
        local, layout = self.dp.local, self.dp.layout
        E, g, data = local.assembler.evaluate(x, terms, hessian)
        E = E if np.all(np.isfinite(g)) else np.nan
        g[layout.dofs] = layout.assembled(g[layout.dofs])
        fixed = np.zeros(layout.fixed_count)
        fixed[layout.fixed_at] = g[local.fixed]
        g[local.fixed] = self.dp.summed(fixed)[layout.fixed_at]
        return float(self.dp.summed(E)[0]), g, data

    def gradient(self, x, terms=None):
        """J(x) and its gradient, summed over the ranks."""
        return self.evaluate(x, terms, hessian=False)[:2]


class Layout:
    """The free dofs numbered rank after rank for PETSc (order[k]: the global free index of
    PETSc's dof k; the global free index numbers the whole problem's free dofs in the order
    of their global numbers, global_numbers, which on whole meshes are the serial dofs),
    this rank's local numbering of the free dofs its elements hold (held[i]: the position in
    problem.free of local free dof i; the `owned` ones first, in PETSc's order, then the
    ghosts; dofs: their dofs in the dof vector; mine: the owned ones' global free indices),
    the COO pattern of each rank's free-free Hessian entries, and the fixed dofs' places in
    the whole problem's (fixed_at, for their gradient's sums).  Owners, free and fixed dofs
    and their indices are found once, at each number's home rank (partition.by_number): no
    rank holds an array of all global dofs (on whole meshes every rank holds every dof)."""

    def __init__(self, dp):
        from mpi4py import MPI
        problem, a = dp.local, dp.local.assembler
        held = np.zeros(problem.ndofs, bool)
        for t in a.terms:
            held[t.global_dofs.ravel()] = True
            if t.nel and hasattr(t.measure, "reachable"):  # paired anew each iterate (nitsche.sliding)
                for f, offset in zip(t.fields, t.offsets):
                    held[t.measure.reachable(f) + offset] = True
        number, N = global_numbers(problem)
        self.whole_ndofs, self.comm = N, dp.comm
        owner = partition.by_number(dp.comm, number, np.where(held, dp.rank, dp.ranks - 1), N, "min")
        kind = np.full(problem.ndofs, 2, np.int8)  # 1 free, 2 fixed
        kind[problem.free] = 1
        counted = {}

        def indices(block, lo):
            """[kind, free index, fixed index] of a home block's numbers, the indices counted
            over the blocks of all ranks (collective)."""
            free, fixed = block == 1, block == 2
            counts = np.array(dp.comm.allgather((int(free.sum()), int(fixed.sum()))), np.int64)
            before = counts[:dp.rank].sum(axis=0)
            counted.update(free=int(counts[:, 0].sum()), fixed=int(counts[:, 1].sum()))
            return np.stack([block, before[0] + np.cumsum(free) - 1,
                             before[1] + np.cumsum(fixed) - 1], axis=1)
        kinds = partition.by_number(dp.comm, number, kind, N, "max", answer=indices)
        if (kinds[problem.free, 0] != 1).any():
            raise ValueError("a dof is free on this rank and fixed on another: the ranks' parts "
                             "of the problem must fix the same dofs")
        self.n, self.fixed_count = counted["free"], counted["fixed"]
        self.fixed_at = kinds[problem.fixed, 2]
        index = kinds[problem.free, 1]  # the global free index of each local free dof
        own = owner[problem.free] == dp.rank
        mine = np.flatnonzero(own)
        mine = mine[np.argsort(index[mine])]  # PETSc's order within a rank: global free order
        self.counts = np.array(dp.comm.allgather(mine.size), np.int64)
        self.start = int(self.counts[:dp.rank].sum())
        self.mine = index[mine]
        petsc = np.full(index.size, -1, np.int64)
        petsc[mine] = self.start + np.arange(mine.size)
        self.petsc_number = -np.ones(problem.ndofs, np.int64)  # PETSc's number of local free dofs
        self.petsc_number[problem.free] = partition.by_number(dp.comm, index, petsc, self.n, "max")
        self.pattern = self.coo(problem)  # given to PETSc once (matrix), then dropped
        self.owner = owner  # a rank per local dof
        self.gathered_numbers = 0  # numbers all-gathered (every rank receives the whole vector)
        self.unshifted = None  # the assembled diagonal while a shift is applied
        ghost = np.flatnonzero(held[problem.free] & ~own)
        self.held = np.concatenate([mine, ghost])  # owned, then ghosts
        self.complete = dp.comm.allreduce(  # every rank's elements hold all its free dofs
            bool(held[problem.free].all()), op=MPI.LAND)
        self.global_free = index  # (whole: the gathered free vector's entries of problem.free)
        self.owned, self.dofs = mine.size, problem.free[self.held]
        self.petsc_held = self.petsc_number[self.dofs]
        self._order = None

    @property
    def order(self):
        """The global free index of each PETSc dof (order[k] for PETSc's dof k): every rank's
        owned ones, rank after rank (an all-gather, for the whole free vector; collective)."""
        if self._order is None:
            self._order = np.concatenate(self.comm.allgather(self.mine))
        return self._order

    def coo(self, problem):
        """(rows, cols) in PETSc's numbering of the free-free entries of the rank's problem's
        CSR pattern (keep: their positions in its data; off_rank: those in other ranks' rows)."""
        a, number = problem.assembler, self.petsc_number
        rows = number[np.repeat(np.arange(problem.ndofs), np.diff(a.indptr))]
        cols = number[a.indices]
        self.keep = np.flatnonzero((rows >= 0) & (cols >= 0))
        rows, cols = rows[self.keep], cols[self.keep]
        lo, hi = self.start, self.start + self.counts[self.comm.rank]
        self.off_rank = int(((rows < lo) | (rows >= hi)).sum())  # rows of other ranks
        return rows, cols

    def grown(self, problem):
        """A new PETSc matrix (A; its near-nullspace kept) on the rank's problem's grown
        pattern (an interface paired anew, nitsche.sliding; collective): the held dofs, and
        hence the owners and the vectors, stay (they hold every dof a pairing can reach)."""
        space = self.A.getNearNullSpace()
        self.pattern, self.unshifted = self.coo(problem), None
        self.A.destroy()
        self.A = self.petsc_matrix()
        if space.handle:
            self.A.setNearNullSpace(space)

    def petsc_matrix(self):
        """The PETSc AIJ matrix of the COO pattern (which is then dropped)."""
        from petsc4py import PETSc
        local = int(self.counts[self.comm.rank])
        A = PETSc.Mat().create(comm=self.comm)
        A.setSizes(((local, self.n), (local, self.n)))
        A.setType(PETSc.Mat.Type.AIJ)
        rows, cols = self.pattern
        self.pattern = None
        A.setPreallocationCOO(rows.astype(PETSc.IntType), cols.astype(PETSc.IntType))
        return A

    def matrix(self):
        """The PETSc matrix, its pattern set once (values: set_values; a pattern grown by a
        new pairing: grown)."""
        from petsc4py import PETSc
        self.A = A = self.petsc_matrix()
        self.ghosted = PETSc.Vec().createSeq(self.held.size, comm=PETSc.COMM_SELF)
        self.to_held = PETSc.Scatter().create(
            A.createVecRight(), PETSc.IS().createGeneral(self.petsc_held.astype(PETSc.IntType),
                                                       comm=PETSc.COMM_SELF), self.ghosted, None)
        self.sum_vector = A.createVecRight()
        return DistributedMatrix(self)

    def held_values(self, x):
        """The free vector (this rank's held free dofs) of the PETSc vector x: its owned
        entries and the ghosts' values scattered from their owners (a copy of the scatter's
        array)."""
        from petsc4py import PETSc
        self.to_held.scatter(x, self.ghosted, addv=PETSc.InsertMode.INSERT_VALUES,
                             mode=PETSc.ScatterMode.FORWARD)
        return self.ghosted.getArray(readonly=True).copy()

    def assembled(self, v):
        """sum over the ranks of their free vectors v (held free dofs), on this rank's held
        dofs: the ghosts' values added to their owners' (a reverse scatter) and sent back, so
        that every rank holding a dof has the owner's bits."""
        from petsc4py import PETSc
        self.ghosted.setArray(np.ascontiguousarray(v, dtype=PETSc.ScalarType))
        self.sum_vector.zeroEntries()
        self.to_held.scatter(self.ghosted, self.sum_vector, addv=PETSc.InsertMode.ADD_VALUES,
                             mode=PETSc.ScatterMode.REVERSE)
        return self.held_values(self.sum_vector)

    def set_values(self, data):
        """The matrix values from this rank's CSR data (entries of all ranks summed)."""
        from petsc4py import PETSc
        self.unshifted = None  # the diagonal before a shift (DistributedMatrix.shifted)
        self.A.setValuesCOO(np.ascontiguousarray(data[self.keep], dtype=PETSc.ScalarType),
                            addv=PETSc.InsertMode.INSERT_VALUES)

    def vector(self, v=None):
        """A PETSc vector, this rank's entries from the free vector v (held free dofs: its
        first `owned` entries; or zero)."""
        x = self.A.createVecRight()
        x.setArray(np.zeros(x.getLocalSize()) if v is None else v[:self.owned])
        return x

    def gather(self, x):
        """A PETSc vector as a replicated free vector (serial numbering) on every rank."""
        local = np.ascontiguousarray(x.getArray(readonly=True))
        whole = np.empty(self.n)
        self.gathered_numbers += self.n
        self.comm.Allgatherv(local, [whole, self.counts])
        out = np.empty(self.n)
        out[self.order] = whole
        return out


class DistributedMatrix:
    """The PETSc Hessian seen by the serial Newton: A @ v on free vectors (this rank's held
    free dofs; the product's values there)."""

    def __init__(self, layout):
        self.layout = layout

    @property
    def mat(self):
        return self.layout.A

    def __matmul__(self, v):
        y = self.layout.vector()
        self.mat.mult(self.layout.vector(v), y)
        return self.layout.held_values(y)

    def shifted(self, tau):
        """A + tau D, D = diag|A| floored at 1e-12 of its largest entry (newton.diagonal_shift),
        in place: the PETSc matrix's diagonal set from the assembled one, which the next
        assembly (Layout.set_values) restores; the KSP's operator is this matrix."""
        from petsc4py import PETSc
        layout = self.layout
        if layout.unshifted is None:
            layout.unshifted = self.mat.getDiagonal()
        D = layout.unshifted.copy()
        D.abs()
        D.setArray(np.maximum(D.getArray(readonly=True), 1e-12 * D.max()[1]))
        M = layout.unshifted.copy()
        M.axpy(tau, D)
        self.mat.setDiagonal(M, addv=PETSc.InsertMode.INSERT_VALUES)
        return self


class KrylovSolver:
    """PETSc's solvers behind the interface of nitsche.linalg's (solve, is_positive_definite,
    stats).  'gamg': CG preconditioned by GAMG (smoothed aggregation) with the near-nullspace
    of nitsche.linalg.near_nullspace (rigid-body modes), to Newton's forcing tolerance;
    'direct': when PETSc has MUMPS, its factorization divided among the ranks, P A P^T =
    L D L^T (symmetric indefinite, 1x1 and 2x2 pivots) for a symmetric problem, else LU, P
    a nested dissection where MUMPS has Scotch (mumps_ordering_options);
    without MUMPS each rank a sequential LU of the whole matrix (PCREDUNDANT).  PETSc
    options (-ksp_type, -pc_type ...) are applied last."""

    def __init__(self, name, dp, rtol=1e-10, maxiter=2000):
        from petsc4py import PETSc
        if name not in SOLVERS:
            raise ValueError(f"solver must be one of {', '.join(SOLVERS)} on MPI ranks, not {name!r}")
        if name == "auto":
            name = "gamg" if dp.local.dim == 3 and dp.local.free.size > AMG_THRESHOLD_3D else "direct"
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
            pc.setType("cholesky" if dp.local.symmetric else "lu")
            pc.setFactorSolverType("mumps")
        else:
            ksp.setType("preonly")
            pc.setType("redundant")  # PCREDUNDANT's own solver: LU
        self.ksp, self.kind, self.iterations, self.factor = ksp, name, [], {}
        self.minimum_checks = []  # per check: lowest_eigenvalue's estimate and steps, or the negative pivots

    def configure(self):
        """PETSc's options applied (last), then for MUMPS, where the options set none of
        ICNTL(7), (28), (29), its ordering (mumps_ordering_options), and for its L D L^T on
        several ranks ICNTL(13) = 1 unless the options set it: the root front factored by
        MUMPS rather than ScaLAPACK, so that INFOG(12) counts its negative pivots too
        (is_positive_definite)."""
        from petsc4py import PETSc
        self.ksp.setFromOptions()
        pc, options = self.ksp.getPC(), PETSc.Options()
        if pc.getType() not in ("cholesky", "lu") or pc.getFactorSolverType() != "mumps":
            return
        if not any(options.hasName(f"mat_mumps_icntl_{i}") for i in ORDERING_ICNTL):
            for i, value in mumps_ordering_options(self.dp.ranks).items():
                options.setValue(f"mat_mumps_icntl_{i}", value)
        if (self.dp.ranks > 1 and pc.getType() == "cholesky"
                and not options.hasName("mat_mumps_icntl_13")):
            options.setValue("mat_mumps_icntl_13", 1)

    def record_factor(self):
        """MUMPS's last factorization (factor_stats), where the PC is MUMPS's."""
        pc = self.ksp.getPC()
        if pc.getType() in ("cholesky", "lu") and pc.getFactorSolverType() == "mumps":
            self.factor = factor_stats(pc.getFactorMatrix())

    def prepare(self, problem):
        """The near-nullspace of GAMG: rigid-body modes of the vector fields, constants."""
        if self.kind != "gamg":
            return
        from petsc4py import PETSc
        B = np.linalg.qr(near_nullspace(self.dp.local))[0]
        vectors = [self.dp.layout.vector(b[self.dp.layout.held]) for b in B.T]  # (rows: local free)
        self.dp.layout.A.setNearNullSpace(PETSc.NullSpace().create(vectors=vectors, comm=self.dp.comm))

    def solve(self, A, b, rtol=0.0):
        from petsc4py import PETSc
        self.ksp.setOperators(self.dp.layout.A)  # (a new one where a pairing grew the pattern)
        # a symmetric problem's matrix must be positive definite (as CHOLMOD's serially); a
        # non-symmetric one's (residual terms) is solved by LU whatever its diagonal, as SuperLU's
        fault = diagonal_fault(self.dp.layout.A) if self.dp.local.symmetric else None
        if fault:
            raise IndefiniteHessian(fault)
        if self.kind == "gamg":
            self.ksp.setTolerances(rtol=max(rtol, self.rtol))
        self.configure()
        x = self.dp.layout.vector()
        self.ksp.solve(self.dp.layout.vector(b), x)
        self.record_factor()
        reason = self.ksp.getConvergedReason()
        self.iterations.append(self.ksp.getIterationNumber())
        R = PETSc.KSP.ConvergedReason
        if reason in (R.DIVERGED_INDEFINITE_MAT, R.DIVERGED_INDEFINITE_PC,
                      R.DIVERGED_PCSETUP_FAILED):
            raise IndefiniteHessian(f"PETSc KSP: {reason_name(reason)}")
        if reason < 0:
            raise NotSolved(f"PETSc KSP ({self.ksp.getType()}, {self.ksp.getPC().getType()}): "
                            f"{reason_name(reason)}")
        if not np.isfinite(x.norm()):
            raise IndefiniteHessian("singular Newton matrix")
        return self.dp.layout.held_values(x)

    def is_positive_definite(self, A):
        """A positive diagonal, then with MUMPS's L D L^T (symmetric_factor) its inertia: no
        negative pivot (INFOG(12) = 0; D's eigenvalues have A's signs by Sylvester's law, a
        singular A fails the factorization), the factorization the next solve of A uses.
        Otherwise as AMGCG's, on distributed vectors: LOBPCG preconditioned by this
        solver's preconditioner (lowest_eigenvalue) estimates the smallest eigenvalue above
        0 (evidence, not proof; with an LU preconditioner it converges in 2-5 steps), from
        a start that depends on the serial free index alone (seeded): the same on any
        number of ranks.  Nothing is gathered."""
        if diagonal_fault(A.mat):
            return False
        self.ksp.setOperators(A.mat)
        self.configure()
        self.ksp.setUp()
        self.record_factor()
        F = self.symmetric_factor()
        if F is not None:
            if self.ksp.getPC().getFailedReason():
                self.minimum_checks.append(dict(negative_pivots=None))
                return False
            negative = F.getMumpsInfog(12)
            self.minimum_checks.append(dict(negative_pivots=negative))
            return negative == 0
        x = self.dp.layout.vector()
        x.setArray(seeded(self.dp.layout.mine))
        theta, steps = lowest_eigenvalue(A.mat, self.ksp.getPC().apply, x)
        self.minimum_checks.append(dict(estimate=theta, steps=steps))
        return bool(theta > 0)

    def symmetric_factor(self):
        """MUMPS's factor when the PC is its Cholesky (L D L^T) and INFOG(12) counts every
        negative pivot (one rank, or the root front factored by MUMPS: ICNTL(13) = 1), else
        None."""
        pc = self.ksp.getPC()
        if pc.getType() != "cholesky" or pc.getFactorSolverType() != "mumps":
            return None
        F = pc.getFactorMatrix()
        return F if self.dp.ranks == 1 or F.getMumpsIcntl(13) == 1 else None

    def stats(self):
        return dict(ranks=self.dp.ranks, ksp_iterations=list(self.iterations),
                    local_meshes=self.dp.local_meshes,
                    elements=self.dp.elements, off_rank_entries=self.dp.off_rank_entries,
                    straddling_constraint_elements=self.dp.straddling,
                    summed_numbers=self.dp.summed_numbers,
                    gathered_numbers=self.dp.layout.gathered_numbers,
                    lobpcg_estimates=[c["estimate"] for c in self.minimum_checks if "estimate" in c],
                    lobpcg_steps=[c["steps"] for c in self.minimum_checks if "steps" in c],
                    negative_pivots=[c["negative_pivots"] for c in self.minimum_checks
                                     if "negative_pivots" in c], **self.factor)


# MUMPS's controls of the ordering: ICNTL(7) the sequential one, ICNTL(28) sequential (1) or
# parallel (2) analysis, ICNTL(29) the parallel one
ORDERING_ICNTL = (7, 28, 29)
# INFOG(7) after a sequential analysis (INFOG(32) = 1), after a parallel one (INFOG(32) = 2)
SEQUENTIAL_ORDERINGS = {0: "amd", 1: "given", 2: "amf", 3: "scotch", 4: "pord", 5: "metis", 6: "qamd"}
PARALLEL_ORDERINGS = {1: "pt-scotch", 2: "parmetis"}


def mumps_has(ordering):
    """Whether the MUMPS that PETSc links was built with 'scotch' or 'pt-scotch': MUMPS
    defines its wrapper mumps_scotch_ (mumps_dgraphinit_) only then; dlsym looks it up
    among petsc4py's module and the libraries it depends on (libpetsc, MUMPS's)."""
    import ctypes
    from petsc4py import PETSc
    symbol = {"scotch": "mumps_scotch_", "pt-scotch": "mumps_dgraphinit_"}[ordering]
    return hasattr(ctypes.CDLL(PETSc.__file__), symbol)


def mumps_ordering_options(ranks):
    """MUMPS's fill-reducing ordering, {ICNTL index: value}: nested dissection where the
    build has it, PT-Scotch's in parallel on several ranks (ICNTL(28) = 2, ICNTL(29) = 1),
    else Scotch's (ICNTL(7) = 3); without Scotch {} (MUMPS's automatic choice: with
    Debian's libmumps-dev PORD above 10,000 unknowns (symmetric), AMF or QAMD below)."""
    if ranks > 1 and mumps_has("pt-scotch"):
        return {28: 2, 29: 1}
    return {7: 3} if mumps_has("scotch") else {}


def factor_stats(F):
    """MUMPS's factor F: the ordering its analysis used (INFOG(32) sequential or parallel,
    INFOG(7) which), the factor's entries summed over the ranks as the analysis estimated
    them (INFOG(20)) and as factored (INFOG(29); a negative one is minus the millions, for
    counts beyond 32-bit integers), and the factorization's floating-point operations
    (RINFOG(3), all ranks)."""
    orderings = PARALLEL_ORDERINGS if F.getMumpsInfog(32) == 2 else SEQUENTIAL_ORDERINGS
    entries = [F.getMumpsInfog(i) for i in (20, 29)]
    entries = [n if n >= 0 else -n * 10 ** 6 for n in entries]
    return dict(mumps_ordering=orderings.get(F.getMumpsInfog(7), str(F.getMumpsInfog(7))),
                factor_entries_estimated=entries[0], factor_entries=entries[1],
                factor_flops=F.getMumpsRinfog(3))


def reason_name(reason):
    from petsc4py import PETSc
    names = {v: k for k, v in vars(PETSc.KSP.ConvergedReason).items() if isinstance(v, int)}
    return names.get(reason, str(reason))


def diagonal_fault(mat):
    """Why the PETSc matrix cannot be positive definite (a diagonal entry <= 0 or not
    finite: a min and a sum reduced over the ranks), or None."""
    diagonal = mat.getDiagonal()
    i, smallest = diagonal.min()
    if smallest > 0 and np.isfinite(diagonal.sum()):
        return None
    return (f"diagonal entry {i} (PETSc numbering) of the Newton matrix is {smallest:.3g} "
            "or one is not finite")


def seeded(indices, seed=0):
    """Numbers in [-1/2, 1/2) that depend on the (global) index alone: SplitMix64 (Steele,
    Lea, Flood 2014) of seed + index, so a start vector is the same whichever rank holds
    which entry."""
    z = (np.asarray(indices, np.uint64) + np.uint64(seed + 1)) * np.uint64(0x9E3779B97F4A7C15)
    z = (z ^ (z >> np.uint64(30))) * np.uint64(0xBF58476D1CE4E5B9)
    z = (z ^ (z >> np.uint64(27))) * np.uint64(0x94D049BB133111EB)
    z = z ^ (z >> np.uint64(31))
    return (z >> np.uint64(11)).astype(float) * 2.0 ** -53 - 0.5


def lowest_eigenvalue(A, precondition, x, iterations=40, tol=1e-3):
    """An estimate from above of the smallest eigenvalue of the symmetric PETSc matrix A
    (nitsche.linalg.lowest_eigenvalue on distributed vectors): LOBPCG with one vector
    (Knyazev 2001) from the start x.  Each step takes the Ritz pair of the smallest Ritz
    value theta of A on span{x, w, p}: w = P r the preconditioned residual
    r = A x - theta x (precondition(r, w); r itself where P r is not finite), p the last
    step's change of x; the 3 x 3 Gram matrices S^T S and S^T A S are one reduction.  Every
    theta is a Rayleigh quotient, so theta <= 0 proves A is not positive definite.  Stops
    there, at |r| <= tol theta (|x| = 1), or after `iterations` steps: (theta, steps)."""
    from mpi4py import MPI
    comm = A.getComm().tompi4py()
    x = x.copy()
    x.scale(1 / x.norm())
    Ax, r, w, Aw = A.createVecLeft(), x.duplicate(), x.duplicate(), x.duplicate()
    A.mult(x, Ax)
    theta, p, Ap = x.dot(Ax), None, None
    for step in range(iterations + 1):
        r.waxpy(-theta, x, Ax)
        if not theta > 0 or step == iterations or r.norm() <= tol * theta:
            return float(theta), step
        precondition(r, w)
        if not np.isfinite(w.norm()):
            r.copy(w)
        w.scale(1 / w.norm())
        A.mult(w, Aw)
        S, AS = [x, w] + ([p] if p else []), [Ax, Aw] + ([Ap] if p else [])
        s = [v.getArray(readonly=True) for v in S]
        a = [v.getArray(readonly=True) for v in AS]
        local = np.array([[si @ sj for sj in s] + [si @ aj for aj in a] for si in s])
        G, H = np.split(comm.allreduce(local, op=MPI.SUM), 2, axis=1)
        c, theta = ritz(G, (H + H.T) / 2)
        p_new, Ap_new = x.duplicate(), x.duplicate()
        for ci, v, Av in zip(c[1:], S[1:], AS[1:]):
            p_new.axpy(ci, v)
            Ap_new.axpy(ci, Av)
        x.scale(c[0])
        x.axpy(1.0, p_new)
        Ax.scale(c[0])
        Ax.axpy(1.0, Ap_new)
        size = p_new.norm()
        for v in (p, Ap) if p else ():
            v.destroy()  # now (petsc4py would keep a parallel vector until garbage_cleanup)
        p, Ap = (p_new, Ap_new) if size > 0 else (None, None)
        if p:
            p.scale(1 / size)
            Ap.scale(1 / size)
    return float(theta), iterations


def ritz(G, H):
    """The smallest Ritz value theta and its coefficients c (c^T G c = 1) of H c = theta G c,
    G the Gram matrix of the basis: directions whose Gram eigenvalue is below 1e-12 of the
    largest (nearly dependent) are dropped."""
    d, V = np.linalg.eigh(G)
    keep = d > 1e-12 * d.max()
    Q = V[:, keep] / np.sqrt(d[keep])
    mu, Y = np.linalg.eigh(Q.T @ H @ Q)
    return Q @ Y[:, 0], float(mu[0])
