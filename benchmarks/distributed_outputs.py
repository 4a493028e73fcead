"""The outputs of `mpirun -n R nitsche run CASE --level L` from the ranks' pieces against an
earlier version whose rank 0 rebuilds the whole problem for them, side by side.

Each repetition runs both versions in fresh processes, interleaved (after, before, ...),
every rank under /usr/bin/time: per rank its peak resident memory (the process's, KB) and
its CPU seconds (user + system, imports included); from result.json the solve's wall
seconds, `output_seconds` (wall, from the end of the solve to result.json: the pieces, the
case's errors, report and figures, solution.png, and before also the rebuild),
`cpu_seconds` (rank 0's CPU of the solve and the outputs), the energy, the Newton
iterations, the errors and `outputs_from_pieces`.  The medians over the repetitions and
the ratios after / before are printed (the machine may be shared: read the CPU and the
memory, not the wall seconds).  Writes benchmarks/results/distributed_outputs_CASE_L.json.

    python benchmarks/distributed_outputs.py plate-plate 5 --before /tmp/before --repeat 2
"""
import argparse
import json
import os
import shutil
import statistics
import subprocess
import sys
import tempfile

HERE = os.path.dirname(os.path.abspath(__file__))
ROOT = os.path.dirname(HERE)
RESULTS = os.path.join(HERE, "results")
RANK_TIME = '/usr/bin/time -o "$0.$OMPI_COMM_WORLD_RANK" -f "%M %U %S" "$@"'


def run(source, case, level, ranks, solver, extra):
    """One `nitsche run` under mpirun importing nitsche from `source`: result.json and per
    rank (peak KB, CPU s)."""
    folder = tempfile.mkdtemp()
    stamp = os.path.join(folder, "time")
    env = dict(os.environ, PYTHONPATH=source, OMPI_ALLOW_RUN_AS_ROOT="1",
               OMPI_ALLOW_RUN_AS_ROOT_CONFIRM="1", OMPI_MCA_rmaps_base_oversubscribe="1",
               OMP_NUM_THREADS="1", OPENBLAS_NUM_THREADS="1")
    command = ["mpirun", "-n", str(ranks), "sh", "-c", RANK_TIME, stamp, sys.executable, "-m",
               "nitsche.cli", "run", case, "--level", str(level), "--solver", solver,
               "--out", os.path.join(folder, "out"), *extra]
    out = subprocess.run(command, env=env, capture_output=True, text=True, cwd=folder)
    if out.returncode != 0:
        raise RuntimeError(out.stdout[-2000:] + out.stderr[-4000:])
    with open(os.path.join(folder, "out", "result.json")) as f:
        data = json.load(f)
    per_rank = []
    for r in range(ranks):
        with open(f"{stamp}.{r}") as f:
            kb, user, system = f.read().split()[-3:]
        per_rank.append(dict(peak_kb=int(kb), cpu_seconds=float(user) + float(system)))
    shutil.rmtree(folder)
    keys = ("seconds", "output_seconds", "cpu_seconds", "energy", "nested_iterations", "errors",
            "outputs_from_pieces", "unknowns")
    return dict({k: data.get(k) for k in keys}, ranks=per_rank)


def median(runs, key, rank=None):
    values = [r["ranks"][rank][key] if rank is not None else r[key] for r in runs]
    return statistics.median(values)


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("case")
    ap.add_argument("level", type=int)
    ap.add_argument("--before", required=True, help="a checkout of the earlier version (its nitsche/)")
    ap.add_argument("--ranks", type=int, default=2)
    ap.add_argument("--solver", default="direct")
    ap.add_argument("--repeat", type=int, default=1)
    ap.add_argument("--set", action="append", default=[], help="a case parameter NAME=VALUE")
    args = ap.parse_args()
    extra = [a for s in args.set for a in ("--set", s)]
    versions = {"after": ROOT, "before": os.path.abspath(args.before)}
    runs = {name: [] for name in versions}
    load = []
    for _ in range(args.repeat):
        for name, source in versions.items():
            load.append(os.getloadavg()[0])
            runs[name].append(run(source, args.case, args.level, args.ranks, args.solver, extra))
            print(name, json.dumps(runs[name][-1]), flush=True)
    summary = {}
    for name, rs in runs.items():
        summary[name] = dict(output_seconds=median(rs, "output_seconds"),
                             rank0_cpu_seconds=median(rs, "cpu_seconds", 0),
                             rank0_peak_mib=median(rs, "peak_kb", 0) / 1024,
                             other_ranks_peak_mib=[median(rs, "peak_kb", r) / 1024
                                                   for r in range(1, args.ranks)])
    summary["ratios_after_over_before"] = {
        k: summary["after"][k] / summary["before"][k]
        for k in ("output_seconds", "rank0_cpu_seconds", "rank0_peak_mib")}
    print(json.dumps(summary, indent=1))
    os.makedirs(RESULTS, exist_ok=True)
    path = os.path.join(RESULTS, f"distributed_outputs_{args.case}_{args.level}.json")
    with open(path, "w") as f:
        json.dump(dict(command=" ".join(sys.argv), ranks=args.ranks, solver=args.solver,
                       load_average_at_starts=load, summary=summary, runs=runs), f, indent=1)
    print("wrote", path)


if __name__ == "__main__":
    main()
