"""Figures: the solution with its contact pressure, and convergence plots."""
import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import matplotlib.tri as mtri  # noqa: E402
import numpy as np  # noqa: E402

from .io import vertex_values  # noqa: E402


def _triangulation(mesh):
    t = mesh.t.T
    if t.shape[1] == 4:  # quadrilaterals: split in two triangles
        t = np.r_[t[:, [0, 1, 2]], t[:, [0, 2, 3]]]
    return mtri.Triangulation(mesh.p[0], mesh.p[1], t)


def plot_solution(problem, result, path, title=""):
    """One panel per 2D scalar field and one per constraint (its discrete multiplier)."""
    parts = problem.split(result.x)
    scal = [f for f in problem.fields if f.is_lagrange and f.mesh.dim() == 2
            and vertex_values(f, parts[f.name]).ndim == 1]
    values = problem.constraint_values(result.x)
    n = len(scal) + len(problem.constraints)
    fig, axes = plt.subplots(1, max(n, 1), figsize=(4.6 * max(n, 1), 4.0), squeeze=False)
    axes = axes[0]
    for ax, f in zip(axes, scal):
        im = ax.tripcolor(_triangulation(f.mesh), vertex_values(f, parts[f.name]), shading="gouraud",
                          cmap="viridis")
        fig.colorbar(im, ax=ax, shrink=0.8)
        ax.set_title(f"{f.name}")
    for ax, c in zip(axes[len(scal):], problem.constraints):
        v = values[c.name]
        xq = v["x"].reshape(-1, v["x"].shape[-1])
        lam = v["multiplier"].ravel()
        if xq.shape[1] >= 2:
            order = np.argsort(lam)
            sc = ax.scatter(xq[order, 0], xq[order, 1], c=lam[order], s=4, cmap="magma")
            fig.colorbar(sc, ax=ax, shrink=0.8)
        ax.set_title(f"{c.name}: multiplier $\\lambda_N$")
    for ax in axes:
        ax.set_aspect("equal")
    if title:
        fig.suptitle(title)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)
    return path


def plot_convergence(rows, path, rate=None, title=""):
    """Successive differences (and errors) against h, log-log, with the reference slope."""
    fig, ax = plt.subplots(figsize=(5.5, 4.2))
    h = np.array([r["h"] for r in rows])
    series = [("difference", "successive difference $E_k$")]
    series += [(k, k.replace("error_", "error ")) for k in rows[0] if k.startswith("error_")]
    for key, label in series:
        pts = [(r["h"], r[key]) for r in rows if r.get(key)]
        if pts:
            ax.loglog(*zip(*pts), "o-", label=label)
    if rate and len(h) > 1:
        ref = [(r["h"], r["difference"]) for r in rows if r.get("difference")]
        if ref:
            h0, e0 = ref[-1]
            ax.loglog(h, e0 * (h / h0) ** rate, "k--", label=f"slope {rate:g}")
    ax.set_xlabel("h (cell diameter)")
    ax.set_ylabel("energy norm")
    ax.grid(True, which="both", alpha=0.3)
    ax.legend()
    ax.set_title(title)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)
    return path
