"""The solution figure's CPU time (nitsche.plot.plot_solution, solution.png) inside
`nitsche run CASE --level L`, side by side with an earlier checkout.

Each process solves once and draws the figure `--draws` times (process CPU of each, the
median kept); the checkouts' processes alternate, `--repeat` of each, and the medians
over them are reported with their ratio and the load average.

    python benchmarks/figure_time.py obstacle 6 --before /tmp/before [--name figure_time.json]
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


def child(case, level, draws):
    """Run the case with plot_solution drawn `draws` times; print the CPU seconds."""
    from nitsche import plot
    from nitsche.cli import main
    draw, seconds = plot.plot_solution, []

    def timed(*args, **kwargs):
        for _ in range(draws):
            c0 = time.process_time()
            path = draw(*args, **kwargs)
            seconds.append(time.process_time() - c0)
        return path
    plot.plot_solution = timed
    with tempfile.TemporaryDirectory() as out:
        main(["run", case, "--level", str(level), "--out", out])
    print(json.dumps(seconds))


def measure(checkout, case, level, draws):
    env = dict(os.environ, PYTHONPATH=checkout)
    done = subprocess.run([sys.executable, __file__, case, str(level), "--child", str(draws)],
                          env=env, capture_output=True, text=True, check=True)
    return json.loads(done.stdout.strip().splitlines()[-1])


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("case")
    ap.add_argument("level", type=int)
    ap.add_argument("--before", help="a checkout of an earlier version")
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--draws", type=int, default=3)
    ap.add_argument("--name", help="a results file in benchmarks/results")
    ap.add_argument("--child", type=int, help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.child:
        return child(args.case, args.level, args.child)
    versions = {"now": ROOT} | ({"before": os.path.abspath(args.before)} if args.before else {})
    runs = {v: [] for v in versions}
    loads = []
    for _ in range(args.repeat):
        for v in [v for v in ("before", "now") if v in versions]:
            runs[v].append(measure(versions[v], args.case, args.level, args.draws))
            loads.append(os.getloadavg()[0])
            print(f"{v}: plot_solution CPU {runs[v][-1]}", file=sys.stderr)
    median = {v: statistics.median(statistics.median(r) for r in runs[v]) for v in runs}
    summary = dict(case=args.case, level=args.level, cpu_seconds=runs, median=median,
                   load=[min(loads), max(loads)], date=time.strftime("%Y-%m-%d %H:%M"))
    if "before" in median:
        summary["ratio"] = median["now"] / median["before"]
    print(json.dumps({k: summary[k] for k in ("median", "load")} | {"ratio": summary.get("ratio")}))
    if args.name:
        with open(os.path.join(HERE, "results", args.name), "w") as fh:
            json.dump(summary, fh, indent=1)


if __name__ == "__main__":
    main()
