"""The outputs computed from the ranks' pieces against the whole problem's, at the same x
(for test_distributed.py): python mpi_outputs.py CASE:LEVEL[:NAME=VALUE,...] ...; every rank
builds its part
and the whole problem, takes one result (the same on every rank: the whole problem's
solution and its constraint report), and rank 0 prints one JSON line per case: the case's
errors (e.g. nitsche.norms.exact_errors) from the pieces and from the whole problem, the
largest relative difference of its report hook's numbers (seconds left out) and of each
constraint's picture in solution.png (plot.multiplier_picture: the binned image of an area,
the gathered graph of a line), with its kind, of the values its figures draw (FIGURE_DATA),
and the figures each wrote, and whether partition.local(None) inside the partition builds
the whole problem (as block-friction's theta study needs)."""
import dataclasses
import json
import os
import sys
import tempfile

import numpy as np

from nitsche import cases, partition
from nitsche.distributed import DistributedProblem
from nitsche.plot import multiplier_picture


# what the cases' figures draw from the pieces (collected or gathered on every rank)
FIGURE_DATA = {
    "two-membrane": lambda m, problem, r, p: [m.cell_pressure(problem, r.x)],
    "elastic-contact": lambda m, problem, r, p: [
        m.cell_von_mises(problem.by_name[n], r[n], E, nu)
        for n, E, nu in (("u1", p.E1, p.nu1), ("u2", p.E2, p.nu2))] + list(m.pressure(problem, r)),
    "plate-plate": lambda m, problem, r, p: list(m.contact_points(problem.constraint_values(r.x)["contact"])),
    "plate-unilateral": lambda m, problem, r, p: [list(line) for line in m.edge_reactions(problem, r.x)],
}


def difference(a, b):
    """The largest relative difference of two pictures' arrays (NaN where both are NaN)."""
    out = 0.0
    for u, v in zip(a[1:], b[1:]):
        if u is None or isinstance(u, (int, str)):
            assert u == v, (u, v)
            continue
        out = max(out, array_difference(u, v))
    return out


def array_difference(u, v):
    u, v = np.asarray(u, float), np.asarray(v, float)
    assert u.shape == v.shape and (np.isnan(u) == np.isnan(v)).all(), (u.shape, v.shape)
    ok = ~np.isnan(u)
    return float(np.abs(u[ok] - v[ok]).max(initial=0) / max(np.abs(v[ok]).max(initial=0), 1e-300))


def report_difference(a, b, where="report"):
    """The largest relative difference of two reports' numbers (nested dicts and lists);
    keys, strings, flags and None must be equal; `*_seconds` (timings) are left out."""
    if isinstance(a, dict):
        assert a.keys() == b.keys(), (where, sorted(a), sorted(b))
        return max([report_difference(a[k], b[k], f"{where}.{k}") for k in a
                    if not k.endswith("seconds")], default=0.0)
    if isinstance(a, (list, tuple)):
        assert len(a) == len(b), where
        return max([report_difference(u, v, where) for u, v in zip(a, b)], default=0.0)
    if a is None or isinstance(a, (str, bool)):
        assert a == b, (where, a, b)
        return 0.0
    return array_difference(a, b) if np.ndim(a) else \
        abs(a - b) / max(abs(b), 1e-300) if a != b else 0.0


def main(specs):
    for spec in specs:
        name, level, *sets = spec.split(":")
        case = cases.get(name)
        p = case.parameters(dict(kv.split("=") for s in sets for kv in s.split(",")))
        make = lambda: case.problem(int(level), case.degrees[0], p)  # noqa: E731
        dp, whole = DistributedProblem.build(make), make()
        serial = whole.minimize(solver="superlu")  # x and the constraint report, as the run's
        mine = dataclasses.replace(serial, problem=dp.local)
        values = whole.constraint_values(serial.x)
        report = getattr(case.module, "report", lambda *a: {})
        folder = tempfile.mkdtemp() if dp.rank == 0 else None
        if dp.rank == 0:
            os.makedirs(os.path.join(folder, "pieces"))
            os.makedirs(os.path.join(folder, "whole"))
        hook = getattr(case.module, "figures", lambda *a: [])
        drawn = FIGURE_DATA.get(name, lambda *a: [])
        with partition.local(dp.comm):
            errors = case.errors(dp.local, mine, p)
            local = dp.local.constraint_values(serial.x)
            pictures = {c: multiplier_picture(local[c]) for c in local}
            extra = report(dp.local, mine, p)
            drawn_pieces = drawn(case.module, dp.local, mine, p)
            figures = hook(dp.local, mine, p, os.path.join(folder, "pieces") if dp.rank == 0 else None)
            with partition.local(None):  # a whole problem built inside the partition (a study's)
                alone = [t.nel for t in make().assembler.terms]
        kinds = {c: pictures[c][0] for c in pictures}
        differences = {c: difference(pictures[c], multiplier_picture(values[c])) for c in values}
        if dp.rank == 0:
            whole_figures = hook(whole, serial, p, os.path.join(folder, "whole"))
            print(json.dumps(dict(case=name, errors=errors, serial_errors=case.errors(whole, serial, p),
                                  pictures=kinds, picture_differences=differences,
                                  report_keys=sorted(extra),
                                  alone_is_whole=alone == [t.nel for t in whole.assembler.terms],
                                  report_difference=report_difference(extra, report(whole, serial, p)),
                                  figure_data_difference=report_difference(
                                      drawn_pieces, drawn(case.module, whole, serial, p)),
                                  figures=[os.path.basename(f) for f in figures if os.path.getsize(f)],
                                  whole_figures=[os.path.basename(f) for f in whole_figures])),
                  flush=True)


if __name__ == "__main__":
    main(sys.argv[1:])
