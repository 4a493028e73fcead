"""The finest solve's memory savings give what the earlier paths gave: element Hessians
scattered call by call (bitwise the sums of one scatter of all of them), the free block's
int32 positions (the same matrix), the factored matrix kept as its values (the same
decisions), the factor and Newton matrices not held through the constraint report."""
import gc
import weakref

import numpy as np
import pytest
import scipy.sparse as sp

from nitsche import linalg
from nitsche.cases import get
from nitsche.linalg import HAVE_CHOLMOD, Cholmod


def problem_of(name, level, degree=1, sets=None):
    case = get(name)
    return case.problem(level, degree, case.parameters(sets or {}))


@pytest.mark.parametrize("name, level, degree, sets", [("obstacle", 2, 1, {}), ("obstacle", 1, 2, {}),
                                                        ("membrane-solid", 0, 1, {"cells": "tet"})])
def test_pieces_scatter_as_all_elements_at_once(name, level, degree, sets):
    """Scatter.add_pieces of a term's element matrices given in uneven pieces equals add()
    of all of them, bit for bit: runs of one column (scalar P1/P2) and node blocks (the
    solid's vector field, by strides); half of the elements' matrices zero (+0 or -0)."""
    problem = problem_of(name, level, degree, sets)
    a = problem.assembler
    rng = np.random.default_rng(3)
    strided = []
    for t, scatter in zip(a.terms, a.scatter):
        k = t.global_dofs.shape[1]
        H = rng.standard_normal((t.nel, k, k))
        H[rng.random(t.nel) < 0.5] = 0.0  # elements off a contact set: not scattered by add_pieces
        H[np.flatnonzero(~H.any(axis=(1, 2)))[:3]] = -0.0
        base = rng.standard_normal(a.nnz)  # other terms' sums already there
        expect = base.copy()
        scatter.add(expect, H)
        cuts = np.unique(np.concatenate([[0, t.nel], rng.integers(0, t.nel, 5)]))
        got = base.copy()
        count = scatter.add_pieces(got, ((slice(s, e), H[s:e]) for s, e in zip(cuts[:-1], cuts[1:])))
        np.testing.assert_array_equal(got, expect)
        assert scatter.add_pieces(got, [(slice(0, 0), H[:0])]) == 0  # a rank without elements
        assert count == np.count_nonzero(H.reshape(t.nel, -1).any(axis=1))
        # the non-zero elements only, given by their indices in pieces (the two-pass assembly)
        rows = np.flatnonzero(H.reshape(t.nel, -1).any(axis=1))
        got = base.copy()
        cuts = np.unique(np.concatenate([[0, rows.size], rng.integers(0, rows.size, 4)]))
        assert scatter.add_pieces(got, ((rows[s:e], H[rows[s:e]]) for s, e in zip(cuts[:-1], cuts[1:]))) == count
        np.testing.assert_array_equal(got, expect)
        strided.append(scatter.strided)
    assert any(strided) == (name == "membrane-solid")


@pytest.mark.parametrize("name, level, degree", [("obstacle", 2, 1), ("obstacle", 1, 2), ("two-membrane", 1, 1)])
def test_evaluate_equals_the_all_elements_path(name, level, degree):
    """J, the gradient and the Hessian's data of Assembler.evaluate (the non-quadratic terms'
    kernel outputs scattered call by call) equal those of the earlier path (all elements'
    energies, gradients and Hessians, then one bincount and one scatter), bit for bit, at a
    point with active and inactive contact points; and without the Hessian."""
    problem = problem_of(name, level, degree)
    a = problem.assembler
    x = problem.initial(None) + 0.3 * np.random.default_rng(2).standard_normal(problem.ndofs)
    E, grad, data = a.evaluate(x)
    E_ref, grad_ref, data_ref = 0.0, np.zeros(problem.ndofs), np.zeros(a.nnz)
    nonlinear = 0
    for t, scatter in zip(a.terms, a.scatter):
        if t.is_quadratic:
            E0, g0, K, positions = a._quadratic(t, scatter)
            Kx = K @ x
            E_ref += E0 + g0 @ x + 0.5 * x @ Kx
            grad_ref = grad_ref + g0 + Kx
            if positions is None:
                data_ref += K.data
            else:
                data_ref[positions] += K.data
            continue
        nonlinear += 1
        e, ge, H = t.run("full", x)
        E_ref += float(e.sum())
        grad_ref += np.bincount(t.global_dofs.ravel(), weights=ge.ravel(), minlength=problem.ndofs)
        scatter.add(data_ref, H)
    assert nonlinear >= 1
    assert E == E_ref
    np.testing.assert_array_equal(grad, grad_ref)
    np.testing.assert_array_equal(data, data_ref)
    E2, grad2 = a.gradient(x)
    assert E2 == E
    np.testing.assert_array_equal(grad2, grad)
    # again with every term assembled in two passes (support, then the Hessians of the
    # elements it flags): the same bits; a contact term's share of non-zero Hessians recorded
    shares = {id(t): a._hessian_share[id(t)] for t in a.terms if not t.is_quadratic}
    assert len(shares) >= 1 and (name != "two-membrane" or any(0 < v < 1 for v in shares.values()))
    a._hessian_share.update({k: 0.0 for k in shares})
    E3, grad3, data3 = a.evaluate(x)
    assert E3 == E
    np.testing.assert_array_equal(grad3, grad)
    np.testing.assert_array_equal(data3, data)
    assert {k: a._hessian_share[k] for k in shares} == shares


@pytest.mark.parametrize("name, level, degree", [("obstacle", 2, 1), ("obstacle", 1, 2), ("two-membrane", 1, 1),
                                                 ("membrane-solid", 0, 1)])
def test_a_quadratic_terms_assembly_equals_np_add_at_call_by_call(name, level, degree):
    """A quadratic term's J(0), gradient at 0 (one bincount of all elements' gradients) and
    Hessian equal those summed call by call with np.add.at and one scatter of all elements'
    Hessians, bit for bit."""
    problem = problem_of(name, level, degree)
    a = problem.assembler
    quadratic = [(t, s) for t, s in zip(a.terms, a.scatter) if t.is_quadratic]
    assert quadratic
    for t, scatter in quadratic:
        E0, g0, K, positions = a._quadratic(t, scatter)
        E_ref, g_ref, data_ref = 0.0, np.zeros(problem.ndofs), np.zeros(a.nnz)
        for s, (e, ge, H) in t.calls("full", np.zeros(problem.ndofs)):
            E_ref += float(e.sum())
            np.add.at(g_ref, t.global_dofs[s:s + len(ge)], ge)
            scatter.add(data_ref, H, s)
        assert E0 == E_ref
        np.testing.assert_array_equal(g0, g_ref)
        data = np.zeros(a.nnz)
        if positions is None:
            data += K.data
        else:
            data[positions] += K.data
        np.testing.assert_array_equal(data, data_ref)


@pytest.mark.parametrize("name, level", [("obstacle", 2), ("two-membrane", 1),
                                         ("membrane-solid", 0)])
def test_the_free_block_in_int32_is_the_free_rows_and_columns_on_their_significant_entries(name, level):
    """The Newton matrix's free-free block, built from int32 positions and counts, is the
    full Hessian's rows and columns of the free dofs on their significant entries: the
    same values there, and off them exact zeros or the round-off of a cancellation
    (|a_ij| <= ROUNDOFF_ENTRY sqrt(|a_ii a_jj|)), which it leaves out."""
    from nitsche.linalg import ROUNDOFF_ENTRY, significant
    problem = problem_of(name, level)
    x = problem.initial(None) + 1e-2 * np.random.default_rng(5).standard_normal(problem.ndofs)
    _, _, data = problem.assembler.evaluate(x)
    full = problem.assembler.matrix(data.copy())[problem.free][:, problem.free]
    A = problem._free_matrix(data)  # (data consumed: compacted in place and shrunk to A's values)
    assert np.shares_memory(A.data, data) and data.size == A.nnz
    assert problem._kept.dtype == bool and problem._ff_indptr.dtype == np.int32
    assert A.indices.dtype == np.int32 and A.indptr.dtype == np.int32
    kept = significant(full)
    assert np.array_equal(A.indptr, np.concatenate([[0], np.cumsum(kept)])[full.indptr])
    assert np.array_equal(A.indices, full.indices[kept])
    np.testing.assert_array_equal(A.data, full.data[kept])
    d = np.sqrt(np.abs(full.diagonal()))
    rows = np.repeat(np.arange(full.shape[0]), np.diff(full.indptr))
    left = ~kept
    assert np.all(np.abs(full.data[left]) <= ROUNDOFF_ENTRY * d[rows[left]] * d[full.indices[left]])


def test_the_free_block_keeps_the_entries_significant_in_any_matrix_so_far():
    """Two membranes: off their contact set the coupling's entries are exact zeros, left out
    of the free block (half of them here); a matrix whose contact set is larger makes them
    grow (a new structure), and a later matrix with fewer is given on the grown structure,
    its left entries as explicit zeros (the kept entries only grow: one symbolic analysis)."""
    problem = problem_of("two-membrane", 2)
    a = problem.assembler
    free = problem.assembler.matrix(np.ones(a.nnz))[problem.free][:, problem.free]
    x0 = problem.initial(None)
    _, _, data = a.evaluate(x0)
    A0 = problem._free_matrix(data)
    assert A0.nnz < 0.8 * free.nnz
    structure = problem._ff_indices
    x1 = x0.copy()
    x1[:problem.offsets["u2"]] += 1.0  # u1 pushed through u2 (gap u2 + d - u1 < 0): contact everywhere
    _, _, data = a.evaluate(x1)
    full = a.matrix(data.copy())[problem.free][:, problem.free]
    A1 = problem._free_matrix(data)
    assert problem._ff_indices is not structure and A1.nnz > A0.nnz
    np.testing.assert_array_equal(A1.toarray(), full.toarray())
    structure = problem._ff_indices
    _, _, data = a.evaluate(x0)
    A2 = problem._free_matrix(data)
    assert problem._ff_indices is structure and A2.nnz == A1.nnz
    np.testing.assert_array_equal(A2.toarray(), A0.toarray())


@pytest.mark.skipif(not HAVE_CHOLMOD, reason="scikit-sparse is not installed")
def test_the_factored_matrix_keeps_a_copy_of_the_values_only():
    """Cholmod keeps the factored matrix's values (a copy) on the matrix's own index arrays:
    the same matrix is solved by the factor, a later change of the values is seen."""
    n = 200
    F = sp.diags([np.full(n - 1, -1.0), np.full(n, 2.01), np.full(n - 1, -1.0)], [-1, 0, 1]).tocsr()
    lin = Cholmod()
    b = np.ones(n)
    x = lin.solve(F, b)
    assert np.shares_memory(lin.factored.indices, F.indices) and np.shares_memory(lin.factored.indptr, F.indptr)
    assert not np.shares_memory(lin.factored.data, F.data)
    F.data[0] += 1.0  # the caller changes its matrix: the factored values stay
    assert lin.factored.data[0] == 2.01
    assert abs(lin.factored - linalg.symmetric_csc(F)).max() == 1.0
    F.data[0] -= 1.0
    assert np.allclose(F @ x, b) and lin.is_positive_definite(F) and lin.factorizations == 1


@pytest.mark.skipif(not HAVE_CHOLMOD, reason="scikit-sparse is not installed")
def test_the_factor_is_not_held_through_the_constraint_report(monkeypatch):
    """Newton drops its solver (the factor and the factored matrix) and its matrices before
    the constraint report, the last array-heavy step of a solve; the result is unchanged."""
    solvers = []
    init = Cholmod.__init__

    def recorded(self, *a, **k):
        init(self, *a, **k)
        solvers.append(weakref.ref(self))
    monkeypatch.setattr(Cholmod, "__init__", recorded)
    problem = problem_of("obstacle", 2)
    report = type(problem).constraint_report
    alive = []

    def checked(self, x):
        gc.collect()
        alive.append(sum(r() is not None for r in solvers))
        return report(self, x)
    monkeypatch.setattr(type(problem), "constraint_report", checked)
    result = problem.minimize()
    assert result.converged and solvers and alive == [0]
    assert result.solver == "cholmod" and result.solver_stats["factorizations"] >= 1


def test_no_earlier_hessian_is_held_through_an_assembly(monkeypatch):
    """Each Newton system is assembled with no earlier one's Hessian values alive (the last
    step's matrix is released before the line search assembles at the full step, and the
    search's result does not keep the system it returned): one values array per pattern
    entry at a time; the result is unchanged."""
    problem = problem_of("obstacle", 3)
    expected = problem.minimize()
    problem = problem_of("obstacle", 3)
    evaluate = type(problem.assembler).evaluate
    earlier, alive = [], []

    def recorded(self, x, terms=None, hessian=True):
        gc.collect()
        alive.append(sum(r() is not None for r in earlier))
        E, g, data = evaluate(self, x, terms, hessian)
        if data is not None:
            earlier.append(weakref.ref(data))
        return E, g, data
    monkeypatch.setattr(type(problem.assembler), "evaluate", recorded)
    result = problem.minimize()
    assert result.converged and result.iterations >= 3 and len(earlier) >= 3
    assert max(alive) == 0
    assert result.energy == expected.energy and np.array_equal(result.x, expected.x)


def test_the_meshes_mappings_are_dropped_after_set_up_and_made_again_equal():
    """A built problem holds no scikit-fem mapping of its fields' meshes (the terms hold
    what they read); the dof basis reads the mapping made again, equal to the first."""
    problem = problem_of("two-membrane", 1)
    for f in problem.fields:
        assert "_cached_mapping" not in f.mesh.__dict__
    f = problem.fields[0]
    again = f.dof_basis.mapping
    assert again is f.mesh._mapping() and "_cached_mapping" in f.mesh.__dict__
    fresh = type(again)(f.mesh)
    np.testing.assert_array_equal(again.A, fresh.A)
    np.testing.assert_array_equal(again.invA, fresh.invA)
    E = problem.minimize().energy
    assert E == problem_of("two-membrane", 1).minimize().energy


@pytest.mark.parametrize("name, level, degree, sets", [("obstacle", 2, 1, {}), ("obstacle", 1, 2, {}),
                                                        ("two-membrane", 1, 1, {}),
                                                        ("membrane-solid", 0, 1, {"cells": "tet"})])
def test_a_quadratic_term_releases_its_data_and_gets_them_back_equal(name, level, degree, sets):
    """Once assembled, a quadratic term on cells holds no per-element data (W, h, the
    inverse Jacobians); read again (a new assembly, its views) they are the same arrays,
    and the element Hessians and a new assembler's matrix are those of the term before."""
    problem = problem_of(name, level, degree, sets)
    a = problem.assembler
    terms = [t for t in a.terms if t.is_quadratic and t.measure.kind == "cells"]
    assert terms
    x = problem.initial(None) + 1e-2 * np.random.default_rng(7).standard_normal(problem.ndofs)
    before = [(np.array(t.W), np.array(t.h), [np.array(J) for J in t.J if J is not None],
               t.run("full", x)[2]) for t in terms]
    E, grad, data = a.evaluate(x)
    for t, (W, h, Js, H) in zip(terms, before):
        held = [c for c in [t.data["W"], t.data["h"]] + [J for J in t.J if J is not None]]
        assert held and all("parts" not in c.__dict__ and "padded" not in c.__dict__ for c in held)
        np.testing.assert_array_equal(t.run("full", x)[2], H)  # back from the measure
        np.testing.assert_array_equal(t.W, W)
        np.testing.assert_array_equal(t.h, h)
        for J, J0 in zip([J for J in t.J if J is not None], Js):
            np.testing.assert_array_equal(np.asarray(J), J0)
    again = type(a)(a.terms, problem.ndofs)  # assembles the quadratic terms anew
    E2, grad2, data2 = again.evaluate(x)
    assert E2 == E
    np.testing.assert_array_equal(grad2, grad)
    np.testing.assert_array_equal(data2, data)


@pytest.mark.skipif(not HAVE_CHOLMOD, reason="scikit-sparse is not installed")
@pytest.mark.parametrize("degree, convex", [(1, True), (2, False)])
def test_the_factored_copy_is_kept_only_for_the_positive_definite_test(degree, convex):
    """Newton keeps no copy of the factored matrix where J_h is certified convex (no test of
    the Hessian reads it: the P1 obstacle) and keeps it where the Hessian is tested (P2);
    the run reaches what a solver that keeps the copy reaches, in as many iterations."""
    class Keeping(Cholmod):
        keep_factored = property(lambda self: True, lambda self, value: None)
    problem = problem_of("obstacle", 2, degree)
    assert problem.convex == convex
    lin = Cholmod()
    result = problem.minimize(solver=lin)
    assert result.converged and result.minimum == ("J_h convex" if convex else "Hessian positive definite")
    assert lin.keep_factored == (not convex) and (lin.factored is None) == convex
    kept = problem_of("obstacle", 2, degree).minimize(solver=Keeping())
    assert kept.iterations == result.iterations and kept.minimum == result.minimum
    np.testing.assert_allclose(kept.x, result.x, rtol=0, atol=1e-12)


@pytest.mark.skipif(not HAVE_CHOLMOD, reason="scikit-sparse is not installed")
def test_a_solver_made_anew_for_a_new_structure_is_set_up_as_the_first(monkeypatch):
    """Where an interface paired anew grows the pattern (here every iteration, by a stand-in
    for update_pairing), Newton makes a new linear solver; each is set up as the first one:
    no pruning of the problem's already pruned matrices, a factored copy only where J_h is
    not certified convex, and the run reaches the plain run's minimizer."""
    from nitsche import newton as newton_module
    made = []

    def recording(*args, **kwargs):
        made.append(newton_module.make_solver.__wrapped__(*args, **kwargs))
        return made[-1]
    recording.__wrapped__ = newton_module.make_solver
    monkeypatch.setattr(newton_module, "make_solver", recording)
    plain = problem_of("two-membrane", 2).minimize(solver="cholmod")
    problem = problem_of("two-membrane", 2)
    problem.sliding = [0]
    problem.update_pairing = lambda x: True
    made.clear()
    result = problem.minimize(solver="cholmod")
    assert result.converged and len(made) > result.iterations  # (the first one and one per pass)
    assert all(isinstance(lin, Cholmod) and not lin.prune and lin.keep_factored == (not problem.convex)
               for lin in made)
    np.testing.assert_allclose(result.x, plain.x, rtol=0, atol=1e-10)


@pytest.mark.parametrize("n, k", [(7, 3), (50, 6), (400, 12), (5000, 3)])
def test_a_gradient_summed_call_by_call_is_one_bincount_bitwise(n, k):
    """GradientSum of element vectors given in uneven pieces (many buffers' sums for small
    n) equals one bincount of all of them bit for bit, with values whose sums depend on the
    order of the additions (mixed magnitudes), and holds no array of all of them."""
    from nitsche.assembly import GradientSum
    rng = np.random.default_rng(n)
    E = 1000
    D = rng.integers(0, n, (E, k)).astype(np.int32)
    g = rng.standard_normal((E, k)) * 10.0 ** rng.integers(-8, 8, (E, k))
    summed = GradientSum(D, n)
    assert summed.index.size <= min(D.size, 3 * n)  # (n = 5000: one bincount of all, no running sums)
    cuts = np.unique(np.concatenate([[0, E], rng.integers(0, E, 17)]))
    for a, b in zip(cuts[:-1], cuts[1:]):
        summed.add(a, g[a:b])
        summed.add(b, g[b:b])  # (a call without elements: a rank that holds none)
    total = summed.total()
    assert np.array_equal(total, np.bincount(D.ravel(), weights=g.ravel(), minlength=n))
    assert not np.array_equal(total, np.bincount(D[::-1].ravel(), weights=g[::-1].ravel(), minlength=n))


@pytest.mark.parametrize("block", [3, 64, 2 ** 20])
def test_the_free_values_are_compacted_in_place(block):
    """compacted(data, keep) is data[keep], written into data's own first entries (a view),
    for any block size (an entry only moves to an earlier position, read before written)."""
    from nitsche.problem import compacted
    rng = np.random.default_rng(3)
    data = rng.standard_normal(1000)
    keep = rng.random(1000) < 0.7
    expected = data[keep]
    out = compacted(data, keep, block)
    assert np.shares_memory(out, data)
    np.testing.assert_array_equal(out, expected)
    assert compacted(np.ones(5), np.zeros(5, bool)).size == 0


def test_an_array_is_shrunk_in_place_to_its_first_entries():
    """shrunk(data, k) is data[:k] in data's own memory (the same array, no copy: realloc
    shrinks in place), and a copy where data is a view or NumPy refuses (weak references)."""
    import weakref
    from nitsche.problem import shrunk
    data = np.arange(10.0)
    out = shrunk(data, 4)
    assert out is data and data.flags.owndata
    np.testing.assert_array_equal(out, [0.0, 1.0, 2.0, 3.0])
    assert shrunk(data, 0).size == 0
    base = np.arange(10.0)
    view = base[2:]
    out = shrunk(view, 3)
    assert not np.shares_memory(out, base) and base.size == 10
    np.testing.assert_array_equal(out, [2.0, 3.0, 4.0])
    watched = np.arange(10.0)
    ref = weakref.ref(watched)
    out = shrunk(watched, 2)
    assert out is not watched and ref() is watched and watched.size == 10
    np.testing.assert_array_equal(out, [0.0, 1.0])


@pytest.mark.skipif(not HAVE_CHOLMOD, reason="scikit-sparse is not installed")
def test_the_analyzed_pattern_does_not_hold_the_matrix_structure():
    """Cholmod's analyzed pattern refers to its matrix's index arrays weakly: a Newton
    matrix's structure that grew is freed once replaced.  It still knows its pattern in
    equal arrays (a digest), and a matrix of another pattern is a new analysis."""
    import gc
    import weakref
    import scipy.sparse as sp
    from nitsche.linalg import Cholmod, NonzeroPattern
    n = 30
    A = (sp.diags([-np.ones(n - 1), 4 * np.ones(n), -np.ones(n - 1)], [-1, 0, 1])).tocsc()
    b = np.ones(n)
    lin = Cholmod()
    lin.prune = False
    lin.solve(A, b)
    indices = weakref.ref(A.indices)
    same = sp.csc_matrix((2 * A.data, A.indices.copy(), A.indptr.copy()), shape=A.shape)
    A = None
    gc.collect()
    assert indices() is None  # (not held by lin.analyzed)
    assert lin.analyzed.holds(same) and lin.analyzed.kept is None
    lin.solve(same, b)
    assert lin.analyses == 1 and lin.factorizations == 2
    other = (same + sp.eye(n, k=2) + sp.eye(n, k=-2)).tocsc()
    assert not NonzeroPattern(same).same_pattern(other)
    x = lin.solve(other, b)
    assert lin.analyses == 2 and np.allclose(other @ x, b)


def test_a_constraint_gives_its_points_on_demand_where_its_measure_can():
    """A constraint on cells whose density does not read x keeps no quadrature points (48 MB
    for the two membranes at 522k unknowns): its `x` (the constraint values' points) are
    computed from the measure at each read, equal to the measure's points; a density that
    reads x still keeps them, and the kernels see the same (zero) points as before."""
    problem = problem_of("two-membrane", 1)
    t = problem.constraint_terms[0]
    assert t.points_on_demand and t.data["x"] is None
    m = t.measure
    for f in t.fields:
        m.attach(f)
    expected = np.moveaxis(m.points, 0, -1)
    m.release()
    np.testing.assert_array_equal(t.x, expected)
    x = problem.minimize().x
    values = problem.constraint_values(x)["contact"]
    np.testing.assert_array_equal(values["x"], expected)
    obstacle = problem_of("obstacle", 1)  # its gap reads x (the obstacle psi(x)): kept
    kept = obstacle.constraint_terms[0]
    assert not kept.points_on_demand and kept.data["x"] is not None


def test_terms_on_equal_maps_share_one_array_of_them():
    """Each term keeps one local-to-global map (global_dofs), its fields' dofs views of its
    columns; terms on equal maps that are never paired anew (the two membranes' energy and
    contact, and the contact's value term) share one array; the solution is unchanged."""
    problem = problem_of("two-membrane", 2)
    e, c, v = problem.energy_terms[0], problem.constraint_terms[0], problem.value_terms[0]
    assert e.global_dofs is c.global_dofs is v.global_dofs
    for t in (e, c, v):
        assert all(np.shares_memory(d, t.global_dofs) for d in t.field_dofs)
        np.testing.assert_array_equal(np.concatenate([d - o for d, o in zip(t.field_dofs, t.offsets)], axis=1),
                                      np.concatenate([f.dof_basis.dofs.element_dofs.T for f in t.fields], axis=1))
    own = problem_of("obstacle", 1)  # one field at offset 0: the map is the field's dofs themselves
    t = own.energy_terms[0]
    assert np.shares_memory(t.field_dofs[0], t.global_dofs)


def test_the_fields_of_one_mesh_share_its_inverse_jacobians():
    """A term's Lagrange fields on its measure's mesh read one array of the mesh's inverse
    Jacobians (the two membranes' energy: held once, 17 MB at 522k unknowns, until its
    matrix is assembled), equal to each field's own tabulation's; the term's energies and
    gradients are unchanged when it is given the fields' own arrays."""
    from nitsche.measures import Mapped
    problem = problem_of("two-membrane", 2)
    t = problem.energy_terms[0]
    assert len(t.fields) == 2 and t.J[0] is t.J[1] is not None
    x = np.random.default_rng(0).standard_normal(problem.ndofs)
    shared = t.run("gradient", x)
    m = t.measure
    for i, f in enumerate(t.fields):
        m.attach(f)
        T, _ = m.tabulation(f, [0, 1])
        assert isinstance(T, Mapped)
        np.testing.assert_array_equal(t.J[i].host, T.invJ)
        t.J[i] = t._stored(T.invJ)  # each field its own array, as before
    m.release()
    assert t.J[0] is not t.J[1]
    own = t.run("gradient", x)
    for a, b in zip(shared, own):
        np.testing.assert_array_equal(a, b)


@pytest.mark.parametrize("name, level, sets", [("two-membrane", 2, {}), ("obstacle", 2, {}),
                                               ("membrane-solid", 0, {"cells": "tet"})])
def test_a_released_problem_drops_its_newton_structures_and_builds_them_again_equal(name, level, sets):
    """Problem.release (after a solve, for the outputs) drops the pattern, the scatters,
    the quadratic terms' matrices and the free block's structure; the next energy,
    gradient and Newton system build them again and equal those before (bitwise; the
    Newton matrix on its significant entries), and Newton's method converges from there."""
    problem = problem_of(name, level, 1, sets)
    result = problem.minimize()
    x = result.x + 1e-3 * np.random.default_rng(3).standard_normal(problem.ndofs)
    E, g, A = problem.newton_system(x)
    A = A.copy()
    energy, gradient = problem.energy(x), problem.gradient(x)
    problem.release()
    a = problem.assembler
    assert not any(k in a.__dict__ for k in a.PATTERN) and not a._quadratics
    assert problem._kept is None and problem._ff_indices is None
    assert problem.energy(x) == energy
    np.testing.assert_array_equal(problem.gradient(x), gradient)
    E2, g2, A2 = problem.newton_system(x)
    assert E2 == E
    np.testing.assert_array_equal(g2, g)
    # the kept entries start again from this matrix's significant ones: the same values
    # there, and what the earlier matrices kept besides is zero or round-off here
    assert (A2 != A.multiply(A2 != 0)).nnz == 0 and A2.nnz <= A.nnz
    assert abs(A - A2).max() <= linalg.ROUNDOFF_ENTRY * abs(A).max()
    problem.release()
    again = problem.minimize(result.x)
    assert again.converged and again.energy == problem.energy(result.x)


@pytest.mark.parametrize("name, level, degree", [("obstacle", 2, 1), ("obstacle", 1, 2), ("two-membrane", 1, 1)])
def test_a_term_on_affine_cells_holds_one_weight_per_element(name, level, degree, monkeypatch):
    """On affine cells W[e, q] = |det A_e| w_q: a term holds |det A_e| (e,) and its kernels
    form the product (47 MB less for the two membranes' contact at 1M unknowns); W read
    from it is the measure's, and J_h, its gradient and Hessian are bitwise those of terms
    that hold W (e, q)."""
    from nitsche import measures
    problem = problem_of(name, level, degree)
    x = problem.initial(None) + 1e-2 * np.random.default_rng(7).standard_normal(problem.ndofs)
    for t in problem.energy_terms + problem.constraint_terms:
        assert t.weight_rule is not None and np.asarray(t.data["W"]).shape[1:] == ()
        np.testing.assert_array_equal(t.W[:t.nel], t.measure.weights)
    E, g, data = problem.assembler.evaluate(x)
    monkeypatch.setattr(measures.Cells, "separable_weights", property(lambda self: None))
    plain = problem_of(name, level, degree)
    assert all(t.weight_rule is None for t in plain.energy_terms + plain.constraint_terms)
    E0, g0, data0 = plain.assembler.evaluate(x)
    assert E == E0
    np.testing.assert_array_equal(g, g0)
    np.testing.assert_array_equal(data, data0)
    report, report0 = problem.constraint_report(x), plain.constraint_report(x)
    for name_ in report:
        assert report[name_]["contact_measure"] == report0[name_]["contact_measure"]
