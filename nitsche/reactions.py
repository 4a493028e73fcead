"""Reactions: the forces that hold the fixed dofs, per field, boundary and component.

At a solution the gradient of J_h vanishes on the free dofs; on a fixed dof it is the
force the support exerts on the body there, R = dJ_h/du_i (internal minus applied
force).  Summed over the value dofs of one component on a boundary it is the resultant
reaction of that boundary in that direction (derivative dofs, such as Morley's normal
slopes, carry moments and are left out).
"""
import numpy as np


def dof_names(field):
    """The name of every dof of a field: 'u', 'u^1', ... for values, 'u_x', 'u_n', ... for
    derivatives (from the element's local dof names)."""
    names, d = np.empty(field.ndofs, dtype=object), field.dof_basis.dofs
    rows = [r for block in (d.nodal_dofs, d.edge_dofs, d.facet_dofs, d.interior_dofs)
            for r in block]  # the order of the element's dofnames
    for name, row in zip(field.dof_basis.elem.dofnames, rows):
        names[row] = name
    return names


def reactions(problem, x, gradient=None, fields=None):
    """{field: {region: [R per component]}} for every field with fixed dofs: the regions
    are 'all' (every fixed dof) and the boundaries named in the field's `fixed` (the dofs
    each one holds: a corner held in x by one and in y by another is split between them),
    or, when `fixed` names none, each named boundary of the mesh with fixed dofs on it (a
    corner then counts for both); the components are those of the value dofs ('u', or
    'u^1', 'u^2' (, 'u^3')).  gradient: the gradient at x where given; fields: the names of
    the fields to report (default those with fixed dofs)."""
    g = problem.gradient(x) if gradient is None else gradient
    out = {}
    for f in problem.fields:
        if (f.name not in fields) if fields is not None else f.fixed_dofs.size == 0:
            continue
        R = g[problem.offsets[f.name]: problem.offsets[f.name] + f.ndofs]
        names = dof_names(f)
        values = [c for c in dict.fromkeys(f.dof_basis.elem.dofnames) if c == "u" or c.startswith("u^")]
        regions = {"all": f.fixed_dofs}
        if f.held:  # boundaries named in `fixed`: the dofs each one holds (corners split)
            regions.update(f.held)
        for name, facets in ({} if f.held else f.mesh.boundaries or {}).items():
            held = np.intersect1d(np.asarray(f.dof_basis.get_dofs(facets).all(), int), f.fixed_dofs)
            if held.size:
                regions[name] = held
        out[f.name] = {name: [float(R[d[names[d] == c]].sum()) for c in values]
                       for name, d in regions.items()}
    return out
