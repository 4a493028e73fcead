"""Arrays held on the device (the accelerator JAX computes on, or the CPU).

The per-element data of the terms are put on the device once, at set-up (assembly.Chunked),
and kept only there; a kernel call then takes them as they are.

On the CPU, jax.device_put of a NumPy array whose data are 64-byte aligned aliases it
instead of copying it, so on_device copies once into aligned memory and the data are held
once; a read-only NumPy view of a device array (host) is free there, a transfer from a GPU.
"""
import jax
import numpy as np

ALIGNMENT = 64  # bytes: what the CPU client needs to alias a host buffer


def empty(shape, dtype=float):
    """An uninitialized array in host memory that starts on an ALIGNMENT boundary."""
    dtype = np.dtype(dtype)
    nbytes = int(np.prod(shape, dtype=np.int64)) * dtype.itemsize
    buf = np.empty(nbytes + ALIGNMENT, np.uint8)
    start = -buf.ctypes.data % ALIGNMENT
    return buf[start:start + nbytes].view(dtype).reshape(shape)


def aligned(a, dtype=None):
    """A copy of a (array-like) in host memory that starts on an ALIGNMENT boundary."""
    a = np.asarray(a, dtype)
    out = empty(a.shape, a.dtype)
    out[...] = a
    return out


def on_device(a, dtype=None):
    """a (array-like) as a JAX array on the default device, held once: an aligned copy,
    which device_put on the CPU aliases (a GPU copies it to its memory and the host copy is
    dropped)."""
    return jax.device_put(aligned(a, dtype))


def is_cpu():
    """Whether JAX computes on the CPU (host and device memory are one)."""
    return jax.default_backend() == "cpu"


def host(a):
    """A read-only NumPy view of a JAX array (on the CPU without a copy)."""
    return np.asarray(a)
