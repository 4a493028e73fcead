"""The problem set-up's shortcuts give what the plain scikit-fem path gives, bit for bit."""
import numpy as np
import pytest
from skfem import (Basis, ElementHex1, ElementQuad1, ElementQuad2, ElementTetP1, ElementTetP2,
                   ElementTriArgyris, ElementTriMorley, ElementTriP1, ElementTriP2, ElementVector,
                   MeshHex, MeshQuad, MeshTet, MeshTri)

import nitsche as ni
from nitsche.bfs import ElementQuadBFSLocal

MESHES = {"tet": lambda: MeshTet.init_tensor(*[np.linspace(0, 1, 5)] * 3),
          "hex": lambda: MeshHex.init_tensor(*[np.linspace(0, 1, 4)] * 3),
          "tri": lambda: MeshTri.init_tensor(*[np.linspace(0, 1, 7)] * 2),
          "quad": lambda: MeshQuad.init_tensor(*[np.linspace(0, 1, 6)] * 2)}
CASES = [("tet", lambda: ElementVector(ElementTetP1())), ("tet", ElementTetP1), ("tet", ElementTetP2),
         ("hex", lambda: ElementVector(ElementHex1())), ("tri", ElementTriP1), ("tri", ElementTriP2)]


def bottom(x):
    return x[-1] < 1e-12


@pytest.mark.parametrize("mesh, element", CASES)
def test_fixed_dofs_as_scikit_fem(mesh, element):
    """Field(fixed=...) holds the dofs skfem's get_dofs finds on a mesh of its own facets:
    a predicate, 'boundary', a named boundary and (vector fields) components."""
    plain = MESHES[mesh]()
    b = Basis(plain, element())
    named = lambda m: m.with_boundaries({"bottom": bottom})  # noqa: E731
    f = ni.Field("u", MESHES[mesh](), element(), fixed=bottom)
    assert np.array_equal(f.fixed_dofs, np.unique(b.get_dofs(plain.facets_satisfying(bottom, True)).all()))
    f = ni.Field("u", MESHES[mesh](), element(), fixed="boundary")
    assert np.array_equal(f.fixed_dofs, np.unique(b.get_dofs(plain.boundary_facets()).all()))
    m = named(plain)
    f = ni.Field("u", named(MESHES[mesh]()), element(), fixed="bottom")
    expect = np.asarray(Basis(m, element()).get_dofs(m.boundaries["bottom"]).all(), np.int64)
    assert np.array_equal(f.held["bottom"], expect) and f.held["bottom"].size > 0
    if isinstance(f.element, ElementVector):
        f = ni.Field("u", named(MESHES[mesh]()), element(), fixed={"bottom": "z", bottom: "x"})
        d = Basis(m, element()).get_dofs(m.boundaries["bottom"])
        assert np.array_equal(f.held["bottom"], np.asarray(d.all("u^3"), np.int64))
        x = np.asarray(b.get_dofs(plain.facets_satisfying(bottom, True)).all("u^1"))
        assert np.array_equal(f.fixed_dofs, np.unique(np.concatenate([d.all("u^3"), x])))


def test_run_numbers_distinct_and_group_pattern():
    """run_numbers is cumsum - 1 in the dtype asked; distinct gives np.unique's keys and
    inverse; group_pattern the pairs of groups sharing an element (and the kept pairs)."""
    from nitsche.pattern import distinct, group_pattern, run_numbers
    starts = np.random.default_rng(1).random(10000) < 0.3
    starts[0] = True
    for dtype in (np.int32, np.int64):
        r = run_numbers(starts, dtype)
        assert r.dtype == dtype and np.array_equal(r, np.cumsum(starts) - 1)
    n = 50
    keys = np.random.default_rng(2).integers(0, n * n, 4000, dtype=np.int64)
    d, inverse = distinct(keys, np.int32)
    assert np.array_equal(d, np.unique(keys)) and np.array_equal(d[inverse], keys)
    g = np.random.default_rng(3).integers(0, n, (30, 3))
    keep = (np.array([0, 7]), np.array([49, 7]))
    indptr, indices = group_pattern([g, g[:5, :2]], n, keep)
    rows = np.repeat(np.arange(n), np.diff(indptr))
    pairs = np.concatenate([(g[:, :, None] * n + g[:, None, :]).ravel(), keep[0] * n + keep[1]])
    assert indices.dtype == np.int32 and np.array_equal(rows * n + indices, np.unique(pairs))


@pytest.mark.parametrize("mesh", sorted(MESHES))
def test_build_facets_as_scikit_fem(mesh):
    """build_facets sets the facets and t2f scikit-fem builds (values and dtypes; the
    predicate's facets in Field take them)."""
    from nitsche.measures import build_facets
    plain, ours = MESHES[mesh](), MESHES[mesh]()
    build_facets(ours)
    assert hasattr(ours, "_facets") or mesh == "hex"  # hexahedra: scikit-fem's own facets
    for a, b in ((plain.facets, ours.facets), (plain.t2f, ours.t2f)):
        assert a.dtype == b.dtype and np.array_equal(a, b)


def previous_free_block(problem):
    """The free-free block's structure as Problem._free_block computed it before s22."""
    a = problem.assembler
    row = np.repeat(np.arange(problem.ndofs), np.diff(a.indptr))
    isfree = np.zeros(problem.ndofs, bool)
    isfree[problem.free] = True
    keep = isfree[row] & isfree[a.indices]
    number = -np.ones(problem.ndofs, np.int64)
    number[problem.free] = np.arange(problem.free.size)
    return (np.flatnonzero(keep), number[a.indices[keep]].astype(np.int32),
            np.concatenate([[0], np.cumsum(np.bincount(number[row[keep]], minlength=problem.free.size))]))


@pytest.mark.parametrize("name, sets", [("obstacle", {}), ("membrane-solid", {"cells": "tet"}),
                                        ("two-membrane", {})])
def test_free_block_as_before(name, sets):
    """Problem._free_block's selection (now a mask), column numbers and row starts equal the
    previous formula's on the entries significant in the matrices so far (here the first;
    linalg.significant), in the pattern's index type (int32 here: the int64 selection and
    row starts of the previous formula were cut to int32 in session 23)."""
    from nitsche.cases import get
    from nitsche.linalg import significant
    case = get(name)
    problem = case.problem(1, case.degrees[0], case.parameters(sets))
    assert problem.fixed.size > 0
    _, _, data = problem.assembler.evaluate(problem.initial(None))
    held = significant(problem.assembler.matrix(data.copy()))
    problem._free_matrix(data)
    selection, indices, indptr = previous_free_block(problem)
    kept = held[selection]
    assert np.array_equal(np.flatnonzero(problem._kept), selection[kept])  # (a mask of the kept entries)
    for e, g in zip((indices[kept], np.concatenate([[0], np.cumsum(kept)])[indptr]),
                    (problem._ff_indices, problem._ff_indptr)):
        assert g.dtype == problem.assembler.indptr.dtype == np.int32 and np.array_equal(e, g)


@pytest.mark.parametrize("mesh, element", CASES + [
    ("tri", lambda: ElementVector(ElementTriP2())), ("tri", ElementTriMorley), ("tri", ElementTriArgyris),
    ("quad", ElementQuad2), ("quad", lambda: ElementVector(ElementQuad1())), ("quad", ElementQuadBFSLocal)])
def test_dof_locations_as_scikit_fem(mesh, element):
    """DofBasis.doflocs equals scikit-fem's Basis.doflocs bit for bit (F once per distinct
    reference point instead of once per dof)."""
    from nitsche.fields import DofBasis
    m = MESHES[mesh]()
    ours, theirs = DofBasis(m, element()).doflocs, Basis(m, element()).doflocs
    assert ours.shape == theirs.shape and np.array_equal(ours.view(np.int64), theirs.view(np.int64))
