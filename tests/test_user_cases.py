"""A user's own case module gets what a shipped case gets: run, study, paper index, nesting."""
import json
import os

import jax.numpy as jnp
import numpy as np
import pytest
from skfem import ElementTriP1, MeshTri

import nitsche as ni
from nitsche.cli import main
from nitsche.ops import dot, grad


@pytest.fixture
def block(tmp_path, monkeypatch, capsys):
    """The template written by `nitsche new block`, in a fresh folder."""
    monkeypatch.chdir(tmp_path)
    assert main(["new", "block"]) == 0
    assert "wrote block.py" in capsys.readouterr().out
    return tmp_path / "block.py"


def test_new_refuses_to_overwrite_and_bad_names(block, capsys):
    text = block.read_text()
    assert main(["new", "block"]) == 2 and "block.py exists" in capsys.readouterr().err
    assert main(["new", "my-block"]) == 2 and "Python identifier" in capsys.readouterr().err
    assert block.read_text() == text


def test_template_case_runs_and_balances_the_load(block, tmp_path):
    """Run through the CLI; the floor force balances the reaction of the held top (the
    gradient of J_h at its fixed dofs) to round-off, P1 and P2."""
    for degree in ("1", "2"):
        assert main(["run", "block.py", "--level", "2", "--degree", degree, "--out", "o"]) == 0
        data = json.loads((tmp_path / "o" / "result.json").read_text())
        assert data["case"] == "block" and data["converged"] and data["level_reached"] == 2
        rx, ry = data["reactions"]["u"]["all"]
        assert data["floor_force"] > 0.02
        assert ry == pytest.approx(-data["floor_force"], rel=1e-10)
        assert abs(rx) < 1e-12 * data["floor_force"]


def test_template_case_study_and_help(block, tmp_path, capsys):
    assert main(["study", "block.py", "--levels", "3", "--degree", "2", "--out", "s"]) == 0
    rows = json.loads((tmp_path / "s" / "study.json").read_text())["levels"]
    assert [r["level"] for r in rows] == [0, 1, 2] and rows[-1]["rate"] > 0.5
    assert main(["run", "block.py", "--help"]) == 0
    assert "Young's modulus" in capsys.readouterr().out
    assert main(["run", "block.py", "--set", "nu=0.5", "--out", "x"]) == 2
    assert not (tmp_path / "x").exists()


def test_a_module_without_build_is_a_clear_error(tmp_path, capsys):
    (tmp_path / "empty.py").write_text("NAME = 'empty'\n")
    assert main(["run", str(tmp_path / "empty.py"), "--out", str(tmp_path / "o")]) == 2
    assert "defines build(level, degree, p)" in capsys.readouterr().err
    (tmp_path / "broken.py").write_text("import no_such_module\n")
    assert main(["run", str(tmp_path / "broken.py"), "--out", str(tmp_path / "o")]) == 2
    assert "importing it failed: ModuleNotFoundError" in capsys.readouterr().err
    assert main(["run", str(tmp_path / "missing.py")]) == 2
    assert not (tmp_path / "o").exists()


def test_paper_index_of_a_folder_of_modules(block, tmp_path):
    os.mkdir("mods")
    os.rename("block.py", "mods/block.py")
    assert main(["paper", "--fast", "--from", "mods", "--out", "idx"]) == 0
    index = (tmp_path / "idx" / "index.md").read_text()
    assert "nitsche study mods/block.py" in index and "block/study-P1/convergence.png" in index
    assert (tmp_path / "idx" / "block" / "run-P1" / "result.json").exists()


def test_nested_iteration_for_a_problem_of_ones_own():
    """ni.nested solves each level from the previous one: fewer Newton iterations than
    from zero on the finest level, and the same solution."""
    def make(level):
        mesh = MeshTri.init_symmetric().refined(level + 2)
        u = ni.Field("u", mesh, ElementTriP1(), fixed="boundary")
        return ni.Problem([u], lambda u: 0.5 * dot(grad(u), grad(u)) + 10.0 * u,
                          [ni.Inequality(gap=lambda u: u + 0.1, multiplier=lambda: -10.0,
                                         scaling=ni.Scaling(0.1, h_power=2), on=ni.cells(u))])
    runs = list(ni.nested(make, range(4)))
    assert [k for k, _, _ in runs] == [0, 1, 2, 3]
    result = runs[-1][2]
    direct = make(3).minimize().check()
    assert result.converged and np.allclose(result.x, direct.x, atol=1e-10)
    assert result.iterations < direct.iterations


def test_reactions_per_named_boundary_and_component():
    """A bar on [0, 1] x [0, 0.25] held at x = 0 (both components) and pulled by a traction
    t = (1, 0.5) on x = 1: the reaction of 'left' is -(t * 0.25), exactly (P1 and P2)."""
    from skfem import ElementTriP2, ElementVector
    from nitsche.ops import sym_grad
    from nitsche.reactions import reactions
    for element in (ElementTriP1(), ElementTriP2()):
        mesh = MeshTri.init_tensor(np.linspace(0, 1, 9), np.linspace(0, 0.25, 3)).with_boundaries(
            {"left": lambda x: x[0] < 1e-12, "right": lambda x: x[0] > 1 - 1e-12})
        u = ni.Field("u", mesh, ElementVector(element), fixed="left")
        energy = [ni.Integral(lambda u: (sym_grad(u) ** 2).sum() + 0.5 * jnp.trace(sym_grad(u)) ** 2,
                              ni.cells(u)),
                  ni.Integral(lambda u: -(u.value[0] + 0.5 * u.value[1]), ni.facets(u, "right"))]
        problem = ni.Problem([u], energy)
        R = reactions(problem, problem.minimize().check().x)["u"]
        assert R["left"] == pytest.approx([-0.25, -0.125], abs=1e-12)
        assert R["all"] == pytest.approx(R["left"], abs=1e-14) and "right" not in R


def test_vtu_shows_every_field_of_every_element_kind(tmp_path):
    """P2: written on the once-refined mesh, whose vertices are the P2 nodes, so the point
    data are the dofs themselves; Morley (plate-plate) and BFS (plate-unilateral) by
    evaluation, matching the solution's values at the vertices."""
    import meshio
    from nitsche.cases import get
    from nitsche.io import write_vtu
    for name, degree, level in (("obstacle", 2, 1), ("plate-plate", 2, 0), ("plate-unilateral", 3, 0)):
        case = get(name)
        p = case.parameters()
        problem = case.problem(level, degree, p, case.alpha0_limits(degree, p))
        x = problem.minimize().check().x
        (path,) = write_vtu(str(tmp_path / name), problem, x)
        m = meshio.read(path)
        for f in problem.fields:
            data = m.point_data[f.name]
            assert np.all(np.isfinite(data)) and np.ptp(data) > 0
            u = problem.split(x)[f.name]
            at = f.jets_at(u, m.points[:, :2].T.copy())["value"] if not f.is_lagrange else None
            if f.is_lagrange:  # P2: the output points are the P2 nodes, the data their dofs
                dof_at = {tuple(np.round(q, 12)): v for q, v in zip(f.basis.doflocs.T, u)}
                assert len(m.points) == len(dof_at) == f.ndofs
                assert np.allclose([dof_at[tuple(np.round(q[:2], 12))] for q in m.points], data,
                                   atol=1e-12)
            else:
                assert np.allclose(data, at, atol=1e-12)
        assert any(k.endswith("_pressure") for k in m.point_data)


def test_weighted_measures_enter_energy_constraints_alpha0_and_forces():
    """The template's block as an axisymmetric-style problem, every measure weighted by
    w = 2 pi r (r = x[0]): the floor force sum W lambda_N balances the reaction of the held
    top (both weighted), and a pure traction t on the top gives the reaction -pi t exactly."""
    from skfem import ElementVector
    from nitsche.ops import sym_grad
    from nitsche.reactions import reactions
    w = lambda x: 2 * np.pi * x[0]
    mesh = MeshTri.init_tensor(np.linspace(0, 1, 9), np.linspace(0, 0.5, 5))
    u = ni.Field("u", mesh, ElementVector(ElementTriP1()), fixed=lambda x: x[1] > 0.5 - 1e-12,
                 value=lambda x: [0 * x[0], -0.01 + 0 * x[0]])
    density = lambda u: (sym_grad(u) ** 2).sum() + 0.5 * jnp.trace(sym_grad(u)) ** 2
    floor = ni.Inequality(gap=lambda u, n: -dot(u, n),
                          multiplier=lambda u, n: -dot(n, dot(2 * sym_grad(u) + jnp.trace(sym_grad(u))
                                                              * jnp.eye(2), n)),
                          scaling=ni.Scaling("auto", h_power=1),
                          on=ni.facets(u, lambda x: x[1] < 1e-12, weight=w), name="floor")
    problem = ni.Problem([u], ni.Integral(density, ni.cells(u, weight=w)), [floor])
    assert 0 < problem.alpha0_limits["floor"] < np.inf
    result = problem.minimize().check()
    force = result.constraints["floor"]["total_multiplier"]
    assert reactions(problem, result.x)["u"]["all"][1] == pytest.approx(-force, rel=1e-10)
    plain = ni.Problem([ni.Field("u", mesh, ElementVector(ElementTriP1()),
                                 fixed=lambda x: x[1] > 0.5 - 1e-12,
                                 value=lambda x: [0 * x[0], -0.01 + 0 * x[0]])], density)
    assert abs(force) > 1.5 * abs(reactions(plain, plain.minimize().check().x)["u"]["all"][1])
    # a traction t = 1 (downward) on the top, the bottom held: reaction pi t upward
    u = ni.Field("u", mesh, ElementVector(ElementTriP1()), fixed=lambda x: x[1] < 1e-12)
    loaded = ni.Problem([u], [ni.Integral(density, ni.cells(u, weight=w)),
                              ni.Integral(lambda u: u.value[1], ni.facets(u, lambda x: x[1] > 0.5 - 1e-12,
                                                                          weight=w))])
    R = reactions(loaded, loaded.minimize().check().x)["u"]["all"]
    assert R == pytest.approx([0.0, np.pi], abs=1e-10)


def test_a_negative_weight_is_refused():
    mesh = MeshTri().refined(1)
    u = ni.Field("u", mesh, ElementTriP1(), fixed="boundary")
    with pytest.raises(ValueError, match="weight of a cells measure must be finite and >= 0"):
        ni.Problem([u], ni.Integral(lambda u: u.value ** 2, ni.cells(u, weight=lambda x: x[0] - 0.5)))


def test_fixed_components_by_boundary_name():
    """Rollers: u_x = 0 on 'left', u_y = 0 on 'bottom', a traction t on 'right': uniaxial
    tension, exact for P1 (a linear field): u_x = t x / E_eff, and the left reaction -t H."""
    from skfem import ElementVector
    from nitsche.ops import sym_grad
    from nitsche.reactions import reactions
    mesh = MeshTri.init_tensor(np.linspace(0, 2, 5), np.linspace(0, 1, 3)).with_boundaries(
        {"left": lambda x: x[0] < 1e-12, "bottom": lambda x: x[1] < 1e-12,
         "right": lambda x: x[0] > 2 - 1e-12})
    u = ni.Field("u", mesh, ElementVector(ElementTriP1()), fixed={"left": "x", "bottom": 1})
    assert u.fixed_dofs.size == 3 + 5
    mu, lam, t = 1.0, 1.0, 0.3
    energy = [ni.Integral(lambda u: mu * (sym_grad(u) ** 2).sum() + 0.5 * lam * jnp.trace(sym_grad(u)) ** 2,
                          ni.cells(u)),
              ni.Integral(lambda u: -t * u.value[0], ni.facets(u, "right"))]
    problem = ni.Problem([u], energy)
    x = problem.minimize().check().x
    E_eff = 4 * mu * (mu + lam) / (2 * mu + lam)  # plane strain, lateral stress free
    ux = x[u.basis.nodal_dofs[0]]
    assert np.allclose(ux, t * mesh.p[0] / E_eff, atol=1e-12)
    R = reactions(problem, x)["u"]
    assert R["left"][0] == pytest.approx(-t * 1.0, abs=1e-12) and R["bottom"][1] == pytest.approx(0, abs=1e-12)
    # the corner (0, 0) is held in x by 'left' and in y by 'bottom': each counts its own
    assert R["left"][1] == 0 and R["bottom"][0] == 0 and "right" not in R
    for bad, message in (({"left": "q"}, "component 'q'"), ({"top": "x"}, "unknown boundary 'top'")):
        with pytest.raises(ValueError, match=message):
            ni.Field("u", mesh, ElementVector(ElementTriP1()), fixed=bad)
    with pytest.raises(ValueError, match="vector fields only"):
        ni.Field("u", mesh, ElementTriP1(), fixed={"left": "x"})


def test_declared_quantities_in_result_and_vtu(block, tmp_path):
    """The template declares stresses: the mean of sigma_yy over the block (height 1/2,
    width 1) equals -(floor force) by equilibrium, int sigma_yy = -F H, to the Nitsche
    consistency level; every quantity is point data of the VTU."""
    import meshio
    assert main(["run", "block.py", "--level", "2", "--degree", "2", "--out", "q"]) == 0
    data = json.loads((tmp_path / "q" / "result.json").read_text())
    q = data["quantities"]
    assert set(q) == {"sigma_xx", "sigma_yy", "sigma_xy", "von_mises"}
    assert q["sigma_yy"]["mean"] == pytest.approx(-data["floor_force"], rel=1e-4)
    assert abs(q["sigma_xy"]["mean"]) < 1e-12 and q["von_mises"]["min"] > 0
    m = meshio.read(tmp_path / "q" / "solution.vtu")
    assert {"von_mises", "sigma_yy", "floor_pressure", "u"} <= set(m.point_data)
    assert np.all(m.point_data["von_mises"] > 0)
