"""partition.by_number under mpirun (for test_distributed.py): each rank gives random values
at a random set of numbers in [0, n); prints, on rank 0, one JSON line with whether every
rank's results equal the reductions computed from all ranks' data gathered."""
import json

import numpy as np
from mpi4py import MPI

from nitsche import partition

comm = MPI.COMM_WORLD
rng = np.random.default_rng(comm.rank)
n = 1000 + 7 * comm.size
numbers = rng.choice(n, size=rng.integers(1, n), replace=False)
values = rng.integers(-50, 50, numbers.size)
everyone = comm.allgather((numbers, values))
low, high = np.full(n, np.iinfo(np.int64).max), np.full(n, np.iinfo(np.int64).min)
for g, v in everyone:
    np.minimum.at(low, g, v)
    np.maximum.at(high, g, v)
held = np.zeros(n, bool)
for g, _ in everyone:
    held[g] = True


def ranks_of(block, lo):
    """[value, index among the held numbers]: an answer that counts across the blocks."""
    here = block > np.iinfo(np.int64).min
    before = sum(comm.allgather(int(here.sum()))[:comm.rank])
    return np.stack([block, before + np.cumsum(here) - 1], axis=1)


total = np.zeros(n)
for g, v in everyone:
    np.add.at(total, g, v / 3.0)
ok = dict(
    sum=bool(np.allclose(partition.by_number(comm, numbers, values / 3.0, n, "sum"), total[numbers],
                         rtol=1e-15, atol=0)),
    min=bool(np.array_equal(partition.by_number(comm, numbers, values, n, "min"), low[numbers])),
    max=bool(np.array_equal(partition.by_number(comm, numbers, values, n, "max"), high[numbers])),
    answer=bool(np.array_equal(partition.by_number(comm, numbers, values, n, "max", ranks_of),
                               np.stack([high[numbers], np.cumsum(held)[numbers] - 1], axis=1))))
ok = comm.gather(ok, root=0)
if comm.rank == 0:
    print(json.dumps(ok))
