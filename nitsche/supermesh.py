"""Supermesh: the intersection of two bodies' traces, on which interface integrals are exact.

Body 1's surface elements S_i (its contact facets, or the cells of a membrane mapped
into the other body's space by `to_other`) and body 2's boundary facets T_j are cut
against each other on the plane of S_i: T_j is projected along the normal n_i of S_i,
the overlap P_ij = S_i ∩ proj T_j is an interval (2D) or a convex polygon (3D:
Sutherland-Hodgman clipping of triangles and quadrilaterals), split into triangles from
its first vertex, and every piece carries a Gauss rule of the requested degree.  A point
x of a piece is paired with the point of T_j's plane along n_i,

    y = x + d n_i,   d = (c_j - x) . n_j / (n_i . n_j)      (c_j: a point of T_j),

the closest point when the surfaces are parallel (the pairing of a curved body follows
its facets' normals).  On a piece both traces are polynomials when S_i and T_j are
affine (segments, triangles, parallelograms) and coplanar, so the interface integral of
a polynomial density is exact (the contact patch test to round-off); on curved or
bilinear surfaces the pieces still follow the kinks of both traces and the error is
that of the geometry.

The construction is a function of the vertex coordinates of both surfaces in the common
space (`Surface(..., points)`): on a deformed configuration it is rebuilt from displaced
vertices, the points still mapped to each body's reference cells.
"""
import time

import numpy as np
from scipy.spatial import cKDTree
from skfem.quadrature import get_quadrature
from skfem.refdom import RefLine, RefTri

from . import partition
from .measures import cell_diameters, tabulate_at, value_shapes

TOL = 1e-10  # pieces smaller than TOL times their surface element are dropped


class Surface:
    """Surface elements of one body, from `points` (D, vertices): its vertex coordinates in
    the common space (the mesh's, mapped by to_other, or displaced ones on a deformed
    configuration).  Per element: `corners` (n, m, D), the owning `cells` (n,), the mesh
    `vertices` (m, n), unit `normals` (n, D) (outward for facets, of arbitrary sign for
    cells), a plane frame (`origin` (n, D), orthonormal `axes` (n, D - 1, D)) and the affine
    map of frame coordinates to the body's own (reference configuration) coordinates
    fitted to the corners (exact for affine elements and maps), with its Gram determinant
    `jacobian` (n,)."""

    def __init__(self, mesh, vertices, cells, points, outward=True):
        self.mesh, self.vertices, self.cells, self.outward = mesh, vertices, cells, outward
        self.corners = points[:, vertices].transpose(2, 1, 0)  # (n, m, D)
        n = plane_normals(self.corners)
        if outward:  # away from the owning cell's centroid
            inner = points[:, mesh.t[:, cells]].mean(axis=1).T
            n *= np.sign(np.sum(n * (self.corners.mean(axis=1) - inner), axis=1))[:, None]
        self.normals = n
        self.origin, self.axes = frames(self.corners, n)
        local = self.local(np.arange(len(cells)), self.corners)
        L = np.concatenate([local, np.ones(local.shape[:2] + (1,))], axis=2)
        own = mesh.p[:, vertices].transpose(2, 1, 0)  # least squares, normal equations
        self.fit = np.linalg.solve(np.swapaxes(L, 1, 2) @ L, np.swapaxes(L, 1, 2) @ own)  # (n, D, d)
        G = self.fit[:, :-1]
        self.jacobian = np.sqrt(np.linalg.det(G @ np.swapaxes(G, 1, 2)))

    @property
    def dim(self):
        return self.corners.shape[2]

    def local(self, idx, x):
        """Frame coordinates (P, Q, D - 1) of points x (P, Q, D) of the planes of elements idx."""
        return (x - self.origin[idx, None]) @ np.swapaxes(self.axes[idx], 1, 2)

    def own(self, idx, local):
        """The body's own coordinates (d, P, Q) of frame coordinates (P, Q, D - 1)."""
        A = self.fit[idx]
        return np.moveaxis(local @ A[:, :-1] + A[:, None, -1], -1, 0)


def facet_surface(mesh, facets, points=None):
    """The boundary facets `facets` of a mesh, outward normals; points: the vertex
    coordinates in the common space (default mesh.p)."""
    facets = np.asarray(facets, dtype=np.int64)
    return Surface(mesh, mesh.facets[:, facets], mesh.f2t[0, facets],
                   mesh.p if points is None else points)


def cell_surface(mesh, points, cells=None):
    """The cells (default all) of a mesh of dimension D - 1 (a membrane) with vertices at
    `points` (D, n)."""
    if points is None or points.shape[0] != mesh.dim() + 1:
        raise ValueError("an interface on cells paired with another body needs to_other, the "
                         "map of the cells into the other body's space (one dimension up)")
    cells = np.arange(mesh.t.shape[1]) if cells is None else cells
    return Surface(mesh, mesh.t[:, cells], cells, points, outward=False)


def plane_normals(corners):
    """Unit normals (n, D) of segments (D = 2), triangles and quadrilaterals (D = 3)."""
    if corners.shape[2] == 2:
        t = corners[:, 1] - corners[:, 0]
        n = np.stack([t[:, 1], -t[:, 0]], axis=1)
    elif corners.shape[1] == 3:
        n = np.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0])
    else:
        n = np.cross(corners[:, 2] - corners[:, 0], corners[:, 3] - corners[:, 1])
    return n / np.linalg.norm(n, axis=1, keepdims=True)


def frames(corners, normals):
    """Origin (n, D) and orthonormal tangent axes (n, D - 1, D) of each element's plane."""
    c = corners.mean(axis=1)
    e1 = corners[:, 1] - corners[:, 0]
    if corners.shape[2] == 2:
        return c, (e1 / np.linalg.norm(e1, axis=1, keepdims=True))[:, None]
    e1 -= np.sum(e1 * normals, axis=1, keepdims=True) * normals
    e1 /= np.linalg.norm(e1, axis=1, keepdims=True)
    return c, np.stack([e1, np.cross(normals, e1)], axis=1)


def _counterclockwise(poly):
    """Polygons (P, m, 2) ordered counterclockwise."""
    x, y = poly[..., 0], poly[..., 1]
    area = np.sum(x * np.roll(y, -1, axis=1) - np.roll(x, -1, axis=1) * y, axis=1)
    return np.where((area < 0)[:, None, None], poly[:, ::-1], poly)


def clip(subject, clipper, scale):
    """Sutherland-Hodgman: convex polygons subject (P, m, 2) clipped by convex polygons
    clipper (P, k, 2), both counterclockwise.  Returns vertices (P, m + k, 2) and counts (P,);
    `scale` (P,): a length, for the tolerance of the inside test."""
    P, k = clipper.shape[:2]
    M = subject.shape[1] + k
    poly = np.zeros((P, M, 2))
    poly[:, :subject.shape[1]] = subject
    count = np.full(P, subject.shape[1])
    rows = np.arange(P)[:, None]
    tol = 1e-12 * scale[:, None] ** 2
    for i in range(k):
        a, b = clipper[:, i, None], clipper[:, (i + 1) % k, None]
        t = b - a
        side = t[..., 0] * (poly[..., 1] - a[..., 1]) - t[..., 1] * (poly[..., 0] - a[..., 0])
        valid = np.arange(M) < count[:, None]
        inside = side >= -tol
        prev = (np.arange(M) - 1) % np.maximum(count, 1)[:, None]
        s0, in0, p0 = side[rows, prev], inside[rows, prev], poly[rows, prev]
        cross = valid & (inside != in0)
        with np.errstate(all="ignore"):
            r = np.where(cross, s0 / (s0 - side), 0.0)
        out = np.stack([p0 + r[..., None] * (poly - p0), poly], axis=2).reshape(P, 2 * M, 2)
        keep = np.stack([cross, valid & inside], axis=2).reshape(P, 2 * M)
        order = np.argsort(~keep, axis=1, kind="stable")[:, :M]
        poly, count = out[rows, order], keep.sum(axis=1)
    return poly, count


def _overlaps(s1, s2, pairs):
    """The overlap of S_i and the projected T_j as simplices (P', D, D - 1) in S_i's frame
    coordinates, with the index of their pair (P',)."""
    i, j = pairs
    local1, local2 = s1.local(i, s1.corners[i]), s1.local(i, s2.corners[j])
    if s1.dim == 2:  # intervals
        lo = np.maximum(local1.min(axis=1), local2.min(axis=1))[:, 0]
        hi = np.minimum(local1.max(axis=1), local2.max(axis=1))[:, 0]
        keep = hi - lo > TOL * (local1.max(axis=1) - local1.min(axis=1))[:, 0]
        return np.stack([lo, hi], axis=1)[keep, :, None], np.flatnonzero(keep)
    size = np.linalg.norm(local1 - local1.mean(axis=1, keepdims=True), axis=2).max(axis=1)
    boxes = np.all((local2.max(axis=1) > local1.min(axis=1) + TOL * size[:, None])
                   & (local2.min(axis=1) < local1.max(axis=1) - TOL * size[:, None]), axis=1)
    pairs = np.flatnonzero(boxes)  # the bounding boxes overlap: clip these
    local1, local2, size = local1[pairs], local2[pairs], size[pairs]
    poly, count = clip(_counterclockwise(local2), _counterclockwise(local1), size)
    tris, owner = [], []
    for k in range(1, poly.shape[1] - 1):  # the fan from vertex 0
        t = np.stack([poly[:, 0], poly[:, k], poly[:, k + 1]], axis=1)
        u, v = t[:, 1] - t[:, 0], t[:, 2] - t[:, 0]
        area = 0.5 * (u[:, 0] * v[:, 1] - u[:, 1] * v[:, 0])
        keep = (k + 1 < count) & (area > TOL * size ** 2)
        tris.append(t[keep])
        owner.append(pairs[keep])
    return np.concatenate(tris), np.concatenate(owner)


def candidate_pairs(s1, s2, reach):
    """(i, j) of surface elements that can face each other within reach[i]:
    |c_i - c_j| <= r_i + r_j + reach_i (centroids c, largest centroid-corner distances r)."""
    c1, c2 = s1.corners.mean(axis=1), s2.corners.mean(axis=1)
    r1 = np.linalg.norm(s1.corners - c1[:, None], axis=2).max(axis=1) + reach
    r2 = np.linalg.norm(s2.corners - c2[:, None], axis=2).max(axis=1)
    near = cKDTree(c2).query_ball_point(c1, r=(r1 + r2.max()) * (1 + 1e-9))
    i = np.repeat(np.arange(len(near)), [len(a) for a in near])
    j = np.fromiter((j for a in near for j in a), dtype=np.int64, count=i.size)
    keep = np.linalg.norm(c1[i] - c2[j], axis=1) <= (r1[i] + r2[j]) * (1 + 1e-9)
    return i[keep], j[keep]


class Supermesh:
    """The interface measure on the pieces of the supermesh of `s1` (body 1, whose mesh
    gives x, n, h) and `s2` (body 2's boundary facets).  Each piece e belongs to one
    element of each body: fields of either mesh are tabulated at its points in that cell.

    Elements T_j facing S_i (n_i . n_j < 0; any orientation for a membrane's cells) and
    within `reach` of it along n_i (default: the diameter h of S_i's cell) are paired;
    `intorder`: degree of the Gauss rule on every piece.  `stats`: pieces, pairs (and the
    build time in seconds, set by nitsche.interface)."""

    def __init__(self, s1, s2, intorder, reach=None):
        self.s1, self.s2 = s1, s2
        self.mesh, self.kind = s1.mesh, "facets" if s1.outward else "cells"
        D = s1.dim
        h1 = cell_diameters(s1.mesh)[s1.cells]
        reach = h1 if reach is None else np.broadcast_to(reach, h1.shape)
        i, j = candidate_pairs(s1, s2, reach)
        cos = np.sum(s1.normals[i] * s2.normals[j], axis=1)
        facing = cos < -TOL if s1.outward else np.abs(cos) > TOL
        i, j = i[facing], j[facing]
        simplices, pair = _overlaps(s1, s2, (i, j))
        i, j = i[pair], j[pair]
        # Gauss rule on every piece: frame coordinates (P, Q, D - 1), weights (P, Q)
        X, w = get_quadrature(RefLine if D == 2 else RefTri, intorder)
        J = simplices[:, 1:] - simplices[:, :1]  # (P, D - 1, D - 1) edge vectors
        local = simplices[:, None, 0] + np.einsum("kq,pkl->pql", X, J)
        W = np.abs(np.linalg.det(J))[:, None] * w
        x = s1.origin[i, None] + np.einsum("pqk,pkD->pqD", local, s1.axes[i])
        n1, n2 = s1.normals[i, None], s2.normals[j, None]
        d = np.sum((s2.origin[j, None] - x) * n2, axis=2) / np.sum(n1 * n2, axis=2)
        near = np.all(np.abs(d) <= reach[i, None], axis=1)
        i, j, local, W, x, d, n1 = i[near], j[near], local[near], W[near], x[near], d[near], n1[near]
        if partition.everywhere(i.size == 0):
            raise ValueError("the supermesh is empty: no facet of the other body faces this "
                             "surface within reach")
        y = x + d[..., None] * n1
        self.owner, self.distance = (i, j), d
        self.W = W * s1.jacobian[i, None]
        self.x1, self.x2 = s1.own(i, local), s2.own(j, s2.local(j, y))
        self.n = np.broadcast_to(np.moveaxis(n1, -1, 0), (D,) + W.shape)
        self.cells1, self.cells2 = s1.cells[i], s2.cells[j]
        self.stats = dict(pieces=int(i.size), pairs=int(np.unique(i * len(s2.cells) + j).size))

    @property
    def conforming(self):
        """Every S_i is covered by one T_j exactly, in contact (matching meshes): then the
        other body's trace is polynomial on S_i at the same physical points."""
        i, j = self.owner
        if np.abs(self.distance).max(initial=0.0) > TOL * self.h.min(initial=np.inf):
            return False
        pairs = np.unique(np.stack([i, j]), axis=1)
        own = np.bincount(i, weights=self.W.sum(axis=1), minlength=len(self.s1.cells))
        return bool(np.array_equal(pairs[0], np.arange(len(self.s1.cells)))
                    and np.allclose(own, surface_measures(self.s1), rtol=1e-10, atol=0))

    weights = property(lambda self: self.W)
    points = property(lambda self: self.x1)
    normals = property(lambda self: self.n if self.s1.outward else None)
    h = property(lambda self: cell_diameters(self.mesh)[self.cells1])
    cells = property(lambda self: self.cells1)  # the cell of this body owning each piece
    nelems = property(lambda self: self.W.shape[0])
    vertices = property(lambda self: self.s1.vertices[:, self.owner[0]])

    def _body(self, field):
        if field.mesh is self.s1.mesh:
            return self.cells1, self.x1
        if field.mesh is self.s2.mesh:
            return self.cells2, self.x2
        raise ValueError(f"field '{field.name}' lives on neither mesh of this supermesh")

    def attach(self, field):
        self._body(field)
        return field.dof_basis

    def release(self):
        pass

    def tabulation(self, field, orders):
        cells, x = self._body(field)
        Q = x.shape[2]
        T = tabulate_at(field, orders, np.repeat(cells[:, None], Q, axis=1), x)
        return T, np.ascontiguousarray(field.dof_basis.dofs.element_dofs[:, cells].T)

    def shapes(self, field, orders):
        return value_shapes(field, orders)


def surface_measures(surface):
    """Length or area of every surface element in the body's own coordinates (flat elements)."""
    p = surface.mesh.p[:, surface.vertices].transpose(2, 1, 0)
    if p.shape[1] == 2:
        return np.linalg.norm(p[:, 1] - p[:, 0], axis=1)
    if p.shape[2] == 2:
        x, y = p[..., 0], p[..., 1]
        return 0.5 * np.abs(np.sum(x * np.roll(y, -1, axis=1) - np.roll(x, -1, axis=1) * y, axis=1))
    return 0.5 * np.linalg.norm(np.sum(np.cross(p, np.roll(p, -1, axis=1)), axis=1), axis=1)


def interface_report(problem, x, name):
    """How constraint `name` is integrated: pairing ('supermesh' or 'points'), number of
    measure elements, the supermesh's build time and, to compare, the time of one Newton
    assembly (J_h, gradient and Hessian) of the whole problem at x.  On a rank's part
    (inside nitsche.partition.local) the elements are summed over the ranks and the
    seconds are the slowest rank's."""
    i = [c.name for c in problem.constraints].index(name)
    stats = getattr(problem.constraints[i].on, "stats", None)
    start = time.perf_counter()
    problem.assembler.evaluate(x)
    seconds = time.perf_counter() - start
    return dict(pairing="supermesh" if stats else "points",
                elements=int(partition.summed(problem.constraint_terms[i].nel)),
                supermesh_seconds=float(partition.largest(stats["seconds"])) if stats else None,
                newton_assembly_seconds=float(partition.largest(seconds)))
