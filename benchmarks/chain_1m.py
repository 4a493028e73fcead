"""The 1M nested chains of peers.py's scaling study, side by side with earlier versions.

Each repetition runs, interleaved, peers.py's worker (the chain `nitsche run` solves, on
the n x n tensor meshes: the obstacle n = 8 .. 1024, 1,046,529 unknowns; two membranes
n = 6 .. 768, 1,179,648) once per checkout, in a fresh process importing nitsche from that
checkout, and prints one JSON line per run: the chain's wall time (`total`, set-up
included: peers.run_ours), the set-up not beside a Newton solve (`setup`), the process's
wall and CPU time (imports included), its peak resident memory (ru_maxrss: with the
benchmark's lists of the fields and their energy, `referee`, after the chain) and the
chain's own (`solve_peak_mb`: VmHWM as the chain ends), the kernels' compilation or
loading within it (`compile`), the Newton iterations per level, J_h and the load average.
Warm the kernel store of each checkout first (a run with --top 4). A checkout runs with its
own environment's Python (ROOT/.venv) where it has one.

--linear adds to each repetition one linear solve of the same size (peers.py's linear
code on the finest n x n tensor mesh: a Laplace assembly per field and one CHOLMOD
factorization and solve), and a table of medians with the ratios of each checkout's chain
to it: the time (`total`) and the peak memory (`solve_peak_mb`).

    python benchmarks/chain_1m.py obstacle 3 . /tmp/before      # checkouts to compare
    python benchmarks/chain_1m.py two-membrane 3 . --linear     # against one linear solve
    python benchmarks/chain_1m.py two-membrane 1 . --top 4       # a short chain (warm-up)
"""
import argparse
import json
import os
import statistics
import subprocess
import sys
import tempfile
import time

from peers import interpreter

CHAINS = {"obstacle": [8 * 2 ** k for k in range(8)], "two-membrane": [6 * 2 ** k for k in range(8)]}


def run(problem, root, ns, code="ours"):
    """One chain (code "linear": one linear solve on the finest mesh) in a fresh process with
    nitsche from the checkout root: its row."""
    fd, path = tempfile.mkstemp(suffix=".json")
    os.close(fd)
    cmd = [interpreter(root), os.path.join(root, "benchmarks", "peers.py"), "--out", path, "--worker", code,
           problem, "0", "0.1", ",".join(map(str, ns))]
    t = time.perf_counter()
    child = subprocess.Popen(cmd, env=dict(os.environ, PYTHONPATH=os.path.abspath(root)),
                             stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    _, status, ru = os.wait4(child.pid, 0)
    wall = time.perf_counter() - t
    if status != 0:
        os.unlink(path)
        return dict(root=root, failed=status)
    with open(path) as fh:
        out = json.load(fh)
    os.unlink(path)
    row = dict(root=root, wall=wall, cpu=ru.ru_utime + ru.ru_stime, peak_mb=ru.ru_maxrss / 1024,
               solve_peak_mb=out.get("solve_peak_mb"), total=out["times"]["total"], setup=out["times"]["setup"],
               compile=out["times"]["compile"])
    if code == "linear":
        return dict(row, root="linear", unknowns=out["unknowns"], load=os.getloadavg()[0])
    return dict(row, its=out["iterations_per_level"], energy=out["own_energy"], unknowns=out["unknowns"],
                load=os.getloadavg()[0])


def ratios(rows):
    """Per checkout: the median chain time and peak, and their ratios to the linear solve's
    medians (rows of one run, the linear ones under root "linear")."""
    done = [r for r in rows if "total" in r]
    linear = [r for r in done if r["root"] == "linear"]
    if not linear:
        return []
    base = {k: statistics.median(r[k] for r in linear) for k in ("total", "solve_peak_mb")}
    table = [f"{'':20s} {'chain s':>8s} {'peak MB':>8s} {'time ratio':>11s} {'peak ratio':>11s}",
             f"{'linear':20s} {base['total']:8.2f} {base['solve_peak_mb']:8.0f} {1:11.2f} {1:11.2f}"]
    for root in dict.fromkeys(r["root"] for r in done if r["root"] != "linear"):
        own = [r for r in done if r["root"] == root]
        total = statistics.median(r["total"] for r in own)
        peak = statistics.median(r["solve_peak_mb"] for r in own)
        table.append(f"{root:20s} {total:8.2f} {peak:8.0f} {total / base['total']:11.2f} "
                     f"{peak / base['solve_peak_mb']:11.2f}")
    return table


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("problem", choices=sorted(CHAINS))
    ap.add_argument("repeat", type=int)
    ap.add_argument("roots", nargs="+", help="checkouts (their nitsche and benchmarks/peers.py)")
    ap.add_argument("--top", type=int, default=None, help="the chain's first TOP meshes only")
    ap.add_argument("--linear", action="store_true", help="one linear solve of the same size in each "
                    "repetition, and the ratios to it (medians)")
    args = ap.parse_args()
    ns = CHAINS[args.problem][:args.top]
    rows = []
    for rep in range(args.repeat):
        for root, code in [(root, "ours") for root in args.roots] + ([(".", "linear")] if args.linear else []):
            rows.append(dict(rep=rep, **run(args.problem, root, ns, code)))
            print(json.dumps({k: round(v, 3) if isinstance(v, float) and k != "energy" else v
                              for k, v in rows[-1].items()}), flush=True)
    for line in ratios(rows):
        print(line, file=sys.stderr)


if __name__ == "__main__":
    main()
