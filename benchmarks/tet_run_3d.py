"""`nitsche run membrane-solid --set cells=tet` at two versions of the library, side by side.

Each commit (or working directory) given by --versions is exported to a temporary folder
(`git archive`; a path is used as it is) and the command runs in its own process from it,
the versions interleaved, --repeat times.  Per run: the process's CPU time (user + system,
os.wait4) and peak memory (ru_maxrss), the wall time, the 1-minute load before and after,
and from result.json the Newton iterations per level, the finest level's CG iterations and
AMG set-ups, J_h, the chain's `seconds`, `cpu_seconds` and `output_seconds` and Newton's
phase timings.  The machine may be shared: compare CPU times, medians and ratios.  Rows
appended to benchmarks/results/tet_membrane_solid.json (--name: another file).

    python benchmarks/tet_run_3d.py --versions b998457 HEAD --level 3 --repeat 2
    python benchmarks/tet_run_3d.py --versions b998457 HEAD --level 3 --set n0=9
"""
import argparse
import json
import os
import statistics
import subprocess
import sys
import tempfile
import time

HERE = os.path.dirname(os.path.abspath(__file__))
ROOT = os.path.dirname(HERE)
RESULTS = os.path.join(HERE, "results")


def export(version, into):
    """A folder holding the library at `version`: a path as it is, a commit exported."""
    if os.path.isdir(version):
        return os.path.abspath(version), version
    commit = subprocess.run(["git", "-C", ROOT, "rev-parse", "--short", version], check=True,
                            capture_output=True, text=True).stdout.strip()
    path = os.path.join(into, commit)
    os.makedirs(path, exist_ok=True)
    archive = subprocess.run(["git", "-C", ROOT, "archive", commit], check=True, capture_output=True).stdout
    subprocess.run(["tar", "-x", "-C", path], input=archive, check=True)
    return path, commit


def run(code, args, out):
    """The command from the library in `code`: a row of its measurements."""
    command = [sys.executable, "-m", "nitsche.cli", "run", "membrane-solid", "--level", str(args.level),
               "--set", "cells=tet", *[a for s in args.set for a in ("--set", s)], "--out", out,
               "--overwrite"]
    env = dict(os.environ, PYTHONPATH=code, OPENBLAS_NUM_THREADS="1")
    load, t = os.getloadavg()[0], time.perf_counter()
    proc = subprocess.Popen(command, env=env, stdout=subprocess.DEVNULL, cwd=code)  # -m puts cwd first
    _, status, usage = os.wait4(proc.pid, 0)
    if status != 0:
        raise RuntimeError(f"{' '.join(command)} failed (status {status})")
    r = json.load(open(os.path.join(out, "result.json")))
    return dict(command=" ".join(["nitsche"] + command[3:-3]), unknowns=r["unknowns"],
                nested_iterations=r["nested_iterations"], energy=r["energy"], seconds=r["seconds"],
                cpu_seconds=r.get("cpu_seconds"), output_seconds=r.get("output_seconds"),
                timings=r["timings"], solver=r["solver"], solver_stats=r["solver_stats"],
                process_cpu_seconds=usage.ru_utime + usage.ru_stime, process_user_seconds=usage.ru_utime,
                process_system_seconds=usage.ru_stime, peak_mb=usage.ru_maxrss / 1024,
                process_wall_seconds=time.perf_counter() - t, load=[load, os.getloadavg()[0]])


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--versions", nargs="+", required=True, help="commits or library folders")
    ap.add_argument("--level", type=int, default=3)
    ap.add_argument("--set", nargs="*", default=[], help="further case parameters name=value")
    ap.add_argument("--repeat", type=int, default=1)
    ap.add_argument("--name", default="tet_membrane_solid.json")
    args = ap.parse_args()
    runs = {}
    with tempfile.TemporaryDirectory(prefix="tet_run_3d_") as tmp:
        codes = [export(v, tmp) for v in args.versions]
        for _ in range(args.repeat):
            for code, version in codes:
                runs.setdefault(version, []).append(run(code, args, os.path.join(tmp, "out")))
                r = runs[version][-1]
                print(f"{version}: process CPU {r['process_cpu_seconds']:.1f} s, peak {r['peak_mb']:.0f} MB, "
                      f"Newton {r['nested_iterations']}, CG {r['solver_stats'].get('cg_iterations')}, "
                      f"J_h {r['energy']!r}, load {r['load'][0]:.1f}-{r['load'][1]:.1f}", flush=True)
    first = statistics.median(r["process_cpu_seconds"] for r in runs[codes[0][1]])
    for version, rs in runs.items():
        cpu = statistics.median(r["process_cpu_seconds"] for r in rs)
        print(f"{version}: median process CPU {cpu:.1f} s ({cpu / first:.2f}x the first), median peak "
              f"{statistics.median(r['peak_mb'] for r in rs):.0f} MB over {len(rs)} runs")
    path = os.path.join(RESULTS, args.name)
    data = json.load(open(path)) if os.path.exists(path) else dict(rows=[])
    stamp = dict(date=time.strftime("%Y-%m-%d %H:%M"), note="benchmarks/tet_run_3d.py, versions interleaved")
    data["rows"] += [dict(r, version=version, **stamp) for version, rs in runs.items() for r in rs]
    with open(path, "w") as fh:
        json.dump(data, fh, indent=1)


if __name__ == "__main__":
    sys.exit(main())
