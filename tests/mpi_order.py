"""distributed.order_statistics against NumPy on arrays split over the ranks (for
test_distributed.py): prints "ok" on rank 0 when every case agrees bit for bit."""
import numpy as np
from mpi4py import MPI

from nitsche.distributed import order_statistics

comm = MPI.COMM_WORLD
rng = np.random.default_rng(7)
arrays = [rng.standard_normal(1001), rng.standard_normal(1000) * 1e-8,
          np.round(rng.standard_normal(999), 1),  # ties
          -np.abs(rng.standard_normal(10)), np.array([3.0]), np.array([-0.0, 0.0, 2.5, np.inf])]
for a in arrays:
    cuts = np.sort(rng.integers(0, a.size + 1, comm.size - 1))
    cuts[:1] = 0  # rank 0 holds none
    mine = np.random.default_rng(comm.rank).permutation(np.split(a, cuts)[comm.rank])
    got = order_statistics(comm, mine)
    want = np.array([a.min(), np.median(a), a.max()])
    assert np.array_equal(got, want), (a.size, got, want)
if comm.rank == 0:
    print("ok")
