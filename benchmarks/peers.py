"""Obstacle and two-membrane problems (P1): nitsche against its peers, and a scaling study.

Same structured meshes, same functional J_h, same alpha = alpha0 h^2 / T per cell (h = cell
diameter = longest edge, alpha0 given), same quadrature (scikit-fem's order-4 rule on the
triangles, passed to NGSolve as an explicit integration rule), same stopping test
(|grad J_h|_free <= 1e-10 |grad J_h(free dofs = 0)|_free):

  ours      nitsche, nested iteration over levels 0..L (as `nitsche run` does), CHOLMOD;
  skfem     scikit-fem's skfem.autodiff.NonlinearForm(hessian=True) (JAX, no compilation),
            plain Newton with full steps from zero (the paper's toolchain), CHOLMOD with the
            symbolic analysis done once (the peer gets the same linear algebra as ours);
  ngsolve   NGSolve, a BilinearForm with the energy as a SymbolicEnergy integrator
            (`Variation(...)`), AssembleLinearization + sparse Cholesky, full Newton steps
            from zero, on the same vertices and triangles;
  linear    the practical limit: one plain scikit-fem BilinearForm Laplace assembly (per
            field) + one CHOLMOD solve of the unconstrained problem of the same size.

For P1 and cell constraints the Nitsche functional is a penalty with a shifted obstacle
(docs methods.md, pitfall 5):
  obstacle:      J_h = int T/2 |grad u|^2 - f u - alpha/2 f^2 + alpha/2 [-f - (u - psi)/alpha]_+^2
  two membranes: J_h = int sum mu_i/2 |grad u_i|^2 - f_i u_i - alpha/2 f1^2
                           + alpha/2 [f1 - (u2 + d - u1)/alpha]_+^2
The peers minimize exactly this.

3D (`--problems obstacle-3d`): the obstacle problem on the cube (-2,2)^3 of linear
tetrahedra (n = 5 * 2^level cells per side, six tetrahedra per cube; 59k unknowns at
level 3), u = 0 on the boundary, psi = sqrt(1 - |x|^2) (-1 outside the unit ball), T = 1,
f = 0, the same J_h with order-2 quadrature (4 points per tetrahedron) and
h = longest edge; ours (nested chain n = 5 .. 5 * 2^level), skfem's autodiff and the
linear solve (NGSolve: 2D only here).  Every solution is re-evaluated by one referee (NumPy, the
same quadrature) for the energy and the active-set size (quadrature points with
lambda - g/alpha > 0), so that the codes can be seen to solve the same problem.

Every solve runs in its own subprocess; peak memory is that child's ru_maxrss (os.wait4).
Codes are interleaved (ours, skfem, ngsolve, linear, ours, ...) and the ratios are medians of
the pairwise ratios of total seconds within one repetition.

    python benchmarks/peers.py                       # the table (docs/performance.md)
    python benchmarks/peers.py --levels 3 4 --repeat 3 --peers skfem
    python benchmarks/peers.py --scaling             # ours to ~1M unknowns (2D), 549k (3D), log-log plot
    python benchmarks/peers.py --problems obstacle-3d --levels 3 --codes ours skfem linear --name peers_3d.json
Results: benchmarks/results/peers.json, scaling.json, scaling.png.
Peers are optional (`pip install -e .[bench]`); a peer that is not installed is skipped.
"""
import os

# every code gets the BLAS setting the library uses (CHOLMOD's OpenBLAS single-threaded:
# threaded triangular solves were 6x slower on 2 cores; the numeric factorizations on the
# cores, see Cholesky); set before any BLAS is loaded
if "OPENBLAS_NUM_THREADS" not in os.environ:  # the library's default (nitsche/__init__)
    os.environ["OPENBLAS_NUM_THREADS"] = "1"
    os.environ["NITSCHE_BLAS_DEFAULTED"] = "1"  # numeric factorizations on the cores (nitsche.threads)

import argparse  # noqa: E402
import inspect  # noqa: E402
import json  # noqa: E402
import statistics  # noqa: E402
import subprocess  # noqa: E402
import sys  # noqa: E402
import tempfile  # noqa: E402
import time  # noqa: E402

import numpy as np  # noqa: E402
from threadpoolctl import threadpool_limits  # noqa: E402

from memory_phases import status  # noqa: E402  (/proc/self/status in MB)

HERE = os.path.dirname(os.path.abspath(__file__))
RESULTS = os.path.join(HERE, "results")
PROBLEMS = ("obstacle", "two-membrane", "obstacle-3d")
CODES = ("ours", "skfem", "ngsolve", "linear")
INTORDER = 4          # the quadrature order the cases use for P1 cell constraints (2p + 2)
INTORDER_3D = 2       # obstacle-3d: 4 points per tetrahedron
N0_TET = 5            # obstacle-3d: n = 5 * 2^level cells per side
RTOL = 1e-10          # the same relative residual test for every code
MAXITER = 200         # full-step Newton from zero may need many iterations
N0_3D = 7             # membrane-solid scaling: n = 7 * 2^level cells per side (549k unknowns at 3)
TM = dict(mu1=1.0, mu2=2.0, f1=1.0, f2=-1.0, d=0.05)
OB = dict(T=1.0, f=0.0)
R_STAR = 0.6979651482


# -- the problems -------------------------------------------------------------------

def case_mesh(problem, level):
    """The mesh of the library's case at this level (obstacle-3d: tetrahedra of the cube)."""
    from skfem import MeshTri
    if problem == "obstacle-3d":
        return tensor_mesh(problem, N0_TET * 2 ** level)
    if problem == "obstacle":
        return MeshTri.init_symmetric().scaled((4.0, 4.0)).translated((-2.0, -2.0)).refined(level + 2)
    return MeshTri().refined(level + 2)


def tensor_mesh(problem, n):
    """n x n squares, each cut into two triangles (scaling study); obstacle-3d: n^3 cubes,
    six tetrahedra each."""
    from skfem import MeshTet, MeshTri
    if problem == "obstacle-3d":
        t = np.linspace(-2.0, 2.0, n + 1)
        return MeshTet.init_tensor(t, t, t)
    if problem == "obstacle":
        t = np.linspace(-2.0, 2.0, n + 1)
    else:
        t = np.linspace(0.0, 1.0, n + 1)
    return MeshTri.init_tensor(t, t)


def refined_tensor_mesh(problem, n0, n):
    """The 2D tensor mesh of n x n squares as the n0 x n0 one refined uniformly (n / n0 a
    power of 2): the same triangles as tensor_mesh(problem, n), numbered as a refinement
    numbers them, so that the library prolongates a level to the next from vertex values
    and facet means (no point location), as in the cases' chains."""
    from nitsche.meshes import refined
    times = int(round(np.log2(n / n0)))
    if n0 * 2 ** times != n:
        raise ValueError(f"mesh sizes {n0} and {n}: a refined chain needs n / n0 a power of 2")
    return refined(tensor_mesh(problem, n0), times)


def psi_np(x):
    r2 = sum(xi ** 2 for xi in x)  # (2D and 3D)
    return np.where(r2 < 1.0, np.sqrt(np.maximum(1.0 - r2, 0.0)), -1.0)


def exact_np(x):
    r = np.maximum(np.sqrt(x[0] ** 2 + x[1] ** 2), 1e-300)
    outer = -R_STAR ** 2 * np.log(r / 2) / np.sqrt(1 - R_STAR ** 2)
    return np.where(r <= R_STAR, np.sqrt(np.maximum(1 - r ** 2, 0.0)), outer)


def alpha_of(mesh, alpha0, stiffness):
    """alpha = alpha0 h^2 / stiffness per cell, h = longest edge."""
    p = mesh.p[:, mesh.t]
    nv = p.shape[1]
    h = np.max([np.linalg.norm(p[:, i] - p[:, j], axis=0) for i in range(nv) for j in range(i + 1, nv)],
               axis=0)
    return alpha0 * h ** 2 / stiffness


def nfields(problem):
    return 2 if problem == "two-membrane" else 1


def p1(mesh):
    """The P1 element of the mesh (triangles or tetrahedra) and the quadrature order."""
    from skfem import ElementTetP1, ElementTriP1
    return (ElementTetP1(), INTORDER_3D) if mesh.dim() == 3 else (ElementTriP1(), INTORDER)


def boundary_values(problem, mesh):
    """Vertex values of every field on the boundary (others zero): the start of the peers."""
    b = mesh.boundary_nodes()
    vals = []
    for _ in range(nfields(problem)):
        v = np.zeros(mesh.p.shape[1])
        if problem == "obstacle":
            v[b] = exact_np(mesh.p[:, b])  # (obstacle-3d: zero)
        vals.append(v)
    return vals, b


def referee(problem, mesh, alpha0, fields):
    """J_h and the active-set size (quadrature points) of vertex values `fields` (list)."""
    from skfem import Basis
    basis = Basis(mesh, *p1(mesh)[:1], intorder=p1(mesh)[1])
    dx = basis.dx
    alpha = alpha_of(mesh, alpha0, TM["mu1"] if problem == "two-membrane" else OB["T"])[:, None]
    us = [basis.interpolate(u) for u in fields]
    if problem != "two-membrane":
        u = us[0]
        psi = psi_np(basis.global_coordinates().value)
        T, f = OB["T"], OB["f"]
        s = -f - (u.value - psi) / alpha
        dens = (0.5 * T * (u.grad ** 2).sum(0) - f * u.value - 0.5 * alpha * f ** 2
                + 0.5 * alpha * np.maximum(s, 0) ** 2)
    else:
        u1, u2 = us
        p = TM
        s = p["f1"] - (u2.value + p["d"] - u1.value) / alpha
        dens = (0.5 * p["mu1"] * (u1.grad ** 2).sum(0) + 0.5 * p["mu2"] * (u2.grad ** 2).sum(0)
                - p["f1"] * u1.value - p["f2"] * u2.value - 0.5 * alpha * p["f1"] ** 2
                + 0.5 * alpha * np.maximum(s, 0) ** 2)
    return float((dens * dx).sum()), int((s > 0).sum())


# -- linear algebra shared by the peers: CHOLMOD, symbolic analysis once -------------

class Cholesky:
    """Imports are outside the timed region of every code (sksparse imported at startup)."""

    def __init__(self):
        try:
            from sksparse.cholmod import CholeskyFactor
            self.analyze, self.name = CholeskyFactor, "cholmod"
        except ImportError:
            self.analyze, self.name = None, "superlu"
        self.symbolic = None

    def solve(self, A, b):
        """A double-precision factorization of A (a copy of the kept analysis) and its solve."""
        if self.analyze is None:
            from scipy.sparse.linalg import spsolve
            return spsolve(A.tocsc(), b)
        A = A.tocsc()
        if self.symbolic is None:
            self.symbolic = self.analyze(A, lower=True)
        factor = self.symbolic.copy()
        with factorization_threads():
            factor.factorize(A)
        return factor.solve(b)


def interpreter(root):
    """The Python that runs a checkout: its own environment's (ROOT/.venv, e.g. a link to the
    environment an earlier version was installed in) where it has one, else this one."""
    own = os.path.join(root, ".venv", "bin", "python")
    return own if os.path.exists(own) else sys.executable


def factorization_threads():
    """BLAS on the process's cores for a numeric factorization, as the library runs its own
    (nitsche.threads' rule where the library chose the BLAS threads, restated here: the
    linear code does not import nitsche, which would load JAX)."""
    threads = int(os.environ.get("NITSCHE_FACTOR_THREADS", "0")) or (
        len(os.sched_getaffinity(0)) if os.environ.get("NITSCHE_BLAS_DEFAULTED") == "1" else 1)
    return threadpool_limits(limits=threads, user_api="blas")


# -- the codes (each runs in a subprocess: `peers.py --worker CODE PROBLEM ...`) ------

def run_ours(problem, level, alpha0, mesh_spec=None):
    """Nested chain as `nitsche run` runs it (nitsche.study.nested: each level from the
    previous one's solution, not lifted, the coarser levels to COARSE_RTOL, the minimum
    checked on the finest level only);
    mesh_spec None: the case's levels 0..level; else ('tensor', [n...]).  times: the
    Newton phases summed over the levels, setup = the rest (problems and prolongations)."""
    import nitsche  # noqa: F401
    import nitsche.assembly  # noqa: F401
    from nitsche.allocator import keep_freed_memory
    import nitsche.study as study
    keep_freed_memory()  # as the `nitsche` command does
    from nitsche.cases import get
    t_all = time.perf_counter()
    t = dict(setup=0.0, assembly=0.0, solve=0.0, line_search=0.0, minimum_check=0.0, compile=0.0)
    solve = None
    if problem == "membrane-solid":  # 3D scaling: the case itself, n = 7 * 2^level
        case = get(problem)
        p = case.parameters({"alpha0": str(alpha0), "n0": str(N0_3D)})
        make, solve = [lambda k=k: case.problem(k, 1, p) for k in range(level + 1)], case.solve
    elif problem == "obstacle-3d":  # the nested chain n = 5, 10, ..., 5 * 2^level
        make = [lambda n=n: build_ours(problem, tensor_mesh(problem, n), alpha0)
                for n in mesh_spec or [N0_TET * 2 ** k for k in range(level + 1)]]
    elif mesh_spec is None:
        case = get(problem)
        p = case.parameters({"alpha0": str(alpha0)} | ({"compare": "false"} if problem != "obstacle" else {}))
        make, solve = [lambda k=k: case.problem(k, 1, p) for k in range(level + 1)], case.solve
    else:  # 2D: the n x n tensor meshes as a nested chain does them, each the coarsest refined
        make = [lambda n=n: build_ours(problem, refined_tensor_mesh(problem, mesh_spec[0], n), alpha0)
                for n in mesh_spec]
    its, levels, newton_seconds = [], [], 0.0
    coarse = {option: getattr(study, name) for option, name in (("coarse_rtol", "COARSE_RTOL"),
                  ("coarse_reduction", "COARSE_REDUCTION")) if hasattr(study, name)}  # as `nitsche run`
    if "ahead" in inspect.signature(study.nested).parameters:  # the last level built ahead (session 30)
        coarse["ahead"] = True
    for k, problem_k, result_k in study.nested(lambda i: make[i](), range(len(make)), solve, **coarse):
        result_k.check()
        for key in ("assembly", "solve", "line_search", "minimum_check", "compile"):
            t[key] += result_k.timings.get(key, 0.0)
        its.append(result_k.iterations)
        newton_seconds += result_k.seconds
        levels.append(dict(unknowns=int(problem_k.free.size), iterations=result_k.iterations,
                           seconds=result_k.seconds))
        if k == len(make) - 1:
            prob, res = problem_k, result_k
        problem_k = result_k = None  # not held through the next level (nested holds its own)
    t["setup"] = time.perf_counter() - t_all - newton_seconds  # (wall: set-up beside the solves is not in it)
    t["total"] = time.perf_counter() - t_all
    solve_peak_mb = status("VmHWM")  # (before the fields' lists below)
    parts = prob.split(res.x)
    names = [f.name for f in prob.fields] if problem in PROBLEMS else []  # (not membrane-solid)
    return dict(unknowns=int(prob.free.size), iterations=sum(its), iterations_per_level=its, converged=True,
                finest_iterations=its[-1], times=t, own_energy=res.energy, solve_peak_mb=solve_peak_mb,
                own_active=res.active_count, fields=[np.asarray(parts[n]).tolist() for n in names] or None,
                levels=levels, mesh=prob.fields[0].mesh)


def build_ours(problem, mesh, alpha0):
    """The case's problem on any mesh, through the public API (scaling study)."""
    import jax.numpy as jnp
    from skfem import ElementTriP1
    import nitsche as ni
    from nitsche.ops import dot, grad, lap
    if problem in ("obstacle", "obstacle-3d"):
        T, f = OB["T"], OB["f"]

        dim = mesh.dim()  # (an int: the kernels' key, unlike the mesh, is the same on every level)

        def psi(x):
            r2 = sum(x[i] ** 2 for i in range(dim))
            return jnp.where(r2 < 1.0, jnp.sqrt(jnp.maximum(1.0 - r2, 0.0)), -1.0)

        element, intorder = p1(mesh)
        u = ni.Field("u", mesh, element, fixed="boundary",
                     value=exact_np if problem == "obstacle" else 0.0)
        contact = ni.Inequality(gap=lambda u, x: u - psi(x), multiplier=lambda u: -T * lap(u) - f,
                                scaling=ni.Scaling(alpha0, h_power=2, stiffness=T),
                                on=ni.cells(u, intorder=intorder), name="contact")
        return ni.Problem([u], lambda u: 0.5 * T * dot(grad(u), grad(u)) - f * u, [contact],
                          alpha0_limits={"contact": np.inf})
    p = TM
    element = ElementTriP1()  # one object: the two fields share their basis
    u1 = ni.Field("u1", mesh, element, fixed="boundary")
    u2 = ni.Field("u2", mesh, element, fixed="boundary")
    contact = ni.Inequality(gap=lambda u1, u2: u2 + p["d"] - u1,
                            multiplier=lambda u1: p["f1"] + p["mu1"] * lap(u1),
                            scaling=ni.Scaling(alpha0, h_power=2, stiffness=p["mu1"]),
                            on=ni.cells(u1, intorder=INTORDER), name="contact")

    def energy(u1, u2):
        return (0.5 * p["mu1"] * dot(grad(u1), grad(u1)) + 0.5 * p["mu2"] * dot(grad(u2), grad(u2))
                - p["f1"] * u1 - p["f2"] * u2)
    # P1: lap_h u1 = 0, the multiplier does not depend on u: alpha0 is unconditionally stable
    return ni.Problem([u1, u2], energy, [contact], alpha0_limits={"contact": np.inf})


def run_skfem(problem, level, alpha0):
    import jax.numpy as jnp
    from skfem import Basis, ElementTriP1
    from skfem.autodiff import NonlinearForm
    from skfem.autodiff.helpers import dot, grad
    t_all = time.perf_counter()
    t = dict(setup=0.0, assembly=0.0, solve=0.0, line_search=0.0, compile=0.0)
    t0 = time.perf_counter()
    mesh = case_mesh(problem, level)
    k = nfields(problem)
    element, intorder = p1(mesh)
    element = element if k == 1 else ElementTriP1() * ElementTriP1()
    basis = Basis(mesh, element, intorder=intorder)
    alpha = jnp.asarray(alpha_of(mesh, alpha0, OB["T"] if k == 1 else TM["mu1"])[:, None]
                        * np.ones(basis.dx.shape))
    if k == 1:
        T, f = OB["T"], OB["f"]
        psi = jnp.asarray(psi_np(basis.global_coordinates().value))

        @NonlinearForm(hessian=True)
        def J(u, w):
            s = -f - (u.value - psi) / alpha
            return (0.5 * T * dot(grad(u), grad(u)) - f * u.value - 0.5 * alpha * f ** 2
                    + 0.5 * alpha * jnp.maximum(s, 0.0) ** 2)
        x = np.zeros(basis.N)
        D = basis.get_dofs().all()
        if problem == "obstacle":
            x[D] = exact_np(basis.doflocs[:, D])
    else:
        p = TM

        @NonlinearForm(hessian=True)
        def J(u1, u2, w):
            s = p["f1"] - (u2.value + p["d"] - u1.value) / alpha
            return (0.5 * p["mu1"] * dot(grad(u1), grad(u1)) + 0.5 * p["mu2"] * dot(grad(u2), grad(u2))
                    - p["f1"] * u1.value - p["f2"] * u2.value - 0.5 * alpha * p["f1"] ** 2
                    + 0.5 * alpha * jnp.maximum(s, 0.0) ** 2)
        x = np.zeros(basis.N)
        D = basis.get_dofs().all()
    free = np.setdiff1d(np.arange(basis.N), D)
    lin = Cholesky()
    t["setup"] += time.perf_counter() - t0
    ref, it = None, 0
    for it in range(MAXITER + 1):
        t0 = time.perf_counter()
        A, b = J.assemble(basis, x=x)        # b = -gradient
        t["assembly"] += time.perf_counter() - t0
        r = np.linalg.norm(b[free])
        ref = r if ref is None else ref
        if r <= RTOL * ref:
            break
        t0 = time.perf_counter()
        dx = lin.solve(A[free][:, free], b[free])
        t["solve"] += time.perf_counter() - t0
        x[free] += dx                         # full Newton step
    t["total"] = time.perf_counter() - t_all
    if k == 1:
        fields = [x]
    else:
        fields = [x[i] for i in basis.split_indices()]
    return dict(unknowns=int(free.size), iterations=it, times=t, converged=bool(r <= RTOL * ref),
                fields=[np.asarray(u).tolist() for u in fields], mesh=mesh, solver=lin.name)


def run_ngsolve(problem, level, alpha0):
    if problem == "obstacle-3d":
        raise NotImplementedError("the NGSolve peer is written for triangles only")
    import ngsolve as ng
    import netgen.meshing as nm
    from skfem import Basis, ElementTriP1
    t_all = time.perf_counter()
    t = dict(setup=0.0, assembly=0.0, solve=0.0, line_search=0.0, compile=0.0)
    t0 = time.perf_counter()
    mesh = case_mesh(problem, level)
    k = nfields(problem)
    # the same vertices and triangles, vertex i of scikit-fem = vertex i of NGSolve
    ngm = nm.Mesh(dim=2)
    ngm.AddPoints(np.ascontiguousarray(mesh.p.T))
    ngm.Add(nm.FaceDescriptor(surfnr=1, domin=1, bc=1))
    ngm.AddElements(dim=2, index=1, data=np.ascontiguousarray(mesh.t.T.astype(np.int32)), base=0)
    ngm.AddElements(dim=1, index=1, data=np.ascontiguousarray(mesh.facets[:, mesh.boundary_facets()].T
                                                              .astype(np.int32)), base=0)
    ngm.SetBCName(0, "bnd")
    m = ng.Mesh(ngm)
    stiff = OB["T"] if k == 1 else TM["mu1"]
    a_cell = alpha_of(mesh, alpha0, stiff)
    assert np.allclose(a_cell, a_cell[0]), "structured meshes: alpha is one number"
    alpha = float(a_cell[0])
    # scikit-fem's order-4 rule (a symmetric Dunavant rule) on the same reference triangle
    X, W = Basis(mesh, ElementTriP1(), intorder=INTORDER).quadrature
    ir = ng.IntegrationRule([tuple(p) for p in X.T], list(W))
    dxq = ng.dx(intrules={ng.TRIG: ir})
    V = ng.H1(m, order=1, dirichlet="bnd")
    if k == 1:
        fes = V
        u = fes.TrialFunction()
        T, f = OB["T"], OB["f"]
        r2 = ng.x * ng.x + ng.y * ng.y
        psi = ng.IfPos(1 - r2, ng.sqrt(ng.IfPos(1 - r2, 1 - r2, 0)), -1)
        s = -f - (u - psi) / alpha
        dens = (0.5 * T * ng.grad(u) * ng.grad(u) - f * u - 0.5 * alpha * f ** 2
                + 0.5 * alpha * ng.IfPos(s, s * s, 0))
    else:
        fes = V * V
        u1, u2 = fes.TrialFunction()
        p = TM
        s = p["f1"] - (u2 + p["d"] - u1) / alpha
        dens = (0.5 * p["mu1"] * ng.grad(u1) * ng.grad(u1) + 0.5 * p["mu2"] * ng.grad(u2) * ng.grad(u2)
                - p["f1"] * u1 - p["f2"] * u2 - 0.5 * alpha * p["f1"] ** 2
                + 0.5 * alpha * ng.IfPos(s, s * s, 0))
    a = ng.BilinearForm(fes, symmetric=True)
    a += ng.Variation(dens * dxq)   # NGSolve's SymbolicEnergy integrator
    gfu = ng.GridFunction(fes)
    vals, _ = boundary_values(problem, mesh)
    gfu.vec.FV().NumPy()[:] = np.concatenate(vals)   # order 1: dof i = vertex i (per component)
    res = gfu.vec.CreateVector()
    du = gfu.vec.CreateVector()
    freemask = np.array(list(fes.FreeDofs()), bool)
    t["setup"] += time.perf_counter() - t0
    ref, it = None, 0
    with ng.TaskManager():
        for it in range(MAXITER + 1):
            t0 = time.perf_counter()
            a.Apply(gfu.vec, res)
            a.AssembleLinearization(gfu.vec)
            t["assembly"] += time.perf_counter() - t0
            r = np.linalg.norm(res.FV().NumPy()[freemask])
            ref = r if ref is None else ref
            if r <= RTOL * ref:
                break
            t0 = time.perf_counter()
            inv = a.mat.Inverse(fes.FreeDofs(), inverse="sparsecholesky")
            du.data = inv * res
            t["solve"] += time.perf_counter() - t0
            gfu.vec.data -= du                 # full Newton step
        own = a.Energy(gfu.vec)
    t["total"] = time.perf_counter() - t_all
    x = gfu.vec.FV().NumPy().copy()
    nv = mesh.p.shape[1]
    return dict(unknowns=int(freemask.sum()), iterations=it, times=t, converged=bool(r <= RTOL * ref),
                own_energy=float(own), fields=[x[i * nv:(i + 1) * nv].tolist() for i in range(k)],
                mesh=mesh, solver="ngsolve sparsecholesky")


def run_linear(problem, level, alpha0, mesh_spec=None):
    """One plain assembly of the unconstrained stiffness (per field) and one Cholesky solve;
    on the case's mesh of this level, or (mesh_spec: the sizes of a 2D chain) on the
    n x n tensor mesh of its last size, made at once (tensor_mesh: as a user would)."""
    import scipy.sparse as sp
    from skfem import Basis, BilinearForm, LinearForm, asm
    from skfem.helpers import dot, grad
    try:
        import sksparse.cholmod  # noqa: F401  (imports are not timed, for every code)
    except ImportError:
        pass
    t_all, c_all = time.perf_counter(), time.process_time()
    t = dict(setup=0.0, assembly=0.0, solve=0.0, line_search=0.0, compile=0.0)
    t0 = time.perf_counter()
    mesh = case_mesh(problem, level) if mesh_spec is None else tensor_mesh(problem, mesh_spec[-1])
    basis = Basis(mesh, p1(mesh)[0])
    free = basis.complement_dofs(basis.get_dofs())
    t["setup"] += time.perf_counter() - t0

    @BilinearForm
    def laplace(u, v, w):
        return dot(grad(u), grad(v))

    @LinearForm
    def unit(v, w):
        return v
    t0 = time.perf_counter()
    K = [asm(laplace, basis) for _ in range(nfields(problem))]
    b = asm(unit, basis)
    A = sp.block_diag([Ki[free][:, free] for Ki in K]).tocsc()
    rhs = np.concatenate([b[free]] * len(K))
    t["assembly"] += time.perf_counter() - t0
    t0 = time.perf_counter()
    lin = Cholesky()
    lin.solve(A, rhs)
    t["solve"] += time.perf_counter() - t0
    t["total"], t["cpu"] = time.perf_counter() - t_all, time.process_time() - c_all
    return dict(unknowns=int(A.shape[0]), iterations=1, times=t, mesh=None, solver=lin.name)


def worker(args):
    code, problem, level, alpha0 = args.worker[0], args.worker[1], int(args.worker[2]), float(args.worker[3])
    spec = [int(n) for n in args.worker[4].split(",")] if len(args.worker) > 4 else None
    try:
        import sksparse.cholmod  # noqa: F401  (not timed)
    except ImportError:
        pass
    fn = dict(ours=run_ours, skfem=run_skfem, ngsolve=run_ngsolve, linear=run_linear)[code]
    out = fn(problem, level, alpha0, spec) if code in ("ours", "linear") else fn(problem, level, alpha0)
    # peak resident memory of this process (VmHWM: this exec'd image only; ru_maxrss of a
    # child on Linux also counts the parent's memory at fork time): the solve's own, before
    # the referee's energy below, and the whole run's
    out.setdefault("solve_peak_mb", status("VmHWM"))
    mesh = out.pop("mesh")
    if out.get("fields"):
        fields = [np.asarray(u) for u in out.pop("fields")]
        out["energy"], out["active"] = referee(problem, mesh, alpha0, fields)
    out["code"] = code
    out["peak_mb"] = status("VmHWM")
    with open(args.out, "w") as fh:
        json.dump(out, fh)


# -- the driver ------------------------------------------------------------------------

def available(code):
    mod = dict(skfem="skfem.autodiff", ngsolve="ngsolve").get(code)
    if mod is None:
        return True
    try:
        __import__(mod)
        return True
    except ImportError as e:
        print(f"[skip] peer '{code}' is not installed ({e}); `pip install -e .[bench]`",
              file=sys.stderr)
        return False


def spawn(code, problem, level, alpha0, timeout, spec=None):
    """Run one solve in a child process; its result dict with peak memory (MB)."""
    fd, path = tempfile.mkstemp(suffix=".json")
    os.close(fd)
    cmd = [sys.executable, os.path.abspath(__file__), "--out", path,
           "--worker", code, problem, str(level), str(alpha0)] + ([",".join(map(str, spec))] if spec else [])
    t0 = time.perf_counter()
    proc = subprocess.Popen(cmd)
    deadline = t0 + timeout
    status = None
    while time.perf_counter() < deadline:
        pid, status, ru = os.wait4(proc.pid, os.WNOHANG)
        if pid:
            break
        time.sleep(0.05)
    else:
        proc.kill()
        _, status, ru = os.wait4(proc.pid, 0)
        os.unlink(path)
        return dict(code=code, skipped=f"over the {timeout:.0f} s limit", wall=time.perf_counter() - t0)
    wall = time.perf_counter() - t0
    if status != 0:
        os.unlink(path)
        return dict(code=code, skipped=f"failed (status {status})", wall=wall)
    with open(path) as fh:
        out = json.load(fh)
    os.unlink(path)
    out["wall"], out["cpu"] = wall, ru.ru_utime + ru.ru_stime  # the child's CPU, imports included
    return out


def fmt(v, spec):
    return "-" if v is None else format(v, spec)


def table(rows):
    head = (f"{'problem':<13}{'code':<9}{'unknowns':>9}{'its':>7}{'assembly':>9}{'solve':>8}{'compile':>8}"
            f"{'total':>8}{'peak MB':>9}{'energy':>20}{'active':>9}{'ratio':>8}  converged")
    lines = [head]
    for r in rows:
        if r.get("skipped"):
            lines.append(f"{r['problem']:<13}{r['code']:<9}{fmt(r.get('unknowns'), '>9d')}  skipped: {r['skipped']}")
            continue
        t = r["times"]
        lines.append(f"{r['problem']:<13}{r['code']:<9}{r['unknowns']:>9d}{fmt(r.get('iterations_str'), '>7')}"
                     f"{t['assembly']:>9.2f}{t['solve']:>8.2f}{t['compile']:>8.2f}{t['total']:>8.2f}"
                     f"{r['peak_mb']:>9.0f}{fmt(r.get('energy'), '>20.12g'):>20}{fmt(r.get('active'), '>9d'):>9}"
                     f"{fmt(r.get('ratio'), '>8.2f'):>8}  "
                     f"{'-' if r.get('converged') is None else ('yes' if r['converged'] else 'NO')}")
    return "\n".join(lines)


def estimate(prev, code):
    """Seconds expected at the next level (4x unknowns) from the last measured one."""
    if prev is None or prev.get("skipped"):
        return None
    growth = 4.0 * (1.6 if code in ("skfem", "ngsolve") else 1.1)   # more full-step iterations
    return prev["times"]["total"] * growth


def compare(args):
    rows = []
    codes = [c for c in args.codes if available(c)]
    if "ngsolve" in codes and "obstacle-3d" in args.problems:
        print("[skip] peer 'ngsolve' on obstacle-3d: written for triangles only", file=sys.stderr)
    for problem in args.problems:
        last = {}
        for level in args.levels:
            runs = {c: [] for c in codes}
            reps = args.repeat
            plan = []
            for code in [c for c in codes if not (c == "ngsolve" and problem == "obstacle-3d")]:
                est = estimate(last.get(code), code)
                if code in ("skfem", "ngsolve") and est is not None and est > args.peer_limit:
                    runs[code] = None
                    print(f"[skip] {problem} level {level}: {code} estimated {est:.0f} s > "
                          f"{args.peer_limit:.0f} s", file=sys.stderr, flush=True)
                else:
                    plan.append(code)
            slow = {c for c in plan if (estimate(last.get(c), c) or 0) > 60}   # one run is enough
            for rep in range(reps):
                for code in plan:
                    if code in ("skfem", "ngsolve") and (rep >= args.peer_repeat or rep and code in slow):
                        continue
                    if runs[code] and runs[code][-1].get("skipped"):
                        continue
                    out = spawn(code, problem, level, args.alpha0, args.peer_limit * 1.5
                                if code in ("skfem", "ngsolve") else 1200)
                    out.update(problem=problem, level=level, rep=rep)
                    print(f"  {problem} L{level} rep {rep} {code}: "
                          + (out['skipped'] if out.get('skipped') else
                             f"{out['unknowns']} unknowns, {out['iterations']} its, "
                             f"{out['times']['total']:.2f} s, {out['peak_mb']:.0f} MB, "
                             f"E = {out.get('energy', float('nan')):.12g}, active {out.get('active')}"),
                          file=sys.stderr, flush=True)
                    runs[code].append(out)
            ours = [r for r in runs.get("ours") or [] if not r.get("skipped")]
            for code in [c for c in codes if runs[c] is None or runs[c]]:
                if runs[code] is None:
                    rows.append(dict(problem=problem, level=level, code=code,
                                     skipped=f"one run estimated over {args.peer_limit:.0f} s",
                                     unknowns=ours[0]["unknowns"] if ours else None))
                    continue
                ok = [r for r in runs[code] if not r.get("skipped")]
                if not ok:
                    rows.append(dict(runs[code][-1], unknowns=ours[0]["unknowns"] if ours else None))
                    last[code] = runs[code][-1]
                    continue
                med = dict(ok[0])
                med["times"] = {k: statistics.median(r["times"][k] for r in ok) for k in ok[0]["times"]}
                med["peak_mb"] = statistics.median(r["peak_mb"] for r in ok)
                med["repeats"] = len(ok)
                if code == "ours":
                    med["iterations_str"] = f"{ok[0]['finest_iterations']}/{ok[0]['iterations']}"
                else:
                    med["iterations_str"] = str(ok[0]["iterations"])
                if code != "ours" and ours:
                    pair = [r["times"]["total"] / o["times"]["total"]
                            for r, o in zip(ok, ours)]
                    med["ratio"] = statistics.median(pair)
                    med["ratios"] = pair
                med.pop("rep", None)
                rows.append(med)
                last[code] = med
            print(table([r for r in rows if r["problem"] == problem and r["level"] == level]),
                  flush=True)
    print("\n" + table(rows))
    os.makedirs(RESULTS, exist_ok=True)
    with open(os.path.join(RESULTS, args.name), "w") as fh:
        json.dump(dict(rows=rows, alpha0=args.alpha0, cpu_count=os.cpu_count(),
                       date=time.strftime("%Y-%m-%d"), rtol=RTOL, intorder=INTORDER), fh, indent=1)


def scaling(args):
    """Ours only, nested chain per size: 2D tensor meshes up to ~1M unknowns, and the 3D
    membrane-solid case up to 549k unknowns."""
    chains = dict(obstacle=[8 * 2 ** k for k in range(8)],        # n = 8 .. 1024: 1.05M unknowns
                  **{"two-membrane": [6 * 2 ** k for k in range(8)],    # n = 6 .. 768: 1.18M
                     "obstacle-3d": [N0_TET * 2 ** k for k in range(5)]})  # n = 5 .. 80: 493k
    rows = []
    for problem in args.problems:
        ns = chains[problem]
        for top in range(3, len(ns)):
            if args.max_n and ns[top] > args.max_n:
                break
            out = spawn("ours", problem, 0, args.alpha0, 1200, spec=ns[:top + 1])
            out.update(problem=problem, n=ns[top])
            rows.append(out)
            report(out)
    if "membrane-solid" in args.problems_3d:
        for level in range(1, 4):
            if args.max_n and N0_3D * 2 ** level > args.max_n:
                break
            out = spawn("ours", "membrane-solid", level, args.alpha0, 1200)
            out.update(problem="membrane-solid", n=N0_3D * 2 ** level)
            rows.append(out)
            report(out)
    os.makedirs(RESULTS, exist_ok=True)
    with open(os.path.join(RESULTS, "scaling.json"), "w") as fh:
        json.dump(dict(rows=rows, alpha0=args.alpha0, cpu_count=os.cpu_count(),
                       date=time.strftime("%Y-%m-%d")), fh, indent=1)
    plot_scaling(rows)


def report(out):
    t = out.get("times", {})
    print(f"{out['problem']:<15} n={out['n']:<5} {out.get('unknowns', 0):>9} unknowns  "
          f"its/level {out.get('iterations_per_level')}  total {t.get('total', float('nan')):7.2f} s "
          f"(setup {t.get('setup', 0):.2f}, assembly {t.get('assembly', 0):.2f}, "
          f"solve {t.get('solve', 0):.2f}, line search {t.get('line_search', 0):.2f}, "
          f"compile {t.get('compile', 0):.2f})  peak {out.get('peak_mb', 0):.0f} MB  "
          f"wall {out.get('wall', 0):.1f} s", flush=True)


def plot_scaling(rows):
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    fig, ax = plt.subplots(1, 2, figsize=(11, 4.3))
    for problem, mk in (("obstacle", "o-"), ("two-membrane", "s-"), ("membrane-solid", "^-")):
        rr = [r for r in rows if r["problem"] == problem and not r.get("skipped")]
        if not rr:
            continue
        n = np.array([r["unknowns"] for r in rr])
        ax[0].loglog(n, [r["times"]["total"] for r in rr], mk, label=f"{problem}: total")
        ax[0].loglog(n, [r["times"]["total"] - r["times"]["compile"] for r in rr], mk[0] + ":",
                     label=f"{problem}: without compile")
        ax[1].loglog(n, [r.get("solve_peak_mb", r["peak_mb"]) / 1024 for r in rr], mk, label=problem)
    n = np.array([1e4, 1e6])
    ax[0].loglog(n, 20 * n / 1e6, "k--", lw=0.8, label="linear in N (20 s at 1M)")
    for seconds, problem, style in ((15, "obstacle", ":"), (25, "two membranes", "-")):  # issue 16's 1M targets
        ax[0].axhline(seconds, color="r", lw=0.6, ls=style, label=f"target at 1M, {problem}: {seconds} s")
    ax[0].set_xlabel("unknowns")
    ax[0].set_ylabel("seconds (nested chain; 2D P1, 3D Q1/Hex1)")
    ax[1].set_xlabel("unknowns")
    ax[1].set_ylabel("peak memory of the chain, GB (VmHWM)")
    for a in ax:
        a.grid(True, which="both", alpha=0.3)
        a.legend(fontsize=8)
    fig.suptitle(f"nitsche, time and memory to solution ({os.cpu_count()} cores)")
    fig.tight_layout()
    fig.savefig(os.path.join(RESULTS, "scaling.png"), dpi=110)
    plt.close(fig)


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--problems", nargs="+", default=list(PROBLEMS[:2]), choices=PROBLEMS)
    ap.add_argument("--levels", nargs="+", type=int, default=[3, 4, 5, 6, 7],
                    help="case levels (obstacle/two-membrane P1: 2k, 8k, 33k, 131k, 524k unknowns)")
    ap.add_argument("--codes", nargs="+", default=list(CODES), choices=CODES)
    ap.add_argument("--alpha0", type=float, default=0.1)
    ap.add_argument("--repeat", type=int, default=3, help="repetitions of ours and linear")
    ap.add_argument("--peer-repeat", type=int, default=3, help="repetitions of the peers")
    ap.add_argument("--peer-limit", type=float, default=240.0,
                    help="skip a peer whose one run is expected to take longer (seconds)")
    ap.add_argument("--name", default="peers.json", help="the comparison's results file in benchmarks/results")
    ap.add_argument("--scaling", action="store_true")
    ap.add_argument("--max-n", type=int, default=0, help="scaling: largest mesh n (0: all)")
    ap.add_argument("--problems-3d", nargs="*", default=["membrane-solid"], choices=["membrane-solid"],
                    help="scaling: 3D problems (none: --problems-3d with no value)")
    ap.add_argument("--worker", nargs="+", help=argparse.SUPPRESS)
    ap.add_argument("--out", help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.worker:
        return worker(args)
    if args.scaling:
        return scaling(args)
    compare(args)


if __name__ == "__main__":
    main()
