"""Where `nitsche run CASE --level L` reaches its peak resident memory, phase by phase.

A thread samples VmRSS every 5 ms while the command runs in this process; the library's
phases (set-up: fields, terms, alpha0, pattern; Newton: evaluate, free matrix, factor,
CG, constraint values; prolongation; the outputs) are labelled by wrapping their
functions, and the highest sample of each phase is printed, highest first, with the
process's VmHWM.  A diagnostic (the wrappers cost little; the seconds are not timings).

Each sample also reads the malloc heap's bytes in use (glibc's mallinfo2: NumPy's arrays,
CHOLMOD's factor, JAX's host buffers; not the heap's free holes nor the mapped libraries):
each phase's highest is printed beside its VmRSS.

--trace PHASE also follows NumPy's memory (tracemalloc, which sees NumPy's arrays but not
CHOLMOD's factor nor JAX's buffers): each phase's highest traced total, and at the highest
heap in use within the phases whose label holds PHASE (e.g. newton) a snapshot, whose
largest allocation sites are printed (the arrays alive there, by the line that allocated
them; tracing slows the run several times).

    python benchmarks/memory_phases.py obstacle 7 [--trace newton] [--out DIR] [--name memory_phases_obstacle7.json]
"""
import argparse
import ctypes
import functools
import json
import os
import sys
import tempfile
import threading
import time
import tracemalloc

HERE = os.path.dirname(os.path.abspath(__file__))
RESULTS = os.path.join(HERE, "results")
stack, samples = ["imports"], []
highest = dict(mb=0.0, heap_mb=0.0, snapshot=None, where="")  # the heap's peak in PHASE (--trace)


class Mallinfo2(ctypes.Structure):
    """glibc's struct mallinfo2 (malloc.h)."""
    _fields_ = [(name, ctypes.c_size_t) for name in
                "arena ordblks smblks hblks hblkhd usmblks fsmblks uordblks fordblks keepcost".split()]


def heap_in_use():
    """MB allocated by malloc and not freed (uordblks + hblkhd); 0 without glibc's mallinfo2."""
    try:
        info = ctypes.CDLL(None).mallinfo2
    except (OSError, AttributeError):
        return 0.0
    info.restype = Mallinfo2
    m = info()
    return (m.uordblks + m.hblkhd) / 2 ** 20


def status(key):
    """A line of /proc/self/status in MB (VmRSS, VmHWM)."""
    with open("/proc/self/status") as fh:
        for line in fh:
            if line.startswith(key):
                return int(line.split()[1]) / 1024.0


def sampler(trace):
    while True:
        traced = tracemalloc.get_traced_memory()[0] / 2 ** 20 if trace else 0.0
        heap = heap_in_use()
        where = "/".join(stack[-3:])
        samples.append((time.perf_counter(), status("VmRSS"), where, traced, heap))
        if trace and trace in where and heap > highest["heap_mb"] + 8:  # a new heap high there
            highest.update(mb=traced, heap_mb=heap, snapshot=tracemalloc.take_snapshot(), where=where)
        time.sleep(0.005)


def label(owner, name, what):
    """Wrap owner.name so that samples taken inside it carry `what`."""
    f = getattr(owner, name)

    @functools.wraps(f)
    def inside(*a, **k):
        stack.append(what)
        try:
            return f(*a, **k)
        finally:
            stack.pop()
    setattr(owner, name, inside)


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("case")
    ap.add_argument("level", type=int)
    ap.add_argument("--out", help="output folder of the run (default: a temporary one)")
    ap.add_argument("--name", help="a results file in benchmarks/results")
    ap.add_argument("--trace", metavar="PHASE", help="follow NumPy's memory (tracemalloc) and list "
                    "what is alive at its peak within the phases labelled PHASE")
    args = ap.parse_args()
    if args.trace:
        tracemalloc.start()
    threading.Thread(target=sampler, args=(args.trace,), daemon=True).start()
    from nitsche import assembly, case, commands, conditioning, fields, linalg, newton, problem, study
    for owner, name, what in [
            (case.Case, "problem", "set-up"), (fields.Field, "__init__", "field"),
            (assembly.Term, "__init__", "term"), (problem.Problem, "_resolve_alpha0", "alpha0"),
            (assembly.Assembler, "__init__", "pattern"), (study, "prolongate", "prolongation"),
            (newton, "newton", "newton"), (assembly.Assembler, "evaluate", "evaluate"),
            (problem.Problem, "_free_matrix", "free matrix"), (linalg.Cholmod, "_factor", "factor"),
            (linalg, "pcg", "CG"), (problem.Problem, "constraint_values", "constraint values"),
            (commands, "solve", "solve"), (commands, "write_vtu", "out: VTU"),
            (commands, "reactions", "out: reactions"),
            (commands, "evaluate", "out: quantities"), (commands, "write_json", "out: result.json"),
            (conditioning, "cholesky_inverse", "out: condition number's factor")]:
        label(owner, name, what)
    outputs = commands.outputs

    def labelled_outputs(*a, **k):  # (nitsche.plot, and with it matplotlib, loaded where the run loads it)
        from nitsche import plot
        if not hasattr(plot.plot_solution, "__wrapped__"):
            label(plot, "plot_solution", "out: figure")
        return outputs(*a, **k)
    commands.outputs = labelled_outputs
    from nitsche.cli import main as cli
    stack[:] = ["run"]
    out = args.out or tempfile.mkdtemp(prefix="memory_phases_")
    cli(["run", args.case, "--level", str(args.level), "--out", out])
    time.sleep(0.02)
    t0, peaks = samples[0][0], {}
    for t, rss, where, traced, heap in samples:
        old = peaks.get(where, (0.0, 0.0, 0.0, 0.0))
        peaks[where] = ((rss, t - t0) if rss > old[0] else old[:2]) + (max(traced, old[2]), max(heap, old[3]))
    rows = sorted(peaks.items(), key=lambda kv: -kv[1][0])
    print(f"{args.case} level {args.level}: VmHWM {status('VmHWM'):.0f} MB, heap in use at most "
          f"{max(s[4] for s in samples):.0f} MB", file=sys.stderr)
    for where, (rss, t, traced, heap) in rows[:25]:
        print(f"  {rss:7.0f} MB  at {t:6.2f} s  heap {heap:5.0f} MB  {where}"
              + (f"  (NumPy {traced:.0f} MB)" if args.trace else ""), file=sys.stderr)
    sites = []
    if highest["snapshot"] is not None:
        stats = highest["snapshot"].statistics("lineno")
        print(f"heap peak {highest['heap_mb']:.0f} MB (NumPy {highest['mb']:.0f} MB) in {highest['where']}; "
              "largest allocation sites:",
              file=sys.stderr)
        for st in stats[:20]:
            frame = st.traceback[0]
            sites.append(dict(site=f"{os.path.relpath(frame.filename)}:{frame.lineno}", mb=st.size / 2 ** 20,
                              blocks=st.count))
            print(f"  {sites[-1]['mb']:7.1f} MB {st.count:6d} blocks  {sites[-1]['site']}", file=sys.stderr)
    if args.name:
        os.makedirs(RESULTS, exist_ok=True)
        with open(os.path.join(RESULTS, args.name), "w") as fh:
            json.dump(dict(case=args.case, level=args.level, vmhwm_mb=status("VmHWM"),
                           heap_in_use_mb=max(s[4] for s in samples),
                           phases=[dict(phase=w, peak_mb=r, at_seconds=t, numpy_mb=n if args.trace else None,
                                        heap_in_use_mb=h) for w, (r, t, n, h) in rows],
                           numpy_peak=dict(mb=highest["mb"], heap_mb=highest["heap_mb"], phase=highest["where"],
                                           sites=sites) if args.trace else None,
                           load=os.getloadavg(), date=time.strftime("%Y-%m-%d %H:%M")), fh, indent=1)


if __name__ == "__main__":
    main()
