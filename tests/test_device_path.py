"""The device path of the assembly (nitsche.device, Term.calls, Assembler.evaluate): the
per-element data are held once, on the device; a Newton step moves only x there and the
gradient and the Hessian's CSR data back; the results equal the earlier host path (NumPy
slices of the per-element data, padded by repeating the last element, passed to the same
kernels; bincount and entry-by-entry sums on the host): the element outputs bitwise, the
sums to round-off."""
import jax
import numpy as np
import pytest
import scipy.sparse as sp

from nitsche.cases import get
from nitsche.device import aligned, host, on_device

CASES = [("obstacle", 1, 2, {}), ("two-membrane", 1, 1, {}), ("elastic-contact", 1, 0, {}),
         ("membrane-solid", 1, 0, {}), ("membrane-solid", 1, 0, {"cells": "tet"}), ("signorini", 2, 1, {})]


def host_outputs(t, kind, x, elements=None):
    """A term's kernel outputs as the earlier path computed them: per call, NumPy slices of
    the per-element data (the last call padded by repeating its last element) and x[dofs]."""
    e = np.arange(t.nel) if elements is None else np.asarray(elements)
    per_element = [x[d] for d in t.field_dofs] + [t.W, t.x, t.n, t.h, t.alpha0]
    theta = t.parameters.values[t.parameter_index]
    outs = []
    for s, chunk in t.blocks(len(e)):
        rows = e[s:s + chunk]
        rows = np.concatenate([rows, np.repeat(rows[-1:], chunk - len(rows))])
        tables = [host(a) if a.shape[0] == 1 else host(a)[rows] for a in t.tables]
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
    dofs and tabulations on the device."""
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
    assert values.device["dofs"] is term.device["dofs"] and values.T[1] is term.T[1]
    assert_same(problem.assembler, x)
    for got, ref in zip(values.run("values", x), host_outputs(values, "values", x)):
        np.testing.assert_array_equal(got, ref)


def test_a_step_moves_nothing_implicitly_to_the_device():
    """Under jax.transfer_guard('disallow') an assembly step runs: nothing crosses
    implicitly (x, the parameters and each call's two bounds are put there explicitly;
    the earlier path passed NumPy slices to the kernels, which the guard refuses)."""
    case = get("two-membrane")
    problem = case.problem(1, 1, case.parameters({}))
    a = problem.assembler
    x = perturbed(problem)
    E, g, data = a.evaluate(x)  # loads the kernels (their set-up may move constants)
    with jax.transfer_guard("disallow"):
        E2, g2, data2 = a.evaluate(x)
        assert a.energy(x) == pytest.approx(E, rel=1e-14)
        with pytest.raises(Exception, match="Disallowed host-to-device transfer"):
            t = next(t for t in a.terms if not t.is_quadratic)
            host_outputs(t, "full", x)
    assert E2 == E and np.array_equal(g2, g) and np.array_equal(data2, data)
    assert g2.flags.writeable and data2.flags.writeable


def test_per_element_data_are_held_once():
    """On the CPU the terms' NumPy views (W, x, h, alpha0, global_dofs) are the device
    buffers themselves (no second copy), and on_device aliases its aligned copy."""
    if jax.devices()[0].platform != "cpu":
        pytest.skip("the views are transfers on an accelerator")
    case = get("obstacle")
    problem = case.problem(2, 1, case.parameters({}))
    t = problem.constraint_terms[0]
    for name, view in (("W", t.W), ("x", t.x), ("h", t.h), ("dofs", t.global_dofs)):
        assert view.ctypes.data == t.device[name].unsafe_buffer_pointer(), name
    assert t.alpha0.ctypes.data == t._alpha0.unsafe_buffer_pointer()
    assert t.global_dofs.dtype == np.int32
    a = np.arange(1000.0).reshape(10, 100)[:, ::2]  # not contiguous
    b = aligned(a)
    assert b.ctypes.data % 64 == 0 and np.array_equal(b, a)
    assert jax.device_put(b).unsafe_buffer_pointer() == b.ctypes.data  # aliased, not copied
    assert np.array_equal(host(on_device(a)), a)
