"""The sparsity pattern built on dof groups and the scatter by blocks (nitsche.pattern)
against the entry-by-entry construction: the same CSR structure and the same assembled
matrices to round-off, for scalar and vector fields, P1/P2/Q1, triangles, tetrahedra and
hexahedra, membranes coupled to solids, interfaces between bodies (re-paired)."""
import numpy as np
import pytest
import scipy.sparse as sp

from nitsche.cases import get
from nitsche.pattern import Pattern, dof_groups, runs, sort_with_order


def entrywise(maps, n, blocks=None):
    """The CSR matrix of the element matrices `blocks` (E, k, k) on the maps (ones: the
    pattern), entry by entry (row, column) as COO, duplicates summed."""
    blocks = blocks or [np.ones(D.shape + D.shape[1:]) for D in maps]
    rows = np.concatenate([np.repeat(D, D.shape[1], axis=1).ravel() for D in maps])
    cols = np.concatenate([np.tile(D, (1, D.shape[1])).ravel() for D in maps])
    A = sp.coo_matrix((np.concatenate([H.ravel() for H in blocks]), (rows, cols)), shape=(n, n)).tocsr()
    A.sum_duplicates()
    return A


def element_hessians(term, x):
    return term.run("full", x)[2]


CASES = [("obstacle", 1, 2, {}), ("obstacle", 2, 1, {}), ("signorini", 1, 1, {}),
         ("two-membrane", 1, 1, {}), ("two-membrane", 2, 0, {}), ("elastic-contact", 1, 0, {}),
         ("elastic-contact", 2, 0, {}), ("membrane-solid", 1, 0, {}),
         ("membrane-solid", 1, 0, {"cells": "tet"}), ("plate-plate", 2, 0, {}), ("ironing", 1, 0, {})]


@pytest.mark.parametrize("name, degree, level, sets", CASES)
def test_pattern_and_assembled_hessian_equal_the_entrywise_ones(name, degree, level, sets):
    case = get(name)
    problem = case.problem(level, degree, case.parameters(sets))
    a = problem.assembler
    n = problem.ndofs
    reference = entrywise([t.global_dofs for t in a.terms], n)
    assert a.indptr.tolist() == reference.indptr.tolist()
    assert a.indices.tolist() == reference.indices.tolist()
    assert a.indices.dtype == np.int32 and a.indptr.dtype == np.int32
    rng = np.random.default_rng(0)
    x = problem.initial(None) + 1e-3 * rng.standard_normal(n)
    H = a.hessian(x)
    K = entrywise([t.global_dofs for t in a.terms], n, [element_hessians(t, x) for t in a.terms])
    scale = abs(K).max()
    assert abs(H - K).max() <= 1e-13 * scale


def test_vector_fields_group_their_components_and_scatter_by_node_blocks():
    """membrane-solid on tetrahedra: the solid's dofs form groups of 3 (one per node), its
    map (E, 12) falls into 4 runs, so its scatter keeps 4 x 4 positions and 4 strides per element."""
    case = get("membrane-solid")
    problem = case.problem(0, 1, case.parameters({"cells": "tet"}))
    a = problem.assembler
    solid = next(t for t in a.terms if t.global_dofs.shape[1] == 12)
    group = a.pattern.group
    u = problem.by_name["u"]
    sizes = np.bincount(group)
    assert (sizes[group[solid.global_dofs]] == 3).all()
    assert runs(solid.global_dofs, group).tolist() == [0, 3, 6, 9]
    scatter = a.scatter[a.terms.index(solid)]
    assert scatter.R.shape == (solid.nel, 4, 4) and scatter.strided and scatter.R.dtype == np.uint8
    assert u.ndofs == 3 * u.mesh.p.shape[1]


def test_groups_break_where_an_element_splits_a_run():
    """Dofs 0-1-2 together everywhere form a group; 3, 4 are split by the second map."""
    D1 = np.array([[0, 1, 2, 3, 4], [3, 4, 0, 1, 2]])
    D2 = np.array([[4, 3]])
    group = dof_groups([D1, D2], 6)
    assert group.tolist() == [0, 0, 0, 1, 2, 3]  # dof 5: held by no element
    p = Pattern([D1, D2], 6)
    ref = entrywise([D1, D2], 6)
    assert p.indptr.tolist() == ref.indptr.tolist() and p.indices.tolist() == ref.indices.tolist()
    H = [np.arange(25.0).reshape(1, 5, 5).repeat(2, 0), np.array([[[1.0, 2.0], [3.0, 4.0]]])]
    data = np.zeros(p.nnz)
    for s, D, h in zip(p.scatters, (D1, D2), H):
        s.add(data, h)
    assert np.array_equal(sp.csr_matrix((data, p.indices, p.indptr), shape=(6, 6)).toarray(),
                          entrywise([D1, D2], 6, H).toarray())


@pytest.mark.parametrize("width, kind", [(4, np.uint8), (300, np.uint16)])
def test_a_scatter_keeps_offsets_in_the_row_in_the_smallest_type_that_holds_them(width, kind):
    """Scalar and vector (runs of 3) maps with one long element (a row of `width` groups):
    the offsets R of the pairs of runs fit the longest row's type, and the scatter from them
    gives the entry-by-entry matrix exactly (integer-valued entries)."""
    rng = np.random.default_rng(3)
    n = 3 * (width + 20)
    scalar = np.vstack([3 * width + rng.permutation(60)[:6] for _ in range(40)])
    nodes = np.vstack([rng.permutation(n // 3)[:4] for _ in range(40)])
    vector = (3 * nodes[:, :, None] + np.arange(3)).reshape(40, 12)
    long_one = (3 * np.arange(width)[None, :, None] + np.arange(3)).reshape(1, -1)
    maps = [scalar, vector, long_one]
    p = Pattern(maps, n)
    H = [rng.integers(-9, 9, D.shape + D.shape[1:]).astype(float) for D in maps]
    data = np.zeros(p.nnz)
    for s, h in zip(p.scatters, H):
        assert s.R.dtype == kind and s.R.shape == (len(s.D), s.first.size, s.first.size)
        s.add(data, h)
    assert p.scatters[2].strided  # (runs of 3 dofs and more)
    assert np.array_equal(sp.csr_matrix((data, p.indices, p.indptr), shape=(n, n)).toarray(),
                          entrywise(maps, n, H).toarray())


def test_a_pattern_keeps_the_entries_of_an_earlier_one():
    D = np.array([[0, 1, 2]])
    old = entrywise([np.array([[3, 4]])], 5)
    p = Pattern([D], 5, keep=(old.indptr, old.indices))
    ref = entrywise([D, np.array([[3, 4]])], 5)
    assert p.indptr.tolist() == ref.indptr.tolist() and p.indices.tolist() == ref.indices.tolist()
    assert p.scatter(np.array([[4, 3]])) is not None and p.scatter(np.array([[2, 3]])) is None


def test_a_re_paired_interface_scatters_within_or_into_a_grown_pattern():
    """ironing: after the block moves along the foundation and the interface is paired
    anew, the pattern holds every entry of the new maps (the same pattern after a small
    move, a grown one after a large move) and the Hessian equals the entry-by-entry one."""
    case = get("ironing")
    problem = case.problem(0, 1, case.parameters({"nx": "12", "nb": "2", "contact": "one-pass"}))
    a = problem.assembler
    u1 = problem.by_name["u1"]
    along = np.zeros(problem.ndofs)
    along[problem.offsets["u1"] + u1.dof_basis.nodal_dofs[0]] = 1.0
    for shift, grows in ((1.0, False), (6.0, True)):
        before = entrywise([t.global_dofs for t in a.terms], problem.ndofs)
        nnz = a.nnz
        x = problem.initial(None) + shift * along
        assert problem.update_pairing(x) is grows
        assert (a.nnz > nnz) is grows
        now = entrywise([t.global_dofs for t in a.terms], problem.ndofs)
        held = sp.csr_matrix((np.ones(a.nnz), a.indices, a.indptr), shape=now.shape)
        assert now.multiply(held).nnz == now.nnz  # every new entry is held
        assert before.multiply(held).nnz == before.nnz  # and every earlier one
        H = a.hessian(x)
        K = entrywise([t.global_dofs for t in a.terms], problem.ndofs,
                      [element_hessians(t, x) for t in a.terms])
        assert abs(H - K).max() <= 1e-13 * abs(K).max()


@pytest.mark.parametrize("high", [50, 2 ** 60])
def test_the_sort_with_order_equals_a_stable_argsort(high):
    """Keys packed with their index (small keys) or argsorted (keys too large to pack)."""
    keys = np.random.default_rng(1).integers(0, high, 1000).astype(np.int64)
    ordered, order = sort_with_order(keys)
    assert np.array_equal(order, np.argsort(keys, kind="stable"))
    assert np.array_equal(ordered, np.sort(keys))


@pytest.mark.parametrize("name, sets", [("membrane-solid", {"cells": "tet"}), ("membrane-solid", {}),
                                        ("two-membrane", {})])
def test_quadratic_terms_on_their_own_entries_add_as_full_length_arrays(name, sets):
    """A quadratic term on fewer than half of the pattern's entries (the membrane beside the
    solid) keeps its matrix on its own entries; J, its gradient and the Newton matrix's data
    equal those of the earlier path, one pattern-long data array per quadratic term."""
    case = get(name)
    problem = case.problem(0, 1, case.parameters(sets))
    a = problem.assembler
    x = problem.initial(None) + 1e-3 * np.random.default_rng(1).standard_normal(problem.ndofs)
    E, grad, data = a.evaluate(x)
    E_ref, grad_ref, data_ref = 0.0, np.zeros(problem.ndofs), np.zeros(a.nnz)
    compact = []
    for t, scatter in zip(a.terms, a.scatter):
        if t.is_quadratic:  # the earlier path: the term's data on the whole pattern
            d, g0, E0 = np.zeros(a.nnz), np.zeros(problem.ndofs), 0.0
            for s, (e, ge, H) in t.calls("full", np.zeros(problem.ndofs)):
                E0 += float(e.sum())
                np.add.at(g0, t.global_dofs[s:s + len(ge)], ge)
                scatter.add(d, H, s)
            K = sp.csr_matrix((d, a.indices, a.indptr), shape=(problem.ndofs,) * 2)
            E_ref += E0 + g0 @ x + 0.5 * x @ (K @ x)
            grad_ref = grad_ref + g0 + K @ x
            data_ref += d
            positions = a._quadratic(t, scatter)[3]
            compact.append(positions is not None)
            assert (positions is not None) == (2 * np.count_nonzero(d) < a.nnz)
        else:
            out = t.run("full", x)
            E_ref += float(out[0].sum())
            grad_ref += np.bincount(t.global_dofs.ravel(), weights=out[1].ravel(), minlength=problem.ndofs)
            scatter.add(data_ref, out[2])
    if name == "membrane-solid":
        assert compact == [False, True]  # the solid on the pattern, the membrane on its entries
    np.testing.assert_array_equal(data, data_ref)
    np.testing.assert_array_equal(grad, grad_ref)
    assert E == E_ref


@pytest.mark.parametrize("name, sets", [("two-membrane", {}), ("membrane-solid", {"cells": "tet"})])
def test_pair_positions_by_small_blocks_of_elements_equal_those_of_one_block(name, sets, monkeypatch):
    """pair_positions locates the group pairs block by block of elements: blocks of one
    element (7 // 36 pairs, an earlier pattern kept) give the pattern and every scatter's
    positions of blocks larger than all the pairs."""
    import nitsche.pattern as pattern
    case = get(name)
    problem = case.problem(1, 1, case.parameters(sets))
    maps = [t.global_dofs for t in problem.assembler.terms]
    n = problem.ndofs
    keep = entrywise([np.array([[0, n - 1]])], n)
    whole = Pattern(maps, n, keep=(keep.indptr, keep.indices))
    monkeypatch.setattr(pattern, "KEYS_PER_BLOCK", 7)
    blocks = Pattern(maps, n, keep=(keep.indptr, keep.indices))
    assert blocks.indptr.tolist() == whole.indptr.tolist()
    assert blocks.indices.tolist() == whole.indices.tolist()
    assert whole.indices[whole.indptr[0]:whole.indptr[1]][-1] == n - 1  # the kept entry
    for a, b in zip(blocks.scatters, whole.scatters):
        assert np.array_equal(a.positions(), b.positions())


def test_symmetric_maps_give_each_entry_its_transpose_and_each_row_its_diagonal():
    """symmetric_maps of a symmetric pattern without some diagonal entries: the transposed
    position of (g, h) holds (h, g), transposing twice is the identity, and the diagonal
    position holds (g, g), -1 where the pattern lacks it."""
    from nitsche.pattern import symmetric_maps
    rng = np.random.default_rng(3)
    S = sp.random(40, 40, density=0.1, random_state=4, format="csr")
    S = (S + S.T).tocsr()
    S.setdiag(0)
    S.eliminate_zeros()
    S = (S + sp.diags((rng.random(40) < 0.7).astype(float))).tocsr()
    S.eliminate_zeros()
    S.sort_indices()
    rows = np.repeat(np.arange(40), np.diff(S.indptr))
    held = rows * 40 + S.indices
    diagonal, transposed = symmetric_maps(S.indptr, S.indices, held)
    assert np.array_equal(rows[transposed], S.indices) and np.array_equal(S.indices[transposed], rows)
    assert np.array_equal(transposed[transposed], np.arange(S.nnz))
    has = S.diagonal() != 0
    assert np.array_equal(diagonal >= 0, has) and 0 < has.sum() < 40
    assert np.array_equal(rows[diagonal[has]], np.flatnonzero(has))
    assert np.array_equal(S.indices[diagonal[has]], np.flatnonzero(has))
