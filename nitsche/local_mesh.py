"""Rank-local meshes: this rank's cells of a uniformly refined mesh of triangles,
quadrilaterals or hexahedra, refined by the rank alone, with the global numbers of its
vertices, edges (3D), facets and cells.

Inside nitsche.partition.local(comm, meshes="local"), nitsche.meshes.refined(base, n) builds
the base mesh refined k times whole (k the fewest refinements that give CELLS_PER_RANK cells
per rank, at most n), partitions its cells (partition.cells: METIS), keeps this rank's cells
(`submesh`) and refines them the other n - k times by itself (`refined_numbered`): no rank
holds more of the finer meshes than its own cells.  The mesh it returns carries
`mesh.numbering` (Numbering): the global number of each of its vertices, edges, facets and
cells, the same on every rank that holds the entity, and which of its facets lie on the
whole mesh's boundary (a facet between two ranks' cells is on the local mesh's boundary
only).  With ghosts_for=(other, to_this) the rank also holds the coarse cells that its
cells of the local mesh `other` reach when mapped by to_this (`reached`), refined along as
ghosts (Numbering.owned False: no elements of this rank's measures; partition.cells gives
the own ones): the cells an interface from `other` onto this mesh evaluates fields in.

The global numbers of a refined mesh follow from the coarse ones (NV vertices, NE edges, NF
facets, NC cells), so that no rank needs another's cells to find them.  Triangles:
  vertices: a coarse vertex keeps its number v; the midpoint of facet f is NV + f;
  facets:   the half of facet f at its endpoint of the smaller number is 2 f, the other
            2 f + 1; the facet between two midpoints of cell c that cuts off its vertex of
            rank r (0, 1, 2 among the cell's vertex numbers) is 2 NF + 3 c + r;
  cells:    the corner child of cell c at its vertex of rank r is 4 c + r, the middle one
            4 c + 3.
Quadrilaterals and hexahedra (a new vertex at every edge, face and cell; `_refined_tensor`):
a fine entity lies in the coarse entity of the highest dimension among its vertices' and is
numbered within it by the rank of the coarse entity its vertex of the lowest dimension is
new at (e.g. hexahedron c's corner children 8 c + r, the faces inside it 4 NF + 12 c + the
rank of their edge among the cell's twelve).
These are not the numbers scikit-fem gives the whole refined mesh; they are a numbering of
it, which the distributed engine needs (nitsche.distributed.Layout: the owner and PETSc
number of every dof, through `global_dofs`).  Tetrahedra are not refined locally (their
inner octahedron's split would need its own rule): their cases keep whole meshes.
"""
import dataclasses

import numpy as np
from skfem import ElementVector, MeshHex1, MeshQuad1, MeshTet1, MeshTri1
from skfem.element import ElementH1

from . import partition
from .measures import boundary_facets, build_edges, build_facets
from .meshes import uniformly_refined

CELLS_PER_RANK = 256  # the coarsest whole mesh partitioned has at least this many cells per rank


@dataclasses.dataclass
class Numbering:
    """Global numbers of a local mesh's vertices (nv,), facets (nf,) and cells (nc,), the
    whole mesh's counts (NV, NF, NC), which local facets lie on the whole mesh's boundary
    (nf,), each vertex's coarser-mesh parents (2^dim, nv): the global numbers of the coarse
    vertices whose mean it is (repeated to 2^dim rows; a coarse vertex itself), or None on
    the base mesh; in 3D the edges' global numbers (ne,) and their count NE; which cells
    are this rank's own (nc,; None: all), the others ghosts, held for an interface."""
    vertices: np.ndarray
    facets: np.ndarray
    cells: np.ndarray
    counts: tuple
    boundary: np.ndarray
    parents: np.ndarray = None
    edges: np.ndarray = None
    edge_count: int = None
    owned: np.ndarray = None

    def numbers(self, dim):
        """The global numbers of the local entities of each dimension 0..dim, and their
        whole counts."""
        NV, NF, NC = self.counts
        if dim == 2:
            return [self.vertices, self.facets, self.cells], [NV, NF, NC]
        return [self.vertices, self.edges, self.facets, self.cells], [NV, self.edge_count, NF, NC]


# the dimensions of the coarse entities that scikit-fem's uniform refinement gives a new
# vertex (edge midpoints, face and cell centres), in the order it numbers them after the
# coarse vertices
NEW_VERTICES = {MeshTri1: (1,), MeshQuad1: (1, 2), MeshTet1: (1,), MeshHex1: (1, 2, 3)}


def connectivity(mesh):
    """conn[D][q] (k, n_D): the local numbers of the q-dimensional entities of each
    D-dimensional one (0 <= q <= D <= dim: vertices, edges (3D), facets, cells; conn[D][D]
    each entity itself)."""
    _build(mesh)
    dim = mesh.dim()
    if dim == 2:
        conn = {1: {0: mesh.facets}, 2: {0: mesh.t, 1: mesh.t2f}}
    else:
        conn = {1: {0: mesh.edges}, 2: {0: mesh.facets, 1: mesh.f2e},
                3: {0: mesh.t, 1: mesh.t2e, 2: mesh.t2f}}
    conn[0] = {}
    for D in range(dim + 1):
        conn[D][D] = np.arange(mesh.p.shape[1] if D == 0 else conn[D][0].shape[1])[None]
    return conn


def _build(mesh):
    """The mesh's facets and (3D) edges, each by one integer sort (measures.build_facets,
    build_edges)."""
    build_facets(mesh)
    build_edges(mesh)


def _check_type(mesh):
    if type(mesh) not in NEW_VERTICES:
        raise ValueError(f"rank-local meshes are built for triangles, quadrilaterals, tetrahedra "
                         f"and hexahedra (MeshTri1, MeshQuad1, MeshTet1, MeshHex1), not "
                         f"{type(mesh).__name__}: run without local meshes")


def _parents(mesh, numbers):
    """(2^dim, fine vertices): the global numbers of the coarse vertices whose mean each
    vertex of mesh refined once is (scikit-fem's order: the coarse vertices, then a vertex
    per entity of each dimension in NEW_VERTICES, in the entities' order)."""
    conn, rows = connectivity(mesh), 2 ** mesh.dim()
    parts = [conn[D][0] for D in (0,) + NEW_VERTICES[type(mesh)]]
    return np.hstack([numbers[p[np.arange(rows) % p.shape[0]]] for p in parts]).astype(np.int64)


def parent_mean(v):
    """The mean over the parents (the first axis of v: 2^dim rows, Numbering.parents) by
    halves, 1/2 (v[:m] + v[m:]), so that repeated parents give their values exactly."""
    while v.shape[0] > 1:
        v = 0.5 * (v[:v.shape[0] // 2] + v[v.shape[0] // 2:])
    return v[0]


def whole_numbering(mesh, coarse=None):
    """The Numbering of a whole mesh (its own numbers), parents from `coarse` when the mesh
    is coarse refined once (scikit-fem's order of the new vertices: NEW_VERTICES)."""
    _check_type(mesh)
    _build(mesh)
    nv, nf, nc = mesh.p.shape[1], mesh.facets.shape[1], mesh.t.shape[1]
    boundary = np.zeros(nf, bool)
    boundary[boundary_facets(mesh)] = True
    parents = None if coarse is None else _parents(coarse, np.arange(coarse.p.shape[1]))
    ne = mesh.edges.shape[1] if mesh.dim() == 3 else None
    return Numbering(np.arange(nv), np.arange(nf), np.arange(nc), (nv, nf, nc), boundary, parents,
                     None if ne is None else np.arange(ne), ne)


def submesh(mesh, numbering, cells, ghosts=None):
    """The mesh of the given cells of a numbered mesh (whole, or a rank-local one) and of the
    ghost cells (held but not owned: Numbering.owned), with their Numbering."""
    held = cells if ghosts is None else np.union1d(cells, ghosts)
    used = np.unique(mesh.t[:, held])
    sub = type(mesh)(mesh.p[:, used], np.searchsorted(used, mesh.t[:, held]))
    _build(sub)
    gv = numbering.vertices
    facets = _lookup(gv[mesh.facets], gv[used][sub.facets])
    parents = None if numbering.parents is None else numbering.parents[:, used]
    edges = None if mesh.dim() == 2 else numbering.edges[_lookup(gv[mesh.edges], gv[used][sub.edges])]
    owned = None if ghosts is None else np.isin(held, cells)  # (all True: no ghost needed)
    return sub, Numbering(gv[used], numbering.facets[facets], numbering.cells[held],
                          numbering.counts, numbering.boundary[facets], parents, edges,
                          numbering.edge_count, owned)


def _lookup(rows, query):
    """The columns of rows (k, n) that hold the vertex sets of the columns of query (k, m)."""
    keys = _set_keys(rows)
    order = np.argsort(keys)
    return order[np.searchsorted(keys, _set_keys(query), sorter=order)]


def _set_keys(rows):
    """One comparable key per column of an integer array: its sorted entries' bytes."""
    s = np.ascontiguousarray(np.sort(np.asarray(rows, np.int64), axis=0).T)
    return s.view(np.dtype((np.void, 8 * s.shape[1]))).ravel()


def refined_numbered(mesh, numbering):
    """The local mesh refined once (scikit-fem's uniform refinement) and its Numbering from
    the coarse one (see the module docstring)."""
    _check_type(mesh)
    refine = {MeshTri1: _refined_triangles, MeshTet1: _refined_tetrahedra}.get(type(mesh), _refined_tensor)
    fine, n, parent = refine(mesh, numbering)
    if numbering.owned is not None:  # a child of an own cell is own, of a ghost a ghost
        n.owned = numbering.owned[parent]
    return fine, n


def _refined_triangles(mesh, numbering):
    """refined_numbered of a triangle mesh."""
    _build(mesh)
    NV, NF, NC = numbering.counts
    nv = mesh.p.shape[1]
    fine = uniformly_refined(mesh, 1)
    _build(fine)
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
    return fine, Numbering(vertices, facets, cells, (NV + NF, 2 * NF + 3 * NC, 4 * NC), boundary,
                           _parents(mesh, gv)), cell


def _refined_tensor(mesh, numbering):
    """refined_numbered of a quadrilateral or hexahedral mesh: each fine vertex is new at a
    coarse entity of dimension D (a vertex, an edge's midpoint, a face's or cell's centre),
    numbered sum_{D' < D} N_D' + its global number; a fine entity of dimension d lies in the
    coarse entity P of its vertices' highest D, and the vertex of lowest dimension D - d is
    new at one of P's entities Q of that dimension: its number is
        sum_{d <= D' < D} k(d, D') N_D' + k(d, D) P + (the rank of Q's number among those
        of P's k(d, D) entities of dimension D - d)
    (a corner child of a cell, face or edge by its coarse vertex; a face inside a
    hexahedron by its edge, an edge inside a face by its edge, inside a hexahedron by its
    face; a quadrilateral's inner facet by its facet)."""
    dim = mesh.dim()
    conn = connectivity(mesh)
    g, N = numbering.numbers(dim)
    fine = uniformly_refined(mesh, 1)
    _build(fine)
    start = np.cumsum([0] + [conn[D][D].shape[1] for D in range(dim + 1)])

    def k(d, D):
        return conn[D][D - d].shape[0]

    def numbered(ent, d):
        """Global numbers of fine entities (vertex lists, (m,) or (j, m)) of dimension d, and
        each one's P (dimension, local number)."""
        vd = np.searchsorted(start, ent, side="right") - 1  # the dimension each vertex is new at
        col = np.arange(ent.shape[1])
        top, low = vd.argmax(axis=0), vd.argmin(axis=0)
        D, P = vd[top, col], (ent - start[vd])[top, col]
        Q = (ent - start[vd])[low, col]
        out = np.empty(ent.shape[1], np.int64)
        for DD in np.unique(D):
            s = D == DD
            qd = DD - d  # the dimension of Q (see the docstring)
            rank = np.sum(g[qd][conn[DD][qd][:, P[s]]] < g[qd][Q[s]], axis=0)
            offset = sum(k(d, D2) * N[D2] for D2 in range(d, DD))
            out[s] = offset + k(d, DD) * g[DD][P[s]] + rank
        return out, D, P

    counts = [sum(k(d, D) * N[D] for D in range(d, dim + 1)) for d in range(dim + 1)]
    vertices = numbered(np.arange(fine.p.shape[1])[None], 0)[0]
    facets, D, P = numbered(fine.facets, dim - 1)
    boundary = np.zeros(facets.size, bool)
    corner = D == dim - 1  # a part of a coarse facet
    boundary[corner] = numbering.boundary[P[corner]]
    cells, _, parent = numbered(fine.t, dim)
    edges = numbered(fine.edges, 1)[0] if dim == 3 else None
    return fine, Numbering(vertices, facets, cells, (counts[0], counts[dim - 1], counts[dim]),
                           boundary, _parents(mesh, g[0]), edges,
                           counts[1] if dim == 3 else None), parent


# fine entities of dimension d inside one coarse entity of dimension D of a tetrahedral mesh
# refined once: (d, D) -> count (a vertex or an edge's midpoint, an edge's halves, a face's
# 3 inner edges and 4 parts, a cell's diagonal, 8 inner faces and 8 children)
TETRAHEDRON_PARTS = {(0, 0): 1, (0, 1): 1, (0, 2): 0, (0, 3): 0, (1, 1): 2, (1, 2): 3, (1, 3): 1,
                     (2, 2): 4, (2, 3): 8, (3, 3): 8}


def _refined_tetrahedra(mesh, numbering):
    """refined_numbered of a tetrahedral mesh (the new vertices: the edges' midpoints, NV + e).
    A fine entity of dimension d lies in the coarse edge, face or cell P that its vertices'
    coarse vertices span (of dimension D); it is numbered
        sum_{d <= D' < D} k(d, D') N_D' + k(d, D) P + (the rank of its sorted global vertex
        numbers among those of the fine d-entities in P)
    (k: TETRAHEDRON_PARTS): every rank that holds P holds all of its parts (the cells around
    it are refined whole), so the ranks agree on the ranks."""
    g, N = numbering.numbers(3)
    fine = uniformly_refined(mesh, 1)
    _build(fine)
    nv = mesh.p.shape[1]
    span = np.hstack([np.tile(np.arange(nv), (2, 1)), mesh.edges])  # coarse vertices of each fine one
    fine_g = np.concatenate([g[0], N[0] + g[1]]).astype(np.int64)
    kinds = {1: mesh.edges, 2: mesh.facets, 3: mesh.t}

    def numbered(ent, d):
        """Global numbers of the fine d-entities (vertex lists (j, m)), and each one's
        coarse entity: its dimension D and local number P."""
        m = ent.shape[1]
        s = np.sort(span[:, ent].reshape(-1, m), axis=0)
        new = np.vstack([np.ones((1, m), bool), s[1:] != s[:-1]])
        D = new.sum(axis=0) - 1  # the coarse vertices spanned, less one
        P, gP = np.empty(m, np.int64), np.empty(m, np.int64)
        for DD in np.unique(D):
            sel = np.flatnonzero(D == DD)
            vertices = s.T[sel][new.T[sel]].reshape(sel.size, DD + 1).T
            P[sel] = vertices[0] if DD == 0 else _lookup(kinds[DD], vertices)
            gP[sel] = g[DD][P[sel]]
        # the rank within P: sort by (D, P's number, the sorted global vertex numbers)
        keys = np.sort(fine_g[ent], axis=0)
        order = np.lexsort(tuple(keys[::-1]) + (gP, D))
        first = np.ones(m, bool)
        first[1:] = (D[order][1:] != D[order][:-1]) | (gP[order][1:] != gP[order][:-1])
        start = np.maximum.accumulate(np.where(first, np.arange(m), 0))
        rank = np.empty(m, np.int64)
        rank[order] = np.arange(m) - start
        offset = np.array([sum(TETRAHEDRON_PARTS[d, D2] * N[D2] for D2 in range(d, DD))
                           for DD in range(4)])
        k = np.array([TETRAHEDRON_PARTS.get((d, DD), 0) for DD in range(4)])  # (D < d: none)
        return offset[D] + k[D] * gP + rank, D, P

    counts = [sum(TETRAHEDRON_PARTS[d, D] * N[D] for D in range(d, 4)) for d in range(4)]
    vertices = numbered(np.arange(fine.p.shape[1])[None], 0)[0]
    facets, D, P = numbered(fine.facets, 2)
    boundary = np.zeros(facets.size, bool)
    boundary[D == 2] = numbering.boundary[P[D == 2]]  # parts of a coarse facet
    cells, _, parent = numbered(fine.t, 3)
    edges = numbered(fine.edges, 1)[0]
    return fine, Numbering(vertices, facets, cells, (counts[0], counts[2], counts[3]), boundary,
                           _parents(mesh, g[0]), edges, counts[1]), parent


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


def local_refined(mesh, times, comm, ghosts_for=None):
    """This rank's cells of the mesh refined `times` times (see the module docstring), with
    mesh.numbering; ghosts_for=(other, to_this): also the cells (ghosts: Numbering.owned)
    that this rank's cells of the rank-local mesh `other`, mapped by to_this (points
    (dim_other, n) -> (dim, n)), may reach (`reached`), for an interface from `other` onto
    this mesh (nitsche.measures.interface): the coarse cells reached, refined along, and
    after each refinement the children that are not reached dropped (the ghosts a layer of
    the fine cells, not of the coarse ones)."""
    _check_type(mesh)
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
    ghosts = None
    if ghosts_for is not None:
        ghosts = np.setdiff1d(np.flatnonzero(reached(mesh, *ghosts_for)), mine)
    mesh, numbering = submesh(mesh, numbering, mine, ghosts)
    for _ in range(times - k):
        mesh, numbering = refined_numbered(mesh, numbering)
        if ghosts_for is not None:  # the ghosts' children that no point reaches dropped
            keep = numbering.owned | reached(mesh, *ghosts_for)
            if not keep.all():
                mesh, numbering = submesh(mesh, numbering, np.flatnonzero(numbering.owned),
                                          np.flatnonzero(keep & ~numbering.owned))
    mesh.numbering = numbering
    return mesh


def reached(mesh, other, to_this):
    """Which cells of mesh (whole, coarse) a point of the other mesh's cells, mapped by
    to_this, may lie in: those whose centre is within (its largest cell diameter + the
    other mesh's largest cell diameter) of a mapped vertex of the other mesh (a superset:
    any point of a cell of the other mesh is within that cell's diameter of its vertices,
    and any point of a cell of mesh within its diameter of its centre)."""
    from scipy.spatial import cKDTree
    from .measures import cell_diameters
    x = np.asarray(to_this(other.p), dtype=float)
    if x.shape[0] != mesh.dim():
        raise ValueError(f"ghosts_for: to_this maps points to dimension {x.shape[0]}, the mesh "
                         f"has {mesh.dim()}")
    reach = cell_diameters(mesh).max() + (cell_diameters(other).max() if other.t.shape[1] else 0.0)
    centres = mesh.p[:, mesh.t].mean(axis=1).T
    return cKDTree(x.T).query_ball_point(centres, reach, return_length=True) > 0 if x.shape[1] \
        else np.zeros(mesh.t.shape[1], bool)


def global_dofs(basis):
    """The global numbers of a basis's dofs on a local mesh, and the whole space's size:
    laid out as scikit-fem lays out a whole mesh's dofs (vertex v's j-th dof v nn + j, then
    in 3D edge e's NV nn + e ne + j, then facet f's, then cell c's, each kind after the
    whole mesh's dofs of the kinds before), from the entities' global numbers; a basis on
    a whole mesh keeps its own numbers."""
    numbering = getattr(basis.mesh, "numbering", None)
    if numbering is None:
        return np.arange(basis.N), basis.N
    e = basis.elem
    inner = e.elem if isinstance(e, ElementVector) else e
    if not isinstance(inner, ElementH1) or inner.edge_dofs > 1 or inner.facet_dofs > 1:
        raise ValueError(f"{type(inner).__name__} on a rank-local mesh: Lagrange elements with "
                         "dofs on vertices, edges and facets (one per component) and cells only "
                         "(the dofs of an edge or facet must not depend on its orientation); "
                         "build the meshes whole (run without --local-meshes)")
    NV, NF, NC = numbering.counts
    kinds = [(basis.nodal_dofs, numbering.vertices, NV), (basis.facet_dofs, numbering.facets, NF),
             (basis.interior_dofs, numbering.cells, NC)]
    if basis.mesh.dim() == 3:
        kinds.insert(1, (basis.edge_dofs, numbering.edges, numbering.edge_count))
    out, start = np.empty(basis.N, np.int64), 0
    for dofs, numbers, count in kinds:
        per = dofs.shape[0]  # dofs per entity
        for j in range(per):
            out[dofs[j]] = start + numbers * per + j
        start += count * per
    return out, start
