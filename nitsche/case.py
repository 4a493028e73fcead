"""Ready cases: a problem of the paper as a module, run at any level and degree.

A case module defines
    NAME, SUMMARY            the name on the command line and one line about it
    PARAMETERS               {name: (default, help)}; every physical and numerical parameter
    DEGREES                  the polynomial degrees it supports
    RATE                     {degree: expected energy-norm rate}
    build(level, degree, p)  -> dict(fields=..., energy=..., constraints=...) for nitsche.Problem,
                                p a namespace of the parameters; level = uniform refinements
and optionally
    errors(problem, result, p) -> {name: error against an exact solution}
"""
import math
from collections import namedtuple
from types import SimpleNamespace

from .problem import Problem


Setup = namedtuple("Setup", "case level degree p")


class ParameterError(ValueError):
    """An unknown parameter name or a bad value."""


class Case:
    def __init__(self, module):
        self.module = module
        self.name, self.summary = module.NAME, module.SUMMARY
        self.defaults = dict(module.PARAMETERS)
        self.degrees = tuple(module.DEGREES)
        self._limits = {}

    def help(self):
        lines = [f"{self.name}: {self.summary}", f"degrees: {', '.join(map(str, self.degrees))}",
                 "parameters (--set name=value):"]
        for k, (default, text) in self.defaults.items():
            lines.append(f"  {k:<12} {str(default):<10} {text}")
        return "\n".join(lines)

    def parameters(self, overrides=None):
        """The parameter namespace: defaults updated by {name: value or string}."""
        values = {k: d for k, (d, _) in self.defaults.items()}
        for k, v in (overrides or {}).items():
            if k not in values:
                raise ParameterError(f"case '{self.name}' has no parameter {k!r}; valid names: "
                                     f"{', '.join(self.defaults)}")
            values[k] = _parse(k, v, values[k])
        return SimpleNamespace(**values)

    def check_degree(self, degree):
        if degree not in self.degrees:
            raise ParameterError(f"case '{self.name}' supports degree {self.degrees}, not {degree}")

    def problem(self, level, degree, p, alpha0_limits=None):
        if level < 0:
            raise ParameterError(f"level must be >= 0, got {level}")
        self.check_degree(degree)
        spec = self.module.build(level, degree, p)
        problem = Problem(spec["fields"], spec["energy"], spec.get("constraints", ()),
                          alpha0_limits=alpha0_limits)
        problem.setup = Setup(self.name, level, degree, p)  # for the case's report hooks
        return problem

    def alpha0_limits(self, degree, p, level=1):
        """Diagnostic: the global stability limits of alpha0 (one value per constraint,
        Problem.global_limits) on a coarse level of this case (remembered per degree and
        parameter values).  Each Problem computes its own element-local limits."""
        key = (degree, level, tuple(sorted((k, repr(v)) for k, v in vars(p).items())))
        if key not in self._limits:
            self._limits[key] = self.problem(level, degree, p).global_limits()
        return dict(self._limits[key])

    def errors(self, problem, result, p):
        fn = getattr(self.module, "errors", None)
        return fn(problem, result, p) if fn else {}

    @property
    def rate(self):
        return getattr(self.module, "RATE", {})


TRUE, FALSE = ("true", "1"), ("false", "0")  # spellings of a boolean parameter, any case


def _parse(name, text, default):
    if not isinstance(text, str):
        return text
    if isinstance(default, bool):
        if text.lower() not in TRUE + FALSE:
            raise ParameterError(f"parameter {name}={text!r}: expected true or false "
                                 f"(accepted: {', '.join(TRUE + FALSE)}; any case)")
        return text.lower() in TRUE
    try:
        if isinstance(default, int):
            return int(text)
        if isinstance(default, float) or default == "auto":
            if default == "auto" and (text == "auto" or text.endswith("*limit")):
                return text  # checked by nitsche.Scaling
            value = float(text)
            if not math.isfinite(value):
                raise ValueError
            return value
        return text
    except ValueError:
        kind = "an integer" if isinstance(default, int) else \
            "a finite number" + (" or 'auto'" if default == "auto" else "")
        raise ParameterError(f"parameter {name}={text!r}: expected {kind}")


def parse_assignments(items):
    """['a=1', 'b=x'] -> {'a': '1', 'b': 'x'}."""
    out = {}
    for item in items or ():
        if "=" not in item:
            raise ParameterError(f"--set expects name=value, got {item!r}")
        k, v = item.split("=", 1)
        out[k.strip()] = v.strip()
    return out
