"""A constrained problem: fields, energy J, constraints; its Nitsche functional J_h."""
import warnings

import numpy as np
import scipy.sparse as sp

from . import partition
from .assembly import Assembler, ConstantDensity, Parameters, Term, check_arguments
from .functional import Integral
from .linalg import is_significant, make_solver, row_blocks
from .measures import cells
from .stability import SingularEnergy, largest_generalized_eigenvalue


class StabilityWarning(UserWarning):
    """alpha0 exceeds the computed stability limit of a constraint."""


class Problem:
    """minimize J_h(u) = J(u) + sum over constraints of their Nitsche terms.

    fields: list of nitsche.Field (the unknowns, in this order in the dof vector).
    energy: a density of the fields (integrated over the cells of the first
        field's mesh), an Integral, or a list of Integrals.
    constraints: Equality / Inequality / Penalty constraints.
    alpha0_limits: {constraint name: limit}: one stability limit for all elements of a
        constraint (e.g. from stability_limits()) instead of the element-local ones computed here.
    parameters: {name: value}: run-time parameters (a load factor, a time) that densities
        name as arguments like fields; they enter the compiled kernels as data, so
        set_parameters(t=...) changes the problem without compiling anything.

    After construction: limits[name] and alpha0[name] per element of each constraint, and
    alpha0_limits[name] the smallest limit.
    """
    pruned = True  # its Newton matrices hold only the entries significant in some matrix so far (_admit)

    def __init__(self, fields, energy, constraints=(), alpha0_limits=None, parameters=None):
        self.fields = list(fields)
        names = [f.name for f in self.fields]
        if len(set(names)) != len(names):
            raise ValueError(f"field names must be unique, got {names}")
        self.parameters = Parameters(parameters)
        clash = sorted(set(names) & set(self.parameters.names))
        if clash:
            raise ValueError(f"parameter names {clash} are also field names; rename one")
        self.by_name = {f.name: f for f in self.fields}
        sizes = [f.ndofs for f in self.fields]
        self.offsets = dict(zip(names, np.cumsum([0] + sizes[:-1]).tolist()))
        self.ndofs = int(sum(sizes))
        self.partition = partition.key()  # (rank, ranks): built on this rank's cells only
        self.dim = self.fields[0].mesh.dim()
        fixed = np.concatenate([f.fixed_dofs + self.offsets[f.name] for f in self.fields])
        self.fixed_values = np.concatenate([f.fixed_values for f in self.fields])
        mask = np.ones(self.ndofs, bool)
        mask[fixed] = False
        self.fixed, self.free = fixed, np.flatnonzero(mask)
        if callable(energy):
            energy = Integral(energy, on=cells(self.fields[0]))
        self.integrals = [energy] if isinstance(energy, Integral) else list(energy)
        self.constraints = list(constraints)
        cnames = [c.name for c in self.constraints]
        if len(set(cnames)) != len(cnames):
            raise ValueError(f"constraint names must be unique, got {cnames}: pass name=...")
        self._check_arguments()
        self.energy_terms = [Term(i.pointwise(), i.names, i.on, self.fields, self.offsets,
                                  f"the {'residual' if i.residual else 'energy'} density",
                                  residual=i.residual, parameters=self.parameters)
                             for i in self.integrals]
        self.constraint_terms = [Term(c.pointwise(), c.names, c.on, self.fields, self.offsets,
                                      f"constraint '{c.name}'", keep_points=True, residual=c.residual,
                                      parameters=self.parameters)
                                 for c in self.constraints]
        # J_h has a potential (Cholesky, energy line search) unless a term is a residual
        self.symmetric = not any(t.residual for t in self.energy_terms + self.constraint_terms)
        self._resolve_alpha0(dict(alpha0_limits or {}))
        self.assembler = Assembler(self.energy_terms + self.constraint_terms, self.ndofs)
        self.value_terms = [t.with_pointwise(c.values())  # (after the assembler: the maps it shares)
                            for c, t in zip(self.constraints, self.constraint_terms)]
        self.sliding = [i for i, c in enumerate(self.constraints) if hasattr(c.on, "pair")]
        self._isfree = np.zeros(self.ndofs, bool)
        self._isfree[self.free] = True
        self._reset_kept()
        self._release_measures()

    def _release_measures(self):
        for m in {id(i.on): i.on for i in self.integrals + self.constraints}.values():
            m.release()
        self.release_mappings()

    def release_mappings(self):
        """Drop scikit-fem's cached mapping of the fields' meshes (A, b, det A and A^-1 of
        every cell: 88 MB at 1M triangles), which the terms no longer read once built: a
        later reader (outputs, a new term) makes it again, the same arrays."""
        for mesh in {id(f.mesh): f.mesh for f in self.fields}.values():
            mesh.__dict__.pop("_cached_mapping", None)

    def _check_arguments(self):
        """Every argument of a constraint's gap and multiplier names a field or x, n, h."""
        p = self.parameters.names
        for c in self.constraints:
            check_arguments(c.gap_names, self.by_name, f"the gap of constraint '{c.name}'", p)
            check_arguments(c.multiplier_names, self.by_name, f"the multiplier of constraint '{c.name}'", p)

    # -- alpha0 -----------------------------------------------------------------
    def _resolve_alpha0(self, given):
        """alpha0 per element of every constraint, as data of its term (the user's Scaling is
        left as given); a given value above an element's limit warns."""
        self.limits, self.alpha0 = {}, {}
        needs = [c for c in self.constraints if c.multiplier is not None and c.name not in given
                 and (c.scaling.needs_limit or self._multiplier_on_own_mesh(c))]
        local = self.local_limits(needs)
        for c in needs:
            unbounded = int((local[c.name] == 0).sum())
            if not unbounded:
                continue
            why = (f"on {unbounded} of its elements {UNBOUNDED}")
            if c.scaling.needs_limit:
                raise ValueError(f"alpha0={c.scaling.alpha0!r} for constraint '{c.name}': {why}; "
                                 f"give alpha0 as a number, or fix {FIX}")
            warnings.warn(f"constraint '{c.name}': alpha0 is not checked against a stability "
                          f"limit {why}", StabilityWarning)
        for c, t in zip(self.constraints, self.constraint_terms):
            limit = np.full(t.nel, given[c.name], dtype=float) if c.name in given \
                else local.get(c.name, np.full(t.nel, np.inf))
            x = centroids(t) if callable(c.scaling.alpha0) else None  # (read by a function alpha0 only)
            alpha0 = c.scaling.per_element(limit, x, t.h)
            self.limits[c.name], self.alpha0[c.name] = limit, alpha0
            t.alpha0 = alpha0
            # (limit 0: no limit, warned above; theta = -1 is stable for every alpha0)
            over = (alpha0 >= limit) & (limit > 0) & (c.theta != -1)
            if over.any():
                warnings.warn(f"constraint '{c.name}': alpha0 = {alpha0[over].max():g} exceeds the "
                              f"stability limit {limit[over].min():.4g} on {over.sum()} of {t.nel} "
                              f"elements (J_h may not be convex; Newton may fail); use a smaller "
                              f"alpha0 or alpha0='auto'", StabilityWarning)
        self.alpha0_limits = {c.name: float(self.limits[c.name].min(initial=np.inf)) for c in self.constraints
                              if c.multiplier is not None}

    def local_limits(self, constraints=None, x=None):
        """{constraint name: the element-local stability limit of alpha0 on each element}
        (nitsche.stability): batched eigenproblems of the cells that own the elements."""
        from .stability import local_limits
        names = {c.name for c in (self.constraints if constraints is None else constraints)}
        x = self.initial(None) if x is None else x
        free = np.zeros(self.ndofs, bool)
        free[self.free] = True
        out = {}
        for c, t in zip(self.constraints, self.constraint_terms):
            if c.name not in names or c.multiplier is None:
                continue
            if not any(k in self.by_name for k in c.multiplier_names):  # lambda = q given: B = 0
                out[c.name] = np.full(t.nel, np.inf)
                continue
            mesh = c.on.mesh
            if not self._multiplier_on_own_mesh(c):
                raise ValueError(f"constraint '{c.name}': element-local alpha0 limits need the "
                                 "multiplier's fields on the constraint's own mesh; give alpha0 as "
                                 "a number (Problem.stability_limits() checks it)")
            energy = [e for e in self.energy_terms
                      if e.measure.kind == "cells" and e.measure.mesh is mesh]
            if not energy:
                raise ValueError(f"constraint '{c.name}': the energy has no cell term on the "
                                 "constraint's mesh to bound its multiplier")
            B = self._multiplier_term(c, like=t)  # the multiplier's jets only, alpha0 = 1
            if not reads_fields(B):  # D lambda = 0 (e.g. -T lap u - f with P1): B_T = 0
                out[c.name] = np.full(t.nel, np.inf)
                continue
            out[c.name] = local_limits(*multiplier_jacobian(B, c, x), t.cells, free,
                                       lambda cells: [cell_hessians(e, x, cells) for e in energy])
        return out

    @property
    def convex(self):
        """Whether J_h is convex, certified term by term (once): every energy term a convex
        quadratic form (Term.is_convex_quadratic), and every constraint a functional (theta =
        1) with a convex potential phi whose multiplier does not depend on the fields (D lambda
        = 0: a penalty, a given lambda, or e.g. f + lap u with P1 elements) and whose gap g is
        affine in them (Term.is_affine): its density -alpha lambda^2 / 2 + alpha phi(lambda -
        g/alpha) is then a constant plus a convex function of an affine map.  (Contact paired
        on the current configuration is not certified.)  A stationary point of a convex J_h is
        a minimum: Newton's minimum check then needs no factorization."""
        if not hasattr(self, "_convex"):
            self._convex = not self.sliding and all(t.is_convex_quadratic for t in self.energy_terms) \
                and all(self._convex_constraint(c, t) for c, t in zip(self.constraints, self.constraint_terms))
        return self._convex

    def _convex_constraint(self, c, t):
        """Whether constraint c's term t is convex in the fields (see convex)."""
        if c.residual or not c.projection.convex:
            return False
        if c.multiplier is not None and any(k in self.by_name for k in c.multiplier_names) \
                and reads_fields(self._multiplier_term(c, like=t)):
            return False
        return t.with_pointwise(c.gap_pointwise()).is_affine

    def _multiplier_on_own_mesh(self, c):
        return all(self.by_name[k].mesh is c.on.mesh for k in c.multiplier_names if k in self.by_name)

    def _multiplier_term(self, c, like=None):
        """The term of c.scaled_multiplier() (alpha0 = 1 until set) on c's measure, sharing
        the per-element data of the term `like` there (Term)."""
        return Term(c.scaled_multiplier(), c.multiplier_names, c.on, self.fields, self.offsets,
                    f"the multiplier of constraint '{c.name}'", vector=True, parameters=self.parameters,
                    like=like)

    def _gram(self, c, alpha0=None):
        """B (free dofs): the Gram matrix of sqrt(alpha/alpha0) D lambda of a constraint, or
        of sqrt(alpha) D lambda with the given alpha0 per element (a term with data of its
        own: the constraint's may have released theirs, which reading them would put back)."""
        try:
            term = self._multiplier_term(c)
        except ConstantDensity:  # a given multiplier lambda = q: B = 0
            return None
        if alpha0 is not None:
            term.alpha0 = alpha0
        G, dofs = multiplier_jacobian(term, c, self.initial(None))
        n = dofs.shape[1]
        B = sp.coo_matrix((np.einsum("eqk,eql->ekl", G, G).ravel(),
                           (np.repeat(dofs, n, axis=1).ravel(), np.tile(dofs, (1, n)).ravel())),
                          shape=(self.ndofs, self.ndofs)).tocsr()
        return B[self.free][:, self.free]

    def _stiffness(self):
        """K (free dofs): the Hessian of the energy J."""
        K = Assembler(self.energy_terms, self.ndofs).hessian(self.initial(None))
        return K[self.free][:, self.free]

    def stability_limits(self, constraints=None):
        """Diagnostic: {name: 1/C_I}, the one alpha0 for all elements up to which J_h is
        convex (each constraint alone), C_I the largest eigenvalue of the global pencil
        B v = mu K v (B: Hessian of int 1/2 (alpha/alpha0) lambda^2; sparse LU of K);
        infinite for a multiplier that does not depend on the fields (B = 0)."""
        constraints = self.constraints if constraints is None else constraints
        limits, K = {}, None
        for c in constraints:
            if c.multiplier is None:
                continue
            B = self._gram(c)
            K = self._stiffness() if K is None and B is not None else K
            if B is not None and not (np.isfinite(B.data).all() and np.isfinite(K.data).all()):
                raise ValueError(f"constraint '{c.name}': the Jacobian of its multiplier or the energy's "
                                 "Hessian is not finite at the initial state, so its global stability "
                                 "limit cannot be computed (e.g. the derivative of a norm or a square root "
                                 "at zero); leave out --global-check or make the multiplier "
                                 "differentiable there")
            try:
                mu = 0.0 if B is None else largest_generalized_eigenvalue(B, K)
            except SingularEnergy:
                raise ValueError(f"constraint '{c.name}' has no stability limit of alpha0: "
                                 f"{SINGULAR}; fix {FIX}") from None
            limits[c.name] = 1.0 / mu if mu > 0 else np.inf
        self._release_measures()
        return limits

    def stability_ratio(self):
        """Diagnostic: the largest eigenvalue of B_alpha v = mu K v, B_alpha the Hessian of
        the sum over constraints of int 1/2 alpha lambda^2 with this problem's alpha0 on
        each element: J_h is convex if it is at most 1 (global sparse LU of K)."""
        grams = [self._gram(c, self.alpha0[c.name]) for c in self.constraints
                 if c.multiplier is not None]
        grams = [B for B in grams if B is not None]
        if not grams:
            return 0.0
        ratio = largest_generalized_eigenvalue(sum(grams[1:], grams[0]), self._stiffness())
        self._release_measures()
        return ratio

    # -- vectors ----------------------------------------------------------------
    def initial(self, x0):
        """A full dof vector from x0 (zeros if None) with the fixed values set."""
        x = np.zeros(self.ndofs) if x0 is None else np.array(x0, dtype=float)
        if x.shape != (self.ndofs,):
            raise ValueError(f"initial guess must have {self.ndofs} entries, got {x.shape}")
        x[self.fixed] = self.fixed_values
        return x

    def split(self, x):
        """{field name: its dofs}."""
        return {f.name: x[self.offsets[f.name]: self.offsets[f.name] + f.ndofs] for f in self.fields}

    def set_values(self, name, values):
        """Prescribe new values on the fixed dofs of field `name` (a load step, or the
        previous step's solution in a history field): `values` for its fixed dofs, or a
        full dof vector of the field (its fixed entries are taken)."""
        f = self.by_name[name]
        values = np.asarray(values, dtype=float)
        if values.shape == (f.ndofs,):
            values = values[f.fixed_dofs]
        if values.shape != f.fixed_dofs.shape:
            raise ValueError(f"set_values('{name}', values): give {f.fixed_dofs.size} values (its "
                             f"fixed dofs) or {f.ndofs} (all its dofs), not shape {values.shape}")
        start = sum(g.fixed_dofs.size for g in self.fields[:self.fields.index(f)])
        self.fixed_values[start:start + values.size] = values

    def set_parameters(self, **values):
        """Change run-time parameters (data of the compiled kernels: nothing recompiles)."""
        for k, v in values.items():
            if k not in self.parameters:
                raise ValueError(f"unknown parameter {k!r}; this problem's parameters: "
                                 f"{list(self.parameters.names)}")
            self.parameters.values[self.parameters.names.index(k)] = float(v)

    def scale_alpha0(self, factor):
        """alpha0 <- factor alpha0 on every element of the constraints whose terms are not
        quadratic forms (those are assembled once, with their alpha0): e.g. where J_h has
        lost its convexity on a deformed configuration.  Returns the names scaled."""
        names = []
        for i, (c, t) in enumerate(zip(self.constraints, self.constraint_terms)):
            if c.multiplier is not None and not t.is_quadratic:
                self._set_alpha0(i, self.alpha0[c.name] * factor)
                names.append(c.name)
        return names

    def _set_alpha0(self, i, alpha0):
        """alpha0 per element of constraint i, in its term and in its value term."""
        self.alpha0[self.constraints[i].name] = alpha0
        self.constraint_terms[i].alpha0 = self.value_terms[i].alpha0 = alpha0

    def state(self):
        """The data that changes along a load path: parameter values, prescribed values and
        alpha0 per element of each constraint."""
        return (dict(zip(self.parameters.names, self.parameters.values.tolist())),
                self.fixed_values.copy(), {k: v.copy() for k, v in self.alpha0.items()})

    def set_state(self, state):
        """Restore a state() (e.g. to evaluate a step of a path after it has been solved);
        a state without its third entry (alpha0) leaves alpha0 as it is."""
        self.set_parameters(**state[0])
        self.fixed_values[:] = state[1]
        for i, (c, t) in enumerate(zip(self.constraints, self.constraint_terms)):
            if len(state) > 2 and c.name in state[2] and t.alpha0 is not None:
                self._set_alpha0(i, state[2][c.name].copy())

    def join(self, parts):
        return np.concatenate([np.asarray(parts[f.name], dtype=float) for f in self.fields])

    # -- functional ------------------------------------------------------------
    def energy(self, x):
        """J_h(x)."""
        return self.assembler.energy(x)

    def gradient(self, x):
        """The gradient of J_h at x (all dofs)."""
        return self.assembler.gradient(x)[1]

    def hessian(self, x):
        """Full (generalized) Hessian of J_h at x, CSR."""
        return self.assembler.hessian(x)

    def energy_matrix(self, x=None):
        """Hessian of J alone (all dofs): the energy norm |v|_E^2 = v^T K v."""
        x = self.initial(None) if x is None else x
        return self.assembler.hessian(x, terms=self.energy_terms)

    def _reset_kept(self):
        """The free-free entries the Newton matrices keep: to begin with (and on a grown
        pattern) the free dofs' diagonal; _admit adds the others as they become significant."""
        a = self.assembler
        self._kept = np.zeros(a.nnz, bool)
        for r0, r1 in row_blocks(a.indptr):
            rows = np.repeat(np.arange(r0, r1), np.diff(a.indptr[r0:r1 + 1]))
            p0, p1 = a.indptr[r0], a.indptr[r1]
            self._kept[p0:p1] = (a.indices[p0:p1] == rows) & self._isfree[rows]
        self._ff_indices = None  # the free block's structure: built on the first matrix

    def _admit(self, data):
        """Keep the free-free entries of the Hessian values `data` (the assembler's pattern)
        that are significant (linalg.is_significant: |a_ij| > ROUNDOFF_ENTRY sqrt(|a_ii
        a_jj|)): not an exact zero (the two membranes' coupling off their contact set, half
        of the pattern) nor the round-off of a cancellation.  The kept entries only grow over
        the matrices of one pattern; True when they grew."""
        a = self.assembler
        d = np.sqrt(np.abs(a.matrix(data).diagonal()))
        grew = False
        for r0, r1 in row_blocks(a.indptr):
            p0, p1 = a.indptr[r0], a.indptr[r1]
            new = np.greater(data[p0:p1] != 0, self._kept[p0:p1])  # (non-zero and not kept)
            if not new.any():
                continue
            j = np.flatnonzero(new)
            rows = np.searchsorted(a.indptr[r0 + 1:r1 + 1], p0 + j, side="right") + r0
            columns = a.indices[p0 + j]
            add = is_significant(data[p0 + j], rows, columns, d)
            add &= self._isfree[rows] & self._isfree[columns]
            self._kept[p0 + j[add]] = True
            grew = grew or bool(add.any())
        return grew

    def _free_block(self):
        """The free-free block's CSR structure on the kept entries (_kept, a mask over the
        assembler's pattern: taking by a mask is twice as fast as by indices, at a quarter
        of their memory): their free column numbers and the free rows' starts (rows of
        fixed dofs keep nothing, and the free dofs are ascending, so a free row ends at the
        kept entries' count up to its end).  Positions and counts in the pattern's index
        type (int32 while the entries fit: the same matrix as with int64 ones, half the
        memory)."""
        a = self.assembler
        index = a.indptr.dtype
        self._ff_indices = None  # (the earlier structure not held beside the new one)
        number = np.full(self.ndofs, -1, index)
        number[self.free] = np.arange(self.free.size, dtype=index)
        columns = a.indices[self._kept]
        ends = np.zeros(self.ndofs + 1, index)  # kept entries up to each row's end, by blocks
        for r0, r1 in row_blocks(a.indptr):
            p0 = a.indptr[r0]
            count = np.zeros(a.indptr[r1] - p0 + 1, index)
            np.cumsum(self._kept[p0:a.indptr[r1]], dtype=index, out=count[1:])
            ends[r0 + 1:r1 + 1] = ends[r0] + count[a.indptr[r0 + 1:r1 + 1] - p0]
            block = columns[ends[r0]:ends[r1]]
            block[:] = number[block]  # the columns' free numbers (np.take would convert all
            # of them to int64 and buffer its output: 60 MB more at the two membranes' 522k)
        self._ff_indices, self._ff_indptr = columns, np.concatenate([ends[:1], ends[self.free + 1]])

    def release(self):
        """Drop what only the Newton matrices use (Assembler.release, and the free block's
        kept entries and structure: with them ~120 MB of the two membranes at 522k
        unknowns), for the outputs that follow a solve; built again on first use."""
        self.assembler.release()
        self._kept = self._ff_indices = self._ff_indptr = None

    def _free_matrix(self, data):
        """The free-free block of the CSR matrix with the assembler's pattern and `data`, on
        its kept entries (the significant ones of every matrix so far: the same matrix to
        round-off, which CG, the factorizations and their fill do not pay for the exact
        zeros; a structure that grew is a new symbolic analysis), its values compacted into
        data's first entries and data shrunk to them (`data` is consumed: no copy of the
        values beside it, 61 MB of the two membranes at 1M unknowns)."""
        if self._kept is None:  # (after release)
            self._reset_kept()
        if self._admit(data) or self._ff_indices is None:
            self._free_block()
        values = shrunk(data, compacted(data, self._kept).size)
        n = self.free.size
        return sp.csr_matrix((values, self._ff_indices, self._ff_indptr), shape=(n, n))

    def update_pairing(self, x):
        """Pair the points of every interface with pairing='current' anew at x (nitsche.sliding)
        and tabulate the other body there; True if the Newton matrix's structure changed."""
        grew = False
        parts = self.split(x) if self.sliding else {}
        for i in self.sliding:
            m = self.constraints[i].on
            m.pair(parts[m.mine.name], parts[m.other.name])
            self.constraint_terms[i].retabulate()  # value_terms[i] shares its tabulations
            grew = self.assembler.refresh([self.constraint_terms[i]]) or grew
        if grew:
            self._reset_kept()
        return grew

    def paired_facets(self):
        """The closest facets of the points of every interface paired in the current
        configuration (nitsche.sliding: the memory its hysteresis keeps), by constraint."""
        return {i: self.constraints[i].on.facet.copy() for i in self.sliding}

    def set_paired_facets(self, facets):
        """Put back closest facets taken by paired_facets(); the next update_pairing pairs
        from them (a failed load step's pairing is not the retried step's start)."""
        for i, facet in facets.items():
            self.constraints[i].on.facet = facet.copy()

    def newton_system(self, x):
        """J_h(x), its gradient on the free dofs and the free-free block of the Hessian (for a
        problem with residual terms: the energy terms' J, the residual and its Jacobian)."""
        E, g, data = self.assembler.evaluate(x)
        return E, g[self.free], self._free_matrix(data)

    def moved(self, x0):
        """The increment d = (prescribed values) - x0 on the fixed dofs, or None when x0
        already holds them (to round-off)."""
        d = self.fixed_values - np.asarray(x0, dtype=float)[self.fixed]
        scale = max(np.abs(self.fixed_values).max(initial=0.0), np.abs(x0).max(initial=0.0), 1e-300)
        return d if np.abs(d).max(initial=0.0) > 1e-12 * scale else None

    def lift(self, x0, solve):
        """x0 with the prescribed values set and their increment d carried into the interior
        by the linearization at x0 (a tangent predictor, for an elastic body a linear
        elastic lifting):

            H_ff dx_f = -H_fc d,   H the Hessian (Jacobian) of J_h at x0,

        solve(A, b) solving A y = b on the free dofs.  Returns x0 itself when nothing moved."""
        x0 = np.asarray(x0, dtype=float)
        d = self.moved(x0)
        x = self.initial(x0)
        if d is None:
            return x
        _, _, data = self.assembler.evaluate(x0)
        step = np.zeros(self.ndofs)
        step[self.fixed] = d
        b = -(self.assembler.matrix(data) @ step)[self.free]  # (before data is compacted)
        x[self.free] += solve(self._free_matrix(data), b)
        return x

    def linear_solver(self, name="auto"):
        """A linear solver of its Newton matrices by name (nitsche.linalg.make_solver for its
        free unknowns, dimension and symmetry; nitsche.distributed's problems give a PETSc one)."""
        return make_solver(name, self.free.size, self.dim, self.symmetric)

    def minimize(self, x0=None, **options):
        """Newton's method from x0; see nitsche.newton.newton for the options."""
        from .newton import newton
        return newton(self, x0, **options)

    # -- constraint report ---------------------------------------------------------
    def constraint_values(self, x):
        """Per constraint: g, lambda, alpha, the discrete multiplier lambda_N = P(s),
        s = lambda - g/alpha, and the weights W at its quadrature points (arrays of shape
        (elements, points); for a frictional constraint g, lam and multiplier have a last
        axis (normal, tangential...) and `state` is 0 separation, 1 stick, 2 slip).
        ValueError when g, lambda or alpha is not finite (see check_finite)."""
        out = {}
        for c, t, (g, lam, alpha, P) in self._finite_values(x):
            a = alpha[..., None] if np.ndim(g) == 3 else alpha
            s = np.divide(g, a)
            np.subtract(lam, s, out=s)  # s = lam - g / a, one array
            s_n = s[..., 0] if np.ndim(s) == 3 else s
            out[c.name] = dict(g=g, lam=lam, alpha=alpha, multiplier=P, W=t.W[:t.nel],
                               x=t.x[:t.nel], active=s_n >= 0 if c.inequality else None)
            if c.projection.frictional:
                slipping = np.linalg.norm(s[..., 1:] - P[..., 1:], axis=-1) \
                    > 1e-10 * np.linalg.norm(s[..., 1:], axis=-1)
                out[c.name]["state"] = np.where(s_n > 0, np.where(slipping, 2, 1), 0)
        return out

    def check_finite(self, x):
        """ValueError naming each constraint whose gap g, multiplier lambda or scaling alpha
        is not finite at x (J_h may stay finite: [lambda - NaN/alpha]_+ = 0 would switch
        the constraint off at those points)."""
        self._finite_values(x)

    def _finite_values(self, x):
        """[(constraint, value term, (g, lambda, alpha))] at x, all finite (else ValueError)."""
        rows, bad = self._ingredients(x)
        if bad:
            raise ValueError("; ".join(bad) + "; check the gap and multiplier (log, sqrt, division, "
                             "data) and the initial guess x0")
        return rows

    def _ingredients(self, x):
        """The values (g, lambda, alpha) of each constraint at x, and a sentence for each
        of them that is not finite (how often, and where)."""
        rows, bad = [], []
        for c, t in zip(self.constraints, self.value_terms):
            values = t.run("values", x)
            rows.append((c, t, values))
            for what, v in zip(INGREDIENTS, values):
                v = np.broadcast_to(v, (t.nel, t.nq) + np.shape(v)[2:])
                wrong = ~np.isfinite(v)
                if wrong.any():
                    kind = "NaN" if np.isnan(v[wrong]).all() else \
                        "infinite" if np.isinf(v[wrong]).all() else "NaN or infinite"
                    e, q = np.argwhere(wrong)[0][:2]
                    at = ", ".join(f"{p:.4g}" for p in t.x[e, q])
                    bad.append(f"the {what} of constraint '{c.name}' is {kind} at {wrong.sum()} "
                               f"of {wrong.size} quadrature points, e.g. x = ({at})")
        return rows, bad

    def non_finite(self, x):
        """Why J_h or its gradient is not finite at x (a sentence for error messages): a
        non-finite ingredient (the energy density, a constraint's g, lambda or alpha), or,
        all of them finite, the term that overflows and why."""
        rows, bad = self._ingredients(x)
        for t in self.energy_terms:
            E, g = self.assembler.gradient(x, [t])
            if not (np.isfinite(E) and np.all(np.isfinite(g))):
                bad.append(f"{t.label} overflows: check the magnitudes of the loads/parameters"
                           if np.isinf(E) or np.isinf(g).any() else
                           f"{t.label} is NaN (outside the domain of a log, sqrt or division?)")
        if bad:
            return "; ".join(bad)
        for (c, _, (g, lam, alpha, _)), term in zip(rows, self.constraint_terms):
            E, grad = self.assembler.gradient(x, [term])
            if np.isfinite(E) and np.all(np.isfinite(grad)):
                continue
            with np.errstate(over="ignore", divide="ignore", invalid="ignore"):
                ratio = np.max(np.abs(g / (alpha[..., None] if np.ndim(g) == 3 else alpha)))
            lam_max = np.max(np.abs(lam))
            bad.append(f"constraint '{c.name}': alpha (g/alpha)^2 overflows (alpha as small as "
                       f"{np.min(alpha):.1e}): alpha0 too small" if ratio >= lam_max else
                       f"constraint '{c.name}': alpha lambda^2 overflows (|lambda| up to "
                       f"{lam_max:.1e}): check the magnitudes of the loads/parameters")
        if bad:
            return "; ".join(bad)
        E, grad = self.assembler.gradient(x)
        return "J_h and its gradient are finite" if np.isfinite(E) and np.all(np.isfinite(grad)) \
            else "the terms of J_h are finite but their sum overflows: check the magnitudes of the loads/parameters"

    def constraint_report(self, x):
        """report_constraints at x (see there)."""
        return report_constraints(self.constraints, self.constraint_values(x), self.split(x),
                                  self.alpha0, self.limits)


INGREDIENTS = ("gap g", "multiplier lambda", "scaling alpha")
UNBOUNDED = ("the energy of the cell does not bound the multiplier: lambda is not zero on the "
             "kernel of the cell's energy Hessian (a rigid-body mode, a field without stiffness "
             "there, or inverted elements)")
SINGULAR = ("the energy Hessian at the initial guess is singular or indefinite where the "
            "multiplier is not zero (a rigid-body mode, a field without Dirichlet conditions, "
            "or inverted elements)")
FIX = "the supports (Dirichlet conditions) or the initial guess"


def report_constraints(constraints, values, parts, alpha0, limits, gather=None):
    """Per constraint (values: Problem.constraint_values, parts: the fields' dofs, alpha0 and
    limits per element): kind, alpha0, active points and contact measure, the largest
    violation v (of g >= 0, or |g| for g = 0) and the multiplier lambda_N; and whether
    the constraint looks infeasible.  At an active point the Nitsche violation is
    -g = alpha (lambda_N - lambda): a feasible problem's lambda_N is a multiplier a
    discrete field of size U (max |u| over the fields of g) can exert, at most
    ~ stiffness U / h^k, so v <~ alpha0 U, and v -> 0 with h (on coarse meshes under
    large loads v reached 8 alpha0 U: hence the factor 50); an infeasible one (an
    obstacle above the boundary values, a gap that cannot be met) keeps v ~ U and
    lambda_N ~ v / alpha -> oo.  Flagged: at the most violated point
        v > violation_limit = min(1/2, 50 alpha0_T) U   and   v > 2 alpha |lambda(u_h)|
    (the second: the violation is not the consistency term alpha (lambda - lambda_N)
    with lambda_N ~ lambda; it also keeps round-off of a zero solution unflagged).
    Where values, parts, alpha0 and limits are one MPI rank's (its elements, its held dofs),
    gather (e.g. comm.allgather) returns every rank's constraint_statistics, rank after
    rank, and the report is the whole problem's: sums, maxima and the first most violated
    point of the ranks' statistics (constraint_summary)."""
    gather = gather or (lambda statistics: [statistics])
    return {c.name: constraint_summary(c, gather(constraint_statistics(
        c, values[c.name], parts, alpha0[c.name], limits[c.name]))) for c in constraints}


def constraint_statistics(c, v, parts, alpha0, limits):
    """What report_constraints needs of constraint c's values v on some of its elements (one
    rank's; alpha0 and limits theirs, parts the dofs they know): the fields' size
    max |u|, alpha0 and limits, and where there are elements the counts, sums and maxima
    over their points and their most violated point's violation, alpha0 and consistency
    term 2 alpha |lambda| (the smallest g where g < 0 somewhere, else the first point;
    the largest |g| for g = 0)."""
    s = dict(size=max([float(np.abs(parts[n]).max(initial=0.0)) for n in c.gap_names if n in parts],
                      default=0.0), alpha0=np.asarray(alpha0, float), limits=np.asarray(limits, float))
    vector = np.ndim(v["g"]) == 3
    g, lam, lam_n = (v[k][..., 0] if vector else v[k] for k in ("g", "lam", "multiplier"))
    if g.size == 0:
        return s
    if c.inequality:  # violation max(-g, 0): largest where g is smallest (first point if none)
        active = lam_n > 0
        worst = np.unravel_index(np.argmin(g), g.shape)
        worst = worst if g[worst] < 0 else (0,) * g.ndim
        viol = float(np.maximum(-g[worst], 0.0))
    else:  # violation |g|
        active = np.zeros_like(g, bool)
        worst = np.unravel_index(np.argmax(np.abs(g)), g.shape)
        viol = float(np.abs(g[worst]))
    alpha_w, lam_w = (np.broadcast_to(b, g.shape)[worst] for b in (v["alpha"], lam))
    s.update(violation=viol, worst_alpha0=float(np.broadcast_to(alpha0, g.shape[:1])[worst[0]]),
             consistency=2 * float(np.abs(alpha_w * lam_w)),
             active_count=int(active.sum()), contact_measure=float((v["W"] * active).sum()),
             peak_multiplier=float(np.max(lam_n)), total_multiplier=float((v["W"] * lam_n).sum()))
    if c.projection.frictional:
        traction = v["multiplier"][..., 1:]
        s.update(stick_measure=float((v["W"] * (v["state"] == 1)).sum()),
                 slip_measure=float((v["W"] * (v["state"] == 2)).sum()),
                 separation_measure=float((v["W"] * (v["state"] == 0)).sum()),
                 peak_tangential_traction=float(np.linalg.norm(traction, axis=-1).max()),
                 total_tangential_traction=(v["W"][..., None] * traction).sum((0, 1)))
    return s


def constraint_summary(c, pieces):
    """report_constraints' entry of constraint c from the constraint_statistics of its
    elements' pieces (rank after rank): counts and measures summed, maxima over the pieces,
    the most violated point the first piece's of the largest violation, alpha0's and the
    limits' statistics over all elements, the size the largest."""
    held = [p for p in pieces if "violation" in p]
    if not held:
        raise ValueError(f"constraint '{c.name}' has no elements: check its measure (the "
                         "boundary facets, interface or cells it is integrated over)")
    w = max(held, key=lambda p: p["violation"])  # the first of the largest
    a, limit_c = (np.concatenate([p[k] for p in pieces]) for k in ("alpha0", "limits"))
    viol, size = w["violation"], max(p["size"] for p in pieces)
    limit = min(0.5, 50 * w["worst_alpha0"]) * size

    def total(k):
        return sum(p[k] for p in held)

    rep = dict(kind=c.kind, alpha0=float(a.min()), alpha0_min=float(a.min()),
               alpha0_median=float(np.median(a)), alpha0_max=float(a.max()),
               alpha0_limit_min=float(limit_c.min()),
               alpha0_limit_median=float(np.median(limit_c)),
               alpha0_limit_max=float(limit_c.max()),
               active_count=total("active_count"), contact_measure=total("contact_measure"),
               max_violation=viol, peak_multiplier=max(p["peak_multiplier"] for p in held),
               total_multiplier=total("total_multiplier"), violation_limit=limit,
               infeasible=bool(viol > limit and viol > w["consistency"]))
    if c.projection.frictional:
        rep.update(theta=c.theta, stick_measure=total("stick_measure"),
                   slip_measure=total("slip_measure"), separation_measure=total("separation_measure"),
                   peak_tangential_traction=max(p["peak_tangential_traction"] for p in held),
                   total_tangential_traction=total("total_tangential_traction").tolist())
    return rep


def reads_fields(term):
    """Whether a term's density can depend on the dofs of its elements: some tabulation of
    the jets it reads is non-zero (not so for the second derivatives of P1 elements)."""
    return any(np.asarray(T).any() for T in term.T)


def cell_hessians(term, x, cells):
    """The element Hessians of a cell term of the energy at x on the given cells of its mesh,
    and their dofs (computed anew: the assembly keeps a quadratic term's matrix, not its
    element Hessians); the term's cells (all, or a rank's) are sorted."""
    e = np.searchsorted(term.cells, cells)
    return term.run("full", x, e)[2], term.global_dofs[e]


def multiplier_jacobian(term, c, x):
    """sqrt(W alpha) D lambda at each point of each element of a term of
    c.scaled_multiplier(), on the dofs of the multiplier's fields: (elements, points, dofs)
    and the global dofs (elements, dofs); the components of a vector multiplier count as
    further points (the Gram matrix sums over them)."""
    mine = np.concatenate([np.full(d.shape[1], f.name in c.multiplier_names)
                           for d, f in zip(term.field_dofs, term.fields)])
    shape = term.output_shape()
    parts = [term] if shape == () else \
        [term.with_pointwise(component(term.pointwise, i)) for i in range(int(np.prod(shape)))]
    G = np.concatenate([p.run("jacobian", x)[0] for p in parts], axis=1)
    return G[:, :, mine], term.global_dofs[:, mine]


def component(pointwise, i):
    """The i-th component of a vector density."""
    return lambda args: pointwise(args).ravel()[i]


def compacted(data, keep, block=2 ** 20):
    """data[keep] in data's own first entries, as a view of them (data overwritten): block
    by block in increasing order, each block's kept values taken before they are written,
    never past that block (the kept entries before a position are at most its number)."""
    end = 0
    for s in range(0, data.size, block):
        part = data[s:s + block][keep[s:s + block]]
        data[end:end + part.size] = part
        end += part.size
    return data[:end]


def shrunk(data, size):
    """data[:size] in data's own memory, the rest of it handed back to the allocator
    (ndarray.resize: realloc shrinks a block in place, no second array beside it).  data is
    consumed: a 1D array that owns its memory and that no view refers to; else (or where
    NumPy refuses, e.g. for an array with weak references) a copy."""
    if data.ndim == 1 and data.flags.owndata and data.base is None:
        try:
            data.resize(size, refcheck=False)  # (the caller's references to data see the new size)
            return data
        except ValueError:
            pass
    return data[:size].copy()


def centroids(term):
    """Centroid of each element of a term, shape (dim, elements)."""
    W = term.W[:term.nel]
    return (np.einsum("eq,eqd->de", W, term.x[:term.nel]) / W.sum(1))

