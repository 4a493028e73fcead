"""The finest level of a 3D nested chain with AMG-CG variants and CHOLMOD, side by side.

For CASE at --level L (--set name=value ...), the chain 0..L-1 is solved once (the library's
'auto' solver) and its solution prolongated to level L; then each variant minimizes J_h on
level L from that start (as nested iteration's finest level does: no lift, the minimum
check) in its own process, the variants interleaved, --repeat times:
  amg         AMGCG as shipped (nitsche.linalg; since session 24 its finest level refreshed
              to each Newton matrix, slack 20)
  amg-double  AMGCG as shipped with its hierarchy kept and applied in double precision
  amg-s22     AMGCG of session 22: pyamg's hierarchy of the unscaled matrix (Jacobi
              prolongation smoother, restarted Arnoldi for rho(D^-1 A)) in double
              precision, applied by pyamg's own V-cycle, the options as now, not refreshed,
              the rebuild limit of sessions 22-23 (2 x rate + 2 iterations)
  amg-before  amg-s22 with pyamg's default options (its symmetric strength measure on every
              level, the candidates improved by 4 Gauss-Seidel sweeps) and the earlier
              rebuild limit (4 x rate + 10 iterations)
  cholmod     CHOLMOD with factor reuse
Per run: Newton iterations, J_h, CG iterations per step, AMG set-ups, the CPU time of the
AMG set-ups, of CG and of the minimum check, Newton's phase timings (wall), the child's
CPU time (user + system: problem set-up and imports included) and peak memory (ru_maxrss),
and, in the amg child, one linear solve: a fresh AMG set-up and CG to 1e-10 on the first
Newton matrix (the `ratio` is the level's Newton CPU time over that solve's).  The machine
may be shared: compare CPU times and medians.  Rows appended to
benchmarks/results/amg_3d.json (--name: another file).

    python benchmarks/amg_3d.py --level 3 --set cells=tet --repeat 3
    python benchmarks/amg_3d.py --level 2 --set cells=tet n0=9 --variants amg cholmod
"""
import argparse
import json
import os
import statistics
import subprocess
import sys
import tempfile
import time

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
HERE = os.path.dirname(os.path.abspath(__file__))
RESULTS = os.path.join(HERE, "results")
VARIANTS = ("amg", "amg-double", "amg-s22", "amg-before", "cholmod")


def session22(base):
    """AMGCG with session 22's hierarchy: pyamg's smoothed aggregation of A itself in double
    precision and pyamg's V-cycle (MultilevelSolver.aspreconditioner)."""
    class AMGCG22(base):
        @staticmethod
        def options():
            return dict(symmetry="symmetric", improve_candidates=None,
                        strength=[(None, {}), ("symmetric", {"theta": 0.0})])

        def _build(self, A):
            import pyamg
            B = self.B if self.B is not None and self.B.shape[0] == A.shape[0] else None
            self.ml = pyamg.smoothed_aggregation_solver(A, B=B, **(self.pyamg_options or self.options()))
            self.M, self.rate = self.ml.aspreconditioner(cycle="V"), None
            self.setups += 1

        def refresh(self, A):
            """Session 22 kept the hierarchy as built (no refresh of its finest level)."""
    return AMGCG22


def solver(variant):
    import numpy as np
    from nitsche.linalg import AMGCG
    if variant == "amg":
        return AMGCG()
    if variant == "amg-double":
        return AMGCG(dtype=np.float64)
    if variant == "amg-s22":
        return session22(AMGCG)(slack=2)
    if variant == "amg-before":
        return session22(AMGCG)(rebuild_factor=4.0, slack=10, pyamg_options=dict(symmetry="symmetric"))
    return variant


def cpu_timed(obj, name, into):
    """Wrap obj.name to add its CPU seconds to into[name]."""
    f = getattr(obj, name)

    def timed(*args, **kwargs):
        t = time.process_time()
        try:
            return f(*args, **kwargs)
        finally:
            into[name] = into.get(name, 0.0) + time.process_time() - t
    setattr(obj, name, timed)


def problem_of(args):
    from nitsche.cases import get
    case = get(args.case)
    p = case.parameters(dict(s.split("=", 1) for s in args.set))
    return case, p


def prepare(args, path):
    """Solve levels 0..L-1 and save the prolongated start of level L."""
    import numpy as np
    from nitsche.study import nested, prolongate
    case, p = problem_of(args)
    for _, coarse, result in nested(lambda k: case.problem(k, 1, p), range(args.level), case.solve):
        result.check()
    x0 = prolongate(coarse, result.x, case.problem(args.level, 1, p))
    np.save(path, x0)


def child(args, variant, path):
    import numpy as np
    case, p = problem_of(args)
    c0 = time.process_time()
    problem = case.problem(args.level, 1, p)
    x0 = np.load(path)
    lin, cpu = solver(variant), {}
    if not isinstance(lin, str):
        for name in ("_build", "_cg", "is_positive_definite"):
            cpu_timed(lin, name, cpu)
    c1 = time.process_time()
    r = problem.minimize(x0, solver=lin, lift=False)
    row = dict(variant=variant, unknowns=int(problem.free.size), converged=bool(r.converged),
               newton_iterations=r.iterations, energy=float(r.energy), solver=r.solver,
               solver_stats=r.solver_stats, timings=r.timings,
               newton_cpu_seconds=time.process_time() - c1, setup_cpu_seconds=c1 - c0,
               amg_setup_cpu_seconds=cpu.get("_build"), cg_cpu_seconds=cpu.get("_cg"),
               minimum_check_cpu_seconds=cpu.get("is_positive_definite"))
    if variant == "amg":  # one linear solve: a fresh hierarchy and CG to 1e-10
        lin = None  # (the Newton solve's hierarchy not held through it)
        one = solver("amg")
        one.prepare(problem)
        _, g, A = problem.newton_system(x0)
        A = A.tocsr()
        t = time.process_time()
        one._build(A)
        _, info, its = one._cg(A, -g, 1e-10)
        row.update(linear_solve_cpu_seconds=time.process_time() - t, linear_solve_cg_iterations=its)
    print("ROW " + json.dumps(row))


def command(args, what, path):
    """This script as a child process doing `what` (a variant, or prepare) with the start file."""
    return [sys.executable, os.path.abspath(__file__), "--child", what, "--start", path,
            "--case", args.case, "--level", str(args.level), "--set", *args.set]


def run_child(args, variant, path):
    proc = subprocess.Popen(command(args, variant, path), stdout=subprocess.PIPE, text=True)
    out = proc.stdout.read()
    _, status, usage = os.wait4(proc.pid, 0)
    if status != 0:
        raise RuntimeError(f"{variant} failed (status {status})")
    row = json.loads(next(line[4:] for line in out.splitlines() if line.startswith("ROW ")))
    row.update(process_cpu_seconds=usage.ru_utime + usage.ru_stime, peak_mb=usage.ru_maxrss / 1024)
    return row


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--case", default="membrane-solid")
    ap.add_argument("--level", type=int, default=3)
    ap.add_argument("--set", nargs="*", default=[], help="case parameters name=value")
    ap.add_argument("--variants", nargs="+", choices=VARIANTS, default=list(VARIANTS))
    ap.add_argument("--repeat", type=int, default=1)
    ap.add_argument("--name", default="amg_3d.json")
    ap.add_argument("--child", choices=VARIANTS + ("prepare",), help=argparse.SUPPRESS)
    ap.add_argument("--start", help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.child:
        return (prepare if args.child == "prepare" else lambda a, p: child(a, args.child, p))(args, args.start)
    with tempfile.TemporaryDirectory(prefix="amg_3d_") as tmp:
        path = os.path.join(tmp, "x0.npy")
        subprocess.run(command(args, "prepare", path), check=True)
        loads, runs = [os.getloadavg()[0]], {v: [] for v in args.variants}
        for _ in range(args.repeat):
            for v in args.variants:
                runs[v].append(run_child(args, v, path))
                loads.append(os.getloadavg()[0])
    rows = []
    print(f"{args.case} level {args.level} {' '.join(args.set)}: load {min(loads):.1f}-{max(loads):.1f}, "
          f"medians of {args.repeat}")
    print("| variant | Newton its | CG its per step | AMG set-ups | set-up CPU s | CG CPU s | "
          "minimum check CPU s | level's Newton CPU s | / one linear solve | process CPU s | peak MB | J_h |")
    print("|---|---:|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|")
    med = lambda rs, k: statistics.median(r[k] for r in rs) if rs[0].get(k) is not None else None  # noqa: E731
    linear = med(runs["amg"], "linear_solve_cpu_seconds") if "amg" in runs else None
    for v, rs in runs.items():
        r = rs[0]
        cg = r["solver_stats"].get("cg_iterations")
        newton = med(rs, "newton_cpu_seconds")
        fmt = lambda x: "-" if x is None else f"{x:.2f}"  # noqa: E731
        print(f"| {v} | {r['newton_iterations']} | {cg} | {r['solver_stats'].get('amg_setups', '-')} | "
              f"{fmt(med(rs, 'amg_setup_cpu_seconds'))} | {fmt(med(rs, 'cg_cpu_seconds'))} | "
              f"{fmt(med(rs, 'minimum_check_cpu_seconds'))} | {newton:.2f} | "
              f"{fmt(newton / linear if linear else None)} | {med(rs, 'process_cpu_seconds'):.2f} | "
              f"{med(rs, 'peak_mb'):.0f} | {r['energy']:.15g} |")
        rows += [dict(row, case=args.case, level=args.level, sets=args.set) for row in rs]
    if linear:
        print(f"one linear solve (AMG set-up + CG to 1e-10 on the first Newton matrix): {linear:.2f} s CPU, "
              f"{runs['amg'][0]['linear_solve_cg_iterations']} CG iterations")
    os.makedirs(RESULTS, exist_ok=True)
    path = os.path.join(RESULTS, args.name)
    old = json.load(open(path))["rows"] if os.path.exists(path) else []
    stamp = dict(date=time.strftime("%Y-%m-%d %H:%M"), load=[min(loads), max(loads)], commit=os.popen(
        f"git -C {HERE} rev-parse --short HEAD 2>/dev/null").read().strip())
    with open(path, "w") as fh:
        json.dump(dict(rows=old + [dict(r, **stamp) for r in rows]), fh, indent=1)


if __name__ == "__main__":
    sys.exit(main())
