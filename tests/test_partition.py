"""nitsche.partition without mpirun: the parts of a problem that two ranks build from their own
cells (a stand-in communicator, the ranks built one after the other) hold every element once,
and their energies, gradients and Hessians sum to the whole problem's, for cells (obstacle),
two fields (two-membrane), boundary facets and an interface between two meshes
(elastic-contact) and a membrane on a 3D body (membrane-solid).  Skipped without pymetis and
mpi4py (`make petsc`)."""
import numpy as np
import pytest
from skfem import MeshTri

from nitsche import cases, partition

pytest.importorskip("pymetis", reason="the partition needs pymetis: make petsc")
pytest.importorskip("mpi4py", reason="nitsche.partition reduces with mpi4py: make petsc")


class StandIn:
    """A communicator of `size` ranks seen from `rank`, the ranks built one after the other:
    rank 0's broadcasts are replayed to the others in order; the k-th all-reduction (a
    logical and: nitsche.partition.everywhere) answers answers[k], or False while the
    answers are being collected into flags[k] (the same calls whatever the answers)."""

    def __init__(self, rank, size, sent, flags, answers):
        self.rank, self.size, self.sent, self.flags, self.answers = rank, size, sent, flags, answers
        self.received = self.reduced = 0

    def bcast(self, obj, root=0):
        if self.rank == 0:
            self.sent.append(obj)
            return obj
        self.received += 1
        return self.sent[self.received - 1]

    def allreduce(self, flag, op=None):
        self.flags.setdefault(self.reduced, []).append(flag)
        self.reduced += 1
        return self.answers[self.reduced - 1] if self.answers else False


def parts(make, size):
    """The parts of the problem make() that `size` ranks build: once to collect each rank's
    flags, once more with the reductions' true answers."""
    answers = []
    for _ in range(2):
        sent, flags, out = [], {}, []
        for rank in range(size):
            with partition.local(StandIn(rank, size, sent, flags, answers)):
                out.append(make())
        answers = [all(flags[k]) for k in sorted(flags)]
    return out


@pytest.mark.parametrize("name, level", [("obstacle", 2), ("two-membrane", 2),
                                         ("elastic-contact", 1), ("membrane-solid", 0)])
def test_rank_parts_sum_to_the_whole(name, level):
    case = cases.get(name)
    p = case.parameters({})
    whole = case.problem(level, case.degrees[0], p)
    ranks = parts(lambda: case.problem(level, case.degrees[0], p), 2)
    assert [r.partition for r in ranks] == [(0, 2), (1, 2)]
    counts = np.array([[t.nel for t in r.assembler.terms] for r in ranks])
    assert counts.sum(axis=0).tolist() == [t.nel for t in whole.assembler.terms]
    assert (counts.sum(axis=1) < sum(t.nel for t in whole.assembler.terms)).all()
    x = whole.initial(0.01 * np.random.default_rng(0).standard_normal(whole.ndofs))
    E = sum(r.energy(x) for r in ranks)
    assert abs(E - whole.energy(x)) <= 1e-12 * max(1.0, abs(whole.energy(x)))
    g = sum(r.gradient(x) for r in ranks)
    assert np.abs(g - whole.gradient(x)).max() <= 1e-12 * max(1.0, np.abs(g).max())
    H = sum(r.hessian(x) for r in ranks) - whole.hessian(x)
    assert abs(H).max() <= 1e-10 * abs(whole.hessian(x)).max()
    assert min(min(r.alpha0_limits.values(), default=np.inf) for r in ranks) == \
        min(whole.alpha0_limits.values(), default=np.inf)


def test_dual_graph_joins_cells_that_share_a_facet():
    mesh = MeshTri()  # the unit square: two triangles sharing the diagonal
    xadj, adjncy = partition.dual_graph(mesh)
    assert xadj.tolist() == [0, 1, 2] and adjncy.tolist() == [1, 0]
    assert partition.cells(mesh) is None and partition.key() is None  # outside a partition
