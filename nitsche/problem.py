"""A constrained problem: fields, energy J, constraints; its Nitsche functional J_h."""
import warnings

import numpy as np
import scipy.sparse as sp

from .assembly import Assembler, ConstantDensity, Term, check_arguments
from .functional import Integral
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
    alpha0_limits: {constraint name: limit} computed on a coarse mesh, used to
        resolve alpha0='auto' and to check given values; computed here if omitted.
    self.constraints: the constraints, those with alpha0='auto' replaced by copies with
    the resolved value (the user's constraint and Scaling are not changed).
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
        self.constraints = self._resolve_alpha0()
        self.constraint_terms = [Term(c.pointwise(), c.names, c.on, self.fields, self.offsets,
                                      f"constraint '{c.name}'", keep_points=True) for c in self.constraints]
        self.value_terms = [t.with_pointwise(c.values())
                            for c, t in zip(self.constraints, self.constraint_terms)]
        self.assembler = Assembler(self.energy_terms + self.constraint_terms, self.ndofs)
        self._free_block()
        self._release_measures()

    def _release_measures(self):
        for m in {id(i.on): i.on for i in self.integrals + self.constraints}.values():
            m.release()

    def _check_arguments(self):
        """Every argument of a constraint's gap and multiplier names a field or x, n, h."""
        for c in self.constraints:
            check_arguments(c.gap_names, self.by_name, f"the gap of constraint '{c.name}'")
            check_arguments(c.multiplier_names, self.by_name, f"the multiplier of constraint '{c.name}'")

    # -- alpha0 -----------------------------------------------------------------
    def _resolve_alpha0(self):
        """The constraints with alpha0='auto' resolved (copies) from the stability limits,
        computed for those with a multiplier unless given; a given alpha0 above its limit
        warns."""
        needs = [c for c in self.constraints
                 if c.multiplier is not None and c.name not in self.alpha0_limits]
        x, K = self._energy_hessian() if needs else (None, None)
        resolved = []
        for c in self.constraints:
            if c in needs:
                try:
                    self.alpha0_limits[c.name] = self._stability_limit(c, x, K)
                except SingularEnergy:
                    if c.scaling.is_auto:
                        raise ValueError(f"alpha0='auto' for constraint '{c.name}': {SINGULAR}; "
                                         f"give alpha0 explicitly or fix {FIX}") from None
                    warnings.warn(f"constraint '{c.name}': alpha0 = {c.scaling.alpha0:g} is not "
                                  f"checked against a stability limit: {SINGULAR}", StabilityWarning)
            limit = self.alpha0_limits.get(c.name, np.inf)
            if c.scaling.is_auto:
                c = c.with_scaling(c.scaling.resolved(auto_alpha0(limit)))
            elif c.multiplier is not None and c.scaling.alpha0 >= limit:
                warnings.warn(f"constraint '{c.name}': alpha0 = {c.scaling.alpha0:g} exceeds the "
                              f"stability limit {limit:.4g} (J_h is not convex; Newton may fail); "
                              f"use alpha0 < {limit:.4g} or alpha0='auto'", StabilityWarning)
            resolved.append(c)
        return resolved

    def stability_limits(self, constraints=None):
        """alpha0 limit 1/C_I of each constraint with a multiplier, C_I the largest
        eigenvalue of  B v = mu K v,  B = Hessian of int 1/2 (alpha/alpha0) lambda^2,
        K = Hessian of the energy J (free dofs, at the initial guess); infinite for a
        multiplier that does not depend on the fields (B = 0)."""
        constraints = self.constraints if constraints is None else constraints
        x, K = self._energy_hessian()
        limits = {}
        for c in constraints:
            if c.multiplier is None:
                continue
            try:
                limits[c.name] = self._stability_limit(c, x, K)
            except SingularEnergy:
                raise ValueError(f"constraint '{c.name}' has no stability limit of alpha0: "
                                 f"{SINGULAR}; fix {FIX}") from None
        self._release_measures()
        return limits

    def _energy_hessian(self):
        """The initial guess x and K, the Hessian of J at x on the free dofs."""
        x = self.initial(None)
        K = Assembler(self.energy_terms, self.ndofs).hessian(x)
        return x, K[self.free][:, self.free]

    def _stability_limit(self, c, x, K):
        """1/C_I of constraint c (see stability_limits); SingularEnergy when K is singular
        or indefinite on a direction where B is not zero."""
        try:
            term = Term(c.multiplier_square(), c.multiplier_names, c.on, self.fields, self.offsets,
                        f"the multiplier of constraint '{c.name}'")
        except ConstantDensity:  # a given multiplier lambda = q: B = 0
            return np.inf
        B = Assembler([term], self.ndofs).hessian(x)[self.free][:, self.free]
        mu = largest_generalized_eigenvalue(B, K)
        return 1.0 / mu if mu > 0 else np.inf

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
        weights W at its quadrature points (arrays of shape (elements, points)).
        ValueError when g, lambda or alpha is not finite (see check_finite)."""
        out = {}
        for c, t, (g, lam, alpha) in self._finite_values(x):
            s = lam - g / alpha
            lam_n = np.maximum(s, 0) if c.inequality else s
            out[c.name] = dict(g=g, lam=lam, alpha=alpha, multiplier=lam_n,
                               W=t.W[:t.nel], x=t.x[:t.nel], active=s >= 0 if c.inequality else None)
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
                v = np.broadcast_to(v, (t.nel, t.nq))
                wrong = ~np.isfinite(v)
                if wrong.any():
                    kind = "NaN" if np.isnan(v[wrong]).all() else \
                        "infinite" if np.isinf(v[wrong]).all() else "NaN or infinite"
                    e, q = np.argwhere(wrong)[0]
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
        for (c, _, (g, lam, alpha)), term in zip(rows, self.constraint_terms):
            E, grad = self.assembler.gradient(x, [term])
            if np.isfinite(E) and np.all(np.isfinite(grad)):
                continue
            with np.errstate(over="ignore", divide="ignore", invalid="ignore"):
                ratio = np.max(np.abs(g / alpha))
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
        """Per constraint: kind, alpha0, active points and contact measure, the largest
        violation v (of g >= 0, or |g| for g = 0) and the multiplier lambda_N; and whether
        the constraint looks infeasible.  At an active point the Nitsche violation is
        -g = alpha (lambda_N - lambda): a feasible problem's lambda_N is a multiplier a
        discrete field of size U (max |u| over the fields of g) can exert, at most
        ~ stiffness U / h^k, so v <~ alpha0 U, and v -> 0 with h (on coarse meshes under
        large loads v reached 8 alpha0 U: hence the factor 50); an infeasible one (an
        obstacle above the boundary values, a gap that cannot be met) keeps v ~ U and
        lambda_N ~ v / alpha -> oo.  Flagged: at the most violated point
            v > violation_limit = min(1/2, 50 alpha0) U   and   v > 2 alpha |lambda(u_h)|
        (the second: the violation is not the consistency term alpha (lambda - lambda_N)
        with lambda_N ~ lambda; it also keeps round-off of a zero solution unflagged)."""
        rep, values, parts = {}, self.constraint_values(x), self.split(x)
        for c in self.constraints:
            v = values[c.name]
            if c.inequality:
                active = v["multiplier"] > 0
                violation = np.maximum(-v["g"], 0.0)
            else:
                active = np.zeros_like(v["g"], bool)
                violation = np.abs(v["g"])
            worst = np.unravel_index(np.argmax(violation), violation.shape)
            viol = float(violation[worst])
            size = max([float(np.abs(parts[n]).max(initial=0.0)) for n in c.gap_names if n in parts],
                       default=0.0)
            limit = min(0.5, 50 * c.scaling.alpha0) * size
            consistency = 2 * float(np.abs(np.broadcast_to(v["alpha"] * v["lam"], violation.shape)[worst]))
            rep[c.name] = dict(kind=c.kind, alpha0=c.scaling.alpha0,
                               active_count=int(active.sum()),
                               contact_measure=float((v["W"] * active).sum()),
                               max_violation=viol,
                               peak_multiplier=float(np.max(v["multiplier"])),
                               total_multiplier=float((v["W"] * v["multiplier"]).sum()),
                               violation_limit=limit,
                               infeasible=bool(viol > limit and viol > consistency))
        return rep


INGREDIENTS = ("gap g", "multiplier lambda", "scaling alpha")
SINGULAR = ("the energy Hessian at the initial guess is singular or indefinite where the "
            "multiplier is not zero (a rigid-body mode, a field without Dirichlet conditions, "
            "or inverted elements)")
FIX = "the supports (Dirichlet conditions) or the initial guess"
SAFE_FRACTION = 0.5  # alpha0='auto' takes this fraction of the stability limit
AUTO_CAP = 0.1       # ... and at most this when the multiplier term is unconditionally stable


def auto_alpha0(limit):
    """A safe alpha0 for a computed stability limit."""
    return min(SAFE_FRACTION * limit, AUTO_CAP)
