"""Kernels kept on disk (nitsche.kernel_store): a new process loads a kernel's lowered
program instead of tracing it, gets the same numbers, and never loads a program stored for
a different density, a damaged entry or one keyed by an object's identity."""
import json
import os
import subprocess
import sys

import numpy as np

from nitsche import assembly, kernel_store

# A child process: solve the obstacle-like problem of the given stiffness and print its
# energy (all digits) and how many kernels it traced (calls of the functions assembly._build
# makes: JAX calls them only to trace them).
CHILD = r"""
import json, sys
import numpy as np
from skfem import MeshTri, ElementTriP1
import nitsche as ni
from nitsche import assembly
from nitsche.ops import dot, grad
traced = []
build = assembly._build


def counted(*a, **k):
    fn = build(*a, **k)
    return lambda *args: traced.append(a[0]) or fn(*args)  # called when traced


assembly._build = counted
K = float(sys.argv[1])
u = ni.Field("u", MeshTri().refined(3), ElementTriP1(), fixed="boundary")
c = ni.Inequality(lambda u, x: u.value + 0.05 + 0.0 * x[0], lambda u: -1.0 * u.value,
                  ni.Scaling(0.1, 1), ni.cells(u), name="obstacle")
problem = ni.Problem([u], lambda u: 0.5 * K * dot(grad(u), grad(u)) + u.value, [c])
result = problem.minimize()
print(json.dumps({"energy": float(result.energy), "traced": len(traced),
                  "iterations": result.iterations}))
"""


def child(folder, stiffness=1.0):
    env = dict(os.environ, NITSCHE_JAX_CACHE=str(folder))
    out = subprocess.run([sys.executable, "-c", CHILD, str(stiffness)], env=env, capture_output=True,
                         text=True, check=True)
    return json.loads(out.stdout.strip().splitlines()[-1])


def test_a_second_process_loads_the_kernels_traces_none_and_gets_the_same_numbers(tmp_path):
    first = child(tmp_path)
    assert first["traced"] > 0
    stored = os.listdir(tmp_path / "kernels")
    assert len(stored) >= first["traced"]  # the kernels and the analyses of the density
    second = child(tmp_path)
    assert second["traced"] == 0
    assert second["energy"] == first["energy"] and second["iterations"] == first["iterations"]
    # another stiffness (a global the energy reads) traces the energy's kernels again, not
    # the constraint's
    other = child(tmp_path, stiffness=2.0)
    assert 0 < other["traced"] < first["traced"]
    assert other["energy"] != first["energy"]


def test_with_the_cache_off_nothing_is_stored(tmp_path):
    env = dict(os.environ, NITSCHE_JAX_CACHE="off", HOME=str(tmp_path))
    out = subprocess.run([sys.executable, "-c", CHILD, "1.0"], env=env, capture_output=True, text=True,
                         check=True)
    assert json.loads(out.stdout.strip().splitlines()[-1])["traced"] > 0
    assert not (tmp_path / ".cache").exists()


def test_digests_follow_the_key_and_refuse_identities():
    key = ("full", ("fn", (lambda u: u).__code__), 1024, (3, 2), 0.5, None, True)
    assert kernel_store.digest(key) == kernel_store.digest(tuple(key))
    changed = ("full", ("fn", (lambda u: 2 * u).__code__), 1024, (3, 2), 0.5, None, True)
    assert kernel_store.digest(changed) != kernel_store.digest(key)
    assert kernel_store.digest(key[:-1] + (1,)) != kernel_store.digest(key)  # True is not 1
    assert kernel_store.digest(key + (kernel_store.Identity(12345),)) is None
    assert kernel_store.digest(key + (object(),)) is None
    thing = object()
    keyed = assembly.fingerprint(thing)  # an object keyed by identity: equal to its id here
    assert keyed == ("id", id(thing)) and isinstance(keyed[1], kernel_store.Identity)
    assert kernel_store.digest(keyed) is None


def test_a_damaged_entry_is_a_miss(tmp_path, monkeypatch):
    monkeypatch.setattr(kernel_store, "folder", lambda: str(tmp_path))
    kernel_store.save("abc", (True, (False,)))
    assert kernel_store.load("abc") == (True, (False,))
    (tmp_path / "abc.pkl").write_bytes(b"not a pickle")
    assert kernel_store.load("abc") is None
    assert kernel_store.load("absent") is None
    assert sorted(os.listdir(tmp_path)) == ["abc.pkl"]  # no temporary files left


def test_digests_are_the_same_in_another_process():
    key = ("values", ("fn", json.dumps.__code__), np.float64(2.5), (1, 2, 3), "u", -0.0)
    code = ("from nitsche import kernel_store; import json, numpy as np; "
            "print(kernel_store.digest(('values', ('fn', json.dumps.__code__), np.float64(2.5), (1, 2, 3), "
            "'u', -0.0)))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == kernel_store.digest(key)


def test_distinct_values_have_distinct_digests():
    values = [1, 1.0, "1", (1,), [1], None, b"1", True, 1 + 0j]
    assert len({kernel_store.digest((v,)) for v in values}) == len(values)
