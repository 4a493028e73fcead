"""The resident memory of `nitsche run CASE --level L` step by step through its outputs,
for one or more checkouts side by side.

A thread samples VmRSS every 2 ms; the steps are labelled by wrapping their functions
(the solve; the VTU; solution.png: the constraint values, the multiplier picture and its
binned mean, the field panels, savefig; the case's figures hook), and the highest sample
of each label is printed in the order reached.  `--triangles` makes nitsche.plot draw every
field as triangles (as_image false), for a checkout that has the rule.  A diagnostic: the
RSS left by the solve differs run to run (what the allocator keeps), so compare each
step's rise over the step before it.

    python benchmarks/figure_memory.py obstacle 7 /tmp/before . [--triangles] [--name figure_memory.json]
"""
import argparse
import functools
import json
import os
import subprocess
import sys
import tempfile
import threading
import time

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, HERE)
STEPS = [("commands", "solve", "solve"), ("commands", "write_vtu", "VTU"),
         ("plot", "plot_solution", "figure"), ("problem.Problem", "constraint_values", "values"),
         ("plot", "multiplier_picture", "picture"), ("plot", "binned_mean", "bins"),
         ("plot", "_scalar_panel", "field panel"), ("plot", "_vector_panel", "field panel"),
         ("plot", "save_figure", "savefig")]


def child(case, level, triangles):
    from memory_phases import label, stack, status  # (the same labels as memory_phases.py)
    samples = []

    def sampler():
        while True:
            samples.append((status("VmRSS"), "/".join(stack)))
            time.sleep(0.002)

    threading.Thread(target=sampler, daemon=True).start()
    import nitsche
    from nitsche import cases, commands, plot, problem  # noqa: F401 (labelled below)
    from nitsche.cli import main
    for path, name, what in STEPS:
        owner = functools.reduce(getattr, path.split("."), nitsche)
        if hasattr(owner, name):
            label(owner, name, what)
    module = cases.get(case).module
    if hasattr(module, "figures"):
        label(module, "figures", "case figures")
    if triangles:
        plot.as_image = lambda ax, cells, dpi=None: False
    stack[:] = ["run"]
    with tempfile.TemporaryDirectory() as out:
        main(["run", case, "--level", str(level), "--out", out])
    time.sleep(0.01)
    peaks = {}
    for order, (mb, where) in enumerate(samples):
        if mb > peaks.get(where, (0.0,))[0]:
            peaks[where] = (mb, order)
    steps = [dict(step=w, peak_mb=mb) for w, (mb, _) in sorted(peaks.items(), key=lambda kv: kv[1][1])]
    print(json.dumps(steps))


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("case")
    ap.add_argument("level", type=int)
    ap.add_argument("checkouts", nargs="+")
    ap.add_argument("--triangles", action="store_true", help="fields drawn as triangles")
    ap.add_argument("--name", help="a results file in benchmarks/results")
    ap.add_argument("--child", action="store_true", help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.child:
        return child(args.case, args.level, args.triangles)
    runs = {}
    for checkout in args.checkouts:
        env = dict(os.environ, PYTHONPATH=os.path.abspath(checkout))
        done = subprocess.run([sys.executable, __file__, args.case, str(args.level), checkout, "--child"]
                              + ["--triangles"] * args.triangles, env=env, capture_output=True,
                              text=True, check=True)
        runs[checkout] = json.loads(done.stdout.strip().splitlines()[-1])
        print(f"{checkout}:", file=sys.stderr)
        for s in runs[checkout]:
            print(f"  {s['peak_mb']:7.0f} MB  {s['step']}", file=sys.stderr)
    if args.name:
        with open(os.path.join(HERE, "results", args.name), "w") as fh:
            json.dump(dict(case=args.case, level=args.level, triangles=args.triangles, runs=runs,
                           load=os.getloadavg(), date=time.strftime("%Y-%m-%d %H:%M")), fh, indent=1)


if __name__ == "__main__":
    main()
