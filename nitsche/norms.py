"""Norms for errors and refinement studies."""
import numpy as np
from skfem import CellBasis

from . import partition


def energy_norm(problem, v, x=None):
    """|v|_E = sqrt(v^T K v), K the Hessian of the energy J (not of J_h)."""
    return float(np.sqrt(max(v @ (problem.energy_matrix(x) @ v), 0.0)))


def exact_errors(field, u, value, grad, extra_order=4, chunk=65536):
    """L2 and H1-seminorm errors of the dofs u of a scalar field against an exact
    solution given by numpy functions value(x) and grad(x) (shape (dim, ...)),
    integrated `chunk` cells at a time (the quadrature data of a whole 1M-cell mesh
    was the peak memory of `nitsche run`); inside nitsche.partition.local over this
    rank's cells, the squares summed over the ranks."""
    mine = partition.cells(field.mesh)
    mine = np.arange(field.mesh.nelements) if mine is None else mine
    squares = np.zeros(2)
    for start in range(0, mine.size, chunk):
        cells = mine[start:start + chunk]
        hb = CellBasis(field.mesh, field.element, intorder=2 * field.element.maxdeg + extra_order,
                       elements=cells)
        uh = hb.interpolate(u)
        x = np.asarray(hb.global_coordinates())
        e0 = np.asarray(uh) - value(x)
        e1 = uh.grad - grad(x)
        squares += np.sum(e0 ** 2 * hb.dx), np.sum(np.sum(e1 ** 2, axis=0) * hb.dx)
    squares = partition.summed(squares)
    return {"L2": float(np.sqrt(squares[0])), "H1": float(np.sqrt(squares[1]))}


def rates(values):
    """log2 of successive ratios (h halves per level); None where undefined."""
    out = [None]
    for a, b in zip(values[:-1], values[1:]):
        out.append(float(np.log2(a / b)) if a and b and a > 0 and b > 0 else None)
    return out
