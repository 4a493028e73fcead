"""The 1M nested chains of peers.py's scaling study, side by side with earlier versions.

Each repetition runs, interleaved, peers.py's worker (the chain `nitsche run` solves, on
the n x n tensor meshes: the obstacle n = 8 .. 1024, 1,046,529 unknowns; two membranes
n = 6 .. 768, 1,179,648) once per checkout, in a fresh process importing nitsche from that
checkout, and prints one JSON line per run: the chain's wall time (`total`, set-up
included: peers.run_ours), the set-up not beside a Newton solve (`setup`), the process's
wall and CPU time (imports included), its peak resident memory (ru_maxrss), the Newton
iterations per level, J_h and the load average.  Warm the kernel store of each checkout
first (a run with --top 4).

    python benchmarks/chain_1m.py obstacle 3 . /tmp/before      # checkouts to compare
    python benchmarks/chain_1m.py two-membrane 1 . --top 4       # a short chain (warm-up)
"""
import argparse
import json
import os
import subprocess
import sys
import tempfile
import time

CHAINS = {"obstacle": [8 * 2 ** k for k in range(8)], "two-membrane": [6 * 2 ** k for k in range(8)]}


def run(problem, root, ns):
    """One chain in a fresh process with nitsche from the checkout root: its row."""
    fd, path = tempfile.mkstemp(suffix=".json")
    os.close(fd)
    cmd = [sys.executable, os.path.join(root, "benchmarks", "peers.py"), "--out", path, "--worker", "ours",
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
    return dict(root=root, wall=wall, cpu=ru.ru_utime + ru.ru_stime, peak_mb=ru.ru_maxrss / 1024,
                total=out["times"]["total"], setup=out["times"]["setup"], its=out["iterations_per_level"],
                energy=out["own_energy"], unknowns=out["unknowns"], load=os.getloadavg()[0])


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("problem", choices=sorted(CHAINS))
    ap.add_argument("repeat", type=int)
    ap.add_argument("roots", nargs="+", help="checkouts (their nitsche and benchmarks/peers.py)")
    ap.add_argument("--top", type=int, default=None, help="the chain's first TOP meshes only")
    args = ap.parse_args()
    ns = CHAINS[args.problem][:args.top]
    for rep in range(args.repeat):
        for root in args.roots:
            row = dict(rep=rep, **run(args.problem, root, ns))
            print(json.dumps({k: round(v, 3) if isinstance(v, float) and k != "energy" else v
                              for k, v in row.items()}), flush=True)


if __name__ == "__main__":
    main()
