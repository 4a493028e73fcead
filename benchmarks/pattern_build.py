"""The sparsity pattern and the scatter of element matrices: the pattern built on dof groups
with the scatter by blocks (nitsche.pattern, now) against the entry-by-entry one (before:
one argsort of the int64 keys row * n + column of every element-matrix entry, one int32
position per entry, as the library did until this benchmark), side by side on the same
maps.

For each case and level: the pattern's build time (CPU, median of --repeat, interleaved)
and its peak of traced memory (tracemalloc: numpy's allocations), the bytes kept (pattern
+ scatter maps), and the scatter of one Hessian's element matrices into the CSR data (the
per-Newton-step part that the scatter maps serve: np.add.at by blocks now, np.bincount by
entry before).  Writes benchmarks/results/pattern_build.json (one row per run, appended).

    python benchmarks/pattern_build.py obstacle:6 membrane-solid:2:cells=tet
"""
import argparse
import json
import os
import statistics
import sys
import time
import tracemalloc

if "OPENBLAS_NUM_THREADS" not in os.environ:  # the library's default (nitsche/__init__)
    os.environ["OPENBLAS_NUM_THREADS"] = "1"
    os.environ["NITSCHE_BLAS_DEFAULTED"] = "1"  # numeric factorizations on the cores (nitsche.threads)

import numpy as np  # noqa: E402

from nitsche.cases import get  # noqa: E402
from nitsche.pattern import Pattern  # noqa: E402

HERE = os.path.dirname(os.path.abspath(__file__))
RESULTS = os.path.join(HERE, "results")


def entrywise(maps, n):
    """The earlier construction (the peer): one argsort of the keys row * n + column of
    every element-matrix entry; (indptr, indices, one position per entry of each map)."""
    keys = np.concatenate([(np.repeat(D, D.shape[1], axis=1) * np.int64(n)
                            + np.tile(D, (1, D.shape[1]))).ravel() for D in maps])
    order = np.argsort(keys)
    ordered = keys[order]
    new = np.empty(ordered.size, bool)
    new[:1] = True
    np.not_equal(ordered[1:], ordered[:-1], out=new[1:])
    rows, columns = np.divmod(ordered[new], n)
    position = np.empty(keys.size, np.int32)
    position[order] = np.cumsum(new) - 1
    indptr = np.zeros(n + 1, np.int32)
    np.cumsum(np.bincount(rows, minlength=n), out=indptr[1:])
    sizes = [D.size * D.shape[1] for D in maps]
    return indptr, columns.astype(np.int32), np.split(position, np.cumsum(sizes)[:-1])


def cpu(fn):
    t = time.process_time()
    out = fn()
    return time.process_time() - t, out


def traced_peak(fn):
    tracemalloc.start()
    fn()
    peak = tracemalloc.get_traced_memory()[1]
    tracemalloc.stop()
    return peak


def measure(spec, repeat):
    name, level, *sets = spec.split(":")
    case = get(name)
    problem = case.problem(int(level), 1, case.parameters(dict(s.split("=", 1) for s in sets)))
    a, n = problem.assembler, problem.ndofs
    maps = []
    for t in a.terms:
        if not any(d.shape == t.global_dofs.shape and np.array_equal(d, t.global_dofs) for d in maps):
            maps.append(t.global_dofs)
    H = [np.random.default_rng(0).random(D.shape + D.shape[1:]) for D in maps]
    times = {"before": [], "now": [], "scatter_before": [], "scatter_now": []}
    for _ in range(repeat):
        dt, (indptr, indices, positions) = cpu(lambda: entrywise(maps, n))
        times["before"].append(dt)
        dt, pattern = cpu(lambda: Pattern(maps, n))
        times["now"].append(dt)

        def add_before():  # as the earlier Assembler.evaluate
            data = np.zeros(indices.size)
            for p, h in zip(positions, H):
                data += np.bincount(p, weights=h.ravel(), minlength=indices.size)
            return data
        dt, old = cpu(add_before)
        times["scatter_before"].append(dt)

        def add():
            data = np.zeros(pattern.nnz)
            for s, D, h in zip(pattern.scatters, maps, H):
                s.add(data, h)
            return data
        dt, new = cpu(add)
        times["scatter_now"].append(dt)
    assert np.array_equal(indptr, pattern.indptr) and np.array_equal(indices, pattern.indices)
    assert np.allclose(old, new, rtol=1e-13, atol=0)
    row = dict(case=spec, unknowns=int(problem.free.size), ndofs=int(n), nnz=int(pattern.nnz),
               element_entries=int(sum(D.shape[0] * D.shape[1] ** 2 for D in maps)),
               group_pairs=int(sum(s.R.size for s in pattern.scatters)),
               **{f"{k}_cpu_seconds": statistics.median(v) for k, v in times.items()},
               before_peak_bytes=traced_peak(lambda: entrywise(maps, n)),
               now_peak_bytes=traced_peak(lambda: Pattern(maps, n)),
               before_kept_bytes=int(indptr.nbytes + indices.nbytes + sum(p.nbytes for p in positions)),
               now_kept_bytes=int(pattern.nbytes))  # with the groups
    return row


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("cases", nargs="+", help="CASE:LEVEL[:name=value...]")
    ap.add_argument("--repeat", type=int, default=3)
    args = ap.parse_args()
    rows = []
    mb = lambda b: f"{b / 2**20:8.1f}"
    print(f"{'case':<32}{'unknowns':>9}{'entries':>11}{'build s before/now':>20}{'ratio':>7}"
          f"{'peak MB before/now':>20}{'kept MB before/now':>20}{'scatter s before/now':>22}")
    for spec in args.cases:
        r = measure(spec, args.repeat)
        rows.append(r)
        print(f"{spec:<32}{r['unknowns']:>9}{r['element_entries']:>11}"
              f"{r['before_cpu_seconds']:>10.2f}/{r['now_cpu_seconds']:<9.2f}"
              f"{r['now_cpu_seconds'] / r['before_cpu_seconds']:>6.2f}"
              f"{mb(r['before_peak_bytes'])}/{mb(r['now_peak_bytes']):<11}"
              f"{mb(r['before_kept_bytes'])}/{mb(r['now_kept_bytes']):<11}"
              f"{r['scatter_before_cpu_seconds']:>10.3f}/{r['scatter_now_cpu_seconds']:<.3f}", flush=True)
    load = os.getloadavg()
    os.makedirs(RESULTS, exist_ok=True)
    path = os.path.join(RESULTS, "pattern_build.json")
    old = json.load(open(path))["rows"] if os.path.exists(path) else []
    stamp = dict(date=time.strftime("%Y-%m-%d %H:%M"), load=load, repeat=args.repeat,
                 commit=os.popen(f"git -C {HERE} rev-parse --short HEAD 2>/dev/null").read().strip())
    with open(path, "w") as fh:
        json.dump(dict(rows=old + [dict(r, **stamp) for r in rows]), fh, indent=1)
    print(f"load average {load[0]:.2f} {load[1]:.2f} {load[2]:.2f}")


if __name__ == "__main__":
    sys.exit(main())
