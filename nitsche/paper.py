"""`nitsche paper`: every figure of every case in one folder, with an index.md.

A case module may list its paper runs:

    PAPER = [dict(command="study" | "run", degree=..., levels=..., level=..., sets={...},
                  fast=dict(levels=...)),  # optional overrides for --fast
             ...]

Cases without PAPER get one study (4 levels) and one run (level 2) at their
lowest degree.  --fast caps the studies at 3 levels and the runs at level 1
unless an entry's `fast` says otherwise.  Each run writes into
OUT/CASE/<command>-P<degree>[-<sets>]/ what `nitsche run` / `nitsche study` write
(nitsche.commands), plus log.txt, as one output transaction; index.md shows each
figure with its table.
"""
import contextlib
import io
import json
import os
import sys
import time

from . import cases as registry
from . import commands
from .case import parse_assignments
from .output import OutputFolder

FAST_LEVELS, FAST_LEVEL = 3, 1


def entries(case, fast=False):
    """The paper runs of a case, with --fast applied."""
    listed = getattr(case.module, "PAPER", None)
    if not listed:
        d = case.degrees[0]
        listed = [dict(command="study", degree=d, levels=4), dict(command="run", degree=d, level=2)]
    out = []
    for e in listed:
        e = dict(e)
        fast_overrides = e.pop("fast", None) or {}
        if fast:
            if fast_overrides:
                e.update(fast_overrides)
            elif e["command"] == "study":
                e["levels"] = min(e.get("levels") or 4, FAST_LEVELS)
            else:
                e["level"] = min(e.get("level") if e.get("level") is not None else 2, FAST_LEVEL)
        e.setdefault("sets", {})
        out.append(e)
    return out


def arguments(case, e, folder):
    """The command line of one paper run."""
    argv = [e["command"], case.command_name, "--degree", str(e.get("degree", case.degrees[0])), "--out", folder]
    if e["command"] == "study":
        argv += ["--levels", str(e.get("levels") or 4)]
    else:
        argv += ["--level", str(e.get("level") if e.get("level") is not None else 2)]
    for k, v in (e.get("sets") or {}).items():
        argv += ["--set", f"{k}={v}"]
    return argv


def folder_name(e, case):
    name = f"{e['command']}-P{e.get('degree', case.degrees[0])}"
    for k, v in (e.get("sets") or {}).items():
        name += f"-{k}{v}"
    return name


def _fmt(v):
    if v is None:
        return "-"
    if isinstance(v, bool) or isinstance(v, str):
        return str(v)
    if isinstance(v, int):
        return str(v)
    if isinstance(v, float):
        return f"{v:.4g}"
    return str(v)


STUDY_COLUMNS = ["level", "h", "unknowns", "newton_iterations", "difference", "rate"]
STUDY_EXTRA = ("error_", "rate_error_", "condition_number", "contact_area", "peak_contact_pressure")
RUN_KEYS = ["level", "degree", "unknowns", "converged", "newton_iterations", "nested_iterations",
            "energy", "active_count", "contact_measure", "max_violation", "seconds"]


def study_table(rows):
    keys = list(STUDY_COLUMNS)
    keys += [k for k in rows[0] if k.startswith(STUDY_EXTRA) and k not in keys]
    keys += [k for r in rows for k in r if k.startswith("condition_number") and k not in keys]
    keys = list(dict.fromkeys(keys + ["max_violation", "seconds"]))
    lines = ["| " + " | ".join(keys) + " |", "|" + "---|" * len(keys)]
    for r in rows:
        lines.append("| " + " | ".join(_fmt(r.get(k)) for k in keys) + " |")
    return "\n".join(lines)


def run_table(data):
    keys = [k for k in RUN_KEYS if k in data]
    keys += [k for k, v in data.items() if k not in keys and k not in ("residuals", "case")
             and (isinstance(v, (int, float, str)) or v is None)]
    lines = ["| quantity | value |", "|---|---|"]
    lines += [f"| {k} | {_fmt(data[k]) if not isinstance(data[k], list) else data[k]} |" for k in keys]
    return "\n".join(lines)


def solve(case, e, folder):
    """One paper run into an entered OutputFolder: the return code."""
    p = case.parameters(parse_assignments(f"{k}={v}" for k, v in (e.get("sets") or {}).items()))
    degree = e.get("degree", case.degrees[0])
    options = dict(solver="auto", maxiter=50, rtol=1e-10)
    if e["command"] == "study":
        return commands.study(case, e.get("levels") or 4, degree, p, folder, options)
    level = e.get("level") if e.get("level") is not None else 2
    return commands.run(case, level, degree, p, folder, options)


def cases_in(folder):
    """{name: Case} of the case modules (*.py) in a folder, by file name."""
    if not os.path.isdir(folder):
        raise ValueError(f"--from {folder}: not a folder of case modules (*.py)")
    files = sorted(f for f in os.listdir(folder) if f.endswith(".py") and not f.startswith("_"))
    if not files:
        raise ValueError(f"--from {folder}: the folder holds no case module (*.py)")
    found = [registry.load(os.path.join(folder, f)) for f in files]
    return {c.name: c for c in found}


def paper(out, fast=False, only=None, overwrite=False, source=None):
    """Run every case's paper runs (the shipped cases, or the case modules in the folder
    `source`) into `out`; write out/index.md. 0 if all succeeded."""
    all_cases = cases_in(source) if source else registry.all_cases()
    if only:
        unknown = [c for c in only if c not in all_cases]
        if unknown:
            raise KeyError(f"unknown case(s) {unknown}; the cases are: {', '.join(all_cases)}")
    with OutputFolder(out, overwrite=overwrite) as top:
        title = f"Figures of the cases in {source}" if source else "Figures of the paper"
        command = "nitsche paper" + (" --fast" if fast else "") + (f" --from {source}" if source else "")
        index = [f"# {title}" + (" (fast version)" if fast else ""), "",
                 f"Generated by `{command}`.", ""]
        failed = 0
        for name, case in all_cases.items():
            if only and name not in only:
                continue
            index += [f"## {name}", "", case.summary, ""]
            for e in entries(case, fast):
                rel = os.path.join(name, folder_name(e, case))
                folder = os.path.join(out, rel)
                argv = arguments(case, e, rel)
                print(f"[paper] nitsche {' '.join(argv)}", file=sys.stderr, flush=True)
                t0 = time.perf_counter()
                rc, log = run_logged(case, e, folder, overwrite)
                seconds = time.perf_counter() - t0
                index += [f"### `nitsche {' '.join(argv)}`", "",
                          f"{'ok' if rc == 0 else 'FAILED (exit ' + str(rc) + ')'}, {seconds:.1f} s", ""]
                if rc != 0:
                    failed += 1
                    index += ["```", log[-2000:], "```", ""]
                index += section(name, rel, folder, e["command"])
        top.write_text("index.md", "\n".join(index) + "\n")
        top.commit()
    path = os.path.join(out, "index.md")
    print(f"wrote {path}" + (f"; {failed} run(s) failed" if failed else ""))
    return 1 if failed else 0


def run_logged(case, e, folder, overwrite):
    """One paper run with its printed output kept in log.txt: (return code, log)."""
    buf = io.StringIO()
    with OutputFolder(folder, overwrite=overwrite) as out:
        try:
            with contextlib.redirect_stdout(buf):
                rc = solve(case, e, out)
        except Exception as exc:  # one failing case must not stop the others
            rc = 1
            buf.write(f"{type(exc).__name__}: {exc}\n")
        out.write_text("log.txt", buf.getvalue())
        out.commit()
    return rc, buf.getvalue()


def section(name, rel, folder, command):
    """The figures and the table of one paper run, for index.md."""
    lines = []
    for png in sorted(f for f in os.listdir(folder) if f.endswith(".png")):
        lines += [f"![{name} {png}]({rel}/{png})", ""]
    if command == "study" and os.path.exists(os.path.join(folder, "study.json")):
        with open(os.path.join(folder, "study.json")) as fh:
            data = json.load(fh)
        if data.get("levels"):
            lines += [f"expected rate: {data.get('expected_rate')}", "",
                      study_table(data["levels"]), ""]
    elif os.path.exists(os.path.join(folder, "result.json")):
        with open(os.path.join(folder, "result.json")) as fh:
            lines += [run_table(json.load(fh)), ""]
    return lines
