"""Compiled kernels kept on disk, so that a new process loads them instead of tracing,
lowering and compiling them.

JAX's persistent cache saves the compilation, but it is keyed by the lowered program, so
every process still traces each kernel (the automatic differentiation and vmap of the
density, in Python) and lowers it to find its entry: about 2 s of a 130k-unknown chain.
Here a kernel's compiled executable (jax.experimental.serialize_executable) is stored under
a digest of the key the assembler already holds for it (the density's fingerprint, the
layout, the chunk, the shapes) and of what the program depends on besides: the library's
own source, the Python and JAX versions, x64, the device and the host's processor; a new
process deserializes and loads it (15-35 ms for a kernel of the 130k chain, against 40-50
ms to lower a stored program and fetch its compilation from JAX's cache).  It is compiled
under a name of its own (fresh), so never fetched from JAX's persistent cache: an
executable that JAX loaded from its cache serializes without its code on the CPU.  A
program with custom calls (code of the process that compiled it), or whose executable
cannot be serialized, is stored as its lowered program (jax.export: StableHLO) and
compiled in each process.  A key that names an object by identity (valid only in its
process) is not stored.  Other values (the analyses of a density) are pickled.  The store
lives under JAX's cache directory (NITSCHE_JAX_CACHE; "off": nothing stored).
"""
import hashlib
import os
import pickle
import sys
import tempfile
import types
import uuid

import jax
import jaxlib
import numpy as np
from jax import export
from jax.experimental import serialize_executable
from jax.stages import Compiled


class Identity(int):
    """The key of an object by its id: equal and hashed as the int, valid in this process only."""


class _Unstable(Exception):
    """A key with a part that has no meaning in another process."""


_ENVIRONMENT = []  # the digest of what every stored value depends on, computed once


def folder():
    """The store's folder (under JAX's compilation cache), or None where caching is off."""
    root = jax.config.jax_compilation_cache_dir
    return os.path.join(root, "kernels") if root else None


def digest(key):
    """A hex digest of key that is the same in every process of the same library, JAX and
    machine, or None if the key holds an identity."""
    h = hashlib.sha256(environment())
    try:
        _encode(key, h)
    except _Unstable:
        return None
    return h.hexdigest()


def load(name):
    """The value stored under name, or None (absent, unreadable or written by a
    different version: then it is computed and stored again)."""
    path = _path(name)
    if path is None or not os.path.exists(path):
        return None
    try:
        with open(path, "rb") as fh:
            kind, value = pickle.load(fh)
        if kind == "executable":
            return serialize_executable.deserialize_and_load(*value)
        return export.deserialize(bytearray(value)) if kind == "exported" else value
    except Exception:  # noqa: BLE001 -- a damaged entry is a miss, never an error
        return None


def fresh(fn):
    """fn under a name of its own (the name of jit's program): its compilation is then never
    one that JAX's persistent cache answers, whose executables serialize without their code
    on the CPU (the cache is keyed by the program, its name included)."""
    def program(*args):
        return fn(*args)
    program.__name__ = program.__qualname__ = f"kernel_{uuid.uuid4().hex}"
    return program


def save(name, value):
    """Store value under name, atomically (another process reads the whole entry or none): a
    compiled executable (of a program made by fresh), a jax.export.Exported or a picklable
    value.  False where it is not stored (no store, an executable that cannot be
    serialized, a store that cannot be written)."""
    path = _path(name)
    if path is None:
        return False
    if isinstance(value, Compiled):
        try:
            entry = ("executable", serialize_executable.serialize(value))
        except Exception:  # noqa: BLE001 -- a backend without serialization
            return False
    elif isinstance(value, export.Exported):
        entry = ("exported", bytes(value.serialize()))
    else:
        entry = ("value", value)
    try:
        os.makedirs(os.path.dirname(path), exist_ok=True)
        fd, tmp = tempfile.mkstemp(dir=os.path.dirname(path), suffix=".tmp")
        with os.fdopen(fd, "wb") as fh:
            pickle.dump(entry, fh, protocol=pickle.HIGHEST_PROTOCOL)
        os.replace(tmp, path)
        return True
    except OSError:
        try:
            os.unlink(tmp)
        except (OSError, NameError):
            pass
        return False


def _path(name):
    root = folder()
    return os.path.join(root, name + ".pkl") if root and name else None


def environment():
    """What a stored value depends on besides its key: the library's source files, the
    versions of Python, NumPy, JAX and jaxlib, x64, the default device and the processor
    (its model and instruction sets: code compiled for one CPU may not run on another that
    shares the cache folder)."""
    if not _ENVIRONMENT:
        h = hashlib.sha256()
        package = os.path.dirname(os.path.abspath(__file__))
        for base, _, files in sorted(os.walk(package)):
            for f in sorted(files):
                if f.endswith(".py"):
                    h.update(os.path.relpath(os.path.join(base, f), package).encode())
                    with open(os.path.join(base, f), "rb") as fh:
                        h.update(fh.read())
        device = jax.devices()[0]
        for part in (sys.version, np.__version__, jax.__version__, jaxlib.__version__, jax.config.jax_enable_x64,
                     device.platform, device.device_kind, processor()):
            h.update(repr(part).encode())
        _ENVIRONMENT.append(h.digest())
    return _ENVIRONMENT[0]


def processor():
    """The host processor's model and instruction-set flags (Linux: /proc/cpuinfo's first
    'model name' and 'flags' lines), else the platform's name for it."""
    try:
        with open("/proc/cpuinfo") as fh:
            lines = fh.read().splitlines()
        return tuple(next((line for line in lines if line.startswith(k)), "") for k in ("model name", "flags"))
    except OSError:
        import platform
        return (platform.machine(), platform.processor())


def _encode(obj, h):
    """Feed a canonical byte form of obj to the hash h (raise _Unstable for identities)."""
    if isinstance(obj, Identity):
        raise _Unstable
    if obj is None or obj is Ellipsis or isinstance(obj, (bool, int, float, complex, str, bytes)):
        h.update(f"{type(obj).__name__}:{obj!r};".encode())
    elif isinstance(obj, (tuple, list)):
        h.update(f"{type(obj).__name__}[{len(obj)}".encode())
        for o in obj:
            _encode(o, h)
        h.update(b"]")
    elif isinstance(obj, types.CodeType):
        _encode(("code", obj.co_qualname, obj.co_code, obj.co_consts, obj.co_names, obj.co_varnames,
                 obj.co_freevars, obj.co_cellvars, obj.co_argcount, obj.co_posonlyargcount,
                 obj.co_kwonlyargcount, obj.co_flags), h)
    elif isinstance(obj, frozenset):
        _encode(sorted(obj, key=repr), h)
    elif isinstance(obj, np.dtype):
        _encode(("dtype", obj.str), h)
    else:
        raise _Unstable
