"""Results on disk: result.json / study.json (a public contract: keys are only added)
and VTK files for ParaView."""
import json
import math
import os

from skfem.io.meshio import to_meshio
import numpy as np
from skfem import ElementVector


def write_json(path, data):
    """Strict JSON (no NaN or Infinity): non-finite numbers are written as null."""
    os.makedirs(os.path.dirname(os.path.abspath(path)), exist_ok=True)
    with open(path, "w") as fh:
        json.dump(_plain(data), fh, indent=2, allow_nan=False)
    return path


def _plain(o):
    """o with NumPy values as Python ones and non-finite floats as None."""
    if isinstance(o, (np.ndarray, np.generic)):
        o = o.tolist()
    if isinstance(o, dict):
        return {k: _plain(v) for k, v in o.items()}
    if isinstance(o, (list, tuple)):
        return [_plain(v) for v in o]
    if isinstance(o, float) and not math.isfinite(o):
        return None
    return o


def vertex_values(field, u):
    """Values of a Lagrange field at the mesh vertices (the first nodal dofs)."""
    nv = field.mesh.nvertices
    if isinstance(field.element, ElementVector):
        return np.asarray(u[field.basis.nodal_dofs[:, :nv]]).T  # (nv, d)
    return np.asarray(u[field.basis.nodal_dofs[0, :nv]])


def vertex_multiplier(problem, values, mesh):
    """Average the discrete multiplier of every constraint on `mesh` to its vertices."""
    out = {}
    for c in problem.constraints:
        if c.on.mesh is not mesh:
            continue
        v = values[c.name]
        per_element = (v["multiplier"] * v["W"]).sum(1) / np.maximum(v["W"].sum(1), 1e-300)
        verts = mesh.t if c.on.kind == "cells" else mesh.facets[:, c.on.facets]
        acc = np.zeros(mesh.nvertices)
        cnt = np.zeros(mesh.nvertices)
        np.add.at(acc, verts, np.broadcast_to(per_element, verts.shape))
        np.add.at(cnt, verts, 1.0)
        out[f"{c.name}_pressure"] = np.where(cnt > 0, acc / np.maximum(cnt, 1), 0.0)
    return out


def cell_alpha0(problem, mesh):
    """alpha0 of every constraint with a multiplier on `mesh` as cell data ('<name>_alpha0':
    the smallest over the cell's constraint elements, NaN on cells without one)."""
    out = {}
    for c, t in zip(problem.constraints, problem.constraint_terms):
        if c.on.mesh is mesh and c.multiplier is not None:
            a = np.full(mesh.nelements, np.inf)
            np.minimum.at(a, t.cells, problem.alpha0[c.name])
            out[f"{c.name}_alpha0"] = [np.where(np.isfinite(a), a, np.nan)]
    return out


def write_vtu(path_prefix, problem, x):
    """One .vtu per mesh: point data named after the fields plus the contact pressure, cell
    data alpha0 per constraint."""
    parts = problem.split(x)
    values = problem.constraint_values(x)
    meshes = []
    for f in problem.fields:
        if all(f.mesh is not m for m in meshes):
            meshes.append(f.mesh)
    paths = []
    for i, mesh in enumerate(meshes):
        data = {f.name: vertex_values(f, parts[f.name]) for f in problem.fields
                if f.mesh is mesh and f.is_lagrange}
        data.update(vertex_multiplier(problem, values, mesh))
        path = f"{path_prefix}.vtu" if len(meshes) == 1 else f"{path_prefix}_{i}.vtu"
        out = to_meshio(mesh, point_data=data, cell_data=cell_alpha0(problem, mesh))
        if out.points.shape[1] == 2:  # VTK points are 3D
            out.points = np.c_[out.points, np.zeros(len(out.points))]
        out.write(path)
        paths.append(path)
    return paths
