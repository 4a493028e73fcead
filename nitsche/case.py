"""Ready cases: a problem as a module, run at any level and degree.

A case module (a shipped one, or a file of one's own: `nitsche new NAME` writes a
commented template) defines
    build(level, degree, p)  -> dict(fields=..., energy=..., constraints=...) for nitsche.Problem,
                                p a namespace of the parameters; level = uniform refinements;
                                optionally parameters={name: value}: the Problem's run-time
                                parameters (e.g. a load a path's set_step changes)
and optionally
    NAME, SUMMARY            the name (default: the file name) and one line about it
                             (default: the docstring's first line)
    PARAMETERS               {name: (default, help)}; every physical and numerical parameter
    DEGREES                  the polynomial degrees it supports (default (1,))
    RATE                     {degree: expected energy-norm rate}
    errors(problem, result, p) -> {name: error against an exact solution}
    report(problem, result, p) -> {key: value} added to result.json
    figures(problem, result, p, folder) -> paths of figures written into folder
    study_extra(problem, result, row), study_figures(rows, p, degree, folder)
    solve(problem, p, x0, **newton_options) -> Result: a load path (e.g. a normal step,
                             then tangential steps; Problem.set_values) instead of
                             problem.minimize(x0, **newton_options)
    path(problem, p)         -> the keyword arguments of nitsche.path (times, set_step, ...):
                             a load path solved step by step; `run` writes its steps
                             (result.json `steps`, solution_NNNN.vtu, solution.pvd, a
                             reaction-time plot)
    OUTPUTS_FROM_PIECES      True where errors, report and figures also work on this rank's
                             part of a distributed problem (result.x whole): integrals over
                             its cells reduced over the ranks (nitsche.partition.summed,
                             e.g. nitsche.norms.exact_errors); under mpirun they are then
                             computed on every rank from its pieces (figures get the
                             folder None on ranks other than 0: they write nothing),
                             otherwise rank 0 rebuilds the whole problem for them
                             (default False)
    RANGES                   {name: Interval or OneOf}: the physical range of a parameter
    check(p)                 raises ParameterError for combinations RANGES cannot say
                             (e.g. D1 <= D2)
Parameters are checked when they are set (Case.parameters), before anything is solved
or written; Case.check_level refuses a level whose memory would exceed the machine.
"""
import math
import os
from collections import namedtuple
from dataclasses import dataclass
from types import SimpleNamespace

from .problem import Problem


Setup = namedtuple("Setup", "case level degree p")


class ParameterError(ValueError):
    """An unknown parameter name or a bad value."""


@dataclass(frozen=True)
class Interval:
    """lo < value < hi (<= at a closed end): the physical range of a parameter."""
    lo: float = -math.inf
    hi: float = math.inf
    closed_lo: bool = False
    closed_hi: bool = False

    def __contains__(self, v):
        return ((v >= self.lo if self.closed_lo else v > self.lo)
                and (v <= self.hi if self.closed_hi else v < self.hi))

    def __str__(self):
        if self.hi == math.inf:
            return (">= " if self.closed_lo else "> ") + f"{self.lo:g}"
        if self.lo == -math.inf:
            return ("<= " if self.closed_hi else "< ") + f"{self.hi:g}"
        return f"in {'[' if self.closed_lo else '('}{self.lo:g}, {self.hi:g}{']' if self.closed_hi else ')'}"


@dataclass(frozen=True)
class OneOf:
    """One of a few words."""
    words: tuple

    def __contains__(self, v):
        return v in self.words

    def __str__(self):
        return "one of " + ", ".join(map(repr, self.words))


POSITIVE = Interval(0.0)
NONNEGATIVE = Interval(0.0, closed_lo=True)
NEGATIVE = Interval(hi=0.0)
POISSON = Interval(-1.0, 0.5)                  # 3D and plane strain: lambda ~ 1/(1 - 2 nu)
PLATE_POISSON = Interval(-1.0, 0.5, closed_hi=True)  # Kirchhoff plates: D (1 - nu) > 0 suffices

# peak memory per unknown by mesh dimension, degree 1 (measured: 2D P1 obstacle 4.1 kB, two
# membranes 4.7 kB; 3D membrane-solid on P1 tetrahedra 11.9 kB at 203k unknowns, since the
# pattern on dof groups and no kept element Hessians, 19.8 kB before); higher degrees couple
# more dofs: twice that
BYTES_PER_UNKNOWN = {1: 5e3, 2: 5e3, 3: 15e3}


def machine_memory():
    """Bytes of memory this process may use: physical memory or the cgroup limit."""
    total = os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES")
    try:
        with open("/sys/fs/cgroup/memory.max") as fh:
            text = fh.read().strip()
        if text.isdigit():
            total = min(total, int(text))
    except OSError:
        pass
    return total


class Case:
    def __init__(self, module, default_name=None, path=None):
        """path: the file a case module of one's own was loaded from (None: shipped)."""
        self.module, self.path = module, path
        where = getattr(module, "__file__", module.__name__)
        if not callable(getattr(module, "build", None)):
            raise ValueError(f"{where}: a case module defines build(level, degree, p) -> "
                             "dict(fields=..., energy=..., constraints=...); see 'nitsche new'")
        self.name = getattr(module, "NAME", default_name)
        doc = (module.__doc__ or "").strip()
        self.summary = getattr(module, "SUMMARY", doc.splitlines()[0] if doc else "")
        self.defaults = dict(getattr(module, "PARAMETERS", {}))
        self.degrees = tuple(getattr(module, "DEGREES", (1,)))
        for k, v in self.defaults.items():
            if not (isinstance(v, tuple) and len(v) == 2):
                raise ValueError(f"{where}: PARAMETERS[{k!r}] must be (default, help), not {v!r}")
        unknown = set(getattr(module, "RANGES", {})) - set(self.defaults)
        if unknown:
            raise ValueError(f"{where}: RANGES names no parameter: {sorted(unknown)}")
        self._limits = {}

    def help(self):
        lines = [f"{self.name}: {self.summary}", f"degrees: {', '.join(map(str, self.degrees))}",
                 "parameters (--set name=value):"]
        ranges = getattr(self.module, "RANGES", {})
        for k, (default, text) in self.defaults.items():
            allowed = f" ({ranges[k]})" if k in ranges else ""
            lines.append(f"  {k:<12} {str(default):<10} {text}{allowed}")
        return "\n".join(lines)

    def parameters(self, overrides=None):
        """The parameter namespace: defaults updated by {name: value or string}."""
        values = {k: d for k, (d, _) in self.defaults.items()}
        for k, v in (overrides or {}).items():
            if k not in values:
                raise ParameterError(f"case '{self.name}' has no parameter {k!r}; valid names: "
                                     f"{', '.join(self.defaults)}")
            values[k] = _parse(k, v, values[k])
        for k, allowed in getattr(self.module, "RANGES", {}).items():
            v = values[k]
            given_as_text = isinstance(v, str) and relative(self.defaults[k][0])  # 'auto', 'F*limit'
            if not given_as_text and v not in allowed:
                auto = " or 'auto'" if relative(self.defaults[k][0]) else ""
                raise ParameterError(f"parameter {k}={v!r} ({self.defaults[k][1]}) must be "
                                     f"{allowed}{auto}; set --set {k}=... within that range")
        p = SimpleNamespace(**values)
        check = getattr(self.module, "check", None)
        if check:
            check(p)
        return p

    def check_degree(self, degree):
        if degree not in self.degrees:
            raise ParameterError(f"case '{self.name}' supports degree {self.degrees}, not {degree}")

    def unknowns(self, level, degree, p):
        """Estimated dofs of each mesh dimension d at `level`: those of level 1 times 2^d per
        uniform refinement (the asymptotic growth; coarse levels grow less): {d: dofs}."""
        n1 = {}
        for f in self.module.build(1, degree, p)["fields"]:
            n1[f.mesh.dim()] = n1.get(f.mesh.dim(), 0) + f.ndofs
        return {d: n * 2.0 ** (d * (level - 1)) for d, n in n1.items()}

    def memory_need(self, level, degree, p):
        """Estimated bytes of a solve at `level` (BYTES_PER_UNKNOWN per estimated unknown)."""
        return sum(n * BYTES_PER_UNKNOWN[d] * (1 if degree == 1 else 2)
                   for d, n in self.unknowns(level, degree, p).items())

    def check_level(self, level, degree, p, option="--level"):
        """Refuse a negative level, or one whose estimated memory exceeds this machine's
        (naming the largest level that fits)."""
        if level < 0:
            raise ParameterError(f"{option} must be >= 0 (0 is the coarsest mesh), got {level}")
        if level <= 1:
            return
        memory, need = machine_memory(), self.memory_need(level, degree, p)
        if need > memory:
            fits = max([k for k in range(level) if self.memory_need(k, degree, p) <= memory], default=0)
            total = sum(self.unknowns(level, degree, p).values())
            raise ParameterError(
                f"{option} {level}: about {total:.3g} unknowns would need about "
                f"{need / 2**30:.3g} GiB, this machine has {memory / 2**30:.3g} GiB; "
                f"the largest level that fits is {fits}")

    def problem(self, level, degree, p, alpha0_limits=None):
        if level < 0:
            raise ParameterError(f"level must be >= 0, got {level}")
        self.check_degree(degree)
        spec = self.module.build(level, degree, p)
        problem = Problem(spec["fields"], spec["energy"], spec.get("constraints", ()),
                          alpha0_limits=alpha0_limits, parameters=spec.get("parameters"))
        problem.setup = Setup(self.name, level, degree, p)  # for the case's report hooks
        return problem

    def alpha0_limits(self, degree, p, level=1):
        """Diagnostic: the global stability limits of alpha0 (one value per constraint,
        Problem.stability_limits) on a coarse level of this case (remembered per degree and
        parameter values).  Each Problem computes its own element-local limits."""
        key = (degree, level, tuple(sorted((k, repr(v)) for k, v in vars(p).items())))
        if key not in self._limits:
            self._limits[key] = self.problem(level, degree, p).stability_limits()
        return dict(self._limits[key])

    @property
    def has_path(self):
        return callable(getattr(self.module, "path", None))

    def solve(self, problem, x0=None, **newton_options):
        """The case's load path (its path hook: nitsche.path, kept as problem.path, its last
        attempted step returned; or its solve hook), or Newton's method from x0."""
        if self.has_path:
            from .path import path
            problem.path = path(problem, **self.module.path(problem, problem.setup.p), **newton_options)
            if problem.path.result is None:
                raise ValueError(f"case '{self.name}': the load path failed at its first step: "
                                 f"{problem.path.reason}")
            return problem.path.result
        hook = getattr(self.module, "solve", None)
        return hook(problem, problem.setup.p, x0, **newton_options) if hook \
            else problem.minimize(x0, **newton_options)

    def errors(self, problem, result, p):
        fn = getattr(self.module, "errors", None)
        return fn(problem, result, p) if fn else {}

    @property
    def outputs_from_pieces(self):
        """Whether the case's output hooks work on a rank's part (OUTPUTS_FROM_PIECES) and it
        declares no quantities (whose vertex values need the whole mesh's cells)."""
        return bool(getattr(self.module, "OUTPUTS_FROM_PIECES", False)) and \
            not hasattr(self.module, "quantities")

    @property
    def command_name(self):
        """How the command line names the case: its name, or its file."""
        return self.path or self.name

    @property
    def rate(self):
        return getattr(self.module, "RATE", {})


TRUE, FALSE = ("true", "1"), ("false", "0")  # spellings of a boolean parameter, any case


def relative(value):
    """An alpha0 given relative to the stability limit: 'auto' or 'F*limit'."""
    return isinstance(value, str) and (value == "auto" or value.endswith("*limit"))


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
        if isinstance(default, float) or relative(default):
            if relative(default) and relative(text):
                return text  # checked by nitsche.Scaling
            value = float(text)
            if not math.isfinite(value):
                raise ValueError
            return value
        return text
    except ValueError:
        kind = "an integer" if isinstance(default, int) else \
            "a finite number" + (" or 'auto'" if relative(default) else "")
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
