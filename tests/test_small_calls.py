"""A term's last (or only) kernel call takes the least rung of 8, 16, 32, ... (powers of two
below the small chunk) and the small chunk that holds the elements left (assembly.last_call)
where the padding it saves is worth a kernel shape (assembly.RUNG_WORTH, in points x local
dofs^2), else the small chunk as before: the ironing contact terms of 24-240 elements are
not padded to 336, the obstacle's terms of 3 dofs keep theirs.  The outputs equal those of
the former call padded to the small chunk to round-off (another batch size may fuse and
round differently)."""
import numpy as np
import pytest

from nitsche.assembly import RUNG_WORTH, Term, last_call
from nitsche.cases import get


@pytest.mark.parametrize("n, small, rung", [(0, 336, 8), (1, 336, 8), (8, 336, 8), (9, 336, 16), (24, 336, 32),
                                            (120, 336, 128), (240, 336, 256), (256, 336, 256), (257, 336, 336),
                                            (335, 336, 336), (3, 16, 8), (9, 16, 16), (3, 8, 8), (2, 5, 5)])
def test_the_last_call_takes_the_least_rung_that_holds_the_rest(n, small, rung):
    assert last_call(n, small) == rung


@pytest.mark.parametrize("nel, calls", [(0, [(0, 8)]), (24, [(0, 32)]), (336, [(0, 336)]),
                                        (700, [(0, 336), (336, 336), (672, 32)]),
                                        (10921, [(0, 10920), (10920, 8)]),
                                        (11300, [(0, 10920), (10920, 336), (11256, 64)])])
def test_the_calls_cover_the_elements_once(nel, calls):
    """Large chunks while a whole one is left, small ones likewise, then one rung (a term
    of 3 points and 100 local dofs: each padded element is worth 3e4); a term whose padding
    is worth less keeps the small chunk for its last call."""
    term = type("T", (), {"chunks": (336, 10920), "element_work": 3 * 100 ** 2})()
    assert Term.blocks(term, nel) == calls
    term.element_work = RUNG_WORTH // 336 - 1  # no rung saves enough
    assert Term.blocks(term, nel) == [(s, 336 if n < 336 else n) for s, n in calls]


def test_a_small_term_is_called_with_its_rung_and_gives_the_padded_call_outputs():
    """ironing level 2: the contact terms (24 and 120 elements of 3 points, small chunk 336)
    are called with 32 and 128 elements; their element outputs equal those of one call of
    the small chunk padded by repeating the last element to 1e-13 relative."""
    case = get("ironing")
    problem = case.problem(2, case.degrees[0], case.parameters({}))
    x = problem.initial(None) + 1e-3 * np.random.default_rng(0).standard_normal(problem.ndofs)
    terms = [problem.constraint_terms[i] for i in problem.sliding]
    assert [(t.nel, t.chunks[0], t.element_work) for t in terms] == [(24, 336, 3e4), (120, 336, 3e4)]
    for t, rung in zip(terms, (32, 128)):
        called = []
        kernel = t.kernel
        t.kernel = lambda kind, chunk: called.append(chunk) or kernel(kind, chunk)
        try:
            got = t.run("full", x)
        finally:
            del t.kernel
        assert called == [rung]
        small = t.chunks[0]
        rows = np.r_[np.arange(t.nel), np.full(small - t.nel, t.nel - 1)]
        per_element = [x[d[rows]] for d in t.field_dofs] + [a[rows] for a in (t.weights, t.x, t.n, t.h, t.alpha0)]
        tables = [np.asarray(a) if a.shape[0] == 1 else np.asarray(a)[rows] for a in t.tables]
        theta = np.broadcast_to(t.parameters.values[t.parameter_index], (small, t.parameter_index.size))
        padded = t.kernel("full", small)(*tables, *per_element, theta)
        for a, b in zip(got, padded):
            b = np.asarray(b)[:t.nel]
            assert a.shape == b.shape
            assert np.abs(a - b).max() <= 1e-13 * np.abs(b).max()


def test_terms_of_few_dofs_keep_the_small_chunk():
    """obstacle level 2 (P1, 3 dofs): the rest of 16 elements is called with the small
    chunk, as before: a rung would save 152 x 6 x 9 points x dofs^2, not worth a shape."""
    case = get("obstacle")
    problem = case.problem(2, 1, case.parameters({}))
    for t in problem.assembler.terms:
        assert t.element_work * t.chunks[0] < RUNG_WORTH
        assert t.blocks(t.nel)[-1][1] == t.chunks[0]
