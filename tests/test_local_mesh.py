"""nitsche.local_mesh: the pieces of a mesh that ranks refine by themselves number its
vertices, facets, cells and dofs as one whole mesh, without MPI: three random sets of cells
of a coarse mesh, each refined three times, against the whole mesh refined three times."""
import numpy as np
import pytest
from skfem import ElementTriMorley, ElementTriP1, ElementTriP2, ElementVector, MeshTri

import nitsche as ni

from nitsche.fields import shared_basis, DOFS
from nitsche.local_mesh import global_dofs, refined_numbered, submesh, whole_numbering
from nitsche.measures import boundary_facets
from nitsche.meshes import uniformly_refined

TIMES = 3


@pytest.fixture(scope="module")
def pieces():
    coarse = MeshTri.init_symmetric().refined(2)
    mesh = uniformly_refined(coarse, 1)
    numbering = whole_numbering(mesh, coarse)
    part = np.random.default_rng(0).integers(0, 3, mesh.t.shape[1])
    out = []
    for r in range(3):
        m, n = submesh(mesh, numbering, np.flatnonzero(part == r))
        for _ in range(TIMES):
            m, n = refined_numbered(m, n)
        m.numbering = n
        out.append(m)
    return out, uniformly_refined(mesh, TIMES)


def test_pieces_number_the_whole_refined_mesh(pieces):
    """Every global number is one entity: the same vertex (bit for bit the same point), the
    same facet (the same vertex numbers) and cell wherever a piece holds it; the numbers of
    each kind are 0..count-1, the counts and the points those of the whole refined mesh,
    every cell in one piece, and the boundary facets (held by one piece) the whole mesh's."""
    parts, whole = pieces
    NV, NF, NC = parts[0].numbering.counts
    assert (NV, NF, NC) == (whole.p.shape[1], whole.facets.shape[1], whole.t.shape[1])
    points, ends = np.full((2, NV), np.nan), -np.ones((2, NF), np.int64)
    cells, on_boundary, held = np.zeros(NC, int), np.zeros(NF, int), np.zeros(NF, int)
    for m in parts:
        n = m.numbering
        seen = ~np.isnan(points[0, n.vertices])
        assert np.array_equal(points[:, n.vertices][:, seen], m.p[:, seen])
        points[:, n.vertices] = m.p
        pair = np.sort(n.vertices[m.facets], axis=0)
        seen = ends[0, n.facets] >= 0
        assert np.array_equal(ends[:, n.facets][:, seen], pair[:, seen])
        ends[:, n.facets] = pair
        cells[n.cells] += 1
        held[n.facets] += 1
        on_boundary[n.facets] += n.boundary
        assert np.unique(n.vertices).size == n.vertices.size and np.unique(n.facets).size == n.facets.size
    assert not np.isnan(points).any() and (ends >= 0).all() and (cells == 1).all()
    order = lambda p: p[:, np.lexsort(p)]  # noqa: E731
    assert np.array_equal(order(points), order(whole.p))
    assert on_boundary.sum() == boundary_facets(whole).size and (held[on_boundary > 0] == 1).all()
    # a facet between two pieces is on each one's boundary, not on the whole mesh's
    assert ((held == 2) & (on_boundary > 0)).sum() == 0 and (held == 2).any()


def test_parents_are_the_coarse_vertices_of_each_midpoint(pieces):
    """Each vertex's parents (coarser global numbers) have it as their midpoint."""
    parts, whole = pieces
    coarse_points = {}
    for m in parts:  # the coarse vertices are those the fine mesh keeps, with their numbers
        old = m.numbering.parents[0] == m.numbering.parents[1]
        coarse_points.update(zip(m.numbering.parents[0, old], m.p[:, old].T))
    for m in parts:
        a, b = m.numbering.parents
        pa = np.array([coarse_points[i] for i in a]).T
        pb = np.array([coarse_points[i] for i in b]).T
        assert np.allclose(0.5 * (pa + pb), m.p, rtol=0, atol=1e-15)


@pytest.mark.parametrize("element", [ElementTriP1(), ElementTriP2(), ElementVector(ElementTriP2())],
                         ids=["P1", "P2", "P2 vector"])
def test_global_dofs_are_one_numbering_of_the_whole_space(pieces, element):
    """The pieces' dofs take the numbers 0..N-1 with N the whole space's dof count, and a
    number shared by pieces is at the same point."""
    parts, whole = pieces
    N = shared_basis(whole, element, DOFS).N
    at = {}
    for m in parts:
        basis = shared_basis(m, element, DOFS)
        number, n = global_dofs(basis)
        assert n == N and np.unique(number).size == number.size
        for g, x in zip(number, basis.doflocs.T):
            assert np.array_equal(at.setdefault(int(g), x), x)
    assert sorted(at) == list(range(N))


def test_what_local_meshes_do_not_build_is_refused(pieces):
    """An interface on a rank-local mesh (the other body's cells would be on other ranks) and
    an element whose facet dofs depend on the facet's orientation (Morley's normal
    derivative) raise errors that say to build the meshes whole."""
    mesh = pieces[0][0]
    u = ni.Field("u", mesh, ElementTriP1())
    with pytest.raises(ValueError, match="interface on a rank-local mesh"):
        ni.interface(u, lambda x: x[1] < 1e-12)
    with pytest.raises(ValueError, match="ElementTriMorley on a rank-local mesh"):
        global_dofs(shared_basis(mesh, ElementTriMorley(), DOFS))


def test_fixed_boundaries_are_the_whole_meshes(pieces):
    """A field fixed on 'boundary' or on a predicate holds the dofs of the whole mesh's
    boundary only, not those of the facets between pieces; a boundary measure likewise."""
    parts, whole = pieces
    for m in parts:
        on_boundary = np.zeros(m.p.shape[1], bool)
        on_boundary[m.facets[:, m.numbering.boundary].ravel()] = True
        u = ni.Field("u", m, ElementTriP1(), fixed="boundary")
        assert np.array_equal(u.fixed_dofs, np.flatnonzero(on_boundary))
        low = ni.Field("v", m, ElementTriP1(), fixed=lambda x: x[1] < 0.5)
        assert on_boundary[low.fixed_dofs].all()
        assert ni.facets(u).facets.size == m.numbering.boundary.sum()
