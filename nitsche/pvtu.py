"""Parallel VTU output of a distributed run: every rank writes the piece of each mesh that
its own cells make (nitsche.io.mesh_vtu of those cells), rank 0 the collection that names
the pieces (PREFIX.pvtu, ParaView's parallel unstructured grid).

    PREFIX_r0.vtu, PREFIX_r1.vtu, ... and PREFIX.pvtu              (one mesh)
    PREFIX_i_r0.vtu, ... and PREFIX_i.pvtu                          (mesh i of several)

The pieces are written into rank 0's staging folder (nitsche.output.OutputFolder, on a file
system all ranks share), each under a temporary name and renamed, so that the folder's
commit moves complete pieces only.  A vertex on the boundary between two pieces is in both,
with the same values: the multipliers averaged to the vertices sum the ranks' elements
(an all-reduce of one vertex vector per constraint).  Collective: call it on every rank.
"""
import os

import numpy as np

from . import partition
from .io import meshes_of, mesh_vtu, vertex_multiplier, write_text, written_atomically

VTK_TYPES = {"float64": "Float64", "float32": "Float32", "int64": "Int64", "int32": "Int32",
             "uint8": "UInt8"}


def write_pieces(prefix, dp, x, staging):
    """This rank's pieces of the solution x of the DistributedProblem dp into the folder
    `staging` (every rank's; rank 0's OutputFolder.staging); rank 0 also writes the .pvtu
    collections.  Returns the paths written, on rank 0 (the pieces of all ranks, the
    collections), ([], []) on the other ranks.  An OSError on any rank is raised on all."""
    from mpi4py import MPI
    comm, local = dp.comm, dp.local
    values = local.constraint_values(x)

    def summed(a):
        out = np.empty_like(a)
        comm.Allreduce(np.ascontiguousarray(a), out, op=MPI.SUM)
        return out
    meshes = meshes_of(local)
    collections, pieces_written, error = [], [], None
    for i, mesh in enumerate(meshes):
        name = prefix if len(meshes) == 1 else f"{prefix}_{i}"
        with partition.local(comm):
            cells = partition.own_cells(mesh)
        total = summed if not hasattr(mesh, "numbering") else \
            lambda a, n=mesh.numbering: partition.by_number(comm, n.vertices, a, n.counts[0], "sum")
        path, arrays = None, None
        if cells.size:
            piece = mesh_vtu(local, x, mesh, values, cells=cells, total=total)
            path = os.path.join(staging, f"{name}_r{comm.rank}.vtu")
            error = error or write_atomically(piece, path)
            arrays = (describe(piece.point_data),
                      describe({k: v[0] for k, v in piece.cell_data.items()}))
        else:  # no cells of this mesh here: only the reductions the others make
            vertex_multiplier(local, values, mesh, total)
        pieces = comm.gather((path, arrays), root=0)
        if comm.rank == 0:
            paths = [p for p, _ in pieces if p]
            collections.append((os.path.join(staging, f"{name}.pvtu"), paths,
                                next(a for p, a in pieces if p)))
            pieces_written += paths
    errors = comm.allgather(error)
    if any(errors):
        raise OSError("; ".join(f"rank {r}: {e}" for r, e in enumerate(errors) if e))
    return pieces_written, [write_collection(path, paths, *arrays)
                            for path, paths, arrays in collections]


def write_atomically(mesh, path):
    """Write the meshio mesh to path (io.written_atomically); the error's text, or None."""
    try:
        written_atomically(path, lambda tmp: mesh.write(tmp, file_format="vtu"))
    except OSError as e:
        return f"{path}: {e.strerror or e}"
    return None


def describe(arrays):
    """[(name, VTK type, components)] of a {name: array} of point or cell data."""
    return [(k, VTK_TYPES[np.asarray(v).dtype.name], 1 if np.ndim(v) == 1 else np.shape(v)[1])
            for k, v in arrays.items()]


def _pdata(tag, arrays):
    rows = "".join(f'      <PDataArray type="{t}" Name="{k}" NumberOfComponents="{c}"/>\n'
                   for k, t, c in arrays)
    return f"    <{tag}>\n{rows}    </{tag}>\n"


def write_collection(path, pieces, points, cells):
    """The .pvtu of the pieces (VTU files beside it) with their point and cell arrays
    [(name, VTK type, components)], whole or absent."""
    text = ('<?xml version="1.0"?>\n<VTKFile type="PUnstructuredGrid" version="0.1" '
            'byte_order="LittleEndian">\n  <PUnstructuredGrid GhostLevel="0">\n'
            + _pdata("PPointData", points) + _pdata("PCellData", cells)
            + '    <PPoints>\n      <PDataArray type="Float64" NumberOfComponents="3"/>\n'
              '    </PPoints>\n'
            + "".join(f'    <Piece Source="{os.path.basename(p)}"/>\n' for p in pieces)
            + "  </PUnstructuredGrid>\n</VTKFile>\n")
    return written_atomically(path, lambda tmp: write_text(tmp, text))
