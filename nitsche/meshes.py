"""Mesh helpers: graded point sequences for tensor meshes (fine near 0, coarse far away),
uniform refinement with the fast facet build."""
import numpy as np

from . import partition
from .measures import build_edges, build_facets


def graded(length, fine, n_fine, growth):
    """Points 0 = t_0 < ... < t_m = length: n_fine equal cells up to `fine`, then cells
    that grow by the factor `growth` (the last one ends at `length`)."""
    t = list(np.linspace(0.0, fine, n_fine + 1))
    step = fine / n_fine
    while t[-1] + step * growth < length:
        step *= growth
        t.append(t[-1] + step)
    t[-1] = length if length - t[-1] < 0.5 * step else t[-1]
    if t[-1] != length:
        t.append(length)
    return np.array(t)


def refined(mesh, times, ghosts_for=None):
    """mesh refined uniformly `times` times, as scikit-fem's mesh.refined(times), with the
    facets and (3D) edges that each refinement step reads (t2f, facets, t2e, edges) built
    by measures.build_facets and build_edges (one integer sort, the same arrays as
    scikit-fem's, about 4x faster); inside
    partition.local(comm, meshes="local") this rank's cells of it only
    (local_mesh.local_refined), and with ghosts_for=(other, to_this) the cells that this
    rank's cells of the mesh `other` reach when mapped by to_this (points (dim_other, n) ->
    (dim, n)): those an interface from `other` onto this mesh evaluates this mesh's fields
    in (nitsche.interface(..., to_other=to_this, other=...))."""
    if partition.local_meshes():
        from .local_mesh import local_refined
        whole = ghosts_for is not None and not hasattr(ghosts_for[0], "numbering")
        return local_refined(mesh, times, partition.active(), None if whole else ghosts_for)
    return uniformly_refined(mesh, times)


def uniformly_refined(mesh, times):
    """The whole mesh refined `times` times (refined outside a partition of local meshes)."""
    for _ in range(times):
        build_facets(mesh)
        build_edges(mesh)
        mesh = mesh.refined()
    return mesh
