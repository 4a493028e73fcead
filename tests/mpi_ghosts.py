"""The ghosted free vectors of nitsche.distributed against the serial engine (for
test_distributed.py): python mpi_ghosts.py CASE:LEVEL ...; every rank builds its part and the
whole problem, evaluates both at one random x, and rank 0 prints one JSON line per case with
each rank's largest relative differences: the gradient on the dofs the rank holds (free and
fixed), the Hessian's product A v there, the norm and the dot product of free vectors; how
many free dofs each rank holds; the numbers summed per gradient evaluation."""
import json
import sys

import numpy as np

from nitsche import cases
from nitsche.distributed import DistributedProblem


def relative(a, b):
    return float(np.abs(a - b).max() / max(np.abs(b).max(), 1e-300)) if b.size else 0.0


def main(specs):
    for spec in specs:
        name, level = spec.split(":")
        case = cases.get(name)
        make = lambda: case.problem(int(level), case.degrees[0], case.parameters({}))  # noqa: E731
        dp, whole = DistributedProblem.build(make), make()
        rng = np.random.default_rng(0)  # the same x and v on every rank
        x = whole.initial(0.01 * rng.standard_normal(whole.ndofs))
        v = rng.standard_normal(whole.free.size)
        w = rng.standard_normal(whole.free.size)
        held, free, fixed = dp.layout.held, whole.free, whole.fixed
        before = dp.summed_numbers
        g = dp.gradient(x)
        summed = dp.summed_numbers - before
        G = whole.gradient(x)
        E, gf, A = dp.newton_system(x)
        H = whole.hessian(x)[free][:, free]
        Av = A @ v[held]  # free vectors: the held free dofs, owned first
        row = dict(gradient=relative(g[free][held], G[free][held]),
                   gradient_fixed=relative(g[fixed], G[fixed]),
                   newton_gradient=relative(gf, G[free][held]),
                   energy=abs(E - whole.energy(x)) / abs(whole.energy(x)),
                   product=relative(Av, (H @ v)[held]),
                   norm=abs(dp.norm(v[held]) - np.linalg.norm(v)) / np.linalg.norm(v),
                   dot=abs(dp.dot(v[held], w[held]) - v @ w) / (np.linalg.norm(v) * np.linalg.norm(w)),
                   held=int(held.size), owned=int(dp.layout.mine.size), free=int(free.size),
                   fixed=int(fixed.size),
                   summed_per_gradient=int(summed))
        rows = dp.comm.gather(row, root=0)
        if dp.rank == 0:
            print(json.dumps(dict(case=name, ranks=rows)), flush=True)


if __name__ == "__main__":
    main(sys.argv[1:])
