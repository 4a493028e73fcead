"""The command line never lies: whole outputs or none, one-line errors, exit statuses."""
import hashlib
import json
import os
import signal
import subprocess
import sys
import time

import meshio
import numpy as np
import pytest

from nitsche import commands, plot
from nitsche.case import Case
from nitsche.cases import get
from nitsche.cli import main
from nitsche.output import LOCK, MANIFEST, STAGING, OutputFolder

PYTHON = [sys.executable, "-m", "nitsche.cli"]


def snapshot(folder):
    """{name: sha1} of the files in a folder (hidden ones included)."""
    return {f: hashlib.sha1((folder / f).read_bytes()).hexdigest()
            for f in sorted(os.listdir(folder)) if (folder / f).is_file() and f != LOCK}


def assert_whole(folder, level=None):
    """The folder holds one complete run: result.json parses, every file of the manifest
    exists and reads, no staging left behind; the run is of `level` if given."""
    names = json.loads((folder / MANIFEST).read_text())["files"]
    data = json.loads((folder / "result.json").read_text())
    assert "result.json" in names
    for n in names:
        assert (folder / n).stat().st_size > 0, n
        if n.endswith(".vtu"):
            assert len(meshio.read(folder / n).points) > 0
    assert not [f for f in os.listdir(folder) if f.startswith(STAGING)]
    if level is not None:
        assert data["level"] == level
    return data


@pytest.fixture
def previous(tmp_path):
    """A folder holding a complete obstacle run at level 1."""
    out = tmp_path / "o"
    assert main(["run", "obstacle", "--level", "1", "--out", str(out)]) == 0
    return out


# -- bad input: exit 2, one line, nothing created --------------------------------------------

@pytest.mark.parametrize("argv,message", [
    (["run", "obstacle", "--level", "-1"], "--level must be >= 0"),
    (["study", "obstacle", "--levels", "0"], "--levels must be >= 1"),
    (["study", "obstacle", "--start", "-2"], "--start must be >= 0"),
    (["run", "elastic-contact", "--set", "nu1=0.5"], "nu1=0.5"),
    (["run", "elastic-contact", "--set", "E1=0"], "E1=0.0"),
    (["run", "elastic-contact", "--set", "setup=hertz", "--set", "delta=-0.1"], "delta=-0.1"),
    (["run", "dirichlet", "--set", "kappa=-1"], "kappa=-1.0"),
    (["run", "obstacle", "--set", "T=0"], "T=0.0"),
    (["run", "two-membrane", "--set", "mu1=3"], "mu1=3 > mu2=2"),
    (["run", "two-membrane", "--set", "method=lagrange"], "method='lagrange'"),
    (["run", "plate-plate", "--set", "D1=5"], "D1=5 > D2=2"),
    (["run", "plate-unilateral", "--set", "f=1"], "f=1.0"),
    (["run", "membrane-solid", "--set", "nu=-1"], "nu=-1.0"),
    (["run", "obstacle", "--maxiter", "-1"], "--maxiter must be >= 0"),
    (["run", "obstacle", "--rtol", "10"], "--rtol must lie in (0, 1)"),
    (["run", "obstacle", "--rtol", "nan"], "--rtol must lie in (0, 1)"),
    (["run", "obstacle", "--solver", "lu"], "invalid choice: 'lu'"),
    (["run", "obstacle", "--level", "30"], "the largest level that fits is"),
    (["study", "obstacle", "--start", "20"], "the largest level that fits is"),
])
def test_user_errors_exit_2_with_one_line_before_any_folder_exists(tmp_path, capsys, argv, message):
    out = tmp_path / "new" / "folder"
    t = time.perf_counter()
    rc = exit_status(argv + ["--out", str(out)])
    err = capsys.readouterr().err.strip().splitlines()
    assert rc == 2
    assert len(err) == 1 and err[0].startswith("nitsche: error:") and message in err[0], err
    assert not (tmp_path / "new").exists()
    assert time.perf_counter() - t < 30  # refused at once, not after a solve


def exit_status(argv):
    """main's return value, or the status of the SystemExit argparse raises."""
    try:
        return main(argv)
    except SystemExit as e:
        return e.code


@pytest.mark.parametrize("where,message", [
    ("file", "is a file, not a folder"),
    ("/proc/nitsche-out", "cannot create the folder"),
    ("/proc", "cannot write into the folder"),   # exists, not writable (even for root)
    ("under-file", "is a file, so the folder cannot be created"),
])
def test_unusable_output_folders_are_refused_before_solving(tmp_path, capsys, where, message):
    (tmp_path / "f").write_text("x")
    out = {"file": str(tmp_path / "f"), "under-file": str(tmp_path / "f" / "sub")}.get(where, where)
    assert main(["run", "obstacle", "--level", "0", "--out", out]) == 2
    err = capsys.readouterr()
    assert message in err.err and len(err.err.strip().splitlines()) == 1
    assert "Newton" not in err.out  # nothing was solved
    assert (tmp_path / "f").read_text() == "x"


# -- outputs: whole or as before ---------------------------------------------------------------

def test_result_json_is_written_last_and_files_are_listed(previous):
    data = assert_whole(previous, level=1)
    assert data["converged"] and data["failure"] is None and data["level_converged"]


def test_a_failing_write_leaves_the_previous_run(previous, monkeypatch, capsys):
    before = snapshot(previous)

    def full_disk(*a, **k):
        raise OSError(28, "No space left on device")
    monkeypatch.setattr(commands, "write_vtu", full_disk)
    assert main(["run", "obstacle", "--level", "2", "--out", str(previous)]) == 3
    assert "No space left on device" in capsys.readouterr().err
    assert snapshot(previous) == before


@pytest.mark.parametrize("exc", [KeyboardInterrupt, MemoryError, RuntimeError])
def test_an_interruption_while_plotting_leaves_the_previous_run(previous, monkeypatch, capsys, exc):
    before = snapshot(previous)

    def interrupted(*a, **k):
        raise exc()
    monkeypatch.setattr(plot, "plot_solution", interrupted)
    if exc is KeyboardInterrupt:
        assert main(["run", "obstacle", "--level", "2", "--out", str(previous)]) == 130
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) >= 1 and err[-1].startswith("nitsche: interrupted (SIGINT)")
        assert not any("Traceback" in line for line in err)
    else:
        with pytest.raises(exc):
            main(["run", "obstacle", "--level", "2", "--out", str(previous)])
    assert snapshot(previous) == before


def test_a_new_folder_is_removed_when_the_run_is_interrupted(tmp_path, monkeypatch):
    def interrupted(*a, **k):
        raise KeyboardInterrupt
    monkeypatch.setattr(plot, "plot_solution", interrupted)
    assert main(["run", "obstacle", "--level", "0", "--out", str(tmp_path / "a" / "b")]) == 130
    assert not (tmp_path / "a").exists()


def test_file_size_limit_leaves_the_previous_run(previous):
    before = snapshot(previous)

    command = " ".join(PYTHON + ["run", "obstacle", "--level", "3", "--out", str(previous)])
    r = subprocess.run(["bash", "-c", f"ulimit -f 1; exec {command}"], capture_output=True,
                       text=True, timeout=300)
    assert r.returncode == 3, r.stderr
    assert "could not write the output" in r.stderr and "Traceback" not in r.stderr
    assert snapshot(previous) == before
    assert_whole(previous, level=1)


@pytest.mark.parametrize("delay", [1.0, 3.0, 4.5, 6.0])
def test_sigterm_at_any_moment_leaves_a_whole_run(previous, delay):
    """Today's failure: a SIGTERM left a 0-byte solution.vtu beside a complete result.json."""
    before = snapshot(previous)
    proc = subprocess.Popen(PYTHON + ["run", "obstacle", "--level", "4", "--out", str(previous)],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    time.sleep(delay)
    proc.send_signal(signal.SIGTERM)
    out, err = proc.communicate(timeout=300)
    assert "Traceback" not in err
    if proc.returncode == 0:  # finished before the signal
        assert_whole(previous, level=4)
    elif "after the output was written" in err:  # the signal came while files were renamed in
        assert proc.returncode == 128 + signal.SIGTERM
        assert_whole(previous, level=4)
    elif proc.returncode == -signal.SIGTERM:  # killed outside main(): while Python imported,
        if snapshot(previous) != before:       # or at exit, after the run was committed
            assert_whole(previous, level=4)
    else:  # stopped by our handler before the commit
        assert proc.returncode == 128 + signal.SIGTERM, err
        assert "interrupted (SIGTERM); the output folder holds what it held before" in err
        assert snapshot(previous) == before


def test_sigint_in_a_subprocess_is_one_line(previous):
    """Ctrl-C once the run has started (its first progress line): one line, status 130."""
    before = snapshot(previous)
    proc = subprocess.Popen(PYTHON + ["run", "obstacle", "--level", "4", "--out", str(previous)],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    first = proc.stderr.readline()
    assert first.startswith("[level 0/4]"), first
    proc.send_signal(signal.SIGINT)
    out, err = proc.communicate(timeout=300)
    err = first + err
    if proc.returncode != 0:
        assert proc.returncode == 130 and "Traceback" not in err, err
        assert err.strip().splitlines()[-1].startswith("nitsche: interrupted (SIGINT)")
        assert snapshot(previous) == before


SLOW_FINEST = """
import time
from nitsche.cases import obstacle
PARAMETERS = obstacle.PARAMETERS


def build(level, degree, p):
    if level == 3:  # the finest level, built ahead on a background thread
        time.sleep(120)
    return obstacle.build(level, degree, p)
"""


@pytest.mark.parametrize("stop", ["failure", "sigterm"])
def test_a_chain_stopped_before_its_finest_level_exits_at_once(tmp_path, stop):
    """A chain that stops on a coarser level (Newton's iteration limit, or SIGTERM) while its
    finest level is still being built in the background exits at once with its status: the
    process does not wait for that build (nor abort at exit)."""
    case = tmp_path / "slow_finest.py"
    case.write_text(SLOW_FINEST)
    command = os.path.join(os.path.dirname(sys.executable), "nitsche")  # the console script: cli.entry
    argv = [command, "run", str(case), "--level", "3", "--out", str(tmp_path / "o")]
    proc = subprocess.Popen(argv + (["--maxiter", "0"] if stop == "failure" else []),
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    t = time.perf_counter()
    if stop == "sigterm":
        assert proc.stderr.readline().startswith("[level 0/3]")
        proc.send_signal(signal.SIGTERM)
    out, err = proc.communicate(timeout=100)
    assert time.perf_counter() - t < 60, "waited for the background build"
    assert proc.returncode == (1 if stop == "failure" else 128 + signal.SIGTERM), err
    assert "Traceback" not in err and "terminate called" not in err


def test_a_second_run_into_a_locked_folder_is_refused(previous, capsys):
    before = snapshot(previous)
    with OutputFolder(str(previous)):
        assert main(["run", "obstacle", "--level", "1", "--out", str(previous)]) == 2
    err = capsys.readouterr().err
    assert "another nitsche run" in err and f"pid {os.getpid()}" in err
    assert snapshot(previous) == before


def test_two_runs_at_once_leave_one_whole_output(previous):
    procs = [subprocess.Popen(PYTHON + ["run", "obstacle", "--level", str(level), "--out",
                                        str(previous)], stdout=subprocess.PIPE,
                              stderr=subprocess.PIPE, text=True) for level in (3, 4)]
    results = [(p.wait(timeout=300), p.stderr.read()) for p in procs]
    assert all(rc in (0, 2) for rc, _ in results), results
    for rc, err in results:
        if rc == 2:
            assert "another nitsche run" in err
    data = assert_whole(previous)
    assert data["level"] in [level for (rc, _), level in zip(results, (3, 4)) if rc == 0]


# -- no files mixed from earlier runs ----------------------------------------------------------

def test_files_of_an_earlier_case_are_removed(tmp_path):
    out = tmp_path / "o"
    assert main(["run", "elastic-contact", "--level", "0", "--out", str(out)]) == 0
    assert (out / "solution_0.vtu").exists() and (out / "contact_pressure.png").exists()
    (out / "notes.txt").write_text("mine")
    assert main(["run", "obstacle", "--level", "0", "--out", str(out)]) == 0
    assert sorted(f for f in os.listdir(out) if not f.startswith(".")) == \
        ["notes.txt", "result.json", "solution.png", "solution.vtu"]
    assert_whole(out, level=0)


def test_outputs_of_an_unknown_run_need_overwrite(tmp_path, capsys):
    out = tmp_path / "o"
    out.mkdir()
    (out / "solution_0.vtu").write_text("old")
    (out / "cube_principal_stress.png").write_text("old")
    (out / "notes.txt").write_text("mine")
    assert main(["run", "obstacle", "--level", "0", "--out", str(out)]) == 2
    assert "--overwrite" in capsys.readouterr().err
    assert (out / "solution_0.vtu").read_text() == "old"
    assert main(["run", "obstacle", "--level", "0", "--out", str(out), "--overwrite"]) == 0
    assert sorted(f for f in os.listdir(out) if not f.startswith(".")) == \
        ["notes.txt", "result.json", "solution.png", "solution.vtu"]


# -- nested runs and studies that fail on a finer level ----------------------------------------

def fail_at(monkeypatch, name, level, exc):
    case = get(name)
    build = case.problem

    def problem(k, *a, **kw):
        if k == level:
            raise exc("simulated")
        return build(k, *a, **kw)
    monkeypatch.setattr(case, "problem", problem)


def test_a_nested_run_that_fails_writes_the_finest_converged_level(tmp_path, monkeypatch, capsys):
    fail_at(monkeypatch, "obstacle", 2, MemoryError)
    out = tmp_path / "o"
    assert main(["run", "obstacle", "--level", "3", "--out", str(out)]) == 1
    data = assert_whole(out, level=3)
    assert data["level_reached"] == 1 and data["level_converged"] and not data["converged"]
    assert data["failure"] == {"level": 2, "reason": "out of memory"}
    assert len(meshio.read(out / "solution.vtu").points) == 145  # level 1's mesh
    assert "the finest converged one" in capsys.readouterr().err


def test_a_nested_failure_returns_the_coarser_problem_built_again(monkeypatch):
    """solve_nested keeps a converged coarser level's result without its problem (memory)
    and, when a finer level fails, builds that problem again: the result's own, with the
    same J_h at the result's x."""
    from nitsche.study import solve_nested
    fail_at(monkeypatch, "obstacle", 2, MemoryError)
    case = get("obstacle")
    problem, result, its, failure = solve_nested(case, 3, 1, case.parameters())
    assert failure == {"level": 2, "reason": "out of memory"} and len(its) == 2
    assert result.problem is problem and problem.setup.level == 1
    assert np.isclose(problem.energy(result.x), result.energy, rtol=1e-13, atol=0)
    # level 1 was a coarse level (COARSE_RTOL, unchecked): solved on to 1e-10 and checked
    assert result.converged and result.residuals[-1] <= 1e-10 and result.timings["minimum_check"] > 0
    assert result.minimum == "J_h convex"  # P1 obstacle: certified, no factorization for it


def test_the_coarser_levels_of_a_nested_chain_are_solved_to_the_coarse_tolerance_only():
    """nested(coarse_rtol): the coarser levels stop at relative residual coarse_rtol, the
    finest at rtol, with the iterations and J_h of a chain solved to rtol throughout."""
    from nitsche.study import COARSE_RTOL, nested
    case = get("obstacle")
    p = case.parameters()
    chains = {c: list(nested(lambda k: case.problem(k, 1, p), range(4), case.solve, c))
              for c in (None, COARSE_RTOL)}
    full, coarse = ([r for _, _, r in chains[c]] for c in (None, COARSE_RTOL))
    assert all(r.converged for r in full + coarse)
    assert all(r.residuals[-1] <= 1e-10 for r in full)
    assert all(r.residuals[-1] <= COARSE_RTOL < r.residuals[-2] for r in coarse[:-1])  # the first below
    assert coarse[-1].residuals[-1] <= 1e-10 and coarse[-1].iterations == full[-1].iterations
    assert sum(r.iterations for r in coarse) < sum(r.iterations for r in full)
    assert np.isclose(coarse[-1].energy, full[-1].energy, rtol=1e-12, atol=0)


@pytest.mark.parametrize("name", ["obstacle", "two-membrane"])
def test_the_coarser_levels_stop_at_a_fraction_of_their_first_residual(name):
    """nested(coarse_reduction): a coarser level after the first also stops once its residual
    is coarse_reduction times its first one (the interpolation error it started from): fewer
    Newton steps there, the finest level's J_h that of the chain without it, to 1e-12."""
    from nitsche.study import COARSE_REDUCTION, COARSE_RTOL, nested
    case = get(name)
    p = case.parameters()
    chains = {c: [r for _, _, r in nested(lambda k: case.problem(k, 1, p), range(4), case.solve, COARSE_RTOL, c)]
              for c in (None, COARSE_REDUCTION)}
    plain, reduced = chains[None], chains[COARSE_REDUCTION]
    assert all(r.converged for r in plain + reduced)
    assert reduced[0].residuals == plain[0].residuals  # (started from zero)
    for r in reduced[1:-1]:
        stop = max(COARSE_RTOL, COARSE_REDUCTION * r.residuals[0])
        assert r.residuals[-1] <= stop < r.residuals[-2]  # the first below
    assert reduced[-1].residuals[-1] <= 1e-10 and "of the first" not in reduced[-1].reason
    assert sum(r.iterations for r in reduced[:-1]) < sum(r.iterations for r in plain[:-1])
    assert np.isclose(reduced[-1].energy, plain[-1].energy, rtol=1e-12, atol=0)


def test_the_finest_level_is_built_ahead_on_another_thread():
    """nested(ahead=True): the last level's problem is built on a background thread (the
    coarser ones on the caller's), the chain is that of ahead=False bit for bit (J_h,
    residuals, iterations), and an error building the last level reaches the caller at
    that level, after the coarser levels."""
    import threading
    from nitsche.study import COARSE_REDUCTION, COARSE_RTOL, nested
    case = get("two-membrane")
    p = case.parameters()
    built = {}

    def make(k):
        built[k] = threading.current_thread() is threading.main_thread()
        return case.problem(k, 1, p)
    chains = {a: [r for _, _, r in nested(make, range(4), case.solve, COARSE_RTOL, COARSE_REDUCTION, ahead=a)]
              for a in (False, True)}
    assert built == {0: True, 1: True, 2: True, 3: False}
    plain, ahead = chains[False], chains[True]
    assert [r.residuals for r in ahead] == [r.residuals for r in plain]
    assert [r.energy for r in ahead] == [r.energy for r in plain] and ahead[-1].converged

    def failing(k):
        if k == 3:
            raise MemoryError("level 3")
        return case.problem(k, 1, p)
    solved = []
    with pytest.raises(MemoryError, match="level 3"):
        for k, _, result in nested(failing, range(4), case.solve, ahead=True):
            solved.append((k, result.converged))
    assert solved == [(0, True), (1, True), (2, True)]


@pytest.mark.parametrize("share,ahead", [(0.5, 1), (0.0, 0)])
def test_solve_nested_builds_ahead_only_what_fits_twice(monkeypatch, share, ahead):
    """solve_nested builds its finest level ahead (study.Ahead) while the level's estimated
    memory is at most AHEAD_MEMORY of the machine's, else in turn: the same result."""
    import nitsche.study as study
    made = []

    class Counted(study.Ahead):
        def __init__(self, make):
            made.append(1)
            super().__init__(make)
    monkeypatch.setattr(study, "Ahead", Counted)
    monkeypatch.setattr(study, "AHEAD_MEMORY", share)
    case = get("obstacle")
    problem, result, its, failure = study.solve_nested(case, 3, 1, case.parameters())
    assert len(made) == ahead and failure is None and result.converged and len(its) == 4


def test_a_study_that_fails_keeps_the_levels_it_finished(tmp_path, monkeypatch, capsys):
    fail_at(monkeypatch, "dirichlet", 2, MemoryError)
    out = tmp_path / "s"
    assert main(["study", "dirichlet", "--levels", "4", "--out", str(out)]) == 1
    data = json.loads((out / "study.json").read_text())
    assert [r["level"] for r in data["levels"]] == [0, 1]
    assert data["failure"] == {"level": 2, "reason": "out of memory"}
    assert data["levels"][1]["rate"] is None or "rate" in data["levels"][1]
    assert (out / "convergence.png").exists()


def test_parameters_of_every_case_accept_their_defaults():
    from nitsche.cases import all_cases
    for case in all_cases().values():
        assert isinstance(case, Case)
        case.parameters()
        case.check_level(3, case.degrees[0], case.parameters())


def test_a_signal_held_during_the_commit_is_reported_after_it(previous, monkeypatch, capsys):
    """SIGTERM while the files are renamed in: the commit completes (signals are held), then
    the run stops with 143 and says that the folder holds this run, whole."""
    import nitsche.output as output
    rename = output.os.replace
    sent = []

    def replace_and_signal(a, b):
        rename(a, b)
        if STAGING not in b and not sent:  # the commit's first rename into the folder
            sent.append(os.kill(os.getpid(), signal.SIGTERM))
    monkeypatch.setattr(output.os, "replace", replace_and_signal)
    assert main(["run", "obstacle", "--level", "2", "--out", str(previous)]) == 143
    monkeypatch.undo()
    assert "after the output was written" in capsys.readouterr().err
    assert_whole(previous, level=2)


def test_an_interruption_in_a_garbage_collector_callback_is_not_lost(monkeypatch):
    """A signal handler that runs inside a gc callback or __del__ (JAX registers one) has its
    exception ignored by Python: the hook delivers the interruption again to the main thread."""
    import sys
    from nitsche.output import Interrupted, raise_interrupted, redeliver_ignored
    monkeypatch.setattr(sys, "unraisablehook", redeliver_ignored)
    previous = signal.signal(signal.SIGTERM, raise_interrupted)
    try:
        class Finalized:
            def __del__(self):
                raise_interrupted(signal.SIGTERM, None)  # as if SIGTERM arrived right here
        with pytest.raises(Interrupted):
            Finalized()  # its __del__ runs at once; the exception there is ignored ...
            for _ in range(1000):  # ... and comes back at one of the next bytecodes
                time.sleep(0.001)
    finally:
        signal.signal(signal.SIGTERM, previous)
