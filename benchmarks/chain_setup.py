"""The nested chain of a case by CPU time, phase by phase, in fresh processes.

Each repetition runs, interleaved (ours, before, ours, ...), a child process that solves
levels 0..L by nitsche.study.nested (what `nitsche run CASE --level L` does before its
outputs) and reports the chain's CPU time (user + system, imports excluded), its wall
time, the set-up of each level (`case.problem`), the prolongations between levels, the
kernel loading (`assembly.compile_seconds`), the checks around each Newton solve
(newton.residual_scale, Problem.constraint_report, and Problem.check_finite in versions
before session 28, whose Newton's method called it at each start: CPU time, all levels;
kernels they load count in loading too; the first residual_scale of a level holds its
quadratic terms' one assembly), the finest level's Newton solve, the peak
resident memory (ru_maxrss), the minor page faults, the energy and the iterations.  CPU
time is the measure that a shared machine disturbs least; medians are printed.  The chain
as `nitsche run` runs it: its last level built ahead in a background thread where
study.nested has that option (session 30); the chain's CPU is the process's (all
threads), the phases' each the CPU of the thread that ran them.

    python benchmarks/chain_setup.py --cases obstacle two-membrane --level 6 --repeat 3 \\
        --before /tmp/before   # a checkout of an earlier version, side by side
    python benchmarks/chain_setup.py --cases membrane-solid --level 3 --set cells=tet
"""
import argparse
import json
import os
import statistics
import subprocess
import sys

from run_ratio import HERE, write_results

CHILD = r"""
import inspect, json, resource, sys, time
import nitsche.assembly as assembly
import nitsche.newton as newton
import nitsche.study as study
from nitsche.problem import Problem
from nitsche.cases import get
from nitsche.cli import parse_assignments
case_name, level = sys.argv[1], int(sys.argv[2])
case = get(case_name)
p = case.parameters(parse_assignments(sys.argv[3:]))
setup, prolongation = [], [0.0]
prolongate = study.prolongate

def timed_prolongate(*a):
    c = time.thread_time()
    try:
        return prolongate(*a)
    finally:
        prolongation[0] += time.thread_time() - c
study.prolongate = timed_prolongate
checks = [0.0]

def timed(fn):
    def call(*a, **k):
        c = time.thread_time()
        try:
            return fn(*a, **k)
        finally:
            checks[0] += time.thread_time() - c
    return call
Problem.check_finite = timed(Problem.check_finite)
Problem.constraint_report = timed(Problem.constraint_report)
newton.residual_scale = timed(newton.residual_scale)

def build(k):
    c = time.thread_time()
    problem = case.problem(k, case.degrees[0], p)
    setup.append(time.thread_time() - c)
    return problem

t0, c0 = time.perf_counter(), time.process_time()
its = []
coarse = {option: getattr(study, name) for option, name in (("coarse_rtol", "COARSE_RTOL"),
              ("coarse_reduction", "COARSE_REDUCTION")) if hasattr(study, name)}  # as `nitsche run`
if "ahead" in inspect.signature(study.nested).parameters:  # as `nitsche run` (session 30)
    coarse["ahead"] = True
for k, problem, result in study.nested(build, range(level + 1), case.solve, **coarse):
    its.append(result.iterations)
    finest = result.seconds
cpu, wall = time.process_time() - c0, time.perf_counter() - t0
usage = resource.getrusage(resource.RUSAGE_SELF)
print(json.dumps(dict(cpu=cpu, wall=wall, setup=setup, prolongation=prolongation[0],
                      loading=assembly.compile_seconds[0], checks=checks[0], finest_solve=finest,
                      energy=result.energy, iterations=its, unknowns=int(problem.free.size),
                      peak_mb=usage.ru_maxrss / 1024.0, minor_faults=usage.ru_minflt)))
"""


def run(case, level, source, sets=()):
    """One chain in a child process that imports nitsche from `source` (case parameters
    NAME=VALUE in `sets`)."""
    env = dict(os.environ, PYTHONPATH=source, OPENBLAS_NUM_THREADS="1")
    out = subprocess.run([sys.executable, "-c", CHILD, case, str(level), *sets], env=env, cwd="/",
                         capture_output=True, text=True, check=True)
    return json.loads(out.stdout.strip().splitlines()[-1])


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--cases", nargs="+", default=["obstacle", "two-membrane"])
    ap.add_argument("--level", type=int, default=6)
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--set", action="append", default=[], metavar="NAME=VALUE",
                    help="a case parameter for every case (repeatable), as `nitsche run --set`")
    ap.add_argument("--before", help="a checkout of an earlier version, run side by side")
    ap.add_argument("--name", default="chain_setup.json", help="the results file in benchmarks/results")
    args = ap.parse_args()
    ours = os.path.dirname(HERE)
    versions = [("ours", ours)] + ([("before", args.before)] if args.before else [])
    rows = []
    for case in args.cases:
        runs = {v: [] for v, _ in versions}
        for rep in range(args.repeat):
            for v, source in versions:
                r = run(case, args.level, source, args.set)
                runs[v].append(r)
                print(f"  {case} L{args.level} rep {rep} {v}: CPU {r['cpu']:.2f} s (wall {r['wall']:.2f}), "
                      f"set-up {sum(r['setup']):.2f} (finest {r['setup'][-1]:.2f}), prolongation "
                      f"{r['prolongation']:.2f}, loading {r['loading']:.2f}, checks "
                      f"{r['checks']:.2f}, finest solve "
                      f"{r['finest_solve']:.2f}, {r['peak_mb']:.0f} MB, {r['minor_faults']} faults",
                      file=sys.stderr, flush=True)
        for v, _ in versions:
            med = lambda f: statistics.median(f(r) for r in runs[v])  # noqa: E731
            rows.append(dict(case=case, version=v, level=args.level, set=args.set, unknowns=runs[v][0]["unknowns"],
                             energy=runs[v][0]["energy"], iterations=runs[v][0]["iterations"],
                             cpu=med(lambda r: r["cpu"]), wall=med(lambda r: r["wall"]),
                             setup=med(lambda r: sum(r["setup"])),
                             finest_setup=med(lambda r: r["setup"][-1]),
                             prolongation=med(lambda r: r["prolongation"]),
                             loading=med(lambda r: r["loading"]),
                             checks=med(lambda r: r["checks"]),
                             finest_solve=med(lambda r: r["finest_solve"]),
                             peak_mb=med(lambda r: r["peak_mb"]),
                             minor_faults=med(lambda r: r["minor_faults"]), runs=runs[v]))
    print(f"{'case':<14}{'version':<8}{'unknowns':>9}{'CPU s':>7}{'set-up':>8}{'finest':>8}"
          f"{'prolong.':>9}{'loading':>8}{'checks':>8}{'solve L':>8}{'peak MB':>8}  energy, iterations")
    for r in rows:
        print(f"{r['case']:<14}{r['version']:<8}{r['unknowns']:>9d}{r['cpu']:>7.2f}{r['setup']:>8.2f}"
              f"{r['finest_setup']:>8.2f}{r['prolongation']:>9.3f}{r['loading']:>8.2f}{r['checks']:>8.2f}"
              f"{r['finest_solve']:>8.2f}{r['peak_mb']:>8.0f}  {r['energy']:.15g}, {r['iterations']}")
    write_results(args.name, rows, "CPU seconds of the chain (imports excluded), medians of the "
                  "repetitions; shared 2-core machine")


if __name__ == "__main__":
    main()
