"""Kernels kept on disk (nitsche.kernel_store): a new process loads a kernel's compiled
executable instead of tracing, lowering and compiling it, gets the same numbers, and never
loads a program stored for a different density, a damaged entry or one keyed by an object's
identity."""
import json
import os
import pickle
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


# A child process: compile sin(x) @ y (with JAX's persistent cache; or as kernel_store.fresh's
# program and store it), or load the stored one and print its value.
EXECUTABLE = r"""
import sys
import jax, jax.numpy as jnp
from nitsche import kernel_store
args = (jnp.full((8, 8), 0.5), jnp.ones((8, 8)))


def f(x, y):
    return jnp.sin(x) @ y


if sys.argv[1] == "compile":
    jax.jit(f).lower(*args).compile()
elif sys.argv[1] == "store":
    print(kernel_store.save("sin", jax.jit(kernel_store.fresh(f)).lower(*args).compile()))
elif sys.argv[1] == "store-cached":  # fetched from JAX's cache: serialized without its code
    print(kernel_store.save("sin", jax.jit(f).lower(*args).compile()))
elif sys.argv[1] == "kernel":  # as the assembler gets its kernels
    from nitsche import assembly
    print(float(assembly._compile(f, args, "sin")(*args)[0, 0]))
else:
    print(float(kernel_store.load("sin")(*args)[0, 0]))
"""


def test_a_stored_executable_runs_in_another_process_though_jax_cached_its_program(tmp_path):
    """An executable that JAX fetched from its persistent cache serializes without its code
    on the CPU (calling it in another process fails); fresh's program's does not, and
    the assembler's kernel (assembly.Loaded) replaces an entry without code."""
    env = dict(os.environ, NITSCHE_JAX_CACHE=str(tmp_path))

    def run(mode):
        """(the child's exit status, its output)."""
        out = subprocess.run([sys.executable, "-c", EXECUTABLE, mode], env=env, capture_output=True,
                             text=True)
        return out.returncode, out.stdout.strip() + out.stderr
    assert run("compile")[0] == 0  # the program now in JAX's cache
    assert run("store") == (0, "True")
    assert run("load") == (0, repr(8 * float(np.sin(0.5))))
    # an entry without its code: the assembler's kernel compiles it again and stores it anew
    assert run("store-cached") == (0, "True")
    status, said = run("load")
    assert status != 0 and "not found" in said
    assert run("kernel") == (0, repr(8 * float(np.sin(0.5))))
    assert run("load") == (0, repr(8 * float(np.sin(0.5))))


def test_the_kernels_are_stored_as_executables(tmp_path):
    child(tmp_path)
    kinds = [pickle.load(open(tmp_path / "kernels" / f, "rb"))[0] for f in os.listdir(tmp_path / "kernels")]
    assert kinds.count("executable") >= 3 and set(kinds) <= {"executable", "value"}, kinds


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


def test_a_program_with_a_custom_call_is_stored_as_its_lowered_program(tmp_path, monkeypatch):
    """LAPACK's LU (jnp.linalg.solve) is a custom call into this process's code: its kernel
    is stored as the lowered program (compiled in each process), a plain one as an executable."""
    import jax.numpy as jnp
    monkeypatch.setattr(kernel_store, "folder", lambda: str(tmp_path))
    a = jnp.array([[2.0, 1.0, 0.0], [1.0, 3.0, 1.0], [0.0, 1.0, 4.0]])
    b = jnp.array([3.0, 5.0, 5.0])

    def solved(a, b):
        return jnp.linalg.solve(a, b)
    for _ in range(2):  # compiled and stored, then loaded
        assert np.allclose(assembly._compile(solved, (a, b), "solve")(a, b), 1.0, rtol=1e-14)
        assert float(assembly._compile(lambda a, b: a.sum() + b.sum(), (a, b), "sum")(a, b)) == 26.0
    kinds = {name: pickle.load(open(tmp_path / f"{name}.pkl", "rb"))[0] for name in ("solve", "sum")}
    assert kinds == {"solve": "exported", "sum": "executable"}
