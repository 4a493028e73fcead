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
    alpha0_limits: {constraint name: limit} computed on a coarse mesh, used to
        resolve alpha0='auto' and to check given values; computed here if omitted.
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
        self.alpha0_limits = dict(alpha0_limits or {})
        self._resolve_alpha0()
        self.constraint_terms = [Term(c.pointwise(), c.names, c.on, self.fields, self.offsets,
                                      f"constraint '{c.name}'", keep_points=True) for c in self.constraints]
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
    def _resolve_alpha0(self):
        needs = [c for c in self.constraints
                 if c.multiplier is not None and c.name not in self.alpha0_limits]
        if needs:
            self.alpha0_limits.update(self.stability_limits(needs))
        for c in self.constraints:
            limit = self.alpha0_limits.get(c.name, np.inf)
            if c.scaling.is_auto:
                c.scaling.alpha0 = auto_alpha0(limit)
            elif c.multiplier is not None and c.scaling.alpha0 >= limit:
                warnings.warn(f"constraint '{c.name}': alpha0 = {c.scaling.alpha0:g} exceeds the "
                              f"stability limit {limit:.4g} (J_h is not convex; Newton may fail); "
                              f"use alpha0 < {limit:.4g} or alpha0='auto'", StabilityWarning)

    def stability_limits(self, constraints=None):
        """alpha0 limit 1/C_I of each constraint with a multiplier, C_I the largest
        eigenvalue of  B v = mu K v,  B = Hessian of int 1/2 (alpha/alpha0) lambda^2,
        K = Hessian of the energy J (free dofs)."""
        from .stability import largest_generalized_eigenvalue
        constraints = self.constraints if constraints is None else constraints
        x = self.initial(None)
        K = Assembler(self.energy_terms, self.ndofs).hessian(x)
        K = K[self.free][:, self.free]
        limits = {}
        for c in constraints:
            if c.multiplier is None:
                continue
            term = Term(c.multiplier_square(), c.multiplier_names, c.on, self.fields, self.offsets,
                        f"the multiplier of constraint '{c.name}'")
            B = Assembler([term], self.ndofs).hessian(x)[self.free][:, self.free]
            mu = largest_generalized_eigenvalue(B, K)
            limits[c.name] = 1.0 / mu if mu > 0 else np.inf
        return limits

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
            rep[c.name] = dict(kind=c.kind, alpha0=c.scaling.alpha0,
                               active_count=int(active.sum()),
                               contact_measure=float((v["W"] * active).sum()),
                               max_violation=viol,
                               peak_multiplier=float(np.max(v["multiplier"])),
                               total_multiplier=float((v["W"] * v["multiplier"]).sum()))
        return rep


SAFE_FRACTION = 0.5  # alpha0='auto' takes this fraction of the stability limit
AUTO_CAP = 0.1       # ... and at most this when the multiplier term is unconditionally stable


def auto_alpha0(limit):
    """A safe alpha0 for a computed stability limit."""
    return min(SAFE_FRACTION * limit, AUTO_CAP)
