"""The CSR sparsity pattern of a sum of element matrices, built on groups of dofs, and the
scatter of element matrices into it by blocks.

The dofs fall into groups: runs of consecutive dofs that every element holds together,
in consecutive local positions (a vector Lagrange field's components at a node; a
scalar field's dofs are groups of one).  The pattern is built on the groups, from the
pairs (g, h) of groups that share an element (one sort of the E r^2 group pairs of E
elements of r groups each, instead of the E k^2 entries of their k x k matrices), then
expanded: every dof row of group g holds the columns of every group h of row g, so a
vector field's pattern is its node pattern with full b x b blocks and no structurally
zero blocks.

An element's local columns fall into runs (consecutive dofs of one group, the same local
columns on every element of a map); its matrix enters by blocks, one offset q[a, c] per
pair of runs (a, c), the position P[a, c] of the entry (first(a), first(c)): the start of
the row of dof D_first(a), plus the columns of the groups before group(D_first(c)) in the
rows of group(D_first(a)), plus D_first(c) minus the first dof of its group.  The rows of
a group have one length (its stride), so the entry (j, l) is at

    P[run(j), run(l)] + (j - first(run(j))) stride(run(j)) + (l - first(run(l))).
"""
import numpy as np

CHUNK = 2 ** 20  # element-matrix entries scattered per call


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


def csr_pattern(keys, n):
    """The CSR pattern (indptr, indices) of an n x n matrix with entries at the keys
    row * n + column (repeated keys: one entry), and each key's position in it: one sort
    of the keys.  Index arrays are int32 while they fit."""
    ordered, order = sort_with_order(keys)
    new = changes(ordered)
    rows, columns = np.divmod(ordered[new], n)
    index = index_type(rows.size, n)
    position = np.empty(keys.size, index)
    position[order] = run_numbers(new, index)
    indptr = np.zeros(n + 1, index)
    np.cumsum(np.bincount(rows, minlength=n), out=indptr[1:])
    return indptr, columns.astype(index), position


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
        keys = [self._pair_keys(D, f) for D, f in zip(maps, firsts)]
        sizes = [k.size for k in keys]
        if keep is not None:
            rows = np.repeat(np.arange(n), np.diff(keep[0]))
            keys.append(self.group[rows] * np.int64(G) + self.group[keep[1]])
        keys = np.concatenate(keys) if keys else np.zeros(0, np.int64)  # one copy kept
        self.group_indptr, self.group_indices, position = csr_pattern(keys, G)
        del keys
        if G == n:  # groups of one dof: the group pattern is the pattern
            self.indptr, self.indices = self.group_indptr, self.group_indices
            self.nnz = self.indices.size
            self.offset = None  # of every group entry: 0
            self.scatters = self._scatters(maps, firsts, position, sizes)
            return
        # each group entry (g, h): its first column within the dof rows of g, and their length
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
        self.scatters = self._scatters(maps, firsts, position, sizes)

    def _scatters(self, maps, firsts, position, sizes):
        """The Scatter of each map from the positions of its group pairs (sizes of each)."""
        return [Scatter(self, D, f, p) for D, f, p in
                zip(maps, firsts, np.split(position[:sum(sizes)], np.cumsum(sizes)[:-1]))]

    @property
    def nbytes(self):
        """Bytes kept: the CSR pattern, its groups and the scatters."""
        kept = {id(a): a for a in (self.indptr, self.indices, self.group, self.start, self.offset,
                                   self.group_indptr, self.group_indices) if a is not None}
        return sum(a.nbytes for a in kept.values()) + sum(s.nbytes for s in self.scatters)

    def _pair_keys(self, D, first):
        """row * G + column of the group pairs of every element of the map D, (E, r, r) raveled."""
        G = np.int64(self.start.size)
        g = self.group[D[:, first]].astype(np.int64)
        return (g[:, :, None] * G + g[:, None, :]).ravel()

    def scatter(self, D):
        """The Scatter of the map D if the pattern holds all of its entries, else None."""
        first = runs(D, self.group)
        keys = self._pair_keys(D, first)
        G = np.int64(self.start.size)
        held = np.repeat(np.arange(G), np.diff(self.group_indptr)) * G + self.group_indices
        position = np.minimum(np.searchsorted(held, keys), held.size - 1)
        if held.size == 0 or not np.array_equal(held[position], keys):
            return None
        return Scatter(self, D, first, position)


class Scatter:
    """The element matrices (E, k, k) on one local-to-global map D into the CSR data of a
    Pattern, by blocks (module docstring): the position P (E, r, r) of the first entry of
    each pair of runs, and the length of the rows of each run's group (E, r)."""

    def __init__(self, pattern, D, first, position):
        E, k = D.shape
        index = pattern.indptr.dtype
        self.run = np.repeat(np.arange(first.size), np.diff(np.append(first, k)))  # of each column
        self.shift = (np.arange(k) - first[self.run]).astype(index)  # column within its run
        lead = D[:, first]
        position = position.reshape(E, first.size, first.size)
        if pattern.offset is None:  # groups of one dof: the group pattern's positions are these
            self.P = position.astype(index)  # (a copy: not a view that keeps all maps' positions)
        else:
            self.P = (pattern.indptr[lead][:, :, None] + pattern.offset[position]
                      + (lead - pattern.start[pattern.group[lead]])[:, None, :]).astype(index)
        self.stride = None if first.size == k else \
            (pattern.indptr[lead + 1] - pattern.indptr[lead]).astype(index)  # None: runs of one column

    @property
    def nbytes(self):
        return sum(a.nbytes for a in (self.P, self.stride, self.run, self.shift) if a is not None)

    def positions(self, elements=slice(None)):
        """The positions in the CSR data of the entries (j, l) of the element matrices of the
        given elements: P[run(j), run(l)] + shift(j) stride[run(j)] + shift(l)."""
        if self.stride is None:
            return self.P[elements]
        P = self.P[elements][:, self.run[:, None], self.run]
        P += (self.stride[elements][:, self.run] * self.shift)[:, :, None]
        P += self.shift
        return P

    def add_pieces(self, data, pieces):
        """data += the element matrices of all elements given piece by piece, (start, H) with
        H (e, k, k) those of the elements start, ..., start + e - 1 in order (a kernel's
        calls): the same sums in the same order as add() of all of them at once (bitwise
        equal), without an array of all of them.  Runs of one column: summed into zeros
        entry by entry in element order, as add's one bincount, then added to data."""
        if self.stride is not None:
            for start, H in pieces:
                self.add(data, H, start)
            return
        total = np.zeros_like(data)
        for start, H in pieces:
            np.add.at(total, self.P[start:start + len(H)].ravel(), H.ravel())
        data += total

    def add(self, data, H, start=0):
        """data += the element matrices H (e, k, k) of the elements start, start + 1, ...:
        by one bincount for all elements with kept positions (runs of one column), else in
        chunks of elements."""
        e, k = H.shape[:2]
        if self.stride is None and e == len(self.P):
            data += np.bincount(self.P.ravel(), weights=H.ravel(), minlength=data.size)
            return
        step = max(1, CHUNK // (k * k))
        for s in range(0, e, step):
            np.add.at(data, self.positions(slice(start + s, start + min(s + step, e))).ravel(),
                      H[s:s + step].ravel())
