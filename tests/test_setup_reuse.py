"""What the set-up of a problem reuses instead of computing anew gives what it would
compute: the density's layout (memoized per process and kept in kernel_store), the data a
constraint's multiplier term shares with the constraint's term, the facets' sorted columns."""
import numpy as np
import pytest
from skfem import ElementTetP1, ElementTriP1, ElementTriP2, MeshTet, MeshTri

import nitsche as ni
from nitsche import assembly, kernel_store
from nitsche.assembly import Term
from nitsche.measures import sorted_columns
from nitsche.ops import dot, grad, lap


@pytest.fixture
def traces(tmp_path, monkeypatch):
    """The layouts traced from here on (an empty store on disk, nothing memoized)."""
    monkeypatch.setattr(kernel_store, "folder", lambda: str(tmp_path))
    monkeypatch.setattr(assembly, "_COMPILED", {})
    traced = []
    trace = Term._trace_layout
    monkeypatch.setattr(Term, "_trace_layout", lambda self, fs, shapes: traced.append(self.label) or trace(self, fs, shapes))
    return traced


def constraint_term(mesh, element, multiplier, offset=0.5):
    u = ni.Field("u", mesh, element, fixed="boundary")
    c = ni.Inequality(lambda u, x: u - offset * x[0], multiplier, ni.Scaling(0.1, 2), ni.cells(u), name="c")
    return u, Term(c.pointwise(), c.names, c.on, [u], {"u": 0}, "c", keep_points=True)


def test_the_layout_is_traced_once_per_density_and_jet_shapes(traces):
    """A density of the same code and values on a finer mesh (a nested chain's next level) or
    with another element of the same jet shapes takes the layout traced first, which equals
    a trace of its own; another value of a closure, another density or other jet shapes
    (3D) trace anew; a second process finds the layout on disk (kernel_store)."""
    _, coarse = constraint_term(MeshTri().refined(1), ElementTriP1(), lambda u: -lap(u))
    assert traces == ["c"] and [orders for _, _, orders in coarse.layout] == [(0, 2)]
    u, fine = constraint_term(MeshTri().refined(3), ElementTriP1(), lambda u: -lap(u))
    _, p2 = constraint_term(MeshTri().refined(1), ElementTriP2(), lambda u: -lap(u))
    assert traces == ["c"] and fine.layout == coarse.layout == p2.layout
    assert fine._trace_layout([u], {"u": dict(zip(u.orders, fine.measure.shapes(u, u.orders)))}) == fine.layout
    del traces[:]
    constraint_term(MeshTri(), ElementTriP1(), lambda u: -lap(u), offset=0.25)
    _, first = constraint_term(MeshTri(), ElementTriP1(), lambda u: dot(grad(u), grad(u)))
    _, tet = constraint_term(MeshTet(), ElementTetP1(), lambda u: -lap(u))
    assert len(traces) == 3 and [o for _, _, o in first.layout] == [(0, 1)]
    assert tet.layout != coarse.layout and [o for _, _, o in tet.layout] == [(0, 2)]
    assembly._COMPILED.clear()  # as in a new process: the layouts come from the store
    _, again = constraint_term(MeshTri().refined(2), ElementTriP1(), lambda u: -lap(u))
    assert len(traces) == 3 and again.layout == coarse.layout


def test_an_invalid_density_is_an_error_every_time(traces):
    """An error of the density's trace is not memoized: the second term raises it too."""
    u = ni.Field("u", MeshTri(), ElementTriP1())
    for _ in range(2):
        with pytest.raises(ValueError, match="must return a scalar"):
            Term(lambda args: args["u"].grad, ("u",), ni.cells(u), [u], {"u": 0}, "the energy density")
    assert len(traces) == 2


def test_the_multiplier_term_shares_the_constraint_terms_data():
    """Problem._multiplier_term(c, like=t) (local_limits) shares W, h, x and the inverse
    Jacobians of the constraint's term (the same device arrays) and gives the Jacobian of
    the multiplier that a term with data of its own (_gram's) gives, bit for bit; a term
    on another measure cannot share them."""
    u = ni.Field("u", MeshTri().refined(2), ElementTriP2(), fixed="boundary")
    c = ni.Inequality(lambda u: u + 0.1, lambda u, x: dot(grad(u), x) - u, ni.Scaling("auto", 1), ni.cells(u),
                      name="c")
    problem = ni.Problem([u], lambda u: 0.5 * dot(grad(u), grad(u)) - u, [c])
    t = problem.constraint_terms[0]
    B = problem._multiplier_term(c, like=t)
    assert all(B.data[k] is t.data[k] for k in ("W", "h", "x")) and B.data["n"] is None
    assert B.J[0] is t.J[0] is not None
    own = problem._multiplier_term(c)
    assert own.data["W"] is not t.data["W"]
    x = np.random.default_rng(3).standard_normal(problem.ndofs)
    assert np.array_equal(B.run("jacobian", x)[0], own.run("jacobian", x)[0])
    assert np.array_equal(B.alpha0, np.ones(B.nel))
    with pytest.raises(ValueError, match="same measure"):
        Term(c.scaled_multiplier(), c.multiplier_names, ni.cells(u), problem.fields, problem.offsets, "other",
             vector=True, like=t)


@pytest.mark.parametrize("rows", [1, 2, 3, 4])
def test_sorted_columns_as_numpy(rows):
    a = np.random.default_rng(rows).integers(0, 5, (rows, 300))
    assert np.array_equal(sorted_columns(a), np.sort(a, axis=0))


def test_centroids_are_computed_for_a_function_alpha0_only(monkeypatch):
    """A function alpha0(x, h) gets the elements' centroids; a number or 'auto' does not
    need them, and the problem is set up without computing them."""
    import nitsche.problem as problem_module
    u = ni.Field("u", MeshTri().refined(2), ElementTriP1(), fixed="boundary")

    def problem(alpha0):
        c = ni.Inequality(lambda u: u + 0.1, lambda u: 1.0 + 0.0 * u, ni.Scaling(alpha0, 2), ni.cells(u), name="c")
        return ni.Problem([u], lambda u: 0.5 * dot(grad(u), grad(u)) - u, [c])
    p = problem(lambda x, h: 0.01 + 0.001 * x[0] + h)
    t = p.constraint_terms[0]
    assert np.array_equal(p.alpha0["c"], 0.01 + 0.001 * problem_module.centroids(t)[0] + t.h)
    monkeypatch.setattr(problem_module, "centroids", None)  # (calling it would fail)
    assert np.array_equal(problem(0.05).alpha0["c"], np.full(t.nel, 0.05))
    assert np.all(problem("auto").alpha0["c"] > 0)
