"""The cells of each mesh that this MPI rank builds: rank-local set-up.

Inside `with partition.local(comm):` the bases of fields and measures are built on this
rank's cells only: a k-way METIS partition (pymetis) of each mesh's dual graph (cells
joined by a facet), computed on rank 0 and broadcast.  An element of a measure (a cell, a
boundary facet, an interface facet or supermesh piece, a membrane cell) belongs to the
rank of the cell that owns it, so every element is tabulated and assembled by exactly one
rank and no ghost cells are needed: a dof that elements of several ranks share is summed
by the reductions and by PETSc's COO assembly (nitsche.distributed).

What stays whole on every rank: the meshes (points, cells, facets, the dof numbering) and
the dof vectors, unless the meshes are rank-local (local(comm, meshes="local"):
nitsche.meshes.refined builds this rank's cells only, nitsche.local_mesh).  Quantities
integrated over the cells (nitsche.norms.exact_errors, the binned pictures of nitsche.plot,
the cases' output hooks) are computed inside `local(comm)`
on this rank's cells and reduced over the ranks (summed, smallest, largest, gathered,
collected, summed_matrix, first: identities outside).  The other body's boundary is
thereby the all-gathered contact surface against which each rank pairs its own interface
facets.
"""
import contextlib
import weakref

import numpy as np

_ACTIVE = []  # (communicator, meshes) of the partition being built in, innermost last
_CELLS = {}  # (id(mesh), ranks) -> this rank's cells, dropped with the mesh


@contextlib.contextmanager
def local(comm, meshes="whole"):
    """Build fields, measures and problems on this rank's cells of every mesh; comm None:
    on every cell (inside a partition: what one rank computes by itself, e.g. a study of
    its own whole problems).  meshes "local": nitsche.meshes.refined builds only this
    rank's cells of the refined mesh (nitsche.local_mesh); "whole": every rank the whole."""
    if meshes not in ("whole", "local"):
        raise ValueError(f"meshes must be 'whole' or 'local', not {meshes!r}")
    _ACTIVE.append((comm, meshes))
    try:
        yield comm
    finally:
        _ACTIVE.pop()


def active():
    """The communicator of the partition being built in, or None (serial set-up)."""
    return _ACTIVE[-1][0] if _ACTIVE else None


def local_meshes():
    """Whether refined meshes are built rank-local (partition.local(comm, meshes="local"))."""
    return bool(_ACTIVE) and _ACTIVE[-1][0] is not None and _ACTIVE[-1][1] == "local"


def key():
    """(rank, ranks) of the partition being built in, None outside: a cache key."""
    comm = active()
    return None if comm is None else (comm.rank, comm.size)


def dual_graph(mesh):
    """The cells' adjacency (CSR: xadj, adjncy): cells sharing a facet."""
    f2t = mesh.f2t[:, mesh.f2t[1] >= 0]
    n = mesh.t.shape[1]
    rows, cols = np.concatenate([f2t[0], f2t[1]]), np.concatenate([f2t[1], f2t[0]])
    order = np.lexsort((cols, rows))
    return np.concatenate([[0], np.cumsum(np.bincount(rows, minlength=n))]), cols[order]


def cells(mesh):
    """This rank's cells of the mesh (sorted), or None outside a partition and on a
    rank-local mesh (all its cells) without ghost cells (on one with them, inside a
    partition or not, its own cells: local_mesh.Numbering.owned)."""
    comm, numbering = active(), getattr(mesh, "numbering", None)
    if numbering is not None:
        return None if numbering.owned is None else np.flatnonzero(numbering.owned)
    if comm is None:
        return None
    k = (id(mesh), comm.size)
    if k not in _CELLS:
        part = None
        if comm.rank == 0:
            import pymetis
            xadj, adjncy = dual_graph(mesh)
            part = np.zeros(mesh.t.shape[1], np.int64) if comm.size == 1 else \
                np.asarray(metis_parts(pymetis, comm.size, xadj, adjncy), np.int64)
        part = comm.bcast(part, root=0)
        _CELLS[k] = np.flatnonzero(part == comm.rank)
        weakref.finalize(mesh, _CELLS.pop, k, None)
    return _CELLS[k]


def own_cells(mesh):
    """This rank's cells of the mesh, or all cells outside a partition."""
    mine = cells(mesh)
    return np.arange(mesh.nelements) if mine is None else mine


def metis_parts(pymetis, k, xadj, adjncy):
    """The k-way METIS part of each vertex of the CSR graph (xadj, adjncy): through
    pymetis.CSRAdjacency where pymetis has it (2025.2; passing xadj/adjncy is deprecated)."""
    if hasattr(pymetis, "CSRAdjacency"):
        return pymetis.part_graph(k, adjacency=pymetis.CSRAdjacency(xadj, adjncy))[1]
    return pymetis.part_graph(k, xadj=xadj, adjncy=adjncy)[1]


def owned(mesh, owners):
    """Which elements, given the cells that own them, are this rank's (all outside a
    partition)."""
    mine = cells(mesh)
    if mine is None:
        return np.ones(len(owners), bool)
    return np.isin(owners, mine)


def everywhere(flag):
    """flag on every rank (logical and over the partition's ranks; flag outside)."""
    comm = active()
    return bool(flag) if comm is None else bool(comm.allreduce(bool(flag), op=_op("LAND")))


def summed(a):
    """The array a summed over the partition's ranks (on every rank; a outside): what a
    quantity integrated over this rank's cells makes over the whole mesh."""
    return _reduced(a, "SUM")


def smallest(a):
    """The entrywise minimum of the array a over the partition's ranks (a outside)."""
    return _reduced(a, "MIN")


def largest(a):
    """The entrywise maximum of the array a over the partition's ranks (a outside)."""
    return _reduced(a, "MAX")


def gathered(a):
    """The arrays a of the partition's ranks concatenated along the first axis, rank after
    rank, on every rank (a outside): for data of a lower dimension (a contact line)."""
    comm = active()
    return a if comm is None else np.concatenate(comm.allgather(np.asarray(a)))


def collected(index, values, n):
    """The rows `values` that the ranks give at the indices `index` of an array of n rows
    (each index given by one rank), on every rank; NaN where no rank gives one (outside:
    values at index): e.g. a value per cell of a figure from the ranks' own cells."""
    values = np.asarray(values, dtype=float)
    out = np.full((n,) + values.shape[1:], np.nan)
    out[gathered(np.asarray(index, np.int64))] = gathered(values)
    return out


def summed_matrix(A):
    """The sum over the partition's ranks of the sparse matrices A (each rank's elements'
    entries), on rank 0 and None on the others (A outside): for an output that needs the
    whole matrix (a condition number) without the whole problem."""
    comm = active()
    if comm is None:
        return A
    from scipy.sparse import csr_matrix
    parts = comm.gather(csr_matrix(A), root=0)
    if comm.rank > 0:
        return None
    total = parts[0]
    for B in parts[1:]:
        total = total + B
    return total


def by_number(comm, numbers, values, n, op, answer=None):
    """For each of this rank's global numbers (0 <= number < n, each at most once per rank)
    the reduction op ("min", "max", "sum") over the ranks of the values they give there,
    or what answer(block, lo) makes of the reduced values of this rank's block of numbers
    lo, lo + 1, ... (called once on every rank: it may be collective; it may return rows of
    several columns).  Each number's values meet at its home rank (the numbers split into R
    equal blocks) by one all-to-all and go back by another, so that no rank holds O(n)
    numbers (at most its own and its block's)."""
    R, numbers = comm.size, np.asarray(numbers, np.int64)
    home = numbers * R // max(n, 1)
    order = np.argsort(home, kind="stable")
    sent = np.bincount(home, minlength=R)
    got = np.array(comm.alltoall(sent.tolist()), np.int64)
    where = np.empty(got.sum(), np.int64)
    value = np.empty(got.sum(), np.asarray(values).dtype)
    comm.Alltoallv([numbers[order], sent], [where, got])
    comm.Alltoallv([np.ascontiguousarray(np.asarray(values)[order]), sent], [value, got])
    lo, hi = -(-comm.rank * n // R), -(-(comm.rank + 1) * n // R)  # the numbers whose home this is
    ufunc = {"min": np.minimum, "max": np.maximum, "sum": np.add}[op]
    limits = np.iinfo(value.dtype) if value.dtype.kind in "iu" else None
    identity = 0 if op == "sum" else (limits.max if limits else np.inf) if op == "min" else \
        (limits.min if limits else -np.inf)
    block = np.full(hi - lo, identity, value.dtype)
    ufunc.at(block, where - lo, value)
    block = block if answer is None else np.asarray(answer(block, lo))
    back = np.ascontiguousarray(block[where - lo])
    columns = back.shape[1:]
    out = np.empty((numbers.size,) + columns, back.dtype)
    width = int(np.prod(columns, dtype=np.int64))
    comm.Alltoallv([back.reshape(-1), got * width], [out.reshape(-1), sent * width])
    result = np.empty_like(out)
    result[order] = out
    return result


def first(value):
    """Rank 0's value on every rank of the partition (value outside)."""
    comm = active()
    return value if comm is None else comm.bcast(value, root=0)


def _reduced(a, op):
    comm = active()
    a = np.asarray(a, dtype=float)
    if comm is None:
        return a
    out = np.empty_like(a)
    comm.Allreduce(np.ascontiguousarray(a), out, op=_op(op))
    return out


def _op(name):
    from mpi4py import MPI
    return getattr(MPI, name)
