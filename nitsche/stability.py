"""The stability limits of alpha0: inverse estimates, cell by cell.

With alpha = alpha0_T h_T^k / stiffness on the elements T of a constraint, the Hessian of
J_h is at least  K - sum_T alpha0_T B_T  (K: Hessian of the energy J; B_T: Hessian of
int_T 1/2 (alpha/alpha0) lambda^2 = sum_q W (alpha/alpha0) D lambda^T D lambda for a linear
lambda; the [.]_+ term only adds a positive semidefinite part).
Write K = sum_C K_C + R, K_C the Hessian of all of the energy's cell terms on cell C and
R >= 0 the rest (e.g. facet terms of a convex energy), and B_C = sum of the B_T of the
elements T owned by C (a facet by the cell it bounds, a cell by itself).  If on every cell

    alpha0_C v^T B_C v <= v^T K_C v    for all local v (fixed dofs zero),           (*)

then summing over the cells, sum_T alpha0_T v^T B_T v <= sum_C v^T K_C v <= v^T K v: J_h is
convex.  The largest alpha0_C in (*) is the local limit 1/mu_C, mu_C the largest eigenvalue
of B_C v = mu K_C v on the local space modulo the kernel of K_C (B_C vanishes there: lambda
does not see the energy's kernel, e.g. rigid motions).  Constraints sharing a cell share its
K_C: J_h is convex when on every cell sum_c alpha0_c / limit_c <= 1 ('auto' takes 1/2 of
each limit: two constraints on a cell).  The limit depends on the cell's shape, not its
size, so graded and anisotropic meshes get a small alpha0 only where their cells need it.

The cells' problems are small and dense; all are solved at once (batched).  The global
pencil B v = mu K v (one value for the whole mesh, sparse LU) stays as a diagnostic.
"""
import numpy as np
import scipy.linalg as sla
import scipy.sparse as sp
import scipy.sparse.linalg as spla

from .conditioning import start_vector

DENSE_LIMIT = 3000
NEGLIGIBLE = 1e-8  # mu below this: the multiplier does not depend on u (e.g. P1 Laplacian)
BATCH_ENTRIES = 2 ** 22  # numbers per dense batch of cells (32 MB; the cells are chunked)
KERNEL_SHIFT = 1e-10  # S K S + shift I (S = diag(K)^-1/2): the kernel of K, where B vanishes
SHIFT_SHARE = 1e-2  # mu above SHIFT_SHARE trace(S B S) / shift: B does not vanish on ker K
GLOBAL_SHIFT_SHARE = 0.5  # global check: an eigenvector whose K_s-energy is mostly shift


class SingularEnergy(ValueError):
    """K is singular (or indefinite) on a direction where B is not zero: C_I is undefined."""


def local_limits(G, B_dofs, owners, free, cell_hessians):
    """The local limit 1/mu_C of each constraint element's cell C (inf where mu_C = 0; 0 where
    B_C does not vanish on the kernel of K_C: the cell's energy does not bound lambda).

    G: (elements, points, m) sqrt(W alpha/alpha0) D lambda at the element's quadrature
    points, so that B_T = G^T G (the Hessian of int_T 1/2 (alpha/alpha0) lambda^2 for a
    linear lambda); B_dofs (elements, m) the global dofs; owners (elements,) the cells;
    free: boolean mask of the free global dofs; cell_hessians(cells) -> [(K_e (cells, n_e,
    n_e), dofs (cells, n_e))] the Hessians of the energy's cell terms on those cells.
    The cells are taken in chunks that keep each dense batch near BATCH_ENTRIES numbers.
    Elements where D lambda vanishes (e.g. lambda = -lap u - f with P1) have B_T = 0: no
    limit, and their cells are not solved."""
    moving = np.abs(G).max(axis=(1, 2)) > 0 if G.size else np.zeros(len(owners), bool)
    limit = np.full(len(owners), np.inf)
    if moving.any():
        limit[moving] = _limits(G[moving], B_dofs[moving], owners[moving], free, cell_hessians)
    return limit


def _limits(G, B_dofs, owners, free, cell_hessians):
    """local_limits of elements with B_T != 0."""
    cells, owner = np.unique(owners, return_inverse=True)
    order = np.argsort(owner, kind="stable")
    starts = np.searchsorted(owner[order], np.arange(cells.size + 1))
    step = max(1, BATCH_ENTRIES // (4 * B_dofs.shape[1] ** 2))
    limit = np.empty(cells.size)
    for a in range(0, cells.size, step):
        b = min(a + step, cells.size)
        mine = order[starts[a]: starts[b]]  # the elements of cells a .. b-1
        limit[a:b] = _cell_limits(G[mine], B_dofs[mine], owner[mine] - a, cells[a:b], free,
                                  cell_hessians)
    return limit[owner]


def _cell_limits(G, B_dofs, owner, cells, free, cell_hessians):
    """local_limits for the elements of the given cells (owner: index into cells)."""
    rank = _rank_within(owner, cells.size)  # the element's slot among those of its cell
    (_, q, m), slots = G.shape, int(rank.max()) + 1
    columns = rank[:, None] * m + np.arange(m)
    side_by_side = np.full((cells.size, slots * m), -1, dtype=np.int64)
    side_by_side[owner[:, None], columns] = B_dofs
    K_parts = cell_hessians(cells)
    local, positions = _numbering([d for _, d in K_parts] + [side_by_side])
    n = local.shape[1]
    K = sum(_scatter(Ke, np.arange(cells.size), pos, n, cells.size)
            for (Ke, _), pos in zip(K_parts, positions))
    rows = owner[:, None] * (slots * q) + rank[:, None] * q + np.arange(q)  # B_C = Gc^T Gc:
    index = rows[:, :, None] * n + positions[-1][owner[:, None], columns][:, None, :]  # its rows
    Gc = np.bincount(index.ravel(), weights=G.ravel(),
                     minlength=cells.size * slots * q * n).reshape(cells.size, slots * q, n)
    mu = largest_local_eigenvalues(Gc, K, (local >= 0) & free[np.maximum(local, 0)])
    with np.errstate(divide="ignore"):
        return np.where(mu > 0, 1.0 / mu, np.inf)


def largest_local_eigenvalues(G, K, mask):
    """max v^T B v / v^T K v, B = G^T G, of each (G, K) in a batch over the components in mask
    (the others are zero), on the complement of the kernel of K where B vanishes: with
    S = diag(K)^-1/2 (the dofs' scales may differ by powers of h, e.g. Hermite dofs) and
    L L^T = S K S + 1e-10 I, the largest eigenvalue of H^T H = L^-1 S B S L^-T, H = G S L^-T
    (or of H H^T when G has fewer rows than columns).  inf where that value comes from the
    shift (1e-10 mu > 1e-2 trace(S B S)): B does not vanish on the kernel of K."""
    diagonal = np.diagonal(K, axis1=1, axis2=2)
    s = np.where(mask, 1 / np.sqrt(np.where(diagonal > 0, diagonal, 1.0)), 0.0)
    K = K * (s[:, :, None] * s[:, None, :])
    shift = np.where(mask, KERNEL_SHIFT, 1.0)  # left-out components: K = 1, B = 0
    try:
        Li = np.linalg.inv(np.linalg.cholesky(K + shift[:, :, None] * np.eye(K.shape[1])))
    except np.linalg.LinAlgError:
        raise ValueError("the energy's Hessian is not positive semidefinite on a cell") from None
    Gs = G * s[:, None, :]
    H = Gs @ np.swapaxes(Li, 1, 2)
    Ht = np.swapaxes(H, 1, 2)
    mu = np.linalg.eigvalsh(H @ Ht if H.shape[1] < H.shape[2] else Ht @ H)[:, -1]
    mu = np.where(KERNEL_SHIFT * mu > SHIFT_SHARE * np.sum(Gs ** 2, axis=(1, 2)), np.inf, mu)
    return np.where(mu > NEGLIGIBLE, mu, 0.0)


def _rank_within(group, ngroups):
    """0, 1, ... for the members of each group, in order."""
    order = np.argsort(group, kind="stable")
    first = np.searchsorted(group[order], np.arange(ngroups))
    rank = np.empty_like(group)
    rank[order] = np.arange(group.size) - first[group[order]]
    return rank


def _numbering(blocks):
    """Rows of global dofs (-1: none) numbered locally: per row the distinct dofs of all the
    blocks, sorted (padded with -1), and each block's positions among them."""
    dofs = np.concatenate(blocks, axis=1)
    order = np.argsort(dofs, axis=1, kind="stable")
    s = np.take_along_axis(dofs, order, axis=1)
    new = np.ones_like(s, dtype=bool)
    new[:, 1:] = s[:, 1:] != s[:, :-1]
    new &= s >= 0
    rank = np.cumsum(new, axis=1, dtype=np.int64)  # (a dtype: the fast loop for booleans)
    rank -= 1
    local = np.full((dofs.shape[0], int(rank[:, -1].max()) + 1), -1, dtype=np.int64)
    r, c = np.nonzero(new)
    local[r, rank[r, c]] = s[r, c]
    positions = np.empty_like(rank)
    np.put_along_axis(positions, order, np.where(s >= 0, rank, -1), axis=1)
    return local, np.split(positions, np.cumsum([b.shape[1] for b in blocks])[:-1], axis=1)


def _scatter(H, target, pos, n, count):
    """The element matrices H (k, a, a) summed into a batch (count, n, n): H[i] into the rows
    and columns pos[i] of matrix target[i]."""
    index = (target[:, None, None] * n + pos[:, :, None]) * n + pos[:, None, :]
    return np.bincount(index.ravel(), weights=H.ravel(), minlength=count * n * n).reshape(count, n, n)


def largest_generalized_eigenvalue(B, K):
    """max v^T B v / v^T K v for sparse symmetric B >= 0 and K >= 0 (the global check): with
    S = diag(K)^-1/2, of S B S v = mu K_s v, K_s = S K S + 1e-10 I (K may have a kernel,
    where B vanishes).  Where B does not vanish on the kernel, mu ~ v^T B v / 1e-10 is an
    artefact of the shift: then v^T K_s v is mostly the shift's, and SingularEnergy is
    raised (also when K is zero or indefinite)."""
    n = K.shape[0]
    if B.nnz == 0 or abs(B).max() == 0:
        return 0.0
    d = K.diagonal()
    if not np.any(d > 0):
        raise SingularEnergy("K has no positive diagonal")
    S = sp.diags(np.where(d > 0, 1 / np.sqrt(np.abs(d) + (d <= 0)), 1.0))
    B, Ks = S @ B @ S, (S @ K @ S + KERNEL_SHIFT * sp.eye(n)).tocsc()
    try:
        if n <= DENSE_LIMIT:
            w, v = sla.eigh(B.toarray(), Ks.toarray(), subset_by_index=[n - 1, n - 1])
            mu, v = float(w[0]), v[:, 0]
        else:
            lu = spla.splu(Ks, permc_spec="MMD_AT_PLUS_A", diag_pivot_thresh=0.0,
                           options=dict(SymmetricMode=True))  # P K_s P^T = L D L^T
            if not np.all(lu.U.diagonal() > 0):  # the pivots D have the signs of K_s's eigenvalues
                raise SingularEnergy("K_s has a pivot <= 0: K is indefinite")
            op = spla.LinearOperator((n, n), matvec=lambda v: lu.solve(B @ v))
            w, v = spla.eigs(op, k=1, which="LR", tol=1e-3, v0=start_vector(n))  # 3 digits suffice
            mu, v = float(np.real(w[0])), np.real(v[:, 0])
    except (np.linalg.LinAlgError, RuntimeError) as e:  # K_s not positive definite, or singular
        raise SingularEnergy(str(e)) from None
    if mu <= NEGLIGIBLE:
        return 0.0
    energy = float(v @ (Ks @ v))
    if not 0 < KERNEL_SHIFT * float(v @ v) <= GLOBAL_SHIFT_SHARE * energy:
        raise SingularEnergy(f"the eigenvector's K_s-energy {energy:.3g} is mostly the shift")
    return mu