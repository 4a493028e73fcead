"""The CSR sparsity pattern of a sum of element matrices, built on groups of dofs, and the
scatter of element matrices into it by blocks.

The dofs fall into groups: runs of consecutive dofs that every element holds together,
in consecutive local positions (a vector Lagrange field's components at a node; a
scalar field's dofs are groups of one).  The pattern is built on the groups, from the
pairs (g, h) of groups that share an element: the pattern of sum_m B_m^T B_m, B_m the
element-group incidence of map m (E elements of r groups each: E r^2 pairs, not the
E k^2 entries of their k x k matrices; SciPy's sparse product, whose memory is that of
its result, not of the pairs); each pair's position in it is then found block by block
of elements, by a search for the pairs of local groups a < c only (the pattern is
symmetric: the diagonal's and the transposed positions give the others).  Then the group
pattern is expanded: every dof row of group g holds the columns of every group h of row g,
so a vector field's pattern is its node pattern with full b x b blocks and no
structurally zero blocks.

An element's local columns fall into runs (consecutive dofs of one group, the same local
columns on every element of a map); its matrix enters by blocks, one offset q[a, c] per
pair of runs (a, c), the position P[a, c] of the entry (first(a), first(c)): the start of
the row of dof D_first(a), plus the columns of the groups before group(D_first(c)) in the
rows of group(D_first(a)), plus D_first(c) minus the first dof of its group.  The rows of
a group have one length (its stride), so the entry (j, l) is at

    P[run(j), run(l)] + (j - first(run(j))) stride(run(j)) + (l - first(run(l))).
"""
import numpy as np
import scipy.sparse as sp

CHUNK = 2 ** 20  # element-matrix entries scattered per call
KEYS_PER_BLOCK = 2 ** 20  # group pairs located per search (pair_positions; 2^22: twice the peak, no faster)


def index_type(*sizes):
    """int32 while the sizes fit, else int64."""
    return np.int32 if max(sizes, default=0) < 2 ** 31 else np.int64


def sort_with_order(keys):
    """(sorted keys, the order that sorts them) of non-negative int64 keys, ties in their
    order: one sort of each key with its index in the low bits where both fit in 63 bits
    (np.sort of plain integers is much faster than np.argsort), else an argsort."""
    bits = max(keys.size - 1, 0).bit_length()
    if keys.size and int(keys.max()).bit_length() + bits <= 63:
        packed = keys << bits
        packed |= np.arange(keys.size)
        packed.sort()
        ordered = packed >> bits
        packed &= (1 << bits) - 1
        return ordered, packed
    order = np.argsort(keys, kind="stable")
    return keys[order], order


def changes(ordered):
    """True where a sorted array's entry differs from the one before (and at the first)."""
    new = np.empty(ordered.size, bool)
    new[:1] = True
    np.not_equal(ordered[1:], ordered[:-1], out=new[1:])
    return new


def run_numbers(starts, dtype=np.int64):
    """The run of each entry, 0, 1, ..., runs beginning where `starts` is True (starts[0]
    True): cumsum(starts) - 1 in `dtype` (numpy's cumsum of booleans without a dtype takes
    a slow casting loop, up to 15x slower)."""
    rank = np.cumsum(starts, dtype=dtype)
    rank -= 1
    return rank


def distinct(keys, dtype=np.int64):
    """(the distinct keys, sorted; the index of each key among them, in `dtype`): one sort."""
    ordered, order = sort_with_order(keys)
    new = changes(ordered)
    inverse = np.empty(keys.size, dtype)
    inverse[order] = run_numbers(new, dtype)
    return ordered[new], inverse


def group_pattern(groups, G, keep=None):
    """The CSR pattern (indptr, indices) on G groups of the pairs (g, h) of groups that share
    an element of some map: the pattern of sum_m B_m^T B_m, B_m (E, G) the incidence of
    the elements' groups `groups` = [g_m (E, r)]; with the pairs `keep` = (rows, columns)
    (of an earlier pattern) added.  Index arrays are int32 while they fit."""
    S = sp.csr_matrix((G, G), dtype=np.float32)
    for g in groups:
        E, r = g.shape
        B = sp.csr_matrix((np.ones(E * r, np.float32), g.ravel(), np.arange(0, E * r + 1, r)), shape=(E, G))
        S = S + (B.T @ B).tocsr()  # (entries: counts >= 1, none cancels)
    if keep is not None:
        rows, columns = keep
        S = S + sp.csr_matrix((np.ones(rows.size, np.float32), (rows, columns)), shape=(G, G))
    S.sort_indices()
    index = index_type(S.nnz, G)
    return S.indptr.astype(index), S.indices.astype(index)


def pair_positions(g, search, G, index):
    """The position in the group pattern of every pair of groups of the elements g (E, r):
    (E, r, r) in `index`, or None when the pattern lacks one; search = (held, diagonal,
    transposed): the sorted keys g * G + h of the pattern's entries and its symmetric_maps.
    Only the pairs of local groups a < c are searched, by blocks of elements (each block's
    distinct pairs located by one search; its pairs are not all held at once): the pattern is
    symmetric, so (c, a) is at transposed[position of (a, c)] and (a, a) at diagonal[g_a]."""
    held, diagonal, transposed = search
    E, r = g.shape
    position = np.empty((E, r, r), index)
    a, c = np.triu_indices(r, 1)
    step = max(1, KEYS_PER_BLOCK // max(a.size, 1))
    for s in range(0, E, step):
        b = g[s:s + step].astype(np.int64)
        block = position[s:s + step]
        own = diagonal[b]
        if np.any(own < 0):
            return None
        block[:, np.arange(r), np.arange(r)] = own
        if not a.size:
            continue
        keys, rank = distinct((b[:, a] * G + b[:, c]).ravel(), index_type(b.shape[0] * a.size))
        where = np.minimum(np.searchsorted(held, keys), max(held.size - 1, 0))
        if held.size == 0 or not np.array_equal(held[where], keys):
            return None
        upper = where.astype(index)[rank].reshape(b.shape[0], a.size)
        block[:, a, c] = upper
        block[:, c, a] = transposed[upper]
    return position


def symmetric_maps(indptr, indices, held):
    """Of a symmetric CSR pattern with sorted rows (keys `held`): the position of each
    diagonal entry (g, g) (-1 where the pattern lacks it), and the transposition: the position
    of (h, g) at the position of (g, h) (the CSC order of the positions, a counting sort)."""
    G = indptr.size - 1
    keys = np.arange(G, dtype=np.int64) * (G + 1)
    diagonal = np.full(G, -1, np.int64)
    if held.size:
        where = np.minimum(np.searchsorted(held, keys), held.size - 1)
        found = held[where] == keys
        diagonal[found] = where[found]
    positions = sp.csr_matrix((np.arange(indices.size, dtype=indices.dtype), indices, indptr), shape=(G, G))
    return diagonal, positions.tocsc().data


def dof_groups(maps, n):
    """The group of each of the n dofs: d and d + 1 are in one group when every element
    of the local-to-global maps (E, k) that holds one of them holds d + 1 right after d."""
    joined = np.zeros(n, bool)  # joined[d]: d and d + 1 in one group
    joined[:-1] = True
    held = np.zeros(n, bool)
    for D in maps:
        if D.size == 0:
            continue
        held[D] = True
        follows = np.zeros(D.shape, bool)
        follows[:, :-1] = D[:, 1:] == D[:, :-1] + 1
        joined[D[~follows]] = False  # a d not followed by d + 1
        led = np.ones(D.shape, bool)
        led[:, 1:] = ~follows[:, :-1]
        d = D[led]
        joined[d[d > 0] - 1] = False  # a d not preceded by d - 1
    joined[:-1] &= held[:-1] & held[1:]
    starts = np.ones(n, bool)
    starts[1:] = ~joined[:-1]
    return run_numbers(starts, index_type(n))


def runs(D, group):
    """The first local column of each run of a map D (E, k): columns j - 1, j are in one
    run when D[:, j] = D[:, j - 1] + 1 in the same group on every element."""
    j = 1 + np.flatnonzero((D[:, 1:] == D[:, :-1] + 1).all(axis=0))  # consecutive dofs
    split = np.ones(D.shape[1], bool)
    split[j] = ~(group[D[:, j]] == group[D[:, j - 1]]).all(axis=0)  # ... of one group
    return np.flatnonzero(split)


class Pattern:
    """The CSR pattern (indptr, indices, nnz) of the element matrices on the given
    local-to-global maps (and of the entries of an earlier pattern `keep` = (indptr,
    indices), so that a pattern only grows), with one Scatter per map (`scatters`)."""

    def __init__(self, maps, n, keep=None):
        self.n = n
        self.group = dof_groups(maps, n)
        G = int(self.group[-1]) + 1 if n else 0
        self.start = np.flatnonzero(np.diff(self.group, prepend=-1)).astype(self.group.dtype)  # of each group
        size = np.diff(np.append(self.start, n))
        firsts = [runs(D, self.group) for D in maps]
        if keep is not None:
            keep = (self.group[np.repeat(np.arange(n), np.diff(keep[0]))], self.group[keep[1]])
        self.group_indptr, self.group_indices = group_pattern(
            [self.group[D[:, f]] for D, f in zip(maps, firsts)], G, keep)
        if G == n:  # groups of one dof: the group pattern is the pattern
            self.indptr, self.indices = self.group_indptr, self.group_indices
            self.nnz = self.indices.size
            self.offset = None  # of every group entry: 0
        else:
            self._expand(size)
        search = self._search()  # (once for all maps)
        self.scatters = [self._located(D, f, search) for D, f in zip(maps, firsts)]

    def _expand(self, size):
        """The dof pattern from the group pattern (groups of `size` dofs): every dof row of
        group g holds the columns of every group h of row g; offset: each group entry's first
        column within the dof rows of g."""
        n = self.n
        width = size[self.group_indices]
        before = np.concatenate([[0], np.cumsum(width)])  # columns before each entry, all rows
        row_start = before[self.group_indptr[:-1]]
        length = (before[self.group_indptr[1:]] - row_start)[self.group]  # of each dof row
        nnz = int(length.sum())
        index = index_type(nnz, n)
        before, row_start = before.astype(index), row_start.astype(index)
        self.offset = before[:-1] - np.repeat(row_start, np.diff(self.group_indptr))
        self.indptr = np.zeros(n + 1, index)
        np.cumsum(length, out=self.indptr[1:])
        columns = np.repeat((self.start[self.group_indices] - before[:-1]).astype(index), width) \
            + np.arange(before[-1], dtype=index)  # the columns of each group row
        self.indices = columns[np.repeat(row_start[self.group] - self.indptr[:-1], length)
                               + np.arange(nnz, dtype=index)]
        self.nnz = nnz

    @property
    def nbytes(self):
        """Bytes kept: the CSR pattern, its groups and the scatters."""
        kept = {id(a): a for a in (self.indptr, self.indices, self.group, self.start, self.offset,
                                   self.group_indptr, self.group_indices) if a is not None}
        return sum(a.nbytes for a in kept.values()) + sum(s.nbytes for s in self.scatters)

    def scatter(self, D):
        """The Scatter of the map D if the pattern holds all of its entries, else None."""
        return self._located(D, runs(D, self.group), self._search())

    def _search(self):
        """What pair_positions searches: the sorted keys g * G + h of the group pattern's
        entries, and its symmetric_maps."""
        G = np.int64(self.start.size)
        held = np.repeat(np.arange(G), np.diff(self.group_indptr)) * G + self.group_indices
        return (held,) + symmetric_maps(self.group_indptr, self.group_indices, held)

    def _located(self, D, first, search):
        """The Scatter of the map D (first: the first local column of each run) from the
        positions of its group pairs (search: see _search), or None if one is missing."""
        G = np.int64(self.start.size)
        position = pair_positions(self.group[D[:, first]], search, G, self.group_indptr.dtype)
        return None if position is None else Scatter(self, D, first, position)


class Scatter:
    """The element matrices (E, k, k) on one local-to-global map D into the CSR data of a
    Pattern, by blocks (module docstring).  The position P[a, c] of the first entry of each
    pair of runs is kept as its offset R = P - indptr[D_first(a)] in the row of the run's
    first dof (E, r, r), in the smallest unsigned type that holds the longest row (uint8 for
    rows of at most 256 entries: a quarter of P's memory, 54 MB less for the two membranes
    at 522k unknowns); the rows' starts and lengths are read from the pattern's indptr and
    the map D (the term's own array, which the Scatter refers to) chunk by chunk."""

    def __init__(self, pattern, D, first, position):
        E, k = D.shape
        index = pattern.indptr.dtype
        self.indptr, self.D, self.first = pattern.indptr, D, first
        self.strided = first.size != k  # runs of more than one column
        self.run = np.repeat(np.arange(first.size), np.diff(np.append(first, k)))  # of each column
        self.shift = (np.arange(k) - first[self.run]).astype(index)  # column within its run
        lead = D[:, first]
        position = position.reshape(E, first.size, first.size)
        start = pattern.indptr[lead]
        if pattern.offset is None:  # groups of one dof: the group pattern's positions are these
            R = position
            R -= start[:, :, None]
        else:
            R = pattern.offset[position] + (lead - pattern.start[pattern.group[lead]])[:, None, :]
        longest = int(np.diff(pattern.indptr).max(initial=0))
        self.R = R.astype(np.uint8 if longest <= 2 ** 8 else np.uint16 if longest <= 2 ** 16 else index)

    @property
    def nbytes(self):
        return sum(a.nbytes for a in (self.R, self.run, self.shift))

    def positions(self, elements=slice(None)):
        """The positions in the CSR data of the entries (j, l) of the element matrices of the
        given elements: P[run(j), run(l)] + shift(j) stride(run(j)) + shift(l), P[a, c] =
        indptr[D_first(a)] + R[a, c] and stride(a) the length of the row of D_first(a)."""
        lead = self.D[elements][:, self.first] if self.strided else self.D[elements]
        start = self.indptr[lead]
        P = start[:, :, None] + self.R[elements]
        if not self.strided:
            return P
        P = P[:, self.run[:, None], self.run]
        stride = self.indptr[lead + 1] - start
        P += (stride[:, self.run] * self.shift)[:, :, None]
        P += self.shift
        return P

    def add_pieces(self, data, pieces):
        """data += the element matrices given piece by piece, (rows, H) with H (e, k, k) those
        of the elements `rows` (a slice or increasing indices; the pieces in increasing
        order: a kernel's calls), entry by entry in element order: the same sums in the same
        order as add() of all of them at once (bitwise equal), without an array of all of
        them.  Element matrices that are exact zeros are left out (adding +-0 to a sum
        changes no value).  Returns the number of non-zero element matrices."""
        count = 0
        for rows, H in pieces:
            nonzero = H.any(axis=tuple(range(1, H.ndim)))
            count += int(np.count_nonzero(nonzero))
            if not nonzero.all():
                rows = np.flatnonzero(nonzero) + rows.start if isinstance(rows, slice) else rows[nonzero]
                H = H[nonzero]
            self.add(data, H, rows)
        return count

    def add(self, data, H, rows=0):
        """data += the element matrices H (e, k, k) of the elements `rows` (the first of e
        consecutive ones, a slice or indices), entry by entry in element order (np.add.at,
        in chunks of elements: no index array of all of them)."""
        e, k = H.shape[:2]
        if isinstance(rows, (int, np.integer)):
            rows = slice(rows, rows + e)
        step = max(1, CHUNK // (k * k))
        for s in range(0, e, step):
            part = slice(rows.start + s, rows.start + min(s + step, e)) if isinstance(rows, slice) \
                else rows[s:s + step]
            np.add.at(data, self.positions(part).ravel(), H[s:s + step].ravel())
