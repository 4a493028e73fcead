"""Results on disk: result.json / study.json (a public contract: keys are only added)
and VTK files for ParaView."""
import json
import math
import os
from dataclasses import replace

from skfem.io.meshio import to_meshio
import numpy as np
from skfem import Basis, ElementVector

from .locate import locate, probes
from .quantities import vertex_average


def write_json(path, data):
    """Strict JSON (no NaN or Infinity): non-finite numbers are written as null; whole or
    absent (written_atomically)."""
    text = json.dumps(_plain(data), indent=2, allow_nan=False)
    os.makedirs(os.path.dirname(os.path.abspath(path)), exist_ok=True)
    return written_atomically(path, lambda tmp: write_text(tmp, text))


def written_atomically(path, write):
    """write(tmp) to a temporary name beside `path`, then renamed: `path` is whole or absent
    (the temporary file is removed if writing fails)."""
    tmp = os.path.join(os.path.dirname(os.path.abspath(path)),
                       f".{os.path.basename(path)}.{os.getpid()}.tmp")
    try:
        write(tmp)
        os.replace(tmp, path)
    finally:
        if os.path.exists(tmp):
            os.remove(tmp)
    return path


def write_text(path, text):
    with open(path, "w") as fh:
        fh.write(text)


def write_pvd(path, series):
    """A ParaView collection of a VTU series: series = [(time, [file names, one per
    mesh])], the files beside `path`."""
    rows = "\n".join(f'    <DataSet timestep="{float(t)!r}" part="{i}" file="{name}"/>'
                     for t, names in series for i, name in enumerate(names))
    with open(path, "w") as fh:
        fh.write('<?xml version="1.0"?>\n<VTKFile type="Collection" version="0.1">\n'
                 f"  <Collection>\n{rows}\n  </Collection>\n</VTKFile>\n")
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
        return np.asarray(u[field.dof_basis.nodal_dofs[:, :nv]]).T  # (nv, d)
    return np.asarray(u[field.dof_basis.nodal_dofs[0, :nv]])


def vertex_multiplier(problem, values, mesh, total=None):
    """Average the discrete multiplier of every constraint on `mesh` to its vertices
    ('<name>_pressure'; a frictional constraint's tangential traction as
    '<name>_tangential_traction'); total: see quantities.vertex_average."""
    out = {}
    for c in problem.constraints:
        if c.on.mesh is not mesh:
            continue
        v = values[c.name]
        lam = v["multiplier"] if v["multiplier"].ndim == 3 else v["multiplier"][..., None]
        per_element = (lam * v["W"][..., None]).sum(1) / np.maximum(v["W"].sum(1), 1e-300)[:, None]
        at = [vertex_average(mesh, per_element[:, i], c.on.vertices, total)
              for i in range(lam.shape[2])]
        out[f"{c.name}_pressure"] = at[0]
        if len(at) > 1:
            out[f"{c.name}_tangential_traction"] = at[1] if len(at) == 2 else np.stack(at[1:], axis=1)
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


def point_values(field, u, mesh):
    """The field's values at the vertices of `mesh` (its own mesh, or a refinement of it):
    (n,) or (n, components).  Vertex dofs where they are the values (P1, Q1), else the
    function evaluated at the points (P2, Morley, BFS, ...)."""
    comps = field.mesh.dim() if isinstance(field.element, ElementVector) else 1
    if mesh is field.mesh and field.is_lagrange and field.ndofs == comps * mesh.nvertices:
        return vertex_values(field, u)
    v = (probes(field.dof_basis, mesh.p) @ u).reshape(comps, -1) if field.is_lagrange else \
        field.jets_at(np.asarray(u, dtype=float), mesh.p)["value"][None]
    return v[0] if comps == 1 else v.T


def vertex_only(fields):
    """Whether vertex values say everything of the fields (P1, Q1); otherwise (P2, Morley,
    BFS, ...) their VTU is written on the mesh refined once, to show their curvature."""
    return all(f.is_lagrange and f.ndofs in (f.mesh.nvertices, f.mesh.dim() * f.mesh.nvertices)
               for f in fields)


def meshes_of(problem):
    """The meshes of the problem's fields, in the order of the fields."""
    meshes = []
    for f in problem.fields:
        if all(f.mesh is not m for m in meshes):
            meshes.append(f.mesh)
    return meshes


def write_vtu(path_prefix, problem, x, vertex_data=None):
    """One .vtu per mesh (see mesh_vtu): path_prefix.vtu, or path_prefix_i.vtu for mesh i
    of several."""
    values = problem.constraint_values(x)
    meshes = meshes_of(problem)
    paths = []
    for i, mesh in enumerate(meshes):
        path = f"{path_prefix}.vtu" if len(meshes) == 1 else f"{path_prefix}_{i}.vtu"
        mesh_vtu(problem, x, mesh, values, vertex_data).write(path)
        paths.append(path)
    return paths


def mesh_vtu(problem, x, mesh, values, vertex_data=None, cells=None, total=None):
    """The VTU (a meshio mesh) of one mesh of the problem, or of its cells `cells` only (a
    piece of a parallel VTU): point data named after the fields (every element kind), the
    contact pressure of the constraints on that mesh (values: problem.constraint_values(x);
    total: see quantities.vertex_average) and vertex_data {name: (mesh, values at its
    vertices)} (e.g. declared quantities); cell data alpha0 per constraint."""
    fields = [f for f in problem.fields if f.mesh is mesh]
    parts = problem.split(x)
    at_vertices = vertex_multiplier(problem, values, mesh, total)
    at_vertices.update({k: v for k, (m, v) in (vertex_data or {}).items() if m is mesh})
    cell_data = cell_alpha0(problem, mesh)
    piece, used = mesh, np.arange(mesh.nvertices)
    if cells is not None:
        piece, used = mesh.restrict(cells, return_mapping=True, skip_boundaries=True,
                                    skip_subdomains=True)
        at_vertices = {k: v[used] for k, v in at_vertices.items()}
        cell_data = {k: [v[0][cells]] for k, v in cell_data.items()}
    if vertex_only(fields):
        out_mesh = piece
        data = {f.name: vertex_values(f, parts[f.name])[used] for f in fields}
    else:
        # the named boundaries are not written: left out, so that refining does not warn
        out_mesh = replace(piece, _boundaries=None, _subdomains=None).refined(1)
        data = {f.name: point_values(f, parts[f.name], out_mesh) for f in fields}
        linear = Basis(piece, piece.elem())  # vertex values are its dofs
        if at_vertices:  # P1 interpolation of the vertex values
            P = probes(linear, out_mesh.p)
            at_vertices = {k: P @ v for k, v in at_vertices.items()}
        if cell_data:  # each cell of the refined mesh takes its parent's
            parent = locate(linear, out_mesh.p[:, out_mesh.t].mean(axis=1))
            cell_data = {k: [v[0][parent]] for k, v in cell_data.items()}
    data.update(at_vertices)
    out = to_meshio(out_mesh, point_data=data, cell_data=cell_data)
    if out.points.shape[1] == 2:  # VTK points are 3D
        out.points = np.c_[out.points, np.zeros(len(out.points))]
    return out
