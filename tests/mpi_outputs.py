"""The outputs computed from the ranks' pieces against the whole problem's, at the same x
(for test_distributed.py): python mpi_outputs.py CASE:LEVEL ...; every rank builds its part
and the whole problem, takes one x (the same on every rank: the whole problem's solution),
and rank 0 prints one JSON line per case: the case's errors (nitsche.norms.exact_errors)
from the pieces and from the whole problem, and the largest relative difference of each
constraint's picture in solution.png (plot.multiplier_picture: the binned image of an area,
the gathered graph of a line), with its kind."""
import json
import sys

import numpy as np

from nitsche import cases, partition
from nitsche.distributed import DistributedProblem
from nitsche.newton import Result
from nitsche.plot import multiplier_picture


def result(problem, x):
    return Result(x=x, converged=True, reason="", iterations=0, residuals=[], energy=0.0,
                  problem=problem)


def difference(a, b):
    """The largest relative difference of two pictures' arrays (NaN where both are NaN)."""
    out = 0.0
    for u, v in zip(a[1:], b[1:]):
        if u is None or isinstance(u, (int, str)):
            assert u == v, (u, v)
            continue
        u, v = np.asarray(u, float), np.asarray(v, float)
        assert u.shape == v.shape and (np.isnan(u) == np.isnan(v)).all()
        ok = ~np.isnan(u)
        out = max(out, float(np.abs(u[ok] - v[ok]).max(initial=0) / max(np.abs(v[ok]).max(initial=0), 1e-300)))
    return out


def main(specs):
    for spec in specs:
        name, level = spec.split(":")
        case = cases.get(name)
        p = case.parameters({})
        make = lambda: case.problem(int(level), case.degrees[0], p)  # noqa: E731
        dp, whole = DistributedProblem.build(make), make()
        x = whole.minimize(solver="superlu").x
        serial = case.errors(whole, result(whole, x), p)
        values = whole.constraint_values(x)
        with partition.local(dp.comm):
            mine = case.errors(dp.local, result(dp.local, x), p)
            local = dp.local.constraint_values(x)
            pictures = {c: multiplier_picture(local[c]) for c in local}
        kinds = {c: pictures[c][0] for c in pictures}
        differences = {c: difference(pictures[c], multiplier_picture(values[c])) for c in values}
        if dp.rank == 0:
            print(json.dumps(dict(case=name, errors=mine, serial_errors=serial, pictures=kinds,
                                  picture_differences=differences)), flush=True)


if __name__ == "__main__":
    main(sys.argv[1:])
