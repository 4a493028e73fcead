"""A constrained problem: fields, energy J, constraints; its Nitsche functional J_h."""
import warnings

import numpy as np
import scipy.sparse as sp

from .assembly import Assembler, Term, check_arguments
from .functional import Integral
from .measures import cells


class StabilityWarning(UserWarning):
    """alpha0 exceeds the computed stability limit of a constraint."""


class Problem:
    """minimize J_h(u) = J(u) + sum over constraints of their Nitsche terms.

    fields: list of nitsche.Field (the unknowns, in this order in the dof vector).
    energy: a density of the fields (integrated over the cells of the first
        field's mesh), an Integral, or a list of Integrals.
    constraints: Equality / Inequality / Penalty constraints.
    alpha0_limits: {constraint name: limit}: one stability limit for all elements of a
        constraint (e.g. from global_limits()) instead of the element-local ones computed here.

    After construction: limits[name] and alpha0[name] per element of each constraint, and
    alpha0_limits[name] the smallest limit.
    """

    def __init__(self, fields, energy, constraints=(), alpha0_limits=None):
        self.fields = list(fields)
        names = [f.name for f in self.fields]
        if len(set(names)) != len(names):
            raise ValueError(f"field names must be unique, got {names}")
        self.by_name = {f.name: f for f in self.fields}
        sizes = [f.ndofs for f in self.fields]
        self.offsets = dict(zip(names, np.cumsum([0] + sizes[:-1]).tolist()))
        self.ndofs = int(sum(sizes))
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
                                  "the energy density") for i in self.integrals]
        self.constraint_terms = [Term(c.pointwise(), c.names, c.on, self.fields, self.offsets,
                                      f"constraint '{c.name}'", keep_points=True) for c in self.constraints]
        self._resolve_alpha0(dict(alpha0_limits or {}))
        self.value_terms = [t.with_pointwise(c.values())
                            for c, t in zip(self.constraints, self.constraint_terms)]
        self.assembler = Assembler(self.energy_terms + self.constraint_terms, self.ndofs)
        self._free_block()
        for m in {id(i.on): i.on for i in self.integrals + self.constraints}.values():
            m.release()

    def _check_arguments(self):
        """Every argument of a constraint's gap and multiplier names a field or x, n, h."""
        for c in self.constraints:
            check_arguments(c.gap_names, self.by_name, f"the gap of constraint '{c.name}'")
            check_arguments(c.multiplier_names, self.by_name, f"the multiplier of constraint '{c.name}'")

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
            if unbounded and c.scaling.needs_limit:
                raise ValueError(f"constraint '{c.name}': on {unbounded} of its elements the energy "
                                 "of the cell does not bound the multiplier (lambda is not zero on "
                                 "the kernel of the cell's energy Hessian): no stability limit; give "
                                 "alpha0 as a number, or check the energy and the multiplier")
        for c, t in zip(self.constraints, self.constraint_terms):
            limit = np.full(t.nel, given[c.name], dtype=float) if c.name in given \
                else local.get(c.name, np.full(t.nel, np.inf))
            alpha0 = c.scaling.per_element(limit, centroids(t), t.h)
            self.limits[c.name], self.alpha0[c.name] = limit, alpha0
            t.alpha0 = alpha0
            over = alpha0 >= limit
            if over.any():
                warnings.warn(f"constraint '{c.name}': alpha0 = {alpha0[over].max():g} exceeds the "
                              f"stability limit {limit[over].min():.4g} on {over.sum()} of {t.nel} "
                              f"elements (J_h may not be convex; Newton may fail); use a smaller "
                              f"alpha0 or alpha0='auto'", StabilityWarning)
        self.alpha0_limits = {c.name: float(self.limits[c.name].min()) for c in self.constraints
                              if c.multiplier is not None}

    def local_limits(self, constraints=None):
        """{constraint name: the element-local stability limit of alpha0 on each element}
        (nitsche.stability): batched eigenproblems of the cells that own the elements."""
        from .stability import local_limits
        names = {c.name for c in (self.constraints if constraints is None else constraints)}
        x = self.initial(None)
        free = np.zeros(self.ndofs, bool)
        free[self.free] = True
        out = {}
        for c, t in zip(self.constraints, self.constraint_terms):
            if c.name not in names or c.multiplier is None:
                continue
            mesh = c.on.mesh
            if not self._multiplier_on_own_mesh(c):
                raise ValueError(f"constraint '{c.name}': element-local alpha0 limits need the "
                                 "multiplier's fields on the constraint's own mesh; give alpha0 as "
                                 "a number (Problem.global_limits() checks it)")
            energy = [e for e in self.energy_terms
                      if e.measure.kind == "cells" and e.measure.mesh is mesh]
            if not energy:
                raise ValueError(f"constraint '{c.name}': the energy has no cell term on the "
                                 "constraint's mesh to bound its multiplier")
            B = t.with_pointwise(c.scaled_multiplier())  # on the constraint's tabulations
            B.alpha0 = np.ones(t.nel)
            out[c.name] = local_limits(*multiplier_jacobian(B, c, x), t.cells, free,
                                       lambda cells: [cell_hessians(e, x, cells) for e in energy])
        return out

    def _multiplier_on_own_mesh(self, c):
        return all(self.by_name[k].mesh is c.on.mesh for k in c.multiplier_names if k in self.by_name)

    def _gram(self, c, alpha0=None):
        """B (free dofs): the Gram matrix of sqrt(alpha/alpha0) D lambda of a constraint, or
        of sqrt(alpha) D lambda with the given alpha0 per element (a fresh term: the
        constraint's own may have released its tabulations)."""
        term = Term(c.scaled_multiplier(), c.multiplier_names, c.on, self.fields, self.offsets,
                    f"the multiplier of constraint '{c.name}'")
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

    def global_limits(self, constraints=None):
        """Diagnostic: {name: 1/C_I}, the one alpha0 for all elements up to which J_h is
        convex (each constraint alone), C_I the largest eigenvalue of the global pencil
        B v = mu K v (B: Hessian of int 1/2 (alpha/alpha0) lambda^2; sparse LU of K)."""
        from .stability import largest_generalized_eigenvalue
        constraints = self.constraints if constraints is None else constraints
        limits = {}
        for c in constraints:
            if c.multiplier is not None:
                mu = largest_generalized_eigenvalue(self._gram(c), self._stiffness())
                limits[c.name] = 1.0 / mu if mu > 0 else np.inf
        return limits

    def stability_ratio(self):
        """Diagnostic: the largest eigenvalue of B_alpha v = mu K v, B_alpha the Hessian of
        the sum over constraints of int 1/2 alpha lambda^2 with this problem's alpha0 on
        each element: J_h is convex if it is at most 1 (global sparse LU of K)."""
        from .stability import largest_generalized_eigenvalue
        grams = [self._gram(c, self.alpha0[c.name]) for c in self.constraints
                 if c.multiplier is not None]
        if not grams:
            return 0.0
        return largest_generalized_eigenvalue(sum(grams[1:], grams[0]), self._stiffness())

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

    def _free_block(self):
        a = self.assembler
        row = np.repeat(np.arange(self.ndofs), np.diff(a.indptr))
        isfree = np.zeros(self.ndofs, bool)
        isfree[self.free] = True
        keep = isfree[row] & isfree[a.indices]
        self._sel = np.flatnonzero(keep)
        number = -np.ones(self.ndofs, np.int64)
        number[self.free] = np.arange(self.free.size)
        self._ff_indices = number[a.indices[keep]].astype(np.int32)
        self._ff_indptr = np.concatenate([[0], np.cumsum(np.bincount(number[row[keep]],
                                                                     minlength=self.free.size))])

    def newton_system(self, x):
        """J_h(x), its gradient on the free dofs and the free-free block of the Hessian."""
        E, g, data = self.assembler.evaluate(x)
        n = self.free.size
        A = sp.csr_matrix((data[self._sel], self._ff_indices, self._ff_indptr), shape=(n, n))
        return E, g[self.free], A

    def minimize(self, x0=None, **options):
        """Newton's method from x0; see nitsche.newton.newton for the options."""
        from .newton import newton
        return newton(self, x0, **options)

    # -- constraint report ---------------------------------------------------------
    def constraint_values(self, x):
        """Per constraint: g, lambda, alpha, the discrete multiplier lambda_N and the
        weights W at its quadrature points (arrays of shape (elements, points))."""
        out = {}
        for c, t in zip(self.constraints, self.value_terms):
            g, lam, alpha = t.run("values", x)
            s = lam - g / alpha
            lam_n = np.maximum(s, 0) if c.inequality else s
            out[c.name] = dict(g=g, lam=lam, alpha=alpha, multiplier=lam_n,
                               W=t.W[:t.nel], x=t.x[:t.nel], active=s >= 0 if c.inequality else None)
        return out

    def non_finite(self, x):
        """Which ingredient is not finite at x: the energy, or a constraint's gap g,
        multiplier lambda or scaling alpha (a sentence for error messages)."""
        bad = [f"the energy density ({t.label})" for t in self.energy_terms
               if not np.all(np.isfinite(self.assembler.gradient(x, [t])[1]))]
        for c, t in zip(self.constraints, self.value_terms):
            for what, v in zip(("gap g", "multiplier lambda", "scaling alpha"), t.run("values", x)):
                if not np.all(np.isfinite(v)):
                    bad.append(f"the {what} of constraint '{c.name}'")
        return "not finite: " + ", ".join(bad) if bad else "no single ingredient is non-finite"

    def constraint_report(self, x):
        rep = {}
        for c in self.constraints:
            v = self.constraint_values(x)[c.name]
            if c.inequality:
                active = v["multiplier"] > 0
                viol = float(np.max(np.maximum(-v["g"], 0.0)))
            else:
                active = np.zeros_like(v["g"], bool)
                viol = float(np.max(np.abs(v["g"])))
            a, limit = self.alpha0[c.name], self.limits[c.name]
            rep[c.name] = dict(kind=c.kind, alpha0=float(a.min()), alpha0_min=float(a.min()),
                               alpha0_median=float(np.median(a)), alpha0_max=float(a.max()),
                               alpha0_limit_min=float(limit.min()),
                               alpha0_limit_median=float(np.median(limit)),
                               alpha0_limit_max=float(limit.max()),
                               active_count=int(active.sum()),
                               contact_measure=float((v["W"] * active).sum()),
                               max_violation=viol,
                               peak_multiplier=float(np.max(v["multiplier"])),
                               total_multiplier=float((v["W"] * v["multiplier"]).sum()))
        return rep


def cell_hessians(term, x, cells):
    """The element Hessians of an energy term at x on the given cells, and their dofs (of a
    quadratic term: from all of its element Hessians, stored for the Newton assembly)."""
    H = term.quadratic_parts()[2][cells] if term.is_quadratic else term.run("full", x, cells)[2]
    return H, term.global_dofs[cells]


def multiplier_jacobian(term, c, x):
    """sqrt(W alpha) D lambda at each point of each element of a term of
    c.scaled_multiplier(), on the dofs of the multiplier's fields: (elements, points, dofs)
    and the global dofs (elements, dofs)."""
    mine = np.concatenate([np.full(d.shape[1], f.name in c.multiplier_names)
                           for d, f in zip(term.field_dofs, term.fields)])
    return term.run("jacobian", x)[0][:, :, mine], term.global_dofs[:, mine]


def centroids(term):
    """Centroid of each element of a term, shape (dim, elements)."""
    W = term.W[:term.nel]
    return (np.einsum("eq,eqd->de", W, term.x[:term.nel]) / W.sum(1))

