"""The problems of the paper, one module each (public API only)."""
import functools
import importlib

from ..case import Case

MODULES = ["dirichlet", "signorini", "obstacle", "elastic_contact", "two_membrane",
           "membrane_solid", "plate_plate", "plate_unilateral"]


@functools.lru_cache(maxsize=None)
def all_cases():
    """{name: Case} in the order of the paper (one Case object per case and process)."""
    cases = [Case(importlib.import_module(f"{__name__}.{m}")) for m in MODULES]
    return {c.name: c for c in cases}


def get(name):
    cases = all_cases()
    if name not in cases:
        raise KeyError(f"unknown case {name!r}; the cases are: {', '.join(cases)}")
    return cases[name]
