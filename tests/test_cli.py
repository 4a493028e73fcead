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
    assert data["minimum"] == "Hessian positive definite"  # P2: lap u reads u, not certified convex
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


def strict_json(path):
    """Parse with a parser that rejects NaN and Infinity."""
    def reject(constant):
        raise ValueError(f"not strict JSON: {constant}")
    return json.loads(path.read_text(), parse_constant=reject)


def test_json_is_strict_and_non_finite_numbers_are_null(tmp_path, capsys):
    out = tmp_path / "o"
    # P1: the multiplier f1 + mu1 lap_h u1 does not depend on u1, so its alpha0 limit is infinite
    assert main(["run", "two-membrane", "--level", "0", "--degree", "1", "--out", str(out)]) == 0
    data = strict_json(out / "result.json")
    assert RESULT_KEYS <= set(data)
    assert data["alpha0_limits"] == {"contact": None}
    assert main(["study", "two-membrane", "--levels", "2", "--degree", "1", "--out", str(out)]) == 0
    assert len(strict_json(out / "study.json")["levels"]) == 2


def test_json_writer_converts_numpy_and_non_finite_values(tmp_path):
    import numpy as np
    from nitsche.io import write_json
    write_json(str(tmp_path / "x.json"), dict(a=np.float64(np.nan), b=np.array([1.0, -np.inf]),
                                              c=(np.int64(3), float("inf")), d={"e": 2.5}))
    assert strict_json(tmp_path / "x.json") == dict(a=None, b=[1.0, None], c=[3, None], d={"e": 2.5})


@pytest.mark.parametrize("args,message", [
    (["--set", "mu=1"], "valid names: T, f, alpha0"),
    (["--set", "T=abc"], "expected a finite number"),
    (["--set", "alpha0=-1"], "alpha0=-1.0 (Nitsche parameter (alpha = alpha0 h^2 / T, h = cell "
                              "diameter)) must be > 0 or 'auto'"),
    (["--set", "alpha0"], "name=value"),
    (["--degree", "3"], "supports degree"),
])
def test_bad_parameters_are_clear_errors(tmp_path, capsys, args, message):
    assert main(["run", "obstacle", "--level", "0", "--out", str(tmp_path)] + args) == 2
    assert message in capsys.readouterr().err


def test_bad_boolean_parameter_lists_the_spellings(tmp_path, capsys):
    assert main(["run", "two-membrane", "--level", "0", "--out", str(tmp_path),
                 "--set", "compare=maybe"]) == 2
    err = capsys.readouterr().err
    assert "compare='maybe': expected true or false (accepted: true, 1, false, 0" in err
    assert "number" not in err


@pytest.mark.parametrize("text,value", [("TRUE", True), ("1", True), ("False", False), ("0", False)])
def test_boolean_parameter_spellings(text, value):
    from nitsche.cases import get
    assert get("two-membrane").parameters({"compare": text}).compare is value


def test_warnings_are_one_short_line(tmp_path, capsys):
    # P2 cell Laplacian: alpha0 = 0.1 is ten times the stability limit (about 0.0107)
    main(["run", "two-membrane", "--level", "0", "--degree", "2", "--no-nested", "--out",
          str(tmp_path), "--set", "alpha0=0.1"])
    err = capsys.readouterr().err.splitlines()
    warned = [line for line in err if "exceeds the stability limit" in line]
    assert warned and all(line.startswith("warning: constraint 'contact': alpha0 = 0.1 exceeds")
                          for line in warned)
    assert not any("StabilityWarning" in line or "warnings.warn" in line for line in err), err


def test_unknown_case(capsys):
    assert main(["run", "nope"]) == 2
    assert "the cases are" in capsys.readouterr().err


def test_case_help_lists_parameters(capsys):
    assert main(["run", "obstacle", "--help"]) == 0
    out = capsys.readouterr().out
    assert "alpha0" in out and "auto" in out and "membrane tension" in out


def test_run_that_fails_on_a_coarse_level_says_which(tmp_path, capsys):
    out = tmp_path / "f"
    assert main(["run", "signorini", "--level", "2", "--maxiter", "1", "--out", str(out)]) == 1
    data = json.loads((out / "result.json").read_text())
    assert data["level"] == 2 and data["level_reached"] == 0 and not data["converged"]
    err = capsys.readouterr().err
    assert "Newton failed at level 0" in err
