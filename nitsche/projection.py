"""Closest points on a surface made of facets: segments (2D), flat triangles and bilinear
quadrilaterals (3D), with the candidate facets of each point found by a k-d tree.

A facet with vertices v_i is the map y(eta) = sum_i N_i(eta) v_i of its reference coordinates
eta (one in 2D, two in 3D):

    segment        N = (1 - t, t),                          t in [0, 1]
    triangle       N = (1 - r - s, r, s),                   r, s >= 0, r + s <= 1
    quadrilateral  N = ((1-r)(1-s), r(1-s), r s, (1-r) s),  r, s in [0, 1]  (vertices in turn)

The closest point of x on a facet minimizes |x - y(eta)| over the facet.  On a triangle it is
the projection onto its plane where that lies inside, and otherwise the nearest of the closest
points on its three edges (the triangle is convex).  On a bilinear quadrilateral the
stationary point of |x - y|^2 / 2 is found by Newton's method in (r, s) from the centre; the
closest point is the nearest of that point (where it lies inside) and the closest points on
the four straight edges.  The unclipped coordinates (the projection onto the triangle's
plane, the stationary point of the quadrilateral) say how far outside a facet a point
projects (the hysteresis of nitsche.sliding).
"""
import numpy as np
from scipy.spatial import cKDTree

NEWTON_STEPS = 30  # at most, for the bilinear quadrilaterals (until eta moves by < 1e-13)
CANDIDATES = 8  # facets nearest by centroid examined first per point


def shape_functions(vertices, eta):
    """N (P, v) and dN/deta (P, v, m) of facets with v = 2 (segment), 3 (triangle) or 4
    (bilinear quadrilateral) vertices at reference coordinates eta (P, m)."""
    P = eta.shape[0]
    if vertices == 2:
        t = eta[:, 0]
        return np.stack([1 - t, t], 1), np.broadcast_to(np.array([[-1.0], [1.0]]), (P, 2, 1)).copy()
    r, s = eta[:, 0], eta[:, 1]
    if vertices == 3:
        dN = np.broadcast_to(np.array([[-1.0, -1.0], [1.0, 0.0], [0.0, 1.0]]), (P, 3, 2)).copy()
        return np.stack([1 - r - s, r, s], 1), dN
    if vertices == 4:
        N = np.stack([(1 - r) * (1 - s), r * (1 - s), r * s, (1 - r) * s], 1)
        dN = np.stack([np.stack([-(1 - s), 1 - s, s, -s], 1), np.stack([-(1 - r), -r, r, 1 - r], 1)], 2)
        return N, dN
    raise ValueError(f"facets with {vertices} vertices: only segments (2), triangles (3) and "
                     "bilinear quadrilaterals (4) are supported")


def on_lines(x, a, b):
    """t of the closest point a + t (b - a) on the lines through a and b to points x (..., d)."""
    e = b - a
    return ((x - a) * e).sum(-1) / np.maximum((e * e).sum(-1), 1e-300)


def on_segments(x, a, b):
    """t in [0, 1] of the closest point a + t (b - a) of segments a -> b to points x (..., d)."""
    return np.clip(on_lines(x, a, b), 0.0, 1.0)


def _nearest(x, candidates):
    """Of candidate points [(eta, y, allowed)], the eta of the one nearest to x (allowed: a
    mask, or None for every point)."""
    best_eta, best = None, None
    for eta, y, allowed in candidates:
        d2 = ((x - y) ** 2).sum(-1)
        if allowed is not None:
            d2 = np.where(allowed, d2, np.inf)
        if best is None:
            best_eta, best = eta.copy(), d2
        else:
            better = d2 < best
            best_eta[better], best = eta[better], np.where(better, d2, best)
    return best_eta


def _edges(x, v, corners):
    """Closest-point candidates on straight edges v[i] -> v[j] whose reference coordinates run
    from corners[i] to corners[j] (pairs (i, j, corner_i, corner_j))."""
    out = []
    for i, j, ci, cj in corners:
        t = on_segments(x, v[:, i], v[:, j])[:, None]
        y = v[:, i] + t * (v[:, j] - v[:, i])
        out.append((np.asarray(ci) + t * (np.asarray(cj) - np.asarray(ci)), y, None))
    return out


def on_triangles(x, v):
    """For points x (P, 3) and triangles v (P, 3, 3) (pairs): the reference coordinates
    (r, s) (P, 2) of the closest point and those of the projection onto the plane."""
    a, e1, e2, w = v[:, 0], v[:, 1] - v[:, 0], v[:, 2] - v[:, 0], x - v[:, 0]
    G = np.stack([np.stack([(e1 * e1).sum(-1), (e1 * e2).sum(-1)], -1),
                  np.stack([(e1 * e2).sum(-1), (e2 * e2).sum(-1)], -1)], -2)
    plane = np.linalg.solve(G, np.stack([(e1 * w).sum(-1), (e2 * w).sum(-1)], -1)[..., None])[..., 0]
    r, s = plane[:, 0], plane[:, 1]
    inside = (r >= 0) & (s >= 0) & (r + s <= 1)
    y = a + r[:, None] * e1 + s[:, None] * e2
    corners = [(0, 1, (0, 0), (1, 0)), (0, 2, (0, 0), (0, 1)), (1, 2, (1, 0), (0, 1))]
    return _nearest(x, [(plane, y, inside)] + _edges(x, v, corners)), plane


def bilinear(v, eta):
    """y(r, s) = sum_i N_i v_i on quadrilaterals v (P, 4, 3)."""
    return np.einsum("pi,pik->pk", shape_functions(4, eta)[0], v)


def on_quadrilaterals(x, v):
    """For points x (P, 3) and bilinear quadrilaterals v (P, 4, 3) (vertices in turn): the
    reference coordinates (r, s) (P, 2) of the closest point and those of the stationary point
    of |x - y(r, s)|^2 / 2 nearest the centre (Newton's method, its iterates kept in [-1, 2]^2)."""
    eta = np.full((len(x), 2), 0.5)
    twist = v[:, 0] - v[:, 1] + v[:, 2] - v[:, 3]  # d^2 y / dr ds
    active = np.arange(len(x))  # the pairs still moving
    for _ in range(NEWTON_STEPS):
        va, e_ = v[active], eta[active]
        N, dN = shape_functions(4, e_)
        tr, ts = (dN[:, :, 0, None] * va).sum(1), (dN[:, :, 1, None] * va).sum(1)  # dy/dr, dy/ds
        e = (N[..., None] * va).sum(1) - x[active]
        gr, gs = (tr * e).sum(1), (ts * e).sum(1)
        a, b, c = (tr * tr).sum(1), (tr * ts).sum(1), (ts * ts).sum(1)
        newton = b + (e * twist[active]).sum(1)  # the Hessian [[a, b'], [b', c]], b' = b + e . y_rs
        convex = (a * c - newton ** 2 > 0) & (a > 0)
        b = np.where(convex, newton, b)  # Gauss-Newton where not convex
        det = a * c - b * b
        det = np.where(det > 0, det, np.inf)  # a degenerate facet: no step (its edges decide)
        step = np.stack([c * gr - b * gs, a * gs - b * gr], 1) / det[:, None]
        eta[active] = np.clip(e_ - step, -1.0, 2.0)
        active = active[np.abs(eta[active] - e_).max(axis=1) >= 1e-13]  # held at the bound: done
        if active.size == 0:
            break
    inside = np.all((eta >= 0) & (eta <= 1), axis=1)
    corners = [(0, 1, (0, 0), (1, 0)), (1, 2, (1, 0), (1, 1)), (3, 2, (0, 1), (1, 1)), (0, 3, (0, 0), (0, 1))]
    return _nearest(x, [(eta, bilinear(v, eta), inside)] + _edges(x, v, corners)), eta


def on_facets(x, v):
    """The closest points of x (P, d) on facets v (P, vertices, d) (pairs): (eta, unclipped
    eta), each (P, d - 1)."""
    if v.shape[1] == 2:
        t = on_lines(x, v[:, 0], v[:, 1])
        return np.clip(t, 0.0, 1.0)[:, None], t[:, None]
    if v.shape[1] == 3:
        return on_triangles(x, v)
    if v.shape[1] == 4:
        return on_quadrilaterals(x, v)
    shape_functions(v.shape[1], np.zeros((0, 2)))  # the error that says which facets work


def within(eta, vertices, margin):
    """True where reference coordinates eta (P, m) lie within `margin` (a share of the facet)
    of the reference facet."""
    if vertices == 3:
        return (eta >= -margin).all(1) & (eta.sum(1) <= 1 + margin)
    return ((eta >= -margin) & (eta <= 1 + margin)).all(1)


def closest_facets(x, v, previous=None, margin=0.0, candidates=CANDIDATES):
    """For points x (P, d) and the facets v (F, vertices, d) of a surface: the facet (P,) of
    each point's closest point on the surface and its reference coordinates eta (P, d - 1).

    Candidates are the `candidates` facets nearest by centroid (a k-d tree); where the
    nearest point found might still be beaten by another facet (the last candidate's centroid
    is closer than the distance found plus the largest facet radius), every facet within
    that reach is examined.  previous: the points' facets so far, kept while the unclipped
    closest point on them lies within `margin` of the facet (hysteresis)."""
    F, nv = v.shape[:2]
    facet, eta = np.zeros(len(x), int), np.zeros((len(x), v.shape[2] - 1))
    search = np.arange(len(x))
    if previous is not None:
        kept, free_eta = on_facets(x, v[previous])
        keep = within(free_eta, nv, margin)
        facet[keep], eta[keep], search = previous[keep], kept[keep], np.flatnonzero(~keep)
    if search.size == 0:
        return facet, eta
    y = x[search]
    centroids = v.mean(axis=1)
    reach = np.sqrt(((v - centroids[:, None]) ** 2).sum(-1)).max()
    tree = cKDTree(centroids)
    k = min(candidates, F)
    dist, near = tree.query(y, k)
    dist, near = dist.reshape(len(y), k), near.reshape(len(y), k)
    f, e = _best(y, v, np.repeat(np.arange(len(y)), k), near.ravel(), len(y))
    found = np.sqrt(((y - _point(v, f, e)) ** 2).sum(-1))
    unsure = np.flatnonzero(dist[:, -1] <= found + reach) if k < F else np.zeros(0, int)
    if unsure.size:
        balls = tree.query_ball_point(y[unsure], found[unsure] + reach)
        points = np.repeat(unsure, [len(b) for b in balls])
        f2, e2 = _best(y, v, points, np.concatenate([np.asarray(b, int) for b in balls]), len(y))
        f[unsure], e[unsure] = f2[unsure], e2[unsure]
    facet[search], eta[search] = f, e
    return facet, eta


def _point(v, facet, eta):
    """y(eta) on the given facets."""
    N, _ = shape_functions(v.shape[1], eta)
    return np.einsum("pi,pik->pk", N, v[facet])


def _best(x, v, points, facets, P):
    """Of the pairs (points[j], facets[j]), the nearest facet of every point and its eta."""
    eta, _ = on_facets(x[points], v[facets])
    d2 = ((x[points] - _point(v, facets, eta)) ** 2).sum(-1)
    order = np.lexsort((d2, points))
    first = order[np.r_[True, points[order][1:] != points[order][:-1]]]
    facet = np.zeros(P, int)
    best_eta = np.zeros((P, v.shape[2] - 1))
    facet[points[first]], best_eta[points[first]] = facets[first], eta[first]
    return facet, best_eta
