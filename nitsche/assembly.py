"""Energy, gradient and Hessian assembly by automatic differentiation at quadrature points.

A term is a pointwise density w(z) of the local jet vector z (the used value and
derivative components of its fields) integrated on a measure.  With
z[e, q] = T[e, q] u_e (T: basis tabulation, u_e: element dofs),

    energy_e = sum_q W w,   grad_e = sum_q W T^T dw/dz,   hess_e = sum_q W T^T d2w/dz2 T.

For a Lagrange field on cells T is not stored: the kernels form it, chunk by chunk, from
the shared reference tabulation and the inverse Jacobians (measures.Mapped, `mapped`).

A residual term is a density returning a pair (c, q) of arrays, paired with the test
function's jets: r_e(u; v) = sum_q W c . Dq[v], i.e. R(z) = (dq/dz)^T c (a vector-Jacobian
product) in place of dw/dz, and its (possibly non-symmetric) Jacobian dR/dz in place of
d2w/dz2; an energy term is the case R = dw/dz.

The pointwise derivatives come from jax.grad / jax.jacfwd, vmapped over all
points and jitted on fixed-size chunks of elements, so one compiled kernel
serves every Newton step and every refinement level.  The sparsity pattern and
the scatter of element matrices into CSR storage (nitsche.pattern) are computed once
per mesh.

The per-element data (tabulations, inverse Jacobians, W, x, n, h, alpha0) are put on the
device once, in the pieces the kernel calls take (Chunked), and kept only there; the
gather x[dofs], the gradient's bincount and the scatter into the CSR data stay on the host
with x and the sparse solvers: on XLA they would be programs of the mesh's sizes, compiled
anew on every level (docs/performance.md, "GPU-ready per-step path").
"""
import copy
import hashlib
import time
import types

import jax
import jax.numpy as jnp
import numpy as np
import scipy.sparse as sp

from jax.extend.core import Literal

from . import kernel_store
from .device import empty, host, is_cpu, on_device
from .functional import ALPHA0, RESERVED
from .jets import Jet
from .measures import Mapped
from .pattern import CHUNK, Pattern

# Quadrature points per kernel call: small, large.  Each size is a kernel shape to load (or
# compile) once per process; a nested chain loads the small set on its coarse levels and
# the large one from the level with a whole large chunk (2D P1, 130k unknowns: level 4),
# about 0.3-0.45 s CPU of loading per set from the persistent cache (then mostly tracing,
# which kernel_store now skips: 0.1-0.2 s a set).  One
# size for all was measured (2026-12-02) and rejected: the large one alone cut the
# obstacle's chain to 130k from 6.8-7.0 to 5.8 s CPU, but a padded 2^15-point call costs
# 1-19 ms in 2D P1 and 0.2-1.8 s in 3D (a 3D P1 energy 5.5 us, a P2 contact 54 us a point),
# so runs on coarse meshes with many Newton steps paid far more (compression --level 0:
# 4.2 -> 14.5 s CPU; block-friction 3.2 -> 4.1 s); 2^14 alone has the same padding.
CHUNK_POINTS = (2 ** 10, 2 ** 15)
# The large call holds at most this many Hessian entries (elements x points x local dofs^2,
# the Hessian kernel's output and the size of its temporaries): heavier elements take fewer
# per call, so that a call's arrays stay in the caches (docs/performance.md, "Kernel calls
# of heavy elements (session 28)"); 2D P1 scalar terms keep their 2^15 points.
WORK_PER_CALL = 2 ** 19
# A term's last call takes a smaller rung than the small chunk (last_call) only where the
# padding it saves, in points x (local dofs)^2 (the Hessian kernel's contraction, about 7 ns
# each: an ironing contact term's call of 336 elements, 3 points, 100 dofs, 67 ms), is at
# least this: each rung is a kernel shape per kind to load once per process (0.02 s CPU
# from kernel_store), which the chains' coarse levels of small elements did not win back
# (docs/performance.md, "Small terms' kernel calls (session 26)").
RUNG_WORTH = 2 ** 20
# A term whose element Hessians were non-zero on at most this share of its elements at its
# last assembly is assembled in two passes (Assembler._assemble): the 'support' kernel
# (energies, gradients, which Hessians can be non-zero: about half the cost of 'full'), then
# 'full' on those elements only.  Two membranes at 130k, 21 % non-zero: 42 -> 21 + 11 ms of
# kernels per Newton system, and a fifth of the scatter.
SPARSE_HESSIAN = 0.25
# a pointwise Hessian d2w/dz2 whose eigenvalues are >= -ROUNDOFF_EIGENVALUE max|eigenvalue| is
# positive semidefinite (Term.is_convex_quadratic)
ROUNDOFF_EIGENVALUE = 1e-12
_COMPILED = {}
_ALIVE = {}  # id -> object: an identity key stays valid while the object lives
compile_seconds = [0.0]  # compilation time spent in this process
MAX_DEPTH = 32  # nesting beyond which an object is keyed by identity


def fingerprint(obj):
    """A hashable key equal for densities that compute the same thing: a function by its
    code, its closure values, its defaults and the module globals that its code (and the
    code nested in it) reads, recursively; arrays and parameter namespaces by value,
    modules by name, other objects by identity."""
    return _key(obj, 0, {})


def _key(obj, depth, functions):
    """fingerprint of obj at nesting depth; `functions`: id -> key of the functions keyed
    so far in this call (None while one is being keyed: a recursive reference)."""
    if obj is None or isinstance(obj, (bool, int, float, complex, str, bytes)):
        return (type(obj).__name__, obj)
    if isinstance(obj, np.ndarray):
        return ("nd", obj.shape, obj.dtype.str, hashlib.sha1(np.ascontiguousarray(obj).tobytes()).hexdigest())
    if isinstance(obj, types.ModuleType):
        return ("module", obj.__name__)
    if depth > MAX_DEPTH:
        return _identity(obj)
    if isinstance(obj, (tuple, list)):
        return (type(obj).__name__,) + tuple(_key(o, depth + 1, functions) for o in obj)
    if isinstance(obj, dict):
        return ("dict",) + tuple((k, _key(v, depth + 1, functions))
                                 for k, v in sorted(obj.items(), key=lambda kv: str(kv[0])))
    if isinstance(obj, types.SimpleNamespace):  # parameters: by value, they may be changed
        return ("namespace", _key(vars(obj), depth + 1, functions))
    if isinstance(obj, types.FunctionType):
        if id(obj) in functions:
            return functions[id(obj)] or ("recursive", obj.__qualname__)
        functions[id(obj)] = None
        cells = tuple(_key(c.cell_contents, depth + 1, functions) for c in (obj.__closure__ or ()))
        read = tuple((name, _key(obj.__globals__[name], depth + 1, functions))
                     for name in global_names(obj.__code__) if name in obj.__globals__)
        functions[id(obj)] = ("fn", obj.__code__, cells, _key(obj.__defaults__, depth + 1, functions), read)
        return functions[id(obj)]
    return _identity(obj)


def _identity(obj):
    """An identity key, valid while the object lives (it is kept alive here) and only in
    this process (not stored on disk: kernel_store)."""
    _ALIVE[id(obj)] = obj
    return ("id", kernel_store.Identity(id(obj)))


def _cached(key, compute):
    """compute() for key, computed once per process (_COMPILED); the seconds it takes are
    added to compile_seconds."""
    if key not in _COMPILED:
        t = time.perf_counter()
        _COMPILED[key] = compute()
        compile_seconds[0] += time.perf_counter() - t
    return _COMPILED[key]


def _stored(key, compute):
    """compute() for key, loaded from disk where an earlier process stored it (kernel_store,
    keys that mean the same in another process), else computed and stored."""
    name = kernel_store.digest(key)
    value = kernel_store.load(name) if name else None
    if value is None:
        value = compute()
        if name:
            kernel_store.save(name, value)
    return value


def _compile(fn, args, name):
    """The compiled program of fn (to jit) for arguments of the shapes args: loaded where an
    earlier process stored it under name (kernel_store: no tracing, lowering or
    compilation; Loaded), else traced, compiled (as kernel_store.fresh's program) and
    stored; an executable with custom calls or that cannot be serialized is stored as its
    lowered program (jax.export), which later processes compile (a program that cannot be
    exported either is compiled in each process)."""
    if name is None or kernel_store.folder() is None:
        return jax.jit(fn).lower(*args).compile()

    def compiled():
        lowered = jax.jit(kernel_store.fresh(fn)).lower(*args)
        program = lowered.compile()
        # a custom call (LAPACK's, a host callback) is code of this process that the
        # executable points into: not stored as an executable (loaded elsewhere, it crashes)
        if "custom_call" in lowered.as_text() or not kernel_store.save(name, program):
            try:
                kernel_store.save(name, jax.export.export(jax.jit(fn))(*args))
            except Exception:  # noqa: BLE001 -- not exportable (e.g. a custom call): not stored
                pass
        return program
    stored = kernel_store.load(name)
    if isinstance(stored, jax.export.Exported):
        return jax.jit(stored.call).lower(*args).compile()
    return Loaded(stored, compiled) if stored is not None else compiled()


class Loaded:
    """A stored executable that is compiled again (and stored anew) where its first call
    fails: an entry written without its code (an executable JAX fetched from its persistent
    cache, e.g. by an older version) would otherwise fail in every process."""

    def __init__(self, executable, compile_again):
        self.executable, self.compile_again = executable, compile_again

    def __call__(self, *args):
        if self.compile_again is None:
            return self.executable(*args)
        try:  # (the error comes with the outputs: the first call is waited for)
            out = jax.block_until_ready(self.executable(*args))
        except jax.errors.JaxRuntimeError:
            self.executable = self.compile_again()
            out = self.executable(*args)
        self.compile_again = None
        return out


def global_names(code):
    """The names that a code object and the code nested in it (lambdas, inner functions)
    may read as globals: its co_names (names not among the function's globals are
    builtins and skipped; an attribute name that is also a global is keyed harmlessly)."""
    names = set(code.co_names)
    for const in code.co_consts:
        if isinstance(const, types.CodeType):
            names.update(global_names(const))
    return tuple(sorted(names))


def elements_per_call(points, nq):
    """Elements of nq points in a call of about `points` points: a multiple of 8 from 8 on
    (so that the calls' pieces of per-element float data start 64-byte aligned: Chunked)."""
    n = max(1, points // nq)
    return n - n % 8 if n >= 8 else n


def call_sizes(nq, element_work):
    """(small, large) elements per kernel call for elements of nq points and element_work
    Hessian entries: CHUNK_POINTS points, the large call at most WORK_PER_CALL entries and
    never below the small one."""
    small = elements_per_call(CHUNK_POINTS[0], nq)
    large = elements_per_call(min(CHUNK_POINTS[1], WORK_PER_CALL * nq // element_work), nq)
    return small, max(small, large)


def last_call(n, small):
    """Elements of a term's last call for the n < small elements left: the least rung of
    8, 16, 32, ... (powers of two below small) and small that holds them (at least one
    element): each rung is one kernel shape more to load once per process."""
    rung = 8
    while rung < max(n, 1) and 2 * rung < small:
        rung *= 2
    return rung if rung >= n and rung < small else small


def _pad(a, n):
    """Pad axis 0 to length n by repeating the last entry, or zeros for a term without
    elements on this rank (results for the padding are discarded); only the last call of
    a term is padded."""
    if a.shape[0] == n:
        return a
    if a.shape[0] == 0:
        return np.zeros((n,) + a.shape[1:], a.dtype)
    return np.concatenate([a, np.repeat(a[-1:], n - a.shape[0], axis=0)])


class Chunked:
    """Per-element data a[e, ...] held on the device in the pieces that the kernel calls over
    all elements take (Term.blocks), the last padded (_pad), so that a call passes its piece
    as it is, with nothing to gather, pad or copy.  The pieces are put there once from one
    aligned host copy (device.empty; the calls' first elements are multiples of 8, so
    every piece starts aligned): on the CPU they alias it, and the host reads that copy
    (`host`, read-only); elsewhere it is dropped and the host reads the pieces back."""

    def __init__(self, a, blocks):
        self.shape, self.dtype, self.blocks = a.shape, a.dtype, blocks
        self.starts = np.array([s for s, _ in blocks], dtype=np.int64)
        self._put(a)

    def _put(self, a):
        """The pieces of a on the device (and the aligned host copy they alias, on the CPU)."""
        blocks = self.blocks
        end = blocks[-1][0] + blocks[-1][1]
        padded = empty((end,) + a.shape[1:])
        padded[:len(a)] = a
        padded[len(a):] = a[-1] if len(a) else 0.0
        self.parts = jax.device_put([padded[s:s + n] for s, n in blocks])  # one batched call
        shared = all(p.unsafe_buffer_pointer() == padded[s:].ctypes.data for p, s in zip(self.parts, self.starts))
        self.padded = padded if shared else None
        if shared:
            padded.flags.writeable = False
        self.host = padded[:a.shape[0]] if shared else None

    def release(self, source):
        """Drop the data, on the device and on the host; source() gives the same array
        again, put there when next read (e.g. a quadratic term's data once assembled)."""
        for name in ("parts", "padded", "host"):
            self.__dict__.pop(name, None)
        self._source = source

    def __getattr__(self, name):
        """The data after release(): put on the device again from their source."""
        if name in ("parts", "padded", "host") and "_source" in self.__dict__:
            a = np.asarray(self.__dict__.pop("_source")(), dtype=self.dtype)
            if a.shape != self.shape:
                raise RuntimeError(f"released data came back with shape {a.shape}, not {self.shape}")
            self._put(a)
            return getattr(self, name)
        raise AttributeError(name)

    def __array__(self, dtype=None, copy=None):
        """All rows on the host."""
        a = self.host if self.host is not None else np.concatenate([host(p) for p in self.parts])[:self.shape[0]]
        return a if dtype is None else a.astype(dtype)

    def rows(self, rows):
        """The given rows on the host (rows of the padding too)."""
        if self.padded is not None:
            return self.padded[rows]
        piece = np.searchsorted(self.starts, rows, side="right") - 1
        out = np.empty((len(rows),) + self.shape[1:], self.dtype)
        for k in np.unique(piece):
            at = piece == k
            out[at] = host(self.parts[k])[rows[at] - self.starts[k]]
        return out


def check_arguments(names, fields, label, parameters=()):
    """Every argument of a density names a field, a parameter or x, n, h: otherwise a clear error."""
    unknown = [k for k in names if k not in fields and k not in RESERVED and k not in parameters]
    if unknown:
        raise ValueError(f"{label}: unknown argument(s) {unknown}; a density takes fields "
                         f"{sorted(fields)}, parameters {sorted(parameters)} and x (point), "
                         "n (normal), h (mesh size)")


class Parameters:
    """Run-time parameters of a problem: names and one array of values, shared by its
    terms and changed in place, so that the compiled kernels take them as data."""

    def __init__(self, values=None):
        values = dict(values or {})
        for k, v in values.items():
            if not (isinstance(k, str) and k.isidentifier()) or k in RESERVED:
                raise ValueError(f"parameter name {k!r} must be a Python identifier other than x, n, h")
        self.names = tuple(values)
        self.values = np.array([float(v) for v in values.values()], dtype=float)

    def __contains__(self, name):
        return name in self.names

    def index(self, names):
        """Positions of the given parameter names among all."""
        return np.array([self.names.index(k) for k in names], dtype=np.int64)


class ConstantDensity(ValueError):
    """A density that depends on no field (e.g. a given multiplier lambda = q)."""


class Term:
    """A pointwise density integrated on a measure, ready to assemble."""

    def __init__(self, pointwise, names, measure, fields, offsets, label, keep_points=False,
                 residual=False, vector=False, parameters=None, like=None):
        """keep_points: the quadrature points x are read even if the density does not use
        them (constraints, for their reports): stored, or, on a measure that gives them
        again (regenerable), computed at each read of `x` (points_on_demand; 48 MB less
        for the two membranes' contact at 522k unknowns, 0.05 s a read); residual: the density returns the
        pair (c, q) of a residual term (module docstring); vector: it may return an array
        (e.g. a vector multiplier, for its Jacobian), not an energy; parameters: the
        problem's Parameters (those the density names enter its kernels as data); like: a
        term on the same measure whose per-element data (W, h, x, n and the inverse
        Jacobians, the same arrays) this one shares instead of putting its own there."""
        if like is not None and like.measure is not measure:
            raise ValueError(f"{label}: a term shares the data of a term on the same measure only")
        self.residual, self.vector = residual, vector
        by_name = {f.name: f for f in fields}
        self.parameters = parameters or Parameters()
        check_arguments(names, by_name, label, self.parameters.names)
        self.parameter_names = tuple(k for k in names if k in self.parameters)
        self.parameter_index = self.parameters.index(self.parameter_names)
        if "n" in names and measure.kind == "cells":
            raise ValueError(f"{label} uses the normal n but is integrated over cells; "
                             "use a facet measure")
        self.label, self.measure = label, measure
        self.pointwise = pointwise
        fs = [by_name[k] for k in names if k in by_name]
        for f in fs:
            measure.attach(f)
        self.dim = measure.mesh.dim()
        self.layout = self._record(fs)
        if not self.layout:
            raise ConstantDensity(f"{label} does not depend on any field")
        W = None  # the weights held: W[e, q], or on affine cells d[e], W = d w_q (weight_rule)
        if like is not None:
            self.weight_rule, self.nel, self.nq = like.weight_rule, like.nel, like.nq
            self.nonnegative_weights = like.nonnegative_weights
        elif getattr(measure, "separable_weights", None) is not None:
            W, w = measure.separable_weights
            self.weight_rule, self.nel, self.nq = tuple(w.tolist()), W.shape[0], w.size
            self.nonnegative_weights = bool(np.all(W >= 0) and np.all(w >= 0))
        else:
            W = measure.weights
            self.weight_rule, (self.nel, self.nq) = None, W.shape
            self.nonnegative_weights = bool(np.all(W >= 0))
        self.has_normal = measure.normals is not None if like is None else like.has_normal
        self.fields = [by_name[name] for name, _, _ in self.layout]
        # per field: T (the tabulation's kept rows) or, for a Mapped one, the reference
        # tabulation R with the inverse Jacobians J and how its rows are formed (maps)
        self.T, self.J, self.maps, self.kept, field_dofs = [], [], [], [], []
        tabulations = [measure.tabulation(by_name[name], [o for o, _, _, _ in parts])
                       for (name, parts, _) in self.layout]
        k = sum(dofs.shape[1] for _, dofs in tabulations)  # local dofs
        self.element_work = like.element_work if like is not None else self.nq * k ** 2
        self.chunks = call_sizes(self.nq, self.element_work)
        while tabulations:  # (each host tabulation dropped once stored)
            T, dofs = tabulations.pop(0)
            mapped = isinstance(T, Mapped)
            # jet components that vanish identically (e.g. P1 Hessians) are left out of the
            # differentiation and enter the density as exact zeros
            kept = np.flatnonzero(T.nonzero_rows() if mapped else T.any(axis=(0, 1, 3)))
            if kept.size == 0:
                kept = np.arange(1)
            if mapped:  # (the inverse Jacobians are the measure's, the same for all its fields:
                # held once, e.g. for the two membranes' energy, 17 MB at 522k unknowns)
                shared = [J for J in (like.J if like is not None else self.J) if J is not None]
                self.T.append(self._stored(T.R))
                self.J.append(shared[0] if shared else self._stored(T.invJ))
                self.maps.append(T.spec)
            else:
                self.T.append(self._stored(T if kept.size == T.shape[2] else T[:, :, kept]))
                self.J.append(None)
                self.maps.append(None)
            self.kept.append(tuple(kept.tolist()))
            field_dofs.append(dofs)
        self.offsets = [offsets[f.name] for f in self.fields]
        self.widths = [d.shape[1] for d in field_dofs]
        if len(field_dofs) == 1 and self.offsets[0] == 0:
            self.global_dofs = field_dofs[0]  # (one field at offset 0: its own array)
        else:
            self.global_dofs = np.empty((field_dofs[0].shape[0], sum(self.widths)), field_dofs[0].dtype)
            for columns, d, o in zip(self._columns(), field_dofs, self.offsets):
                self.global_dofs[:, columns] = d
                self.global_dofs[:, columns] += o
        del field_dofs
        self.share_dofs(self.global_dofs)
        # per-point data on the device (Chunked); x and n None where the term keeps none
        given = dict(W=lambda: W, h=lambda: np.asarray(measure.h, dtype=float),
                     x=lambda: np.moveaxis(measure.points, 0, -1), n=lambda: np.moveaxis(measure.normals, 0, -1))
        # a constraint's points for its reports: kept where the measure cannot give them again
        self.points_on_demand = keep_points and "x" not in names and self.regenerable
        held = dict(W=True, h=True, x="x" in names or keep_points and not self.points_on_demand,
                    n=self.has_normal)
        self.data = {k: None if not held[k] else like.data[k] if like is not None and like.data[k] is not None
                     else self._chunked(given[k]()) for k in given}
        self.cells = measure.cells  # the cell of measure.mesh that owns each element
        self._alpha0 = None  # per-element data of constraint terms (functional.ALPHA0): 1 until set
        self._kernels, self._zeros = {}, {}

    def _record(self, fs):
        """Which derivative orders of which field the density uses: the layout [(field name,
        ((order, shape, start, size) of each order used), orders used)], found by tracing the
        density once per process for its fingerprint and the fields' jet shapes (and kept
        in kernel_store, like the kernels, for later processes)."""
        shapes = {f.name: dict(zip(f.orders, self.measure.shapes(f, f.orders))) for f in fs}
        key = ("layout", fingerprint(self.pointwise), self.residual, self.vector, self.dim, self.parameter_names,
               tuple((f.name, tuple((o, tuple(s)) for o, s in shapes[f.name].items())) for f in fs))
        return _cached(key, lambda: _stored(key, lambda: self._trace_layout(fs, shapes)))

    def _trace_layout(self, fs, shapes):
        """_record's layout, by tracing the density on jets of the given shapes."""
        used = {f.name: set() for f in fs}

        def trace(zs, x, n, h, a, t):
            args = {"x": x, "n": n, "h": h, ALPHA0: a, **dict(zip(self.parameter_names, t))}
            for f in fs:
                args[f.name] = Jet(f.name, zs[f.name], f.orders, used[f.name])
            return self.pointwise(args)

        zs = {f.name: {o: jax.ShapeDtypeStruct(s, jnp.float64) for o, s in shapes[f.name].items()}
              for f in fs}
        vec = jax.ShapeDtypeStruct((self.dim,), jnp.float64)
        scalar = jax.ShapeDtypeStruct((), jnp.float64)
        out = jax.eval_shape(trace, zs, vec, vec, scalar, scalar,
                             jax.ShapeDtypeStruct((len(self.parameter_names),), jnp.float64))
        if self.residual:
            if not (isinstance(out, tuple) and len(out) == 2 and out[0].shape == out[1].shape):
                raise ValueError(f"{self.label} must return a pair (c, q) of arrays of one shape")
        elif hasattr(out, "shape") and out.shape != () and not self.vector:
            raise ValueError(f"{self.label} must return a scalar at each point, not shape {out.shape}")
        layout = []
        for f in fs:
            parts, start = [], 0
            for o in sorted(used[f.name]):
                size = int(np.prod(shapes[f.name][o], dtype=int))
                parts.append((o, tuple(shapes[f.name][o]), start, size))
                start += size
            if parts:
                layout.append((f.name, tuple(parts), tuple(sorted(used[f.name]))))
        return tuple(layout)

    def retabulate(self):
        """Tabulate again the fields that live on another mesh than the measure's (after an
        interface changed its pairing, nitsche.sliding), in place: terms made by
        with_pointwise share the new tabulations, and the shapes, hence the kernels, stay."""
        for i, ((name, parts, _), f) in enumerate(zip(self.layout, self.fields)):
            if f.mesh is self.measure.mesh:
                continue
            T, dofs = self.measure.tabulation(f, [o for o, _, _, _ in parts])
            kept = list(self.kept[i])
            self.T[i] = self._stored(T if len(kept) == T.shape[2] else T[:, :, kept])
            self.field_dofs[i][...] = dofs + self.offsets[i]  # (a view: global_dofs' columns)

    def _columns(self):
        """The columns of each field in global_dofs (slices)."""
        ends = np.cumsum(self.widths)
        return [slice(int(e - w), int(e)) for e, w in zip(ends, self.widths)]

    def share_dofs(self, global_dofs):
        """Take global_dofs (E, k), the fields' dofs with their offsets side by side (this
        term's own or an equal array of another term: one array for both), and field_dofs
        as views of its columns."""
        self.global_dofs = global_dofs
        self.field_dofs = [global_dofs[:, columns] for columns in self._columns()]

    @property
    def regenerable(self):
        """Whether the measure gives the per-element data again (on cells, the fields on its
        mesh)."""
        m = self.measure
        return m.kind == "cells" and all(f.mesh is m.mesh for f in self.fields)

    def _again(self, what):
        """A source of per-element data computed again from the measure: what() with the
        measure's bases built for the term's fields, and released after."""
        m = self.measure

        def source():
            for f in self.fields:
                m.attach(f)
            try:
                return what()
            finally:
                m.release()
        return source

    def release(self):
        """Drop the per-element data on the device that the measure gives again (W, h, x, n
        and the tabulations), for a term on cells whose fields live on its mesh (e.g. a
        quadratic term once assembled); a later kernel call (a new pattern, a stability
        check) computes them again from the measure, the same arrays.  alpha0 is kept."""
        if not self.regenerable:
            return
        m, again = self.measure, self._again
        given = dict(W=lambda: m.weights if self.weight_rule is None else m.separable_weights[0],
                     h=lambda: m.h, x=lambda: np.moveaxis(m.points, 0, -1))
        for k, a in self.data.items():
            if a is not None:
                a.release(again(given[k]))
        for i, ((_, parts, _), f) in enumerate(zip(self.layout, self.fields)):
            orders, kept = [o for o, _, _, _ in parts], list(self.kept[i])

            def tabulation(f=f, orders=orders):
                return m.tabulation(f, orders)[0]
            if isinstance(self.J[i], Chunked):
                self.J[i].release(again(lambda tab=tabulation: tab().invJ))
            if isinstance(self.T[i], Chunked):
                self.T[i].release(again(lambda tab=tabulation, kept=kept: tab()[:, :, kept]))

    def _chunked(self, a):
        """Per-element data on the device in the pieces of the kernel calls (Chunked)."""
        return Chunked(np.asarray(a, dtype=float), self.blocks(self.nel))

    def _stored(self, a):
        """A tabulation on the device: one row shared by all elements as it is, else Chunked."""
        return on_device(a, float) if a.shape[0] == 1 else self._chunked(a)

    def _view(self, name):
        """Per-point data `name` of all elements on the host (zeros where the term keeps none;
        the points computed again where it gives them on demand)."""
        a = self.data[name]
        if a is None and name == "x" and self.points_on_demand:
            return self._again(lambda: np.moveaxis(self.measure.points, 0, -1))()
        if name == "W" and self.weight_rule is not None:  # W[e, q] = d[e] w_q, formed here
            return np.asarray(a)[:, None] * np.array(self.weight_rule)
        return np.asarray(a) if a is not None else np.broadcast_to(np.zeros((1, self.nq, self.dim)),
                                                                  (self.nel, self.nq, self.dim))

    # read on the host: on the CPU read-only views of the device data, elsewhere copies
    W = property(lambda self: self._view("W"), doc="W[e, q]: quadrature weight x Jacobian")
    weights = property(lambda self: np.asarray(self.data["W"]),
                       doc="the weights as the kernels take them: W[e, q], or d[e] (weight_rule: W = d w_q)")
    x = property(lambda self: self._view("x"), doc="the quadrature points x[e, q, :]")
    n = property(lambda self: self._view("n"), doc="the outward normals n[e, q, :]")
    h = property(lambda self: self._view("h"), doc="the mesh size h[e] of the cell that owns each element")

    @property
    def alpha0(self):
        """alpha0 per element (see functional.ALPHA0), read on the host."""
        return np.ones(self.nel) if self._alpha0 is None else np.asarray(self._alpha0)

    @alpha0.setter
    def alpha0(self, values):
        self._alpha0 = self._chunked(np.broadcast_to(np.asarray(values, dtype=float), (self.nel,)))

    def with_pointwise(self, pointwise):
        """The same term (same tabulations) with another density (not a residual) of the
        same jets."""
        other = copy.copy(self)
        other.pointwise, other._kernels, other.residual = pointwise, {}, False
        for cached in ("_quadratic", "_coupling", "_convex", "_affine"):
            other.__dict__.pop(cached, None)
        return other

    def output_shape(self):
        """The shape of the density's value at a point."""
        return jax.eval_shape(self._point_fn(), *self._sample()).shape

    @property
    def sizes(self):
        """(jet components kept, local dofs) of each field."""
        return [(len(k), T.shape[3]) for T, k in zip(self.T, self.kept)]

    @property
    def tables(self):
        """The per-element data of the tabulations, in kernel order: each field's T (or R),
        then the inverse Jacobians of the Mapped ones; one row where the same on every element."""
        return list(self.T) + [J for J in self.J if J is not None]

    def _theta0(self):
        """The parameters the density reads, at their current values (for tracing)."""
        return jnp.asarray(self.parameters.values[self.parameter_index])

    def parameter_data(self, n):
        """The values of the parameters the density reads, one row per element of a chunk."""
        return np.broadcast_to(self.parameters.values[self.parameter_index], (n, self.parameter_index.size))

    def per_point(self, i, chunk, rows=None):
        """The per-point data (W, x, n, h, alpha0) of kernel call i of `chunk` elements: its
        pieces on the device, or, for the given rows (padded), gathered on the host; zeros
        (put there once per chunk size) for x, n where the term keeps none."""
        def one(a, shape):
            if a is None:
                if chunk not in self._zeros:
                    self._zeros[chunk] = on_device(np.zeros((chunk,) + shape))
                return self._zeros[chunk]
            return a.parts[i] if rows is None else a.rows(rows)
        if self._alpha0 is None:
            self.alpha0 = 1.0
        d, point = self.data, (self.nq, self.dim)
        return [one(d["W"], ()), one(d["x"], point), one(d["n"], point), one(d["h"], ()), one(self._alpha0, ())]

    def _point_fn(self, by_field=False):
        """The density w(z, x, n, h, a, t) of the kept jet components z of all fields (one
        vector), or, by_field, w(z_1, ..., z_k, x, n, h, a, t) of one vector per field (a: the
        element's alpha0, t: the values of the parameters it reads)."""
        layout, pointwise, kept, pnames = self.layout, self.pointwise, self.kept, self.parameter_names
        offsets = np.cumsum([0] + [m for m, _ in self.sizes])

        def of_fields(*a):
            zs, (x, n, h, alpha0, t) = a[:len(layout)], a[len(layout):]
            args = {"x": x, "n": n, "h": h, ALPHA0: alpha0}
            args.update((k, t[i]) for i, k in enumerate(pnames))
            for (name, parts, provided), z, kf in zip(layout, zs, kept):
                full = jnp.zeros(sum(p[3] for p in parts)).at[np.array(kf)].set(z)
                args[name] = Jet(name, {o: full[s: s + size].reshape(shape)
                                        for o, shape, s, size in parts}, provided)
            return pointwise(args)

        def f(z, x, n, h, a, t):
            return of_fields(*[z[i:j] for i, j in zip(offsets[:-1], offsets[1:])], x, n, h, a, t)
        return of_fields if by_field else f

    @property
    def is_quadratic(self):
        """True when d2w/dz2 does not depend on z (found from the computation graph) and
        the density reads no parameter: then J restricted to this term is a quadratic form,
        assembled once."""
        if self.parameter_names:
            return False
        if not hasattr(self, "_quadratic"):
            def quadratic():
                second = jax.jacfwd(derivative(self._point_fn(), self.residual))
                return not _depends_on_first_input(jax.make_jaxpr(second)(*self._sample()).jaxpr)
            self._quadratic = self._traced("quadratic", quadratic)
        return self._quadratic

    @property
    def is_convex_quadratic(self):
        """True when J restricted to this term is a convex quadratic form: d2w/dz2 is one
        positive semidefinite matrix D at every point (it depends on none of z, x, n, h,
        alpha0: found from the computation graph; D's eigenvalues at one point, to round-off)
        and every weight W >= 0, so that each element Hessian sum_q W_q T_q^T D T_q is
        positive semidefinite."""
        if self.residual or not self.is_quadratic or not self.nonnegative_weights:
            return False
        if not hasattr(self, "_convex"):
            def convex():
                second = jax.jacfwd(derivative(self._point_fn(), False))
                sample = self._sample()
                if any(_dependent_outputs(jax.make_jaxpr(second)(*sample).jaxpr, [True] * 5 + [False])):
                    return False
                D = np.asarray(second(*sample))
                w = np.linalg.eigvalsh(0.5 * (D + D.T))
                return bool(w.min() >= -ROUNDOFF_EIGENVALUE * np.abs(w).max())
            self._convex = self._traced("convex", convex)
        return self._convex

    @property
    def is_affine(self):
        """True when the density (a scalar or a vector) is affine in z at every point: dw/dz
        does not depend on z (found from the computation graph)."""
        if not hasattr(self, "_affine"):
            def affine():
                first = jax.jacfwd(self._point_fn())
                return not _depends_on_first_input(jax.make_jaxpr(first)(*self._sample()).jaxpr)
            self._affine = self._traced("affine", affine)
        return self._affine

    def _sample(self):
        """Arguments (z, x, n, h, alpha0, t) of the density at one point, for tracing."""
        vec = jnp.zeros(self.dim)
        return jnp.zeros(sum(mf for mf, _ in self.sizes)), vec, vec, 0.1, 1.0, self._theta0()

    def _traced(self, what, compute):
        """compute() of a property found by tracing the density, once per process and kept in
        the kernel store (keyed by the density and its jets)."""
        key = (what, fingerprint(self.pointwise), tuple(self.layout), tuple(self.kept))
        return _cached(key, lambda: _stored(key, compute))

    @property
    def coupling(self):
        """coupling[i][j]: whether d2w/dz_i dz_j (fields i, j) can be non-zero, i.e. whether
        dw/dz_i depends on z_j (found from the computation graph); the element Hessian
        blocks of uncoupled pairs are exact zeros and not computed (all pairs of a residual)."""
        if self.residual:
            return tuple((True,) * len(self.sizes) for _ in self.sizes)
        if not hasattr(self, "_coupling"):
            def coupling():
                sizes = [mf for mf, _ in self.sizes]
                nf = len(sizes)
                args = [jnp.zeros(mf) for mf in sizes] + [jnp.zeros(self.dim), jnp.zeros(self.dim), 0.1, 1.0,
                                                          self._theta0()]
                coupled = []
                for i in range(nf):
                    jaxpr = jax.make_jaxpr(jax.grad(self._point_fn(by_field=True), argnums=i))(*args).jaxpr
                    coupled.append(tuple(any(_dependent_outputs(jaxpr, [k == j for k in range(len(jaxpr.invars))]))
                                         for j in range(nf)))
                return tuple(coupled)
            key = ("coupling", fingerprint(self.pointwise), tuple(self.layout), tuple(self.kept),
                   self.parameter_names)
            self._coupling = _cached(key, lambda: _stored(key, coupling))
        return self._coupling

    def kernel(self, kind, chunk):
        """The compiled kernel of `chunk` elements: 'energy', 'gradient' (energy, gradient),
        'full' (energy, gradient, Hessian), 'jacobian' (per point) or 'values'."""
        if (kind, chunk) in self._kernels:
            return self._kernels[kind, chunk]
        key = (kind, self.residual, fingerprint(self.pointwise), tuple(self.layout), tuple(self.kept), chunk,
               tuple((a.shape[0] == 1,) + a.shape[1:] for a in self.tables), tuple(self.maps),
               self.dim, self.has_normal, self.parameter_names, self.weight_rule)
        coupling = self.coupling if kind == "full" else None

        def compiled():
            fn = _build(kind, self._point_fn(), self.sizes, chunk, self.nq, coupling, self.residual,
                        self.maps, self.kept, self.weight_rule)
            args = [jax.ShapeDtypeStruct((1 if a.shape[0] == 1 else chunk,) + a.shape[1:], jnp.float64)
                    for a in self.tables]
            args += [jax.ShapeDtypeStruct((chunk, k), jnp.float64) for _, k in self.sizes]
            point = (self.nq, self.dim)
            weights = (self.nq,) if self.weight_rule is None else ()  # W (chunk, nq), or d (chunk,)
            args += [jax.ShapeDtypeStruct((chunk,) + shape, jnp.float64)  # W, x, n, h, alpha0, parameters
                     for shape in (weights, point, point, (), (), (self.parameter_index.size,))]
            return _compile(fn, args, kernel_store.digest(key))
        self._kernels[kind, chunk] = _cached(key, compiled)
        return self._kernels[kind, chunk]

    def blocks(self, nel, rungs=True):
        """(start, size) of the kernel calls over nel elements: calls of the large chunk while
        a whole one is left, then calls of the small one while a whole one is left, then one
        call of the small chunk, or of the least rung that holds the rest (last_call) where
        that saves padding worth a kernel shape (RUNG_WORTH), so that a term of 1.1 large
        chunks is not padded to 2, nor an ironing contact term of 24 elements to 336; no
        elements: one padded call, no rows."""
        small, large = self.chunks
        whole = nel // large * large if large > small else 0
        calls = [(s, large) for s in range(0, whole, large)]
        calls += [(s, small) for s in range(whole, nel - small + 1, small)]
        rest = calls[-1][0] + calls[-1][1] if calls else 0
        if nel == rest and calls:
            return calls
        rung = last_call(nel - rest, small) if rungs else small
        return calls + [(rest, rung if (small - rung) * self.element_work >= RUNG_WORTH else small)]

    def calls(self, kind, x, elements=None, rungs=True):
        """Apply a kernel to all elements (or to the given ones) for the global dof vector x,
        call by call: yields (the first element of the call, its outputs without padding).
        Over all elements a call passes the pieces of the per-element data stored on the
        device (Chunked) as they are; what crosses per call is the element dofs x[dofs] (a
        gather on the host, where x lives) and the parameters, and back the outputs (on the
        CPU without a copy); given elements, their rows are gathered on the host.  A call's
        outputs are handed out once the next call is dispatched (JAX dispatches
        asynchronously), so that the caller's work on them (the scatter into the Hessian's
        data) and the next gather run beside that kernel.  rungs=False: the last call is one
        of the small chunk (no kernel shape of a rung that the whole term's calls may not
        have loaded)."""
        dofs = self.field_dofs if elements is None else [d[elements] for d in self.field_dofs]
        nel = self.nel if elements is None else len(elements)

        def outputs(s, chunk, out):
            return s, [host(o)[:max(0, min(chunk, nel - s))] for o in out]
        before = None  # the call dispatched before: (start, chunk, its outputs)
        for i, (s, chunk) in enumerate(self.blocks(nel, rungs)):
            rows = None if elements is None else _pad(np.asarray(elements[s:s + chunk]), chunk)
            Ts = [a if a.shape[0] == 1 else a.parts[i] if rows is None else a.rows(rows) for a in self.tables]
            u = [_pad(x[d[s:s + chunk]], chunk) for d in dofs]  # the call's gather (host: x lives there)
            out = self.kernel(kind, chunk)(*Ts, *u, *self.per_point(i, chunk, rows), self.parameter_data(chunk))
            if before is not None:
                yield outputs(*before)
            before = (s, chunk, out)
        if before is not None:
            yield outputs(*before)

    def run(self, kind, x, elements=None):
        """The kernel's outputs on all elements (or on the given ones): each call's outputs
        copied into arrays of all elements as they come (peak: one copy plus two calls')."""
        nel = self.nel if elements is None else len(elements)
        outs = None
        for s, got in self.calls(kind, x, elements):
            if outs is None:
                outs = [np.empty((nel,) + o.shape[1:], o.dtype) for o in got]
            for out, o in zip(outs, got):
                out[s:s + len(o)] = o
        return outs


def _dependent_outputs(jaxpr, dependent_inputs):
    """Which outputs of a jaxpr depend on the flagged inputs (looking inside nested jit
    calls; other nested computations are treated conservatively as dependent)."""
    dependent = {v for v, d in zip(jaxpr.invars, dependent_inputs) if d}
    for eqn in jaxpr.eqns:
        flags = [not isinstance(v, Literal) and v in dependent for v in eqn.invars]
        if not any(flags):
            continue
        sub = eqn.params.get("jaxpr")
        sub = getattr(sub, "jaxpr", sub)
        if sub is not None and hasattr(sub, "invars") and len(sub.invars) == len(flags):
            dependent.update(v for v, d in zip(eqn.outvars, _dependent_outputs(sub, flags)) if d)
        else:
            dependent.update(eqn.outvars)
    return [not isinstance(v, Literal) and v in dependent for v in jaxpr.outvars]


def _depends_on_first_input(jaxpr):
    """Whether any output of a jaxpr depends on its first input."""
    return any(_dependent_outputs(jaxpr, [True] + [False] * (len(jaxpr.invars) - 1)))


def derivative(point_fn, residual):
    """z -> dw/dz of an energy density, or z -> R(z) = (dq/dz)^T c of a residual's (c, q)."""
    if not residual:
        return jax.grad(point_fn)

    def R(z, *rest):
        _, pull, c = jax.vjp(lambda z: point_fn(z, *rest)[::-1], z, has_aux=True)
        return pull(c)[0]
    return R


def mapped(R, J, spec, kept, chunk, nq):
    """The kept rows of T[e, q, c, k] of a chunk from a Mapped tabulation (measures.Mapped):
    values R, gradients sum_i J[e, q, i, m] R[q, (j, i), k], zero Hessians."""
    orders, vc, dim = spec
    J = jnp.broadcast_to(J, (chunk, nq, dim, dim))
    blocks, start = [], 0
    for o in orders:
        size = vc * dim ** o
        Ro = R[0, :, start:start + size]
        if o == 0:
            blocks.append(jnp.broadcast_to(Ro, (chunk,) + Ro.shape))
        elif o == 1:
            blocks.append(jnp.einsum("eqim,qjik->eqjmk", J, Ro.reshape(nq, vc, dim, -1))
                          .reshape(chunk, nq, size, -1))
        else:
            blocks.append(jnp.zeros((chunk, nq, size, R.shape[-1])))
        start += size
    return jnp.concatenate(blocks, axis=2)[:, :, np.array(kept)]


def _build(kind, point_fn, sizes, chunk, nq, coupling=None, residual=False, maps=None, kept=None,
           weight_rule=None):
    """The kernel of `kind` on calls of `chunk` elements; weight_rule (w_q): the weights come
    as d (chunk,), W[e, q] = d[e] w_q (Term.weight_rule), else as W (chunk, nq)."""
    m = sum(mf for mf, _ in sizes)
    first = derivative(point_fn, residual)
    nf = len(sizes)
    maps = maps or [None] * nf
    ng = sum(s is not None for s in maps)

    def split(a):
        """(T of each field, dofs u of each field, the per-point data) of a kernel's arguments."""
        tables, Js, us, rest = a[:nf], iter(a[nf:nf + ng]), a[nf + ng:2 * nf + ng], a[2 * nf + ng:]
        Ts = [T if spec is None else mapped(T, next(Js), spec, k, chunk, nq)
              for T, spec, k in zip(tables, maps, kept or [None] * nf)]
        if weight_rule is not None:  # W[e, q] = d[e] w_q: the product the measure's weights are
            rest = (rest[0][:, None] * jnp.asarray(weight_rule),) + tuple(rest[1:])
        return Ts, us, rest

    def value_and_first(z, *rest):
        """(w, dw/dz), or (0, R) for a residual term (it has no energy)."""
        return (jnp.zeros(()), first(z, *rest)) if residual else jax.value_and_grad(point_fn)(z, *rest)

    def value(z, *rest):
        return jnp.zeros(()) if residual else point_fn(z, *rest)

    offsets = np.cumsum([0] + [mf for mf, _ in sizes])

    def jets(Ts, us):
        return jnp.concatenate([jnp.einsum("eqck,ek->eqc", T, u) for T, u in zip(Ts, us)], axis=-1)

    def points(W, x, n, h, a, t):
        return (x.reshape(chunk * nq, -1), n.reshape(chunk * nq, -1), jnp.repeat(h, nq),
                jnp.repeat(a, nq), jnp.repeat(t, nq, axis=0))

    def contract_gradient(Ts, Wdw):
        """grad_e = sum_q W T^T dw/dz, field by field."""
        return jnp.concatenate([jnp.einsum("eqc,eqck->ek", Wdw[..., a:b], T)
                                for T, a, b in zip(Ts, offsets[:-1], offsets[1:])], axis=1)

    def block(i, j, Ts, Wd2w):
        Ti, Tj = Ts[i], Ts[j]
        if not coupling[i][j]:  # structurally zero (e.g. two fields of a sum of energies)
            return jnp.zeros((chunk, Ti.shape[-1], Tj.shape[-1]))
        return jnp.einsum("eqck,eqcd,eqdl->ekl", Ti,
                          Wd2w[:, :, offsets[i]:offsets[i + 1], offsets[j]:offsets[j + 1]], Tj)

    def contract_hessian(Ts, Wd2w):
        """hess_e = sum_q W T^T d2w/dz2 T, one block per coupled pair of fields."""
        return jnp.concatenate([jnp.concatenate([block(i, j, Ts, Wd2w) for j in range(nf)], axis=2)
                                for i in range(nf)], axis=1)

    def energy(*a):
        Ts, us, (W, x, n, h, alpha0, t) = split(a)
        z = jets(Ts, us).reshape(chunk * nq, m)
        w = jax.vmap(value)(z, *points(W, x, n, h, alpha0, t)).reshape(chunk, nq)
        return (jnp.sum(W * w, axis=1),)

    def gradient(*a):
        Ts, us, (W, x, n, h, alpha0, t) = split(a)
        z = jets(Ts, us).reshape(chunk * nq, m)
        w, dw = jax.vmap(value_and_first)(z, *points(W, x, n, h, alpha0, t))
        Wdw = (W[..., None] * dw.reshape(chunk, nq, m))
        return jnp.sum(W * w.reshape(chunk, nq), axis=1), contract_gradient(Ts, Wdw)

    def second(a):
        """(Ts, W, w, W dw/dz, W d2w/dz2) at the points of a call."""
        Ts, us, (W, x, n, h, alpha0, t) = split(a)
        z = jets(Ts, us).reshape(chunk * nq, m)
        px = points(W, x, n, h, alpha0, t)
        w, dw = jax.vmap(value_and_first)(z, *px)
        d2w = jax.vmap(jax.jacfwd(first))(z, *px)
        return (Ts, W, w, W[..., None] * dw.reshape(chunk, nq, m),
                W[..., None, None] * d2w.reshape(chunk, nq, m, m))

    def full(*a):
        Ts, W, w, Wdw, Wd2w = second(a)
        return (jnp.sum(W * w.reshape(chunk, nq), axis=1), contract_gradient(Ts, Wdw),
                contract_hessian(Ts, Wd2w))

    def support(*a):
        """(energies, gradients, whether each element's Hessian can be non-zero: W d2w/dz2
        non-zero at one of its points), without the Hessians' contraction."""
        Ts, W, w, Wdw, Wd2w = second(a)
        return (jnp.sum(W * w.reshape(chunk, nq), axis=1), contract_gradient(Ts, Wdw),
                jnp.any(Wd2w != 0, axis=(1, 2, 3)))

    def jacobian(*a):
        """sqrt(W) dw/dz T at every point (w: e.g. a multiplier), shape (chunk, nq, dofs)."""
        Ts, us, (W, x, n, h, alpha0, t) = split(a)
        z = jets(Ts, us).reshape(chunk * nq, m)
        dw = jax.vmap(jax.grad(point_fn))(z, *points(W, x, n, h, alpha0, t))
        rdw = jnp.sqrt(W)[..., None] * dw.reshape(chunk, nq, m)
        return (jnp.concatenate([jnp.einsum("eqc,eqck->eqk", rdw[..., i:j], T)
                                 for T, i, j in zip(Ts, offsets[:-1], offsets[1:])], axis=2),)

    def values(*a):
        Ts, us, (W, x, n, h, alpha0, t) = split(a)
        z = jets(Ts, us).reshape(chunk * nq, m)
        out = jax.vmap(point_fn)(z, *points(W, x, n, h, alpha0, t))
        return tuple(o.reshape((chunk, nq) + o.shape[1:]) for o in out)

    return {"energy": energy, "gradient": gradient, "full": full, "support": support, "jacobian": jacobian,
            "values": values}[kind]


class GradientSum:
    """The global vector sum_e P_e^T g_e of a term's element vectors g_e (the gradients),
    given call by call in increasing element order (add(first element, g)): the sums of
    one bincount of all of them over the map D (E, k), bit for bit, without an array of all
    g_e nor an int64 copy of all of D (50 MB for the two membranes at 522k).  The g_e are
    gathered with their dofs in a buffer of at most n entries (all of them for a term of
    fewer: one bincount), after [0, n), which holds the running sums; a full buffer is
    summed by one bincount, which adds in array order: the running sum of each dof first,
    then its new entries, as one bincount of all would."""

    def __init__(self, D, n):
        E, self.k = D.shape
        self.D, self.n = D, n
        self.step = max(1, min(E, n // max(self.k, 1)))  # elements per bincount
        self.prefix = n if E > self.step else 0  # the running sums, where more than one bincount
        self.index = np.empty(self.prefix + self.step * self.k, np.intp)
        self.index[:self.prefix] = np.arange(self.prefix)
        self.values = np.zeros(self.index.size)
        self.held, self.sums = 0, None  # elements in the buffer; the sums of a single bincount

    def add(self, first, g):
        g = g.reshape(len(g), self.k)  # (e, k): a call may hold no element
        i = 0
        while i < len(g):
            m = min(self.step - self.held, len(g) - i)
            a = self.prefix + self.held * self.k
            self.values[a:a + m * self.k] = g[i:i + m].ravel()
            self.index[a:a + m * self.k] = self.D[first + i:first + i + m].ravel()
            self.held += m
            i += m
            if self.held == self.step:
                self._sum()

    def _sum(self):
        end = self.prefix + self.held * self.k
        sums = np.bincount(self.index[:end], weights=self.values[:end], minlength=self.n)
        if self.prefix:
            self.values[:self.n] = sums
        else:
            self.sums = sums
        self.held = 0

    def total(self):
        """The sums (n,)."""
        if self.held:
            self._sum()
        if self.prefix:
            return self.values[:self.n].copy()
        return np.zeros(self.n) if self.sums is None else self.sums


class Assembler:
    """Global energy, gradient and Hessian (CSR, fixed pattern) of a sum of terms; residual
    terms add to the gradient (the residual) and Hessian (its Jacobian), not to the energy."""

    PATTERN = ("pattern", "indptr", "indices", "nnz", "scatter")  # what _build_pattern sets

    def __init__(self, terms, ndofs):
        self.terms, self.ndofs = terms, ndofs
        self._build_pattern()

    def __getattr__(self, name):
        """The pattern and the scatters, built again on first use after release()."""
        if name not in Assembler.PATTERN:
            raise AttributeError(name)
        self._build_pattern()
        return getattr(self, name)

    def release(self):
        """Drop the pattern, the terms' scatters and the quadratic terms' matrices, which
        only the Hessian and its energy and gradient need (after a solve, for the outputs
        that follow it: ~80 MB of the two membranes at 522k unknowns); the next energy,
        gradient or Hessian builds them again as at set-up (a pattern grown by an interface
        paired anew: only its current entries)."""
        for name in Assembler.PATTERN:
            self.__dict__.pop(name, None)
        self._quadratics = {}

    def _build_pattern(self, keep=None):
        """The CSR pattern of all terms' element matrices (and the entries `keep` = (indptr,
        indices) of an earlier pattern, so that it only grows) and each term's Scatter;
        terms on one local-to-global map array share theirs (a Scatter reads the array, which
        an interface paired anew rewrites in place), and so do terms on equal maps where
        neither is ever paired anew (Term.regenerable), which then share the array itself
        (Term.share_dofs: the two membranes' energy and contact, one 13 MB array at 522k
        unknowns instead of two)."""
        distinct, owners, of_term = [], [], []
        for t in self.terms:
            k = next((k for k, d in enumerate(distinct) if d is t.global_dofs or t.regenerable and owners[k].regenerable
                      and d.shape == t.global_dofs.shape and np.array_equal(d, t.global_dofs)), None)
            if k is None:
                k = len(distinct)
                distinct.append(t.global_dofs)
                owners.append(t)
            elif distinct[k] is not t.global_dofs:  # (maps never paired anew: one array)
                t.share_dofs(distinct[k])
            of_term.append(k)
        self.pattern = Pattern(distinct, self.ndofs, keep)
        self.indptr, self.indices, self.nnz = self.pattern.indptr, self.pattern.indices, self.pattern.nnz
        self.scatter = [self.pattern.scatters[k] for k in of_term]
        self._quadratics = {}  # assembled on this pattern
        self._hessian_share = {}  # id(term): the share of its elements with a non-zero Hessian

    def refresh(self, terms):
        """After the given terms changed their global dofs (an interface paired anew): their
        scatters, within the pattern if it holds their entries (returns False), else on a
        pattern grown to hold them (returns True: the matrix structure changed)."""
        for t in terms:
            scatter = self.pattern.scatter(t.global_dofs)
            if scatter is None:
                self._build_pattern(keep=(self.indptr, self.indices))
                return True
            for k, other in enumerate(self.terms):
                if other.global_dofs is t.global_dofs:  # (a Scatter reads its terms' map)
                    self.scatter[k] = scatter
        return False

    def _quadratic(self, t, scatter):
        """(E(0), grad(0), Hessian K, the positions of K's entries in the pattern's data) of a
        quadratic term, assembled once, kernel call by kernel call (no array of all of its
        element Hessians).  A term on a small part of the pattern (a membrane beside a solid)
        keeps K on its non-zero entries only, where that takes less memory than one value per
        pattern entry (8 bytes each against 16: value, column, position); positions None: K
        has the pattern's own structure and data."""
        if id(t) not in self._quadratics:
            E, gradient, data = 0.0, GradientSum(t.global_dofs, self.ndofs), np.zeros(self.nnz)
            for s, (e, ge, H) in t.calls("full", np.zeros(self.ndofs)):
                E += float(e.sum())
                gradient.add(s, ge)
                scatter.add(data, H, s)
            g = gradient.total()
            own = np.flatnonzero(data)
            if 2 * own.size < self.nnz:
                index = np.int32 if self.nnz < 2 ** 31 else np.int64
                own = own.astype(index)
                K = sp.csr_matrix((data[own], self.indices[own], np.searchsorted(own, self.indptr).astype(index)),
                                  shape=(self.ndofs, self.ndofs))
            else:
                own, K = None, self.matrix(data)
            self._quadratics[id(t)] = (E, g, K, own)
            t.release()  # its per-element data, until a kernel needs them again
        return self._quadratics[id(t)]

    def energy(self, x, terms=None):
        E = 0.0
        for t, scatter in zip(self.terms, self.scatter):
            if terms is not None and t not in terms or t.residual:
                continue
            if t.is_quadratic:
                E0, g0, K, _ = self._quadratic(t, scatter)
                E += E0 + g0 @ x + 0.5 * x @ (K @ x)
            else:
                E += float(t.run("energy", x)[0].sum())
        return E

    def evaluate(self, x, terms=None, hessian=True):
        """J(x), its gradient (ndofs,) and the CSR data (nnz,) of its Hessian (None
        unless asked).  Quadratic terms are assembled once and then applied as matrices."""
        E, grad = 0.0, np.zeros(self.ndofs)
        data = np.zeros(self.nnz) if hessian else None
        for t, scatter in zip(self.terms, self.scatter):
            if terms is not None and t not in terms:
                continue
            if t.is_quadratic:
                E0, g0, K, positions = self._quadratic(t, scatter)
                Kx = K @ x
                E += 0.0 if t.residual else E0 + g0 @ x + 0.5 * x @ Kx
                grad = grad + g0 + Kx
                if hessian and positions is None:
                    data += K.data
                elif hessian:  # (by chunks: no temporary of all of K's values)
                    for c in range(0, K.nnz, CHUNK):
                        data[positions[c:c + CHUNK]] += K.data[c:c + CHUNK]
                continue
            e, ge = self._assemble(t, scatter, x, data)
            E += float(e.sum())
            grad += ge
        return E, grad, data

    def _assemble(self, t, scatter, x, data=None):
        """A term's element energies and its global gradient at x, and, data given, data +=
        its Hessian (CSR data), kernel call by kernel call: each call's element Hessians are
        scattered as they come (Scatter.add_pieces: the sums of one scatter of all of them,
        bitwise), and its gradients summed as they come (GradientSum: those of one bincount
        of all of them, bitwise), so that no array of all elements' Hessians or gradients is
        formed.  (Per call, np.add.at took 10x the bincount's time.)

        A term whose element Hessians were mostly exact zeros at its last assembly (at most
        SPARSE_HESSIAN of them non-zero: a contact term off its active set where the
        multiplier does not depend on u) is assembled in two passes: energies, gradients and
        which elements have W d2w/dz2 non-zero at a point ('support'), then the Hessians of
        those elements only; the others' are exact zeros, which add_pieces leaves out
        anyway, so the sums are the same bit for bit.  (On the CPU only: the second pass
        gathers its elements' data on the host, a transfer from an accelerator.)"""
        energies, gradient = np.empty(t.nel), GradientSum(t.global_dofs, self.ndofs)
        share = self._hessian_share.get(id(t))
        sparse = data is not None and share is not None and share <= SPARSE_HESSIAN and is_cpu()
        kind = "gradient" if data is None else "support" if sparse else "full"
        support = np.empty(t.nel, bool) if sparse else None

        def pieces():
            for s, out in t.calls(kind, x):
                rows = slice(s, s + len(out[0]))
                energies[rows] = out[0]
                gradient.add(s, out[1])
                if sparse:
                    support[rows] = out[2]
                elif data is not None:
                    yield rows, out[2]
        if data is None or sparse:
            for _ in pieces():
                pass
        if sparse:
            elements = np.flatnonzero(support)
            count = scatter.add_pieces(data, ((elements[s:s + len(out[2])], out[2])
                                              for s, out in t.calls("full", x, elements, rungs=False)))
        elif data is not None:
            count = scatter.add_pieces(data, pieces())
        if data is not None:
            self._hessian_share[id(t)] = count / max(t.nel, 1)
        return energies, gradient.total()

    def gradient(self, x, terms=None):
        """J(x) and its gradient, without the Hessian."""
        return self.evaluate(x, terms, hessian=False)[:2]

    def matrix(self, data):
        return sp.csr_matrix((data, self.indices, self.indptr), shape=(self.ndofs, self.ndofs))

    def hessian(self, x, terms=None):
        return self.matrix(self.evaluate(x, terms)[2])
