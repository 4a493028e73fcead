"""nitsche: constrained problems of solid mechanics by the general Nitsche method.

Declare the energy J(u), the constraint g(u) >= 0 (or = 0) and where it acts,
the multiplier lambda(u) and the scaling alpha = alpha0 h^k / stiffness; the
library builds J_h, differentiates it with JAX and minimizes it with Newton.
"""
import logging
import os
import warnings

# CHOLMOD's BLAS (Debian's OpenBLAS where installed) single-threaded unless the user says
# otherwise: on 2 cores its threads made every triangular solve of the factor-reusing CG
# 6x slower (spinning against JAX's threads); the numeric factorizations alone take the
# cores (nitsche.threads).
if "OPENBLAS_NUM_THREADS" not in os.environ:
    os.environ["OPENBLAS_NUM_THREADS"] = "1"
    os.environ["NITSCHE_BLAS_DEFAULTED"] = "1"  # (nitsche.threads.DEFAULTED; kept by child processes)

import jax  # noqa: E402

jax.config.update("jax_enable_x64", True)
_cache = os.environ.get("NITSCHE_JAX_CACHE", os.path.expanduser("~/.cache/nitsche/jax"))
if _cache != "off":
    jax.config.update("jax_compilation_cache_dir", _cache)
    jax.config.update("jax_persistent_cache_min_compile_time_secs", 0.0)
    jax.config.update("jax_persistent_cache_min_entry_size_bytes", 0)
    # an entry another process was still writing reads as truncated; JAX then compiles the
    # kernel itself, so the warning is noise (it would break the one-line error output)
    warnings.filterwarnings("ignore", message="Error reading persistent compilation cache entry")

# scikit-fem notes that it copied a refined mesh's arrays into C order: its own internals,
# nothing a user can act on, printed once per refinement of a large tetrahedral mesh
logging.getLogger("skfem.mesh.mesh").addFilter(lambda record: "to C_CONTIGUOUS" not in record.getMessage())

from .fields import Field, history, coordinates  # noqa: E402
from .measures import cells, facets, interface  # noqa: E402
from .functional import (Scaling, Integral, Residual, Equality, Inequality, Penalty, Tresca,  # noqa: E402
                         Coulomb, Constraint)
from .problem import Problem, StabilityWarning  # noqa: E402
from .newton import Result, NotConverged, FeasibilityWarning  # noqa: E402
from .jets import DerivativeError  # noqa: E402
from .study import nested, prolongate  # noqa: E402
from .path import path, Path  # noqa: E402
from .sliding import facet_tangents  # noqa: E402
from . import ops, obstacles  # noqa: E402


def minimize(energy, fields, constraints=(), x0=None, **options):
    """Build the problem and run Newton's method: the one-call form of the API."""
    return Problem(fields, energy, constraints).minimize(x0, **options)


__all__ = ["Field", "history", "coordinates", "facet_tangents", "cells", "facets", "interface", "Scaling", "Integral", "Residual",
           "Equality", "Inequality", "Penalty", "Tresca", "Coulomb", "Constraint", "Problem", "Result",
           "NotConverged", "StabilityWarning", "FeasibilityWarning",
           "DerivativeError", "ops", "obstacles", "minimize", "nested", "prolongate", "path", "Path"]
