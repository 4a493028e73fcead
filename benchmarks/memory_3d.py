"""3D: the memory of the assembly data against that of the linear solver, one level.

For a 3D case at one level (default: membrane-solid, cube of trilinear hexahedra, vector
Q1, plus a Q1 membrane; --set cells=tet: P1 tetrahedra and triangles), prints the bytes
held by
  - the fields' scikit-fem bases held (dof_basis: one point per cell; a full basis with
    the basis functions at every quadrature point of every cell only if one was built),
  - the terms' assembly data: tabulations (or reference tabulations and inverse Jacobians),
    weights, points, normals, local-to-global maps, the element parts of quadratic terms,
  - the assembler's sparsity pattern and scatter maps (nitsche.pattern: with its groups),
  - the quadratic terms' assembled matrices (their data and constant gradient; the
    index arrays are the pattern's),
  - the Newton matrix (free-free block, CSR),
against the linear solver of the first Newton matrix: the CHOLMOD factor (nnz(L) x 12
bytes: values and row indices) or the smoothed-aggregation AMG hierarchy (the operators,
prolongators and restrictors of every level), and the process's peak memory (VmHWM).
Writes benchmarks/results/memory_3d.json (one row per run, appended).

    python benchmarks/memory_3d.py --case membrane-solid --level 2 --solver amg
    python benchmarks/memory_3d.py --level 3 --set cells=tet --solver amg
    python benchmarks/memory_3d.py --case indentation --set geometry=3d --degree 2 --level 2
    python benchmarks/memory_3d.py --case signorini-hex20 --cells 25 --solver amg

signorini-hex20 is no shipped case but this script's own problem (no case has 20-node
hexahedra): a linear elastic unit cube (E = 1, nu = 0.3) of --cells^3 serendipity hexahedra
(ElementHexS2, vector), fixed on its top face, under a body force 0.1 downward, on a rigid
plane 0.01 below its bottom face: g = u_z + 0.01 >= 0, lambda = -sigma_zz(u), alpha0 auto.
"""
import argparse
import json
import os
import sys
import time

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import numpy as np  # noqa: E402

HERE = os.path.dirname(os.path.abspath(__file__))
RESULTS = os.path.join(HERE, "results")


def nbytes(*arrays):
    """Bytes of the distinct arrays (None skipped, views counted by their base once)."""
    seen, total = set(), 0
    for a in arrays:
        if a is None or not hasattr(a, "nbytes"):
            continue
        base = getattr(a, "base", None)  # (a device array has none)
        base = a if base is None else base
        if id(base) in seen:
            continue
        seen.add(id(base))
        total += base.nbytes if hasattr(base, "nbytes") else a.nbytes
    return total


def basis_bytes(basis):
    """Bytes of a scikit-fem basis's weights and tabulated basis functions (a DofBasis's
    only once something read them)."""
    arrays = [vars(basis).get("dx"), basis.X, basis.W]
    for functions in vars(basis).get("basis", ()):
        for df in functions:
            arrays += [np.asarray(f) for f in df.astuple if f is not None]
    return nbytes(*arrays)


def term_bytes(t):
    """Bytes of a term's tabulations, per-point data and local-to-global maps (kept: a
    quadratic term's element Hessians are computed anew where needed, not kept; a
    constraint's points given on demand are not kept either)."""
    points = None if getattr(t, "points_on_demand", False) else t.x
    arrays = list(t.T or []) + list(getattr(t, "J", None) or []) + [t.W, points, t.n, t.h, t.alpha0]
    arrays += [t.global_dofs] + list(t.field_dofs)
    return nbytes(*arrays)


def signorini_hex20(cells):
    """The problem signorini-hex20 (module docstring) on cells^3 hexahedra."""
    import jax.numpy as jnp
    from skfem import ElementHexS2, ElementVector, MeshHex
    import nitsche as ni
    s = np.linspace(0.0, 1.0, cells + 1)
    mesh = MeshHex.init_tensor(s, s, s).with_boundaries(
        {"bottom": lambda x: np.isclose(x[2], 0.0), "top": lambda x: np.isclose(x[2], 1.0)})
    u = ni.Field("u", mesh, ElementVector(ElementHexS2()), fixed={"top": "all"})
    E, nu = 1.0, 0.3
    mu, lam = E / (2 * (1 + nu)), E * nu / ((1 + nu) * (1 - 2 * nu))

    def sigma(G):
        eps = 0.5 * (G + G.T)
        return 2 * mu * eps + lam * jnp.trace(eps) * jnp.eye(3)

    def energy(u):
        G = u.grad
        return 0.5 * jnp.sum(sigma(G) * 0.5 * (G + G.T)) + 0.1 * u.value[2]
    support = ni.Inequality(lambda u: u.value[2] + 0.01, lambda u: -sigma(u.grad)[2, 2],
                            ni.Scaling("auto", h_power=1, stiffness=E), ni.facets(u, "bottom", intorder=6),
                            name="support")
    return ni.Problem([u], ni.Integral(energy, ni.cells(u, intorder=4)), [support])


def peak_mb():
    """The process's peak resident memory so far (VmHWM), MB."""
    with open("/proc/self/status") as fh:
        return next(int(line.split()[1]) for line in fh if line.startswith("VmHWM")) / 1024


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--case", default="membrane-solid")
    ap.add_argument("--level", type=int, default=2)
    ap.add_argument("--degree", type=int, default=1, help="the case's element degree (e.g. "
                    "indentation --set geometry=3d --degree 2: P2 tetrahedra)")
    ap.add_argument("--set", nargs="*", default=[], help="case parameters name=value")
    ap.add_argument("--solver", choices=["cholmod", "amg", "both"], default="both")
    ap.add_argument("--cells", type=int, default=25, help="signorini-hex20: hexahedra per side "
                    "(25: 205k unknowns)")
    args = ap.parse_args()
    t0 = time.perf_counter()
    if args.case == "signorini-hex20":
        p, args.level, args.degree = argparse.Namespace(cells=args.cells), None, 2
        problem = signorini_hex20(args.cells)
    else:
        from nitsche.cases import get
        case = get(args.case)
        p = case.parameters(dict(s.split("=", 1) for s in args.set))
        problem = case.problem(args.level, args.degree, p)
    setup = time.perf_counter() - t0
    x = problem.initial(None)
    a = problem.assembler
    terms = {f"{i}: {t.label}": term_bytes(t) for i, t in enumerate(a.terms)}  # before assembly
    t0 = time.perf_counter()
    _, _, A = problem.newton_system(x)
    assembly = time.perf_counter() - t0
    assembly_peak = peak_mb()
    row = dict(case=args.case, level=args.level, degree=args.degree, parameters=vars(p), unknowns=int(problem.free.size),
               setup_seconds=setup, first_assembly_seconds=assembly,
               field_bases=sum(basis_bytes(vars(f).get("dof_basis") or f.basis)  # (older: f.basis)
                               + (basis_bytes(f._basis) if "_basis" in vars(f) else 0)
                               for f in problem.fields),  # held: dof bases (and any full one built)
               terms=terms, terms_after_first_assembly={f"{i}: {t.label}": term_bytes(t)
                                                        for i, t in enumerate(a.terms)},
               value_terms=sum(term_bytes(t) for t in problem.value_terms),
               pattern=a.pattern.nbytes if hasattr(a, "pattern") else nbytes(a.indices, a.indptr, *a.scatter),
               quadratic_matrices=sum(nbytes(g0, K.data, own) + (0 if own is None else nbytes(K.indices, K.indptr))
                                      for (_, g0, K, own) in a._quadratics.values()),
               newton_matrix=nbytes(A.data, A.indices, A.indptr), peak_assembly_mb=assembly_peak)
    row["assembly_data"] = sum(row["terms"].values()) + row["pattern"]
    if args.solver in ("cholmod", "both"):
        from nitsche.linalg import cholmod_factor
        t0 = time.perf_counter()
        factor = cholmod_factor(A.tocsc(), "default")
        row["cholmod_seconds"] = time.perf_counter() - t0
        row["cholmod_factor"] = int(factor.nnz) * 12
        del factor
    if args.solver in ("amg", "both"):
        from nitsche.linalg import AMGCG
        amg = AMGCG()
        amg.prepare(problem)
        t0 = time.perf_counter()
        amg._build(A)
        row["amg_seconds"] = time.perf_counter() - t0
        row["amg_hierarchy"] = sum(nbytes(M.data, M.indices, M.indptr) for lvl in amg.ml.levels
                                   for M in (getattr(lvl, k, None) for k in ("A", "P", "R"))
                                   if M is not None and hasattr(M, "data"))
    row["peak_mb"] = peak_mb()
    mb = lambda b: f"{b / 2**20:9.1f} MB"
    print(f"{args.case} level {args.level} degree {args.degree}: {row['unknowns']} unknowns, setup {setup:.1f} s, "
          f"first assembly {assembly:.1f} s, peak {row['peak_mb']:.0f} MB "
          f"({assembly_peak:.0f} MB after the first assembly)")
    print(f"  fields' scikit-fem bases     {mb(row['field_bases'])}")
    for (k, v), after in zip(row["terms"].items(), row["terms_after_first_assembly"].values()):
        print(f"  term {k:<24}{mb(v)}  (after the first assembly {mb(after).strip()})")
    print(f"  constraint value terms       {mb(row['value_terms'])}  (share the constraint's arrays)")
    print(f"  pattern + scatter maps       {mb(row['pattern'])}")
    print(f"  assembly data (terms+pattern){mb(row['assembly_data'])}")
    print(f"  quadratic terms' matrices    {mb(row['quadratic_matrices'])}")
    print(f"  Newton matrix (free block)   {mb(row['newton_matrix'])}")
    for k in ("cholmod_factor", "amg_hierarchy"):
        if k in row:
            print(f"  {k.replace('_', ' '):<29}{mb(row[k])}  ratio assembly data / it "
                  f"{row['assembly_data'] / row[k]:.2f}")
    os.makedirs(RESULTS, exist_ok=True)
    path = os.path.join(RESULTS, "memory_3d.json")
    rows = json.load(open(path))["rows"] if os.path.exists(path) else []
    rows.append(dict(row, date=time.strftime("%Y-%m-%d %H:%M"), commit=os.popen(
        f"git -C {HERE} rev-parse --short HEAD 2>/dev/null").read().strip()))
    with open(path, "w") as fh:
        json.dump(dict(rows=rows), fh, indent=1)


if __name__ == "__main__":
    sys.exit(main())
