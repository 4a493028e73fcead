"""A load path with a cut step on the ranks (for test_distributed.py): python mpi_path_cuts.py
CASE:LEVEL[:NAME=VALUE,...].  Every rank builds its part and solves the case's path as `nitsche
run` does (PETSc's LU); rank 0 prints one JSON line: per accepted step [time, Newton
iterations, energy, cuts] and per Newton run (failed attempts included) its iterations and
whether it converged."""
import json
import sys

from nitsche import cases
from nitsche.distributed import DistributedProblem


def main(spec):
    name, level, *sets = spec.split(":")
    case = cases.get(name)
    p = case.parameters(dict(kv.split("=") for s in sets for kv in s.split(",")))
    dp = DistributedProblem.build(lambda: case.problem(int(level), case.degrees[0], p))
    attempts, minimize = [], dp.minimize

    def recorded(*args, **kwargs):
        result = minimize(*args, **kwargs)
        attempts.append([result.iterations, bool(result.converged)])
        return result
    dp.minimize = recorded
    case.solve(dp, None, solver="direct")
    if dp.rank == 0:
        print(json.dumps(dict(steps=[[s["time"], s["iterations"], s["energy"], s["cuts"]]
                                     for s in dp.path.steps], attempts=attempts)), flush=True)


if __name__ == "__main__":
    main(sys.argv[1])
