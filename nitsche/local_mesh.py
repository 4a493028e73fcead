"""Rank-local meshes: this rank's cells of a uniformly refined triangle mesh, refined by the
rank alone, with the global numbers of its vertices, facets and cells.

Inside nitsche.partition.local(comm, meshes="local"), nitsche.meshes.refined(base, n) builds
the base mesh refined k times whole (k the fewest refinements that give CELLS_PER_RANK cells
per rank, at most n), partitions its cells (partition.cells: METIS), keeps this rank's cells
(`submesh`) and refines them the other n - k times by itself (`refined_numbered`): no rank
holds more of the finer meshes than its own cells.  The mesh it returns carries
`mesh.numbering` (Numbering): the global number of each of its vertices, facets and cells,
the same on every rank that holds the entity, and which of its facets lie on the whole
mesh's boundary (a facet between two ranks' cells is on the local mesh's boundary only).

The global numbers of a refined mesh follow from the coarse ones (NV vertices, NF facets,
NC cells), so that no rank needs another's cells to find them:
  vertices: a coarse vertex keeps its number v; the midpoint of facet f is NV + f;
  facets:   the half of facet f at its endpoint of the smaller number is 2 f, the other
            2 f + 1; the facet between two midpoints of cell c that cuts off its vertex of
            rank r (0, 1, 2 among the cell's vertex numbers) is 2 NF + 3 c + r;
  cells:    the corner child of cell c at its vertex of rank r is 4 c + r, the middle one
            4 c + 3.
These are not the numbers scikit-fem gives the whole refined mesh; they are a numbering of
it, which the distributed engine needs (nitsche.distributed.Layout: the owner and PETSc
number of every dof, through `global_dofs`).
"""
import dataclasses

import numpy as np
from skfem import ElementVector, MeshTri1
from skfem.element import ElementH1

from . import partition
from .measures import boundary_facets, build_facets
from .meshes import uniformly_refined

CELLS_PER_RANK = 256  # the coarsest whole mesh partitioned has at least this many cells per rank


@dataclasses.dataclass
class Numbering:
    """Global numbers of a local mesh's vertices (nv,), facets (nf,) and cells (nc,), the
    whole mesh's counts (NV, NF, NC), which local facets lie on the whole mesh's boundary
    (nf,), and each vertex's coarser-mesh parents (2, nv): the global numbers of the two
    coarse vertices whose midpoint it is (a coarse vertex twice), or None on the base mesh."""
    vertices: np.ndarray
    facets: np.ndarray
    cells: np.ndarray
    counts: tuple
    boundary: np.ndarray
    parents: np.ndarray = None


def whole_numbering(mesh, coarse=None):
    """The Numbering of a whole mesh (its own numbers), parents from `coarse` when the mesh
    is coarse refined once (the coarse vertices first, then the facets' midpoints in facet
    order, as scikit-fem refines)."""
    build_facets(mesh)
    if coarse is not None:
        build_facets(coarse)
    nv, nf, nc = mesh.p.shape[1], mesh.facets.shape[1], mesh.t.shape[1]
    boundary = np.zeros(nf, bool)
    boundary[boundary_facets(mesh)] = True
    parents = None
    if coarse is not None:
        n = coarse.p.shape[1]
        parents = np.hstack([np.tile(np.arange(n), (2, 1)), coarse.facets]).astype(np.int64)
    return Numbering(np.arange(nv), np.arange(nf), np.arange(nc), (nv, nf, nc), boundary, parents)


def submesh(mesh, numbering, cells):
    """The mesh of the given cells of a whole (numbered) mesh, its vertices numbered in the
    order of their global numbers, with their Numbering."""
    used = np.unique(mesh.t[:, cells])
    sub = MeshTri1(mesh.p[:, used], np.searchsorted(used, mesh.t[:, cells]))
    build_facets(sub)
    g = numbering.vertices[used][sub.facets]  # (2, nf) global vertex numbers, sorted per column
    facets = np.searchsorted(_pair_keys(numbering.vertices[mesh.facets], numbering.counts[0]),
                             _pair_keys(g, numbering.counts[0]))
    parents = None if numbering.parents is None else numbering.parents[:, used]
    return sub, Numbering(numbering.vertices[used], numbering.facets[facets],
                          numbering.cells[cells], numbering.counts,
                          numbering.boundary[facets], parents)


def refined_numbered(mesh, numbering):
    """The local mesh refined once (scikit-fem's uniform refinement) and its Numbering from
    the coarse one (see the module docstring)."""
    build_facets(mesh)
    NV, NF, NC = numbering.counts
    nv = mesh.p.shape[1]
    fine = uniformly_refined(mesh, 1)
    build_facets(fine)
    gv = numbering.vertices
    ends = gv[mesh.facets]  # (2, coarse facets): their endpoints' global numbers
    vertices = np.concatenate([gv, NV + numbering.facets])
    # a fine facet joins an old vertex a to the midpoint b of coarse facet b - nv (a half),
    # or two midpoints (inside a coarse cell); old vertices are numbered first
    a, b = fine.facets.astype(np.int64)
    half = a < nv
    f = b[half] - nv
    facets = np.empty(a.size, np.int64)
    facets[half] = 2 * numbering.facets[f] + (gv[a[half]] != ends.min(axis=0)[f])
    cells_of = _cells_of_facet_pairs(mesh)
    cell, corner = _cell_of_midpoints(mesh, cells_of, a[~half] - nv, b[~half] - nv)
    facets[~half] = 2 * NF + 3 * numbering.cells[cell] + _vertex_rank(mesh, gv, cell, corner)
    boundary = np.zeros(a.size, bool)
    boundary[half] = numbering.boundary[f]
    # a fine cell: one old vertex (the corner child at it) or three midpoints (the middle one)
    t = np.sort(fine.t.astype(np.int64), axis=0)
    middle = t[0] >= nv
    cell, corner = _cell_of_midpoints(mesh, cells_of, t[1] - nv, t[2] - nv)
    cells = 4 * numbering.cells[cell] + np.where(middle, 3, _vertex_rank(mesh, gv, cell, corner))
    parents = np.hstack([np.tile(gv, (2, 1)), ends])
    return fine, Numbering(vertices, facets, cells, (NV + NF, 2 * NF + 3 * NC, 4 * NC), boundary,
                           parents)


def _pair_keys(pairs, n):
    """Integer keys of sorted vertex pairs (2, m): their order is the lexicographic one."""
    return pairs[0].astype(np.int64) * n + pairs[1]


def _cells_of_facet_pairs(mesh):
    """(keys, cells): the sorted keys lo nf + hi of every pair of facets (lo < hi) of one
    cell, and that cell."""
    t2f = mesh.t2f.astype(np.int64)
    nf, nc = mesh.facets.shape[1], mesh.t.shape[1]
    keys = np.concatenate([np.minimum(t2f[i], t2f[j]) * nf + np.maximum(t2f[i], t2f[j])
                           for i, j in ((0, 1), (1, 2), (0, 2))])
    order = np.argsort(keys, kind="stable")
    return keys[order], np.tile(np.arange(nc), 3)[order]


def _cell_of_midpoints(mesh, cells_of, f1, f2):
    """The coarse cell whose facets f1 and f2 are (two facets of one cell; cells_of:
    _cells_of_facet_pairs), and the cell's vertex that they share."""
    keys, cells = cells_of
    nf = mesh.facets.shape[1]
    cell = cells[np.searchsorted(keys, np.minimum(f1, f2) * nf + np.maximum(f1, f2))]
    e1, e2 = mesh.facets[:, f1], mesh.facets[:, f2]
    corner = np.where((e1[0] == e2[0]) | (e1[0] == e2[1]), e1[0], e1[1])
    return cell, corner


def _vertex_rank(mesh, gv, cell, vertex):
    """The rank (0, 1, 2) of the vertex's global number among those of the cell's vertices."""
    g = gv[mesh.t[:, cell]]
    return np.sum(g < gv[vertex], axis=0)


def local_refined(mesh, times, comm):
    """This rank's cells of the mesh refined `times` times (see the module docstring), with
    mesh.numbering."""
    if type(mesh) is not MeshTri1:
        raise ValueError(f"rank-local meshes are built for triangle meshes (MeshTri1), not "
                         f"{type(mesh).__name__}: run without local meshes")
    if mesh.boundaries or mesh.subdomains:
        raise ValueError("rank-local meshes keep no named boundaries or subdomains: give "
                         "boundaries as predicates of x, or run without local meshes")
    k, coarse = 0, None
    while k < times and mesh.t.shape[1] < CELLS_PER_RANK * comm.size:
        coarse, mesh, k = mesh, uniformly_refined(mesh, 1), k + 1
    numbering = whole_numbering(mesh, coarse)
    if mesh.t.shape[1] < comm.size:
        raise ValueError(f"{mesh.t.shape[1]} cells for {comm.size} ranks: refine the mesh more")
    with partition.local(comm):
        mine = partition.cells(mesh)
    mesh, numbering = submesh(mesh, numbering, mine)
    for _ in range(times - k):
        mesh, numbering = refined_numbered(mesh, numbering)
    mesh.numbering = numbering
    return mesh


def global_dofs(basis):
    """The global numbers of a basis's dofs on a local mesh, and the whole space's size:
    laid out as scikit-fem lays out a whole mesh's dofs (vertex v's j-th dof v nn + j, then
    facet f's NV nn + f nf + j, then cell c's NV nn + NF nf + c ni + j), from the entities'
    global numbers; a basis on a whole mesh keeps its own numbers."""
    numbering = getattr(basis.mesh, "numbering", None)
    if numbering is None:
        return np.arange(basis.N), basis.N
    e = basis.elem
    inner = e.elem if isinstance(e, ElementVector) else e
    if not isinstance(inner, ElementH1) or e.edge_dofs or inner.facet_dofs > 1:
        raise ValueError(f"{type(inner).__name__} on a rank-local mesh: Lagrange elements with "
                         "dofs on vertices, facets (one per component) and cells only (the "
                         "dofs of a facet must not depend on its orientation); build the "
                         "meshes whole (run without --local-meshes)")
    NV, NF, NC = numbering.counts
    nn, nf, ni = e.nodal_dofs, e.facet_dofs, e.interior_dofs
    out = np.empty(basis.N, np.int64)
    for j in range(nn):
        out[basis.nodal_dofs[j]] = numbering.vertices * nn + j
    for j in range(nf):
        out[basis.facet_dofs[j]] = NV * nn + numbering.facets * nf + j
    for j in range(ni):
        out[basis.interior_dofs[j]] = NV * nn + NF * nf + numbering.cells * ni + j
    return out, NV * nn + NF * nf + NC * ni
