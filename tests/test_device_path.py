"""The per-element data on the device (nitsche.device, assembly.Chunked): held once, in the
pieces the kernel calls take, so that a call passes them without gathering, padding or
copying; the results equal the earlier path (NumPy slices of the per-element data, padded
by repeating the last element, passed to the same kernels): the element outputs bitwise,
J, the gradient and the Hessian to round-off against sums on the host."""
import jax
import numpy as np
import pytest
import scipy.sparse as sp

from nitsche.cases import get
from nitsche.assembly import CHUNK_POINTS, Chunked, elements_per_call
from nitsche.device import aligned, host, on_device

CASES = [("obstacle", 1, 2, {}), ("two-membrane", 1, 1, {}), ("elastic-contact", 1, 0, {}),
         ("membrane-solid", 1, 0, {}), ("membrane-solid", 1, 0, {"cells": "tet"}), ("signorini", 2, 1, {})]


def host_outputs(t, kind, x, elements=None):
    """A term's kernel outputs as the earlier path computed them: per call, NumPy slices of
    the per-element data (the last call padded by repeating its last element) and x[dofs]."""
    e = np.arange(t.nel) if elements is None else np.asarray(elements)
    per_element = [x[d] for d in t.field_dofs] + [t.weights, t.x, t.n, t.h, t.alpha0]
    theta = t.parameters.values[t.parameter_index]
    outs = []
    for s, chunk in t.blocks(len(e)):
        rows = e[s:s + chunk]
        rows = np.concatenate([rows, np.repeat(rows[-1:], chunk - len(rows))])
        tables = [np.asarray(a) if a.shape[0] == 1 else np.asarray(a)[rows] for a in t.tables]
        got = t.kernel(kind, chunk)(*tables, *[np.ascontiguousarray(a[rows]) for a in per_element],
                                    np.broadcast_to(theta, (chunk, theta.size)))
        outs.append([np.asarray(o)[:len(e) - s] for o in got])
    return [np.concatenate(o) for o in zip(*outs)]


def host_assembly(a, x):
    """J, gradient and Hessian (CSR) on the host from host_outputs: sums, bincount, COO."""
    E, g, blocks = 0.0, np.zeros(a.ndofs), []
    for t in a.terms:
        e, ge, H = host_outputs(t, "full", x)
        E += 0.0 if t.residual else float(e.sum())
        g += np.bincount(t.global_dofs.ravel(), weights=ge.ravel(), minlength=a.ndofs)
        blocks.append((H, t.global_dofs))
    k = [D.shape[1] for _, D in blocks]
    rows = np.concatenate([np.repeat(D, n, axis=1).ravel() for (_, D), n in zip(blocks, k)])
    cols = np.concatenate([np.tile(D, (1, n)).ravel() for (_, D), n in zip(blocks, k)])
    K = sp.coo_matrix((np.concatenate([H.ravel() for H, _ in blocks]), (rows, cols)), shape=(a.ndofs,) * 2).tocsr()
    return E, g, K


def perturbed(problem, seed=0):
    return problem.initial(None) + 1e-3 * np.random.default_rng(seed).standard_normal(problem.ndofs)


def assert_same(a, x):
    """evaluate (device path, quadratic terms as kept matrices) against host_assembly."""
    E, g, data = a.evaluate(x)
    E_ref, g_ref, K = host_assembly(a, x)
    assert E == pytest.approx(E_ref, rel=1e-13, abs=1e-15)
    assert np.abs(g - g_ref).max() <= 1e-13 * max(np.abs(g_ref).max(), 1e-300)
    assert abs(a.matrix(data) - K).max() <= 1e-13 * abs(K).max()
    E2, g2 = a.gradient(x)  # the gradient kernel: the same sums
    assert E2 == pytest.approx(E, rel=1e-14, abs=1e-15) and np.abs(g2 - g).max() <= 1e-14 * np.abs(g).max()


@pytest.mark.parametrize("name, degree, level, sets", CASES)
def test_the_device_path_equals_the_host_path(name, degree, level, sets):
    case = get(name)
    problem = case.problem(level, degree, case.parameters(sets))
    a = problem.assembler
    x = perturbed(problem)
    for t in a.terms:  # element outputs: the same kernels on the same numbers, bitwise
        for got, ref in zip(t.run("full", x), host_outputs(t, "full", x)):
            np.testing.assert_array_equal(got, ref)
    assert_same(a, x)


def test_element_subsets_as_a_rank_calls_them():
    """Term.run on a subset of elements (unsorted, repeated, several chunks, and none)
    equals the host path on the same subset and the full run's rows."""
    case = get("obstacle")
    problem = case.problem(3, 1, case.parameters({}))
    x = perturbed(problem)
    for t in problem.assembler.terms:
        full = t.run("full", x)
        subset = np.r_[np.arange(0, t.nel, 3)[::-1], 0, 0]
        for got, ref, whole in zip(t.run("full", x, subset), host_outputs(t, "full", x, subset), full):
            np.testing.assert_array_equal(got, ref)
            np.testing.assert_array_equal(got, whole[subset])
        assert [o.shape[0] for o in t.run("gradient", x, np.zeros(0, int))] == [0, 0]


def test_a_re_paired_interface_assembles_its_new_tabulations():
    """ironing: after the block moves and the interface is paired anew (a grown pattern),
    the constraint term and its value term (which shares the tabulations) use the new
    dofs and tabulations."""
    case = get("ironing")
    problem = case.problem(0, 1, case.parameters({"nx": "12", "nb": "2", "contact": "one-pass"}))
    u1 = problem.by_name["u1"]
    along = np.zeros(problem.ndofs)
    along[problem.offsets["u1"] + u1.dof_basis.nodal_dofs[0]] = 1.0
    x = perturbed(problem) + 6.0 * along
    i = problem.sliding[0]
    term, values = problem.constraint_terms[i], problem.value_terms[i]
    before = term.global_dofs.copy()
    assert problem.update_pairing(x)
    assert not np.array_equal(term.global_dofs, before)
    assert values.T is term.T and values.global_dofs is term.global_dofs
    assert_same(problem.assembler, x)
    for got, ref in zip(values.run("values", x), host_outputs(values, "values", x)):
        np.testing.assert_array_equal(got, ref)


def test_a_call_passes_the_stored_pieces():
    """Over all elements, each kernel call gets the device arrays stored at set-up (the
    same objects: nothing gathered, padded or copied per call) for the tabulations and the
    per-point data; only the element dofs u and the parameters come from the host."""
    case = get("elastic-contact")
    problem = case.problem(0, 1, case.parameters({}))
    for t in problem.assembler.terms:
        stored = [a for a in t.tables if isinstance(a, Chunked)] + \
            [a for a in (*t.data.values(), t._alpha0) if a is not None]
        for i, (s, chunk) in enumerate(t.blocks(t.nel)):
            for a in stored:
                assert isinstance(a.parts[i], jax.Array) and a.parts[i].shape[0] == chunk
            W, _, _, h, alpha0 = t.per_point(i, chunk)
            assert W is t.data["W"].parts[i] and h is t.data["h"].parts[i] and alpha0 is t._alpha0.parts[i]
        for a in t.tables:
            assert isinstance(a, (Chunked, jax.Array))


@pytest.mark.parametrize("nel, blocks", [(30, [(0, 16), (16, 8), (24, 8)]),
                                         (23, [(0, 10), (10, 4), (14, 4), (18, 4), (22, 4)])])
def test_chunked_data_keep_their_rows(nel, blocks):
    """Chunked: the pieces of the calls (a large chunk, small ones, the last padded by
    repeating the last row) give back every row and the rows of a subset across pieces;
    pieces that start on multiples of 8 rows alias one host copy on the CPU (read there
    without a copy), others are read back piece by piece."""
    a = np.random.default_rng(2).standard_normal((nel, 3, 2))
    c = Chunked(a, blocks)
    assert [p.shape[0] for p in c.parts] == [n for _, n in blocks]
    np.testing.assert_array_equal(np.asarray(c), a)
    start, n = blocks[-1]
    np.testing.assert_array_equal(host(c.parts[-1]), np.concatenate([a[start:], a[-1:].repeat(start + n - nel, 0)]))
    rows = np.array([len(a) - 1, 0, 9, 10, 17, 18, 3, len(a) - 1])
    np.testing.assert_array_equal(c.rows(rows), a[rows])
    empty = Chunked(np.zeros((0, 2)), [(0, 4)])
    assert np.asarray(empty).shape == (0, 2) and host(empty.parts[0]).shape == (4, 2)
    assert empty.rows(np.zeros(4, int)).shape == (4, 2)  # the padding of a term without elements
    if jax.devices()[0].platform == "cpu":
        assert (c.host is not None) == all(s % 8 == 0 for s, _ in blocks)


def test_calls_take_multiples_of_8_elements():
    assert [elements_per_call(p, 6) for p in CHUNK_POINTS] == [168, 5456]
    assert elements_per_call(1024, 200) == 5 and elements_per_call(1024, 2000) == 1


def test_per_element_data_are_held_once():
    """A term keeps its per-element floating-point data only on the device (no NumPy copy
    of its own; on the CPU its weights, x, h read on the host are read-only views of the
    device buffers), and on_device's aligned copy is aliased by device_put on the CPU."""
    case = get("obstacle")
    problem = case.problem(2, 1, case.parameters({}))
    t = problem.constraint_terms[0]
    assert not any(isinstance(v, np.ndarray) and v.dtype == float and v.size >= t.nel
                   for v in list(vars(t).values()) + list(t.data.values()))
    assert t.W.shape == (t.nel, t.nq) and t.x.shape == (t.nel, t.nq, 2) and t.h.shape == t.alpha0.shape == (t.nel,)
    if jax.devices()[0].platform != "cpu":
        return
    held = t.data["W"].host  # (on affine cells d = |det A_e|, W[e, q] = d[e] w_q formed where read)
    for name, view in (("W", held), ("x", t.x), ("h", t.h)):  # the device buffers themselves
        assert view.ctypes.data == t.data[name].parts[0].unsafe_buffer_pointer() and not view.flags.writeable
    for p in t.data["W"].parts + t._alpha0.parts:
        assert p.unsafe_buffer_pointer() % 64 == 0
    a = np.arange(1000.0).reshape(10, 100)[:, ::2]  # not contiguous
    b = aligned(a)
    assert b.ctypes.data % 64 == 0 and np.array_equal(b, a)
    assert jax.device_put(b).unsafe_buffer_pointer() == b.ctypes.data  # aliased, not copied
    assert np.array_equal(host(on_device(a)), a)
