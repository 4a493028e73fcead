"""The per-step assembly with the per-element data on the device (assembly.Chunked) against
an earlier checkout of the code (and other designs), side by side in one run.

For each case the problem is set up in a fresh process per code version (this checkout:
"now"; the one given by --before: "before"), one after the other (one heavy process at a
time), and at x = the initial guess + 1e-3 noise it times:
  - the first Hessian assembly (loads or compiles the kernels; a fully device-resident
    design also compiles its gathers and scatters for this mesh's sizes) and then
    `--repeat` Hessian assemblies (Assembler.evaluate: J, gradient, CSR data) and gradient
    assemblies (J and gradient), wall and CPU time (user + sys of the process, all
    threads), medians;
  - memory: the resident set after set-up and its peak during the steps (VmHWM, reset
    after set-up), in MB.
J, the gradient and the Hessian data of the versions are compared with "before" (max
relative difference).  --runs times whole `nitsche run` processes (the nested chain and
its outputs: CPU seconds, wall, peak RSS), version after version.  --also adds further
versions (e.g. a rejected design).  Writes benchmarks/results/device_path.json.  Usage:

    git archive <commit> nitsche | tar -x -C /tmp/before     # the earlier code
    python benchmarks/device_path.py --before /tmp/before [--also NAME=DIR ...] [--repeat 5]
        [--cases obstacle:6 ...] [--runs obstacle:6 ...]

--platform cpu|cuda sets JAX_PLATFORMS for the measured processes; on a machine with an
NVIDIA GPU install JAX's CUDA wheels first (pip install -U "jax[cuda12]") and run with
--platform cuda: the per-element data then live in GPU memory; per kernel call the element
dofs x[dofs] go there and the outputs come back to the host's bincount, scatter and sparse
solvers.
"""
import argparse
import json
import os
import pickle
import statistics
import subprocess
import sys
import tempfile
import time

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, HERE)
from run_ratio import write_results  # noqa: E402

CASES = {"obstacle:4": ("obstacle", 4, {}), "obstacle:6": ("obstacle", 6, {}), "obstacle:7": ("obstacle", 7, {}),
         "two-membrane:6": ("two-membrane", 6, {"compare": "false"}),
         "membrane-solid-tet:3": ("membrane-solid", 3, {"cells": "tet"})}


def status(key):
    """A line of /proc/self/status in MB (VmRSS, VmHWM)."""
    with open("/proc/self/status") as fh:
        for line in fh:
            if line.startswith(key + ":"):
                return int(line.split()[1]) / 1024
    return float("nan")


def cpu():
    """CPU seconds of this process, all threads (user + sys)."""
    return time.process_time()


def child(spec, repeat, dump):
    """Measure one case in this process (the code on sys.path) and print a JSON row."""
    import jax
    import numpy as np
    from nitsche.cases import get
    name, level, sets = CASES[spec]
    case = get(name)
    t0 = time.perf_counter()
    problem = case.problem(level, 1, case.parameters(sets))
    setup = time.perf_counter() - t0
    a = problem.assembler
    x = problem.initial(None) + 1e-3 * np.random.default_rng(0).standard_normal(problem.ndofs)
    rss = status("VmRSS")
    with open("/proc/self/clear_refs", "w") as fh:  # reset VmHWM
        fh.write("5")
    w, c = time.perf_counter(), cpu()
    E, g, data = a.evaluate(x)
    first = (time.perf_counter() - w, cpu() - c)
    a.evaluate(x, hessian=False)  # loads the gradient kernels (not timed)
    steps = {"hessian": [], "gradient": []}
    for _ in range(repeat):
        for kind, hessian in (("hessian", True), ("gradient", False)):
            w, c = time.perf_counter(), cpu()
            a.evaluate(x, hessian=hessian)
            steps[kind].append((time.perf_counter() - w, cpu() - c))
    with open(dump, "wb") as fh:
        pickle.dump((E, np.asarray(g), np.asarray(data)), fh)
    row = dict(unknowns=int(problem.free.size), nnz=int(a.nnz), elements=int(sum(t.nel for t in a.terms)),
               setup_seconds=setup, first_wall=first[0], first_cpu=first[1],
               rss_after_setup_mb=rss, step_peak_rss_mb=status("VmHWM"), device=str(jax.devices()[0]))
    for kind, v in steps.items():
        row[f"{kind}_wall"] = statistics.median(s[0] for s in v)
        row[f"{kind}_cpu"] = statistics.median(s[1] for s in v)
    print("ROW " + json.dumps(row), flush=True)


def measure(spec, code, repeat, platform, dump):
    env = dict(os.environ, PYTHONPATH=code, JAX_PLATFORMS=platform)
    out = subprocess.run([sys.executable, os.path.abspath(__file__), "--child", spec, "--repeat", str(repeat),
                          "--dump", dump], env=env, capture_output=True, text=True, check=False)
    rows = [line[4:] for line in out.stdout.splitlines() if line.startswith("ROW ")]
    if not rows:
        raise RuntimeError(f"{spec} with {code} failed:\n{out.stderr[-3000:]}")
    return json.loads(rows[0])


def whole_run(spec, code, platform, out):
    """`nitsche run CASE --level L` (the nested chain with its outputs) in a fresh process:
    its CPU seconds (user + sys) and peak resident set (MB), and J_h and the iterations."""
    name, level, sets = CASES[spec]
    command = [sys.executable, "-c", "import sys; from nitsche.cli import main; sys.exit(main())", "run", name,
               "--level", str(level), "--out", out] + [a for k, v in sets.items() for a in ("--set", f"{k}={v}")]
    env = dict(os.environ, PYTHONPATH=code, JAX_PLATFORMS=platform)
    wall = time.perf_counter()
    proc = subprocess.Popen(command, env=env, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    _, status, usage = os.wait4(proc.pid, 0)
    wall = time.perf_counter() - wall
    if status:
        raise RuntimeError(f"{' '.join(command)} failed (status {status})")
    with open(os.path.join(out, "result.json")) as fh:
        result = json.load(fh)
    return dict(cpu=usage.ru_utime + usage.ru_stime, wall=wall, peak_mb=usage.ru_maxrss / 1024,
                energy=result.get("energy"), iterations=result.get("nested_iterations", result.get("iterations")))


def relative(u, v):
    import numpy as np
    u, v = np.asarray(u, float), np.asarray(v, float)
    return float(np.abs(u - v).max() / max(np.abs(v).max(), 1e-300))


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--before", help="a directory holding the earlier nitsche package")
    ap.add_argument("--also", nargs="*", default=[], metavar="NAME=DIR",
                    help="further versions to measure side by side (e.g. a design that was rejected)")
    ap.add_argument("--cases", nargs="+", default=list(CASES), choices=list(CASES))
    ap.add_argument("--repeat", type=int, default=5)
    ap.add_argument("--platform", default="cpu", help="JAX_PLATFORMS of the measured processes (cpu, cuda)")
    ap.add_argument("--runs", nargs="*", default=[], choices=list(CASES),
                    help="also time whole `nitsche run` processes of these cases, versions alternating")
    ap.add_argument("--out", default="device_path.json")
    ap.add_argument("--child")
    ap.add_argument("--dump")
    args = ap.parse_args()
    if args.child:
        return child(args.child, args.repeat, args.dump)
    now = os.path.dirname(HERE)
    versions = [("before", os.path.abspath(args.before))] if args.before else []
    versions += [(v.split("=", 1)[0], os.path.abspath(v.split("=", 1)[1])) for v in args.also]
    versions.append(("now", now))
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        for spec in args.cases:
            load = os.getloadavg()[0]
            got = {v: measure(spec, code, args.repeat, args.platform, os.path.join(tmp, v)) for v, code in versions}
            row = dict(case=spec, load=load, **{f"{v}_{k}": val for v, r in got.items() for k, val in r.items()})
            if args.before:
                E0, g0, d0 = pickle.load(open(os.path.join(tmp, "before"), "rb"))
                for v, _ in versions[1:]:
                    E1, g1, d1 = pickle.load(open(os.path.join(tmp, v), "rb"))
                    row.update({f"{v}_rel_energy": abs(E1 - E0) / abs(E0), f"{v}_rel_gradient": relative(g1, g0),
                                f"{v}_rel_hessian": relative(d1, d0)})
                    for k in ("hessian_wall", "hessian_cpu", "gradient_wall", "gradient_cpu", "first_cpu",
                              "rss_after_setup_mb", "step_peak_rss_mb"):
                        row[f"{v}_ratio_{k}"] = got[v][k] / got["before"][k]
            rows.append(row)
            print(json.dumps(row), flush=True)
        for spec in args.runs:
            load = os.getloadavg()[0]
            got = {v: whole_run(spec, code, args.platform, os.path.join(tmp, f"run-{v}")) for v, code in versions}
            row = dict(case=f"run {spec}", load=load,
                       **{f"{v}_run_{k}": val for v, r in got.items() for k, val in r.items()})
            rows.append(row)
            print(json.dumps(row), flush=True)
    print(f"\n{'case':22s} {'version':10s} {'unknowns':>9s} {'hess wall':>9s} {'hess cpu':>9s} {'grad wall':>9s} "
          f"{'grad cpu':>9s} {'first':>7s} {'rss MB':>8s} {'peak MB':>8s}")
    for r in rows:
        if r["case"].startswith("run "):
            print(f"{r['case']:22s} " + "; ".join(f"{v}: {r[f'{v}_run_cpu']:.2f} s CPU, {r[f'{v}_run_wall']:.2f} s "
                                                  f"wall, {r[f'{v}_run_peak_mb']:.0f} MB" for v, _ in versions))
            continue
        for v, _ in versions:
            print(f"{r['case']:22s} {v:10s} {r[f'{v}_unknowns']:9d} {r[f'{v}_hessian_wall']:9.3f} "
                  f"{r[f'{v}_hessian_cpu']:9.3f} {r[f'{v}_gradient_wall']:9.3f} {r[f'{v}_gradient_cpu']:9.3f} "
                  f"{r[f'{v}_first_wall']:7.2f} {r[f'{v}_rss_after_setup_mb']:8.0f} {r[f'{v}_step_peak_rss_mb']:8.0f}")
        for v, _ in versions[1:] if args.before else []:
            print(f"{'':22s} {v}/before: hessian wall {r[f'{v}_ratio_hessian_wall']:.2f}, "
                  f"cpu {r[f'{v}_ratio_hessian_cpu']:.2f}; gradient wall {r[f'{v}_ratio_gradient_wall']:.2f}, "
                  f"cpu {r[f'{v}_ratio_gradient_cpu']:.2f}; first cpu {r[f'{v}_ratio_first_cpu']:.2f}; "
                  f"rss {r[f'{v}_ratio_rss_after_setup_mb']:.2f}, peak {r[f'{v}_ratio_step_peak_rss_mb']:.2f}; "
                  f"max rel. diff J {r[f'{v}_rel_energy']:.1e}, gradient {r[f'{v}_rel_gradient']:.1e}, "
                  f"Hessian {r[f'{v}_rel_hessian']:.1e}")
    write_results(args.out, rows, "per-step assembly, device path (now) against --before, medians of "
                  f"{args.repeat}; CPU = user + sys of the process; load = 1-min load average at the case's start")


if __name__ == "__main__":
    main()
