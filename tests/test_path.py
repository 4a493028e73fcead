"""Load paths: run-time parameters (compiled once), lifting of moved prescribed values, the
path driver (step cutting, history, records) and its output (steps, VTU series, pvd, plot)."""
import json
import xml.etree.ElementTree as ET

import numpy as np
import pytest
from skfem import ElementTriP1, ElementTriP2, MeshTri

import nitsche as ni
from nitsche import assembly
from nitsche.cases import get
from nitsche.cli import main
from nitsche.ops import dot, grad, lap


def membrane(parameters):
    """A P2 membrane under the load t (a parameter) on an obstacle at -0.1."""
    mesh = MeshTri.init_symmetric().scaled((4, 4)).translated((-2, -2)).refined(2)
    u = ni.Field("u", mesh, ElementTriP2(), fixed="boundary")
    contact = ni.Inequality(lambda u: u + 0.1, lambda u: -lap(u) + 0.0, ni.Scaling("auto", 2, 1.0),
                            ni.cells(u))
    return ni.Problem([u], lambda u, t: 0.5 * dot(grad(u), grad(u)) + t * u, [contact],
                      parameters=parameters)


def test_parameters_change_the_answer_without_compiling():
    problem = membrane({"t": 0.0})
    first = problem.minimize().check()
    assert np.abs(first.x).max() == 0.0
    compiled, seconds = len(assembly._COMPILED), assembly.compile_seconds[0]
    contact = []
    for t in (1.0, 2.0):
        problem.set_parameters(t=t)
        r = problem.minimize(first.x).check()
        contact.append(r.contact_measure)
        assert r.x.min() < -0.09  # pressed onto the obstacle
    assert contact[1] > contact[0] > 0
    assert len(assembly._COMPILED) == compiled and assembly.compile_seconds[0] == seconds
    with pytest.raises(ValueError, match="unknown parameter 's'"):
        problem.set_parameters(s=1.0)
    with pytest.raises(ValueError, match="unknown argument"):
        membrane({})
    with pytest.raises(ValueError, match="also field names"):
        membrane({"u": 1.0})


def compression(**sets):
    case = get("compression")
    p = case.parameters({k: str(v) for k, v in sets.items()})
    return case, case.problem(0, 1, p), p


def test_lifting_carries_a_large_boundary_move_into_the_interior():
    case, problem, p = compression()
    rest = problem.initial(None)
    case.module.path(problem, p)["set_step"](problem, 0.2)  # the press moved by 0.2 R
    lifted = problem.minimize(rest).check()
    assert "lift" in lifted.timings and lifted.iterations <= 8
    try:  # the plain start inverts the elements under the press
        plain = problem.minimize(rest, lift=False)
        assert not plain.converged or plain.iterations > lifted.iterations + 3
    except ValueError as e:
        assert "not finite at the initial guess" in str(e)


def test_compression_path_force_balance_and_compiles_once():
    case, problem, p = compression()
    problem.minimize()  # the rest state: compiles every kernel
    alpha0 = problem.alpha0["contact"].copy()
    compiled, seconds = len(assembly._COMPILED), assembly.compile_seconds[0]
    path = ni.path(problem, **case.module.path(problem, p), quiet=True)
    assert path.converged, path.reason
    assert len(assembly._COMPILED) == compiled and assembly.compile_seconds[0] == seconds
    assert path.steps[-1]["time"] == pytest.approx(1.0) and p.compression >= 0.2
    assert len(path.steps) >= int(p.steps)
    contact = [s["contact_measure"] for s in path.steps]
    assert contact[-1] > 2 * contact[0] > 0
    for k, s in enumerate(path.steps):
        assert s["converged"] and s["iterations"] <= 10
        R = s["reactions"]["u"]["top"]
        total = problem.constraint_report(path.at(problem, k))["contact"]["total_multiplier"]
        assert R["reaction_y"] == pytest.approx(-total, rel=1e-8)  # the press holds the plane's force
        assert abs(R["reaction_x"]) < 1e-10 * abs(R["reaction_y"])  # frictionless, symmetric
    forces = [-s["reactions"]["u"]["top"]["reaction_y"] for s in path.steps]
    assert all(b > a for a, b in zip(forces, forces[1:]))
    # 30 % with the defaults (alpha0 'auto'), no step cut, alpha0 unchanged
    assert p.compression == 0.3 and p.alpha0 == "auto"
    assert path.cuts == 0 and all(s["alpha0_scale"] == 1.0 for s in path.steps)
    assert np.array_equal(problem.alpha0["contact"], alpha0)


def test_a_path_on_a_non_convex_j_h_halves_alpha0_and_goes_on():
    """alpha0 at twice the stability limit: Newton meets an indefinite J_h, takes convexified
    steps and fails; after two such failures the path halves alpha0 and reaches the end."""
    with pytest.warns(ni.StabilityWarning):
        case, problem, p = compression(alpha0="2*limit")
    alpha0 = problem.alpha0["contact"].copy()
    path = ni.path(problem, **case.module.path(problem, p), quiet=True)
    assert path.converged and path.steps[-1]["time"] == pytest.approx(1.0)
    scale = [s["alpha0_scale"] for s in path.steps]
    assert scale == sorted(scale, reverse=True) and scale[-1] <= 0.5
    assert np.allclose(problem.alpha0["contact"], scale[-1] * alpha0)
    assert np.all(problem.alpha0["contact"] < problem.limits["contact"])


def test_a_step_too_large_is_cut_and_the_path_recovers():
    case, problem, p = compression(steps=1, compression=0.3)
    path = ni.path(problem, **case.module.path(problem, p), quiet=True)
    assert path.converged and path.cuts >= 1
    assert path.steps[-1]["time"] == pytest.approx(1.0)
    assert min(s["increment"] for s in path.steps) < 1.0
    with pytest.raises(ValueError, match="times must increase"):
        ni.path(problem, [0.5, 0.2])


def test_history_fields_take_the_previous_step():
    mesh = MeshTri().refined(2)
    u = ni.Field("u", mesh, ElementTriP1())
    u_old = ni.history(u)

    def energy(u, u_old, t):
        return 0.5 * (u - t - 0.5 * u_old) ** 2  # u = t + u_old / 2
    problem = ni.Problem([u, u_old], ni.Integral(energy, ni.cells(u)), parameters={"t": 0.0})
    path = ni.path(problem, [1.0, 2.0], quiet=True)
    assert path.converged
    x = path.results[-1].x
    parts = problem.split(x)
    assert np.allclose(parts["u_old"], 1.0)  # the step-1 solution u = 1
    assert np.allclose(parts["u"], 2.0 + 0.5 * 1.0)


def test_run_writes_steps_vtu_series_pvd_and_plot(tmp_path, capsys):
    out = tmp_path / "c"
    assert main(["run", "compression", "--set", "steps=4", "--set", "compression=0.2",
                 "--out", str(out)]) == 0
    data = json.loads((out / "result.json").read_text())
    assert data["converged"] and data["compression_reached"] == pytest.approx(0.2)
    steps = data["steps"]
    assert len(steps) >= 4 and steps[-1]["time"] == pytest.approx(1.0)
    for s in steps:
        assert {"time", "iterations", "converged", "contact_measure", "reactions"} <= set(s)
        assert set(s["reactions"]["u"]["top"]) == {"reaction_x", "reaction_y"}
    files = [d.get("file") for d in ET.parse(out / "solution.pvd").getroot().iter("DataSet")]
    assert files == [f"solution_{k:04d}.vtu" for k in range(1, len(steps) + 1)]
    assert all((out / f).exists() for f in files)
    assert (out / "reactions.png").stat().st_size > 1000
    manifest = json.loads((out / ".nitsche-manifest.json").read_text())["files"]
    assert set(files) | {"solution.pvd", "reactions.png"} <= set(manifest)
    assert "step 4" in capsys.readouterr().err
