"""Quantities of a solution declared by the user: any scalar density of the fields' jets
(and x, n, h), e.g. a stress component, the von Mises stress, a principal stress,
evaluated at the quadrature points of the cells of the mesh of its first field (or of
another measure, e.g. a constraint's facets).

    quantity(problem, x, lambda u: von_mises(u)) -> q[e, q_point]

For reports: the range and the mean (int q / int 1) over the cells; for the VTU: the
cell averages of q averaged again onto the vertices.
"""
import numpy as np

from .assembly import Term
from .functional import argument_names, call
from .measures import cells


def quantity(problem, x, density, label="quantity", on=None):
    """The density's values at the quadrature points of the measure `on` (default: the
    cells of its first field's mesh; e.g. a constraint's facets, c.on, whose points and
    weights are those of Problem.constraint_values), shape (elements, points), the
    weights W of those points and the mesh."""
    names = argument_names(density, label)
    fields = [problem.by_name[k] for k in names if k in problem.by_name]
    if not fields:
        raise ValueError(f"{label} must take a field argument (one of {sorted(problem.by_name)})")
    term = Term(lambda args: call(density, names, args), names, on or cells(fields[0]),
                problem.fields, problem.offsets, label, parameters=problem.parameters)
    (values,) = term.with_pointwise(lambda args: (call(density, names, args),)).run("values", x)
    return values, term.W[:term.nel], term.measure.mesh


def summary(values, W):
    """min, max and mean (sum W q / sum W) of quadrature-point values."""
    return dict(min=float(values.min()), max=float(values.max()),
                mean=float((W * values).sum() / W.sum()))


def vertex_average(mesh, per_element, vertices, total=None):
    """Average of element values onto the vertices they touch (vertices: (k, elements));
    total(a), where given, sums the per-vertex sums a over the ranks of a distributed run
    that hold the elements (nitsche.pvtu)."""
    acc, count = np.zeros(mesh.nvertices), np.zeros(mesh.nvertices)
    np.add.at(acc, vertices, np.broadcast_to(per_element, vertices.shape))
    np.add.at(count, vertices, 1.0)
    if total is not None:
        acc, count = total(acc), total(count)
    return np.where(count > 0, acc / np.maximum(count, 1), 0.0)


def evaluate(problem, x, declared):
    """{name: (summary, mesh, vertex values)} of the declared {name: density}."""
    out = {}
    for name, density in declared.items():
        q, W, mesh = quantity(problem, x, density, f"quantity '{name}'")
        per_cell = (W * q).sum(1) / np.maximum(W.sum(1), 1e-300)
        out[name] = (summary(q, W), mesh, vertex_average(mesh, per_cell, mesh.t))
    return out
