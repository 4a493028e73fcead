"""The problems of the paper, one module each (public API only), and case modules of
one's own: a Python file with the same contract (nitsche.case), run as `nitsche run FILE.py`."""
import functools
import importlib
import importlib.util
import os
import sys

from ..case import Case

MODULES = ["dirichlet", "signorini", "obstacle", "elastic_contact", "two_membrane",
           "membrane_solid", "plate_plate", "plate_unilateral", "friction", "block_friction", "compression",
           "indentation", "ironing"]


@functools.lru_cache(maxsize=None)
def all_cases():
    """{name: Case} in the order of the paper (one Case object per case and process)."""
    cases = [Case(importlib.import_module(f"{__name__}.{m}")) for m in MODULES]
    return {c.name: c for c in cases}


def load(path):
    """The case defined by the module file `path` (its NAME defaults to the file name)."""
    if not os.path.isfile(path):
        raise KeyError(f"no case file {path!r}; give a shipped case or an existing FILE.py")
    stem = os.path.splitext(os.path.basename(path))[0]
    spec = importlib.util.spec_from_file_location(f"nitsche_case_{stem}", path)
    module = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = module  # so that pickling and inspect find it
    try:
        spec.loader.exec_module(module)
    except Exception as e:
        del sys.modules[spec.name]
        raise ValueError(f"{path}: importing it failed: {type(e).__name__}: {e}")
    return Case(module, default_name=stem, path=path)


def get(name):
    """A shipped case by name, or the case module in the file `name` (ending in .py)."""
    if name.endswith(".py"):
        return load(name)
    cases = all_cases()
    if name not in cases:
        raise KeyError(f"unknown case {name!r}; the cases are: {', '.join(cases)}")
    return cases[name]
