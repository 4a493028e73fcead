"""A fill-reducing ordering of a sparse symmetric matrix from its rows' coordinates.

`nested_dissection` dissects the rows geometrically (recursive coordinate bisection)
and takes each separator from the matrix graph; CHOLMOD factors the reordered matrix
without an ordering of its own (nitsche.linalg.Cholmod).
"""
import numpy as np
import scipy.sparse as sp

LEAF = 16  # subdomains of at most this many rows are not dissected further


def nested_dissection(A, points, leaf=LEAF):
    """A permutation p of the n rows of the sparse matrix A of a symmetric pattern (its upper
    triangle read; P A P^T = A[p][:, p]) from the coordinates points (n, dim) of its rows,
    by geometric nested dissection.

    A subdomain D (at first all rows) of more than `leaf` rows and a positive extent is cut
    across its longest extent a at the median m of the rows' x_a (to one bucket of the
    |D| equal buckets of that extent): L = the rows below m's bucket (where there are none:
    up to it) and R the rest, so that rows at one point stay together.  The separator S is
    the rows of L with a neighbour in R in A's graph or those of R with one in L, whichever
    are fewer: no edge of A joins L - S and R - S.  The order is the dissection tree's
    post-order: L - S and R - S (each dissected in turn), then S; a leaf keeps its rows in
    their given order.  Each level of the tree is done at once for all its subdomains (a
    bucket count per subdomain and one pass over A's edges, no sort): O(nnz log n)."""
    n = A.shape[0]
    x = np.ascontiguousarray(np.asarray(points, dtype=float).reshape(n, -1 if n else 1).T)  # (dim, n)
    C = sp.coo_matrix(A)
    upper = C.row < C.col
    I, J = C.row[upper].astype(np.int32), C.col[upper].astype(np.int32)
    del C, upper
    perm = np.empty(n, dtype=np.int64)
    items = np.arange(n, dtype=np.int32)          # the undecided rows, grouped by subdomain
    sizes, starts = np.array([n]), np.array([0])  # per subdomain: rows, first position in perm
    label = np.full(n, -1, dtype=np.int32)        # 2 * subdomain + side of a row being cut, else -1
    touched = np.zeros(n, dtype=bool)
    while items.size:
        first = np.cumsum(sizes) - sizes
        xs = np.take(x, items, axis=1)
        lo = np.minimum.reduceat(xs, first, axis=1)
        extent = np.maximum.reduceat(xs, first, axis=1) - lo
        axis = np.argmax(extent, axis=0)
        lo, width = np.take_along_axis(lo, axis[None], 0)[0], np.take_along_axis(extent, axis[None], 0)[0]
        cut = (sizes > leaf) & (width > 0)
        if not cut.all():  # the leaves: their rows in place
            leaves = np.repeat(~cut, sizes)
            perm[np.repeat(starts - first, sizes)[leaves] + np.flatnonzero(leaves)] = items[leaves]
            kept = ~leaves
            items, xs = items[kept], np.compress(kept, xs, axis=1)
            sizes, starts, lo, axis, width = sizes[cut], starts[cut], lo[cut], axis[cut], width[cut]
            first = np.cumsum(sizes) - sizes
        if not items.size:
            break
        k, m = sizes.size, items.size
        group = np.repeat(np.arange(k, dtype=np.int32), sizes)
        c = xs.ravel()[axis[group] * m + np.arange(m)]  # x_a of each row
        bucket = ((c - np.repeat(lo, sizes)) * np.repeat(sizes / width, sizes)).astype(np.int64)
        np.minimum(bucket, np.repeat(sizes - 1, sizes), out=bucket)
        bucket += np.repeat(first, sizes)
        median = np.repeat(np.searchsorted(np.cumsum(np.bincount(bucket, minlength=m)),
                                           first + sizes // 2, side="right"), sizes)
        left = bucket < median
        if not counts(left, first).all():  # more than half at the lowest bucket
            left = np.where(np.repeat(counts(left, first) > 0, sizes), left, bucket <= median)
        label[items] = 2 * group + ~left
        cross = np.flatnonzero((label[I] ^ label[J]) == 1)  # the same subdomain, both sides
        label[items] = -1
        touched[I[cross]] = touched[J[cross]] = True
        near = touched[items]
        touched[I[cross]] = touched[J[cross]] = False
        separator = near & (left == np.repeat(counts(near & left, first) <= counts(near & ~left, first),
                                              sizes))
        n_sep, n_left = counts(separator, first), counts(left & ~separator, first)
        n_right = sizes - n_left - n_sep
        perm[np.repeat(starts + n_left + n_right, n_sep)
             + rank_in_group(separator, first, sizes)[separator]] = items[separator]
        # the children L - S and R - S, each kept in order: a stable partition of each subdomain
        rank = np.where(left, rank_in_group(left & ~separator, first, sizes),
                        rank_in_group(~left & ~separator, first, sizes) + np.repeat(n_left, sizes))
        order = np.empty(m - n_sep.sum(), dtype=np.int32)
        order[(np.repeat(first - np.cumsum(n_sep) + n_sep, sizes) + rank)[~separator]] = items[~separator]
        items = order
        sizes = np.stack([n_left, n_right], axis=1).ravel()
        starts = np.stack([starts, starts + n_left], axis=1).ravel()
        sizes, starts = sizes[sizes > 0], starts[sizes > 0]
    return perm


def counts(mask, first):
    """The number of True entries of mask in each group (groups contiguous, from first)."""
    return np.add.reduceat(mask, first, dtype=np.int64)


def rank_in_group(mask, first, sizes):
    """For each entry: how many True entries of mask precede it in its group (groups
    contiguous, group g the sizes[g] entries from first[g])."""
    before = np.cumsum(mask, dtype=np.int64) - mask
    return before - np.repeat(before[first], sizes)
