"""Point location and evaluation of finite element functions at arbitrary points.

`locate` finds the cell of every point with a k-d tree of cell centroids and a
test in reference coordinates (linear in memory, unlike a dense search);
`reference_coordinates` inverts the cells' maps, also for non-affine cells and points
outside the candidate cell;
`probes` is the sparse matrix P with (P u)[i] = u_h(x_i) (component-major rows
for vector elements), as scikit-fem's CellBasis.probes but for many points.
"""
import numpy as np
from scipy.sparse import coo_matrix
from scipy.spatial import cKDTree
from skfem.mapping import MappingAffine

SIMPLICES = ("MeshTri1", "MeshTet1", "MeshLine1")


def _inside(mesh, X, tol=1e-9):
    if type(mesh).__name__ in SIMPLICES:
        return np.all(X >= -tol, axis=0) & (X.sum(axis=0) <= 1 + tol)
    return np.all((X >= -tol) & (X <= 1 + tol), axis=0)


def reference_coordinates(mapping, x, tind, tol=1e-13, iterations=40):
    """X with F_c(X) = x for the cells c = tind (x of shape (dim, n, 1), as skfem's invF).

    Affine maps are inverted exactly.  Otherwise Newton's method X <- X + DF(X)^-1 (x - F(X))
    point by point, not clipped to the reference cell (unlike skfem's invF, whose clipped
    iteration stalls and raises for a point outside the cell), kept in [-1, 2]^dim against
    divergence; a point still moving after `iterations` steps gets NaN (never inside)."""
    if isinstance(mapping, MappingAffine):
        return mapping.invF(x, tind=tind)
    X = np.full(x.shape, 0.5)
    todo = np.arange(x.shape[1])
    with np.errstate(all="ignore"):
        for _ in range(iterations):
            t = tind[todo]
            Xt = X[:, todo]
            dX = np.einsum("ijkl,jkl->ikl", mapping.invDF(Xt, t), x[:, todo] - mapping.F(Xt, t))
            X[:, todo] = np.clip(Xt + dX, -1.0, 2.0)
            moving = ~(np.abs(dX).max(axis=(0, 2)) <= tol)  # NaN counts as moving
            todo = todo[moving]
            if todo.size == 0:
                return X
    X[:, todo] = np.nan
    return X


def locate(basis, x, outside="raise"):
    """Cell index of every point x (shape (dim, n)).  Points outside the mesh: ValueError,
    or with outside='nearest' the cell of the nearest centroid (where the cell's polynomial
    is extrapolated, e.g. a refined curved boundary outside the coarse mesh's chords)."""
    mesh, mapping = basis.mesh, basis.mapping
    corners = mesh.p[:, mesh.t]  # (dim, nverts, ncells)
    lo, hi = corners.min(axis=1), corners.max(axis=1)
    slack = 1e-9 * (hi - lo).max()
    tree = cKDTree(corners.mean(axis=1).T)
    cells = -np.ones(x.shape[1], dtype=np.int64)
    todo = np.arange(x.shape[1])
    for k in (4, 16, 64, min(256, mesh.t.shape[1])):
        k = min(k, mesh.t.shape[1])
        _, cand = tree.query(x[:, todo].T, k=k)
        cand = cand.reshape(todo.size, k)
        for j in range(k):
            c, pts = cand[:, j], x[:, todo]
            near = np.all((pts >= lo[:, c] - slack) & (pts <= hi[:, c] + slack), axis=0)
            near &= cells[todo] < 0
            if not near.any():
                continue
            X = reference_coordinates(mapping, pts[:, near, None], c[near])[:, :, 0]
            hit = np.flatnonzero(near)[_inside(mesh, X)]
            cells[todo[hit]] = c[hit]
        todo = todo[cells[todo] < 0]
        if todo.size == 0:
            return cells
    if outside == "nearest":
        cells[todo] = tree.query(x[:, todo].T)[1]
        return cells
    raise ValueError(f"{todo.size} points lie outside the mesh, e.g. {x[:, todo[0]]}")


def probes(basis, x, outside="raise"):
    """Sparse matrix evaluating a function of `basis` at the points x (shape (dim, n));
    outside: see locate."""
    cells = locate(basis, x, outside)
    X = reference_coordinates(basis.mapping, x[:, :, None], cells)
    phis = np.array([np.asarray(basis.elem.gbasis(basis.mapping, X, k, tind=cells)[0])
                     for k in range(basis.Nbfun)])  # (Nbfun, *components, n, 1)
    comp = int(np.prod(phis.shape[1:-2], dtype=int))
    rows = np.tile(np.arange(comp * x.shape[1]), basis.Nbfun)
    cols = basis.dofs.element_dofs[:, np.tile(cells, comp)].ravel()  # cells of the whole mesh
    return coo_matrix((phis.ravel(), (rows, cols)), shape=(comp * x.shape[1], basis.N)).tocsr()
