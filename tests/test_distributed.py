"""nitsche.distributed under mpirun: 1, 2 and 3 ranks give the serial energy and Newton
iterations (obstacle; two-membrane: two fields; elastic-contact: an interface across rank
boundaries, two meshes; membrane-solid: 3D, CG + GAMG), each rank building the elements of
its own cells only; `mpirun nitsche run` writes one result.json and one VTU.  Skipped
without petsc4py / mpirun (installed by `make petsc`)."""
import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

from nitsche import cases
from nitsche.study import solve_nested

pytest.importorskip("petsc4py", reason="the distributed engine needs petsc4py: make petsc")
pytest.importorskip("mpi4py", reason="the distributed engine needs mpi4py: make petsc")
if shutil.which("mpirun") is None:
    pytest.skip("mpirun not found: make petsc installs Open MPI", allow_module_level=True)

ROOT = Path(__file__).resolve().parents[1]
CASES = {"obstacle": 3, "two-membrane": 3, "elastic-contact": 2}
SOLID = {"membrane-solid": 1}


def mpirun(ranks, *args, cwd=ROOT):
    """Run `python args` on `ranks` ranks (root allowed, more ranks than cores allowed)."""
    env = dict(os.environ, PYTHONPATH=os.pathsep.join([str(ROOT), os.environ.get("PYTHONPATH", "")]),
               OMPI_ALLOW_RUN_AS_ROOT="1", OMPI_ALLOW_RUN_AS_ROOT_CONFIRM="1",
               OMPI_MCA_rmaps_base_oversubscribe="1", OMP_NUM_THREADS="1",
               OPENBLAS_NUM_THREADS="1")
    out = subprocess.run(["mpirun", "-n", str(ranks), sys.executable, *args], cwd=cwd, env=env,
                         capture_output=True, text=True, timeout=900)
    assert out.returncode == 0, out.stdout + out.stderr
    return out.stdout


def distributed(ranks, solver, levels):
    lines = mpirun(ranks, str(ROOT / "tests" / "mpi_solve.py"), solver,
                   *[f"{name}:{level}" for name, level in levels.items()])
    return {r["case"]: r for r in map(json.loads, lines.strip().splitlines())}


def serial(levels, solver):
    out = {}
    for name, level in levels.items():
        case = cases.get(name)
        problem = case.problem(level, case.degrees[0], case.parameters({}))
        r = problem.minimize(solver=solver)
        out[name] = dict(energy=r.energy, iterations=r.iterations, active_count=r.active_count,
                         elements=[t.nel for t in problem.assembler.terms])
    return out


@pytest.fixture(scope="module")
def reference():
    """The serial engine with the same kind of linear solve (exact: SuperLU, as PETSc's LU;
    AMG-CG to Newton's forcing tolerance, as GAMG; CHOLMOD's factor reuse solves inexactly
    and may take another Newton step)."""
    return {**serial(CASES, "superlu"), **serial(SOLID, "amg")}


def agree(runs, reference, ranks):
    """The serial energy, iterations and active points; every element built by one rank
    (the ranks' counts sum to the serial ones), each rank holding a part only."""
    for name, r in runs.items():
        serial = reference[name]
        assert r["converged"] and r["ranks"] == ranks, r
        assert abs(r["energy"] - serial["energy"]) <= 1e-10 * abs(serial["energy"]), \
            (name, ranks, r["energy"], serial["energy"])
        assert r["iterations"] == serial["iterations"], (name, ranks, r, serial)
        assert r["active_count"] == serial["active_count"], (name, ranks, r, serial)
        per_rank = r["stats"]["elements"]
        assert [sum(c) for c in zip(*per_rank)] == serial["elements"], (name, per_rank, serial)
        assert all(sum(c) < sum(serial["elements"]) for c in per_rank) or ranks == 1, per_rank


@pytest.mark.parametrize("ranks", [1, 2, 3])
def test_ranks_give_the_serial_energy_and_iterations(ranks, reference):
    runs = distributed(ranks, "direct", CASES)
    agree(runs, reference, ranks)
    # the contact facets of body 1 pair with cells of body 2 on another rank
    assert (runs["elastic-contact"]["stats"]["straddling_constraint_elements"] > 0) == (ranks > 1)


@pytest.mark.parametrize("ranks", [1, 2, 3])
def test_3d_with_gamg(ranks, reference):
    runs = distributed(ranks, "gamg", SOLID)
    agree(runs, reference, ranks)
    assert runs["membrane-solid"]["solver"] == "petsc-gamg"


def test_mpirun_nitsche_run_writes_one_result(tmp_path):
    """Rank 0 writes result.json and one VTU; PETSc options reach the KSP."""
    out = tmp_path / "run"
    text = mpirun(2, "-m", "nitsche.cli", "run", "obstacle", "--level", "2", "--solver", "gamg",
                  "--out", str(out), "-ksp_type", "gmres", "-ksp_view")
    data = json.loads((out / "result.json").read_text())
    assert data["ranks"] == 2 and data["converged"] and data["solver"] == "petsc-gamg"
    assert sorted(p.suffix for p in out.iterdir() if p.suffix == ".vtu") == [".vtu"]
    assert text.count("wrote ") == 1  # rank 0 alone reports
    assert "type: gmres" in text  # PETSc options pass through (-ksp_view prints the KSP)
    case = cases.get("obstacle")
    result = solve_nested(case, 2, 1, case.parameters({}))[1]
    assert abs(data["energy"] - result.energy) <= 1e-10 * abs(result.energy)
    assert data["nested_iterations"][-1] == result.iterations
