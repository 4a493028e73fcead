"""`nitsche run CASE --level L` against one linear solve of the same size, side by side.

Each repetition runs, in fresh processes and interleaved (ours, linear, ours, ...):
  ours    the command `nitsche run CASE --level L` (the whole nested chain 0..L, set-up,
          compilation or loading of the kernels and the minimum check included): its
          result.json `seconds` (the chain) and `output_seconds` (errors, reactions, VTU,
          figures) and `cpu_seconds` (the CPU time of both), the per-phase timings of the
          finest level, the process's CPU time (user + system, imports included) and peak
          resident memory (ru_maxrss);
  linear  benchmarks/peers.py's linear code: the case's mesh, one scikit-fem Laplace
          assembly per field and one CHOLMOD analyze-factorize-solve (mesh and basis
          included; its wall and CPU time without imports), its process's CPU time (imports
          included) and its peak memory (VmHWM).
The ratios ours / linear are taken within each repetition and their median printed (the
machine may be shared: read the ratios, not the seconds; the CPU ratio is the one a busy
machine disturbs least).  Writes benchmarks/results/run_ratio.json (--name: another file).

    python benchmarks/run_ratio.py --cases obstacle two-membrane --level 6 --repeat 3
    python benchmarks/run_ratio.py --before /tmp/before   # an earlier version side by side
    (a checkout runs with its own environment's Python, CHECKOUT/.venv, where it has one: e.g.
    `ln -s /tmp/old-venv /tmp/before/.venv` for a version built against other libraries)
"""
import argparse
import json
import os
import shutil
import statistics
import subprocess
import sys
import tempfile
import time

HERE = os.path.dirname(os.path.abspath(__file__))
RESULTS = os.path.join(HERE, "results")
sys.path.insert(0, HERE)
import peers  # noqa: E402


def run_ours(case, level, source=None):
    """`nitsche run` in a child process (source: a checkout of another version to import
    nitsche from): (result.json, peak MB: the child's ru_maxrss, which on Linux also counts
    this small parent's memory at fork time, CPU s: the child's user + system time)."""
    out = tempfile.mkdtemp(prefix="run_ratio_")
    command = [peers.interpreter(source) if source else sys.executable, "-c",
               "import sys; from nitsche.cli import main; sys.exit(main())"]
    env = dict(os.environ, PYTHONPATH=source) if source else None
    proc = subprocess.Popen(command + ["run", case, "--level", str(level), "--out", out], cwd=out,
                            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, env=env)
    # (cwd: `python -c` imports from its working directory first, which must not shadow `source`)
    _, status, usage = os.wait4(proc.pid, 0)
    if status != 0:
        raise RuntimeError(f"nitsche run {case} --level {level} failed (status {status})")
    with open(os.path.join(out, "result.json")) as fh:
        data = json.load(fh)
    shutil.rmtree(out, ignore_errors=True)
    return data, usage.ru_maxrss / 1024.0, usage.ru_utime + usage.ru_stime


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--cases", nargs="+", default=["obstacle", "two-membrane"])
    ap.add_argument("--level", type=int, default=6)
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--before", help="a checkout of an earlier version, run side by side "
                    "(e.g. git worktree add /tmp/before COMMIT)")
    ap.add_argument("--name", default="run_ratio.json", help="the results file in benchmarks/results")
    args = ap.parse_args()
    rows = []
    for case in args.cases:
        runs = []
        for rep in range(args.repeat):
            data, peak, cpu = run_ours(case, args.level)
            linear = peers.spawn("linear", case, args.level, 0.1, 1200)
            runs.append(dict(seconds=data["seconds"], output_seconds=data.get("output_seconds", 0.0),
                             cpu_seconds=data.get("cpu_seconds"), process_cpu_seconds=cpu,
                             peak_mb=peak, unknowns=data["unknowns"],
                             energy=data["energy"], iterations=data["nested_iterations"],
                             timings=data["timings"], linear_seconds=linear["times"]["total"],
                             linear_cpu_seconds=linear["times"]["cpu"], linear_process_cpu_seconds=linear["cpu"],
                             linear_peak_mb=linear["peak_mb"], linear_unknowns=linear["unknowns"]))
            r = runs[-1]
            r["with_outputs"] = r["seconds"] + r["output_seconds"]
            if args.before:
                old, old_peak, old_cpu = run_ours(case, args.level, args.before)
                r.update(before_seconds=old["seconds"], before_peak_mb=old_peak, before_energy=old["energy"],
                         before_cpu_seconds=old.get("cpu_seconds"), before_process_cpu_seconds=old_cpu)
            print(f"  {case} L{args.level} rep {rep}: ours {r['seconds']:.2f} s (+ outputs "
                  f"{r['output_seconds']:.2f} s), CPU {r['cpu_seconds']:.2f} s (process {cpu:.2f} s), "
                  f"{r['peak_mb']:.0f} MB; linear {r['linear_seconds']:.2f} s, CPU {r['linear_cpu_seconds']:.2f} "
                  f"s (process {linear['cpu']:.2f} s), {r['linear_peak_mb']:.0f} MB"
                  + (f"; before {r['before_seconds']:.2f} s, process CPU {old_cpu:.2f} s, "
                     f"{r['before_peak_mb']:.0f} MB" if args.before else ""),
                  file=sys.stderr, flush=True)
        med = lambda key: statistics.median(r[key] for r in runs)
        rows.append(dict(case=case, level=args.level, unknowns=runs[0]["unknowns"],
                         energy=runs[0]["energy"], iterations=runs[0]["iterations"],
                         seconds=med("seconds"), linear_seconds=med("linear_seconds"),
                         time_ratio=statistics.median(r["seconds"] / r["linear_seconds"] for r in runs),
                         with_outputs=med("with_outputs"),
                         with_outputs_ratio=statistics.median(r["with_outputs"] / r["linear_seconds"]
                                                              for r in runs),
                         cpu_seconds=med("cpu_seconds"), linear_cpu_seconds=med("linear_cpu_seconds"),
                         cpu_ratio=statistics.median(r["cpu_seconds"] / r["linear_cpu_seconds"] for r in runs),
                         process_cpu_ratio=statistics.median(r["process_cpu_seconds"]
                                                             / r["linear_process_cpu_seconds"] for r in runs),
                         peak_mb=med("peak_mb"), linear_peak_mb=med("linear_peak_mb"),
                         memory_ratio=statistics.median(r["peak_mb"] / r["linear_peak_mb"] for r in runs),
                         finest_timings={k: statistics.median(r["timings"].get(k, 0.0) for r in runs)
                                         for k in runs[0]["timings"]},
                         runs=runs))
        if args.before:
            rows[-1].update(before_seconds=med("before_seconds"), before_peak_mb=med("before_peak_mb"),
                            before_time_ratio=statistics.median(r["before_seconds"] / r["linear_seconds"]
                                                                for r in runs),
                            before_memory_ratio=statistics.median(r["before_peak_mb"] / r["linear_peak_mb"]
                                                                  for r in runs),
                            before_process_cpu_ratio=statistics.median(
                                r["before_process_cpu_seconds"] / r["linear_process_cpu_seconds"] for r in runs),
                            before_energy=runs[0]["before_energy"])
    # wall: the chain (result.json seconds), with its outputs; CPU: solve + outputs (imports
    # excluded, as the linear code's); process: each process's whole CPU time, imports included
    print(f"{'case':<14}{'unknowns':>9}{'chain s':>8}{'+outputs':>9}{'linear s':>9}{'ratio':>7}"
          f"{'+outputs':>9}{'CPU s':>7}{'lin. CPU':>9}{'ratio':>7}{'process':>8}{'ours MB':>9}"
          f"{'linear MB':>10}{'ratio':>7}  energy")
    for r in rows:
        print(f"{r['case']:<14}{r['unknowns']:>9d}{r['seconds']:>8.2f}{r['with_outputs']:>9.2f}"
              f"{r['linear_seconds']:>9.2f}{r['time_ratio']:>7.2f}{r['with_outputs_ratio']:>9.2f}"
              f"{r['cpu_seconds']:>7.2f}{r['linear_cpu_seconds']:>9.2f}{r['cpu_ratio']:>7.2f}"
              f"{r['process_cpu_ratio']:>8.2f}{r['peak_mb']:>9.0f}{r['linear_peak_mb']:>10.0f}"
              f"{r['memory_ratio']:>7.2f}  {r['energy']:.12g}")
        if args.before:
            print(f"{'  before':<14}{'':>9}{r['before_seconds']:>8.2f}{'':>9}{'':>9}"
                  f"{r['before_time_ratio']:>7.2f}{'':>9}{'':>7}{'':>9}{'':>7}{r['before_process_cpu_ratio']:>8.2f}"
                  f"{r['before_peak_mb']:>9.0f}{'':>10}{r['before_memory_ratio']:>7.2f}  {r['before_energy']:.12g}")
    write_results(args.name, rows, "shared 2-core machine: ratios within one repetition, medians")


def write_results(name, rows, note):
    """benchmarks/results/NAME: the rows with the machine's CPU count, the date and the load."""
    os.makedirs(RESULTS, exist_ok=True)
    with open(os.path.join(RESULTS, name), "w") as fh:
        json.dump(dict(rows=rows, cpu_count=os.cpu_count(), date=time.strftime("%Y-%m-%d %H:%M"),
                       load=os.getloadavg(), note=note), fh, indent=1)


if __name__ == "__main__":
    main()
