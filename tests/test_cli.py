"""The command line and its JSON contract."""
import json
import os

import pytest

from nitsche.cli import main

RESULT_KEYS = {"case", "level", "degree", "dofs", "converged", "newton_iterations", "energy",
               "active_count", "max_violation", "seconds"}
STUDY_KEYS = {"level", "h", "dofs", "newton_iterations", "difference", "rate"}


def test_list(capsys):
    assert main(["list"]) == 0
    out = capsys.readouterr().out
    for name in ("dirichlet", "signorini", "obstacle"):
        assert name in out


def test_run_writes_result_vtu_and_png(tmp_path, capsys):
    out = tmp_path / "o"
    assert main(["run", "obstacle", "--level", "1", "--degree", "2", "--out", str(out),
                 "--set", "alpha0=0.004"]) == 0
    data = json.loads((out / "result.json").read_text())
    assert RESULT_KEYS <= set(data)
    assert data["converged"] and data["case"] == "obstacle" and data["degree"] == 2
    assert data["parameters"]["alpha0"] == 0.004
    assert (out / "solution.png").stat().st_size > 1000
    import meshio
    m = meshio.read(out / "solution.vtu")
    assert "u" in m.point_data and "contact_pressure" in m.point_data
    assert m.point_data["contact_pressure"].max() > 0


def test_study_writes_study_json(tmp_path, capsys):
    out = tmp_path / "s"
    assert main(["study", "dirichlet", "--levels", "3", "--out", str(out)]) == 0
    data = json.loads((out / "study.json").read_text())
    assert len(data["levels"]) == 3
    assert STUDY_KEYS <= set(data["levels"][-1])
    assert os.path.exists(out / "convergence.png")
    assert "[3/3]" in capsys.readouterr().err  # progress display


@pytest.mark.parametrize("args,message", [
    (["--set", "mu=1"], "valid names: T, f, alpha0"),
    (["--set", "T=abc"], "expected a finite number"),
    (["--set", "alpha0=-1"], "alpha0 must be a positive"),
    (["--set", "alpha0"], "name=value"),
    (["--degree", "3"], "supports degree"),
])
def test_bad_parameters_are_clear_errors(tmp_path, capsys, args, message):
    assert main(["run", "obstacle", "--level", "0", "--out", str(tmp_path)] + args) == 2
    assert message in capsys.readouterr().err


def test_unknown_case(capsys):
    assert main(["run", "nope"]) == 2
    assert "the cases are" in capsys.readouterr().err


def test_case_help_lists_parameters(capsys):
    assert main(["run", "obstacle", "--help"]) == 0
    out = capsys.readouterr().out
    assert "alpha0" in out and "auto" in out and "membrane tension" in out
