"""The theta study (after Chouly, Hild and Renard): the energy-norm error of an elastic
block pressed and dragged on rigid ground (tests/test_friction.py's block: unit square,
P1, level 3), against alpha0 from 1/400 to 400, for theta = 1, 0, -1, frictionless and
Coulomb (F = 0.3); the reference is theta = -1, alpha0 = 0.1 at level 5.  Writes
docs/theta_study.png and benchmarks/results/theta_study.json.

    python benchmarks/theta_study.py
"""
import json
import os
import sys
import warnings

import numpy as np

sys.path.insert(0, os.path.join(os.path.dirname(__file__), "..", "tests"))
from test_friction import block  # noqa: E402
from nitsche.study import prolongate  # noqa: E402

ALPHA0 = [1 / 400, 1 / 100, 1 / 25, 1 / 5, 1, 5, 25, 100, 400]
THETAS = (1, 0, -1)
LAWS = ("inequality", "coulomb")
TOP = (0.02, -0.03)


def solve(law, theta, alpha0, level):
    problem = block(law, theta, top=TOP, level=level, alpha0=alpha0)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        result = problem.minimize(maxiter=60)
    return problem, result


def main(level=3, fine=5):
    rows = []
    for law in LAWS:
        ref_problem, ref = solve(law, -1, 0.1, fine)
        K = ref_problem.energy_matrix()
        norm = np.sqrt(ref.x @ (K @ ref.x))
        for theta in THETAS:
            for a in ALPHA0:
                problem, result = solve(law, theta, a, level)
                e = prolongate(problem, result.x, ref_problem) - ref.x
                rows.append(dict(law=law, theta=theta, alpha0=a, converged=result.converged,
                                 iterations=result.iterations,
                                 error=float(np.sqrt(e @ (K @ e)) / norm) if result.converged else None))
                print(rows[-1], flush=True)
    here = os.path.dirname(__file__)
    with open(os.path.join(here, "results", "theta_study.json"), "w") as fh:
        json.dump(dict(level=level, reference_level=fine, rows=rows), fh, indent=1)
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    fig, axes = plt.subplots(1, 2, figsize=(10, 4), sharey=True)
    for ax, law in zip(axes, LAWS):
        for theta, style in zip(THETAS, ("o-", "s--", "^:")):
            pts = [(r["alpha0"], r["error"]) for r in rows if r["law"] == law and r["theta"] == theta
                   and r["error"] is not None]
            if pts:
                ax.loglog(*zip(*pts), style, label=f"theta = {theta}")
        ax.set_xlabel("alpha0")
        ax.set_title("frictionless" if law == "inequality" else "Coulomb, F = 0.3")
        ax.grid(alpha=0.3, which="both")
        ax.legend()
    axes[0].set_ylabel("relative energy-norm error (missing: Newton failed)")
    fig.tight_layout()
    fig.savefig(os.path.join(here, "..", "docs", "theta_study.png"), dpi=120)


if __name__ == "__main__":
    main()
