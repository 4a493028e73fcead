"""nitsche.local_mesh: the pieces of a mesh that ranks refine by themselves number its
vertices, edges, facets, cells and dofs as one whole mesh, without MPI: three random sets of
cells of a coarse mesh of triangles, quadrilaterals or hexahedra, each refined by itself,
against the whole mesh refined as often."""
from types import SimpleNamespace

import numpy as np
import pytest
from skfem import (ElementHex1, ElementHex2, ElementQuad1, ElementQuad2, ElementTetP1, ElementTetP2,
                   ElementTriMorley, ElementTriP1,
                   ElementTriP2, ElementVector, MeshHex, MeshQuad, MeshTet, MeshTri)

import nitsche as ni
from nitsche import partition

from nitsche.fields import shared_basis, DOFS
from nitsche.local_mesh import global_dofs, refined_numbered, submesh, whole_numbering
from nitsche.measures import boundary_facets, build_facets
from nitsche.meshes import uniformly_refined

TIMES = 3
MESHES = {"triangles": lambda: MeshTri.init_symmetric().refined(2),
          "quadrilaterals": lambda: MeshQuad().refined(2),
          "tetrahedra": lambda: MeshTet().refined(1),
          "hexahedra": lambda: MeshHex().refined(1)}


@pytest.fixture(scope="module", params=list(MESHES))
def pieces(request):
    """Three random sets of cells of a coarse mesh (each with three ghost cells of the
    next set), refined three times (hexahedra twice) piece by piece, and the whole mesh
    refined as often."""
    coarse = MESHES[request.param]()
    times = 2 if coarse.dim() == 3 else TIMES
    mesh = uniformly_refined(coarse, 1)
    numbering = whole_numbering(mesh, coarse)
    part = np.random.default_rng(0).integers(0, 3, mesh.t.shape[1])
    out = []
    for r in range(3):
        m, n = submesh(mesh, numbering, np.flatnonzero(part == r),
                       ghosts=np.flatnonzero(part == (r + 1) % 3)[:3])
        for _ in range(times):
            m, n = refined_numbered(m, n)
        m.numbering = n
        out.append(m)
    whole = uniformly_refined(mesh, times)
    build_facets(whole)
    return out, whole


def test_pieces_number_the_whole_refined_mesh(pieces):
    """Every global number is one entity: the same vertex (bit for bit the same point), the
    same edge and facet (the same vertex numbers) and cell (the same centre) wherever a
    piece holds it; the numbers of each kind are 0..count-1, the counts and the points
    those of the whole refined mesh, every cell owned by one piece, and the boundary facets
    the whole mesh's."""
    parts, whole = pieces
    dim = whole.dim()
    NV, NF, NC = parts[0].numbering.counts
    assert (NV, NF, NC) == (whole.p.shape[1], whole.facets.shape[1], whole.t.shape[1])
    if dim == 3:
        assert parts[0].numbering.edge_count == whole.edges.shape[1]
    points, centres = np.full((dim, NV), np.nan), np.full((dim, NC), np.nan)
    owned, on_boundary, entity = np.zeros(NC, int), np.zeros(NF, bool), {}
    for m in parts:
        n = m.numbering
        for x, numbers, at in ((points, n.vertices, m.p), (centres, n.cells, m.p[:, m.t].mean(axis=1))):
            seen = ~np.isnan(x[0, numbers])
            assert np.array_equal(x[:, numbers][:, seen], at[:, seen])
            x[:, numbers] = at
        owned[n.cells[n.owned]] += 1
        on_boundary[n.facets[n.boundary]] = True
        kinds = [("facet", n.facets, m.facets)] + ([("edge", n.edges, m.edges)] if dim == 3 else [])
        for kind, numbers, vertices in kinds:
            assert np.unique(numbers).size == numbers.size
            for g, v in zip(numbers, np.sort(n.vertices[vertices], axis=0).T):
                assert entity.setdefault((kind, int(g)), tuple(v)) == tuple(v)
    assert not np.isnan(points).any() and not np.isnan(centres).any() and (owned == 1).all()
    kinds = [("facet", NF)] + ([("edge", parts[0].numbering.edge_count)] if dim == 3 else [])
    for kind, count in kinds:  # numbers 0..count-1, each one vertex set
        numbers = sorted(g for (k, g) in entity if k == kind)
        assert numbers == list(range(count))
        assert len({v for (k, _), v in entity.items() if k == kind}) == count
    order = lambda p: p[:, np.lexsort(p)]  # noqa: E731
    assert np.array_equal(order(points), order(whole.p))
    assert np.allclose(order(centres), order(whole.p[:, whole.t].mean(axis=1)), rtol=0, atol=1e-14)
    assert on_boundary.sum() == boundary_facets(whole).size


def test_parents_are_the_coarse_vertices_of_each_new_vertex(pieces):
    """Each vertex is the mean of its parents (coarser global numbers): an edge's midpoint,
    a face's or cell's centre, or a coarse vertex itself."""
    parts, whole = pieces
    coarse_points = {}
    for m in parts:  # the coarse vertices are those the fine mesh keeps, with their numbers
        old = (m.numbering.parents == m.numbering.parents[0]).all(axis=0)
        coarse_points.update(zip(m.numbering.parents[0, old], m.p[:, old].T))
    for m in parts:
        parents = m.numbering.parents
        assert parents.shape[0] == 2 ** whole.dim()
        mean = np.mean([[coarse_points[i] for i in row] for row in parents], axis=0).T
        assert np.allclose(mean, m.p, rtol=0, atol=1e-15)


ELEMENTS = {"MeshTri1": [ElementTriP1, ElementTriP2, lambda: ElementVector(ElementTriP2())],
            "MeshQuad1": [ElementQuad1, ElementQuad2, lambda: ElementVector(ElementQuad2())],
            "MeshTet1": [ElementTetP1, ElementTetP2, lambda: ElementVector(ElementTetP2())],
            "MeshHex1": [ElementHex1, ElementHex2, lambda: ElementVector(ElementHex1())]}


@pytest.mark.parametrize("which", [0, 1, 2], ids=["P1/Q1", "P2/Q2", "vector"])
def test_global_dofs_are_one_numbering_of_the_whole_space(pieces, which):
    """The pieces' dofs take the numbers 0..N-1 with N the whole space's dof count, and a
    number shared by pieces is at the same point (second order: dofs on edges, facets and
    cells)."""
    parts, whole = pieces
    element = ELEMENTS[type(whole).__name__][which]()
    N = shared_basis(whole, element, DOFS).N
    at = {}
    for m in parts:
        basis = shared_basis(m, element, DOFS)
        number, n = global_dofs(basis)
        assert n == N and np.unique(number).size == number.size
        for g, x in zip(number, basis.doflocs.T):
            assert np.array_equal(at.setdefault(int(g), x), x)
    assert sorted(at) == list(range(N))


def test_what_local_meshes_do_not_build_is_refused():
    """On 2 ranks, an interface into a rank-local mesh built without the ghost cells its
    points reach, and one paired in the current configuration, and an element whose facet
    dofs depend on the facet's orientation (Morley's normal derivative) raise errors that
    say what to do (the interface's checks read the communicator's size only)."""
    coarse = MeshTri.init_symmetric().refined(2)
    m, n = submesh(coarse, whole_numbering(coarse), np.arange(10))
    m.numbering = n
    u, v = ni.Field("u", m, ElementTriP1()), ni.Field("v", m, ElementTriP1())
    with partition.local(SimpleNamespace(size=2, rank=0)):
        with pytest.raises(ValueError, match="ghosts_for=.this body's mesh, to_other"):
            ni.interface(u, lambda x: x[1] < 1e-12, other=v)
        with pytest.raises(ValueError, match="pairing='current'.* on a rank-local mesh"):
            ni.interface(u, lambda x: x[1] < 1e-12, other=v, pairing="current", onto="boundary")
    with pytest.raises(ValueError, match="ElementTriMorley on a rank-local mesh"):
        global_dofs(shared_basis(m, ElementTriMorley(), DOFS))


def test_fixed_boundaries_are_the_whole_meshes(pieces):
    """A field fixed on 'boundary' or on a predicate holds the dofs of the whole mesh's
    boundary only, not those of the facets between pieces; a boundary measure likewise,
    those of its own cells only."""
    parts, whole = pieces
    element = ELEMENTS[type(whole).__name__][0]()
    for m in parts:
        on_boundary = np.zeros(m.p.shape[1], bool)
        on_boundary[m.facets[:, m.numbering.boundary].ravel()] = True
        u = ni.Field("u", m, element, fixed="boundary")
        assert np.array_equal(u.fixed_dofs, np.flatnonzero(on_boundary))
        low = ni.Field("v", m, element, fixed=lambda x: x[1] < 0.5)
        assert on_boundary[low.fixed_dofs].all()
        boundary = np.flatnonzero(m.numbering.boundary)  # a ghost cell's facets are its owner's
        assert ni.facets(u).facets.size == m.numbering.owned[m.f2t[0, boundary]].sum() > 0
