"""Figures: the solution with its contact pressure, and convergence plots.  A field on a
mesh with more cells than its axes have pixels is drawn as an image of one sample per
pixel (Raster), in memory bounded by the picture."""
import gc

import matplotlib

matplotlib.use("Agg")
import matplotlib.image as mimage  # noqa: E402
import matplotlib.pyplot as plt  # noqa: E402
import matplotlib.tri as mtri  # noqa: E402
from matplotlib.colors import ListedColormap  # noqa: E402
from matplotlib.ticker import NullFormatter  # noqa: E402
import numpy as np  # noqa: E402

from . import partition  # noqa: E402
from .io import vertex_values  # noqa: E402


DPI = 120  # the resolution the figures are written at


def _triangles(mesh):
    t = mesh.t.T
    if t.shape[1] == 4:  # quadrilaterals: split in two triangles
        t = np.r_[t[:, [0, 1, 2]], t[:, [0, 2, 3]]]
    return t


def as_image(ax, cells, dpi=DPI):
    """Whether a field on `cells` triangles is drawn in ax as an image (Raster) rather than
    as triangles: where there are more cells than the axes' box has pixels at dpi (its
    width x height in inches x dpi^2), so that a triangle is on average smaller than a
    pixel (the domain, inside the box, gets fewer still) and one sample per pixel shows
    what the triangles would, in memory bounded by the picture, not by the mesh."""
    width, height = ax.get_position().size * ax.figure.get_size_inches() * dpi
    return cells > width * height


def raster(x, y, triangles, values, extent, shape, per_cell=False, chunk=1 << 14):
    """A field on triangles (vertices x, y; triangles (n, 3)) sampled at the centres of a
    grid of pixels: shape (rows, columns) over extent (left, right, bottom, top), pixel
    (i, j) centred at (left + (j + 1/2) dx, bottom + (i + 1/2) dy).  A centre in a
    triangle (barycentric coordinates l_k >= -1e-12) takes sum_k l_k values[vertex k]
    (values per vertex: exact for P1) or the triangle's value (per_cell); NaN where no
    triangle holds it (outside the domain).  Each triangle visits the centres in its
    bounding box, `chunk` triangles at a time: memory O(pixels + vertices + chunk + the
    boxes' centres), which large cells (a graded mesh) fill without holes."""
    rows, columns = shape
    left, right, bottom, top = extent
    dx, dy = (right - left) / columns, (top - bottom) / rows
    image = np.full(rows * columns, np.nan)
    tol = 1e-12
    for start in range(0, len(triangles), chunk):
        t = triangles[start:start + chunk]
        X, Y = x[t], y[t]
        j0 = np.maximum(np.ceil((X.min(axis=1) - left) / dx - 0.5), 0).astype(np.int64)
        j1 = np.minimum(np.floor((X.max(axis=1) - left) / dx - 0.5), columns - 1).astype(np.int64)
        i0 = np.maximum(np.ceil((Y.min(axis=1) - bottom) / dy - 0.5), 0).astype(np.int64)
        i1 = np.minimum(np.floor((Y.max(axis=1) - bottom) / dy - 0.5), rows - 1).astype(np.int64)
        nj = np.maximum(j1 - j0 + 1, 0)
        count = np.maximum(i1 - i0 + 1, 0) * nj
        cell = np.repeat(np.arange(len(t)), count)  # (cell, centre) pairs: the boxes' centres
        k = np.arange(cell.size) - np.repeat(np.cumsum(count) - count, count)
        i = i0[cell] + k // nj[cell]
        j = j0[cell] + k % nj[cell]
        del k
        e1x, e1y = X[:, 1] - X[:, 0], Y[:, 1] - Y[:, 0]  # the edges from corner 0
        e2x, e2y = X[:, 2] - X[:, 0], Y[:, 2] - Y[:, 0]
        det = e1x * e2y - e1y * e2x
        px = left + (j + 0.5) * dx - X[cell, 0]
        py = bottom + (i + 0.5) * dy - Y[cell, 0]
        with np.errstate(divide="ignore", invalid="ignore"):  # degenerate triangles: NaN, left out
            l1 = (px * e2y[cell] - py * e2x[cell]) / det[cell]
            l2 = (e1x[cell] * py - e1y[cell] * px) / det[cell]
        inside = (l1 >= -tol) & (l2 >= -tol) & (l1 + l2 <= 1 + tol)
        cell, l1, l2 = cell[inside], l1[inside], l2[inside]
        if per_cell:
            v = values[start:start + chunk][cell]
        else:
            V = values[t[cell]]
            v = V[:, 0] + l1 * (V[:, 1] - V[:, 0]) + l2 * (V[:, 2] - V[:, 0])
        image[i[inside] * columns + j[inside]] = v
    return image.reshape(rows, columns)


class Raster(mimage.AxesImage):
    """A field on triangles drawn as an image of one sample per screen pixel (raster),
    sampled when drawn at the centres of the pixels that the triangles' bounding box
    touches then (the final layout and dpi); NaN samples transparent.  In the axes' data
    limits like tripcolor (the box, autoscaled with the axes' margins), out of the tight
    layout."""

    def __init__(self, ax, x, y, triangles, values, per_cell=False, **style):
        self.box = (x.min(), x.max(), y.min(), y.max())
        super().__init__(ax, origin="lower", interpolation="nearest", extent=self.box, **style)
        self.field = (x, y, triangles, values, per_cell)
        self.set_data(np.full((1, 1), np.nan))
        self.drawn = None  # the extent of the last sampled picture: whole pixels
        self.set_in_layout(False)
        ax.add_image(self)
        ax.update_datalim([(self.box[0], self.box[2]), (self.box[1], self.box[3])])
        ax.autoscale_view()

    def get_extent(self):
        """The whole pixels sampled when last drawn (before: the triangles' box)."""
        return self.box if self.drawn is None else self.drawn

    def draw(self, renderer):
        """Sampled again where the pixels that the box touches have changed."""
        left, right, bottom, top = self.box
        to_screen = self.axes.transData
        corners = to_screen.transform([(left, bottom), (right, top)])
        low, high = np.floor(corners.min(axis=0)), np.ceil(corners.max(axis=0))
        high = np.maximum(np.minimum(high, low + 4096), low + 1)
        (x0, y0), (x1, y1) = to_screen.inverted().transform([low, high])
        if (x0, x1, y0, y1) != self.drawn:
            x, y, triangles, values, per_cell = self.field
            shape = (int(high[1] - low[1]), int(high[0] - low[0]))
            self.set_data(np.ma.masked_invalid(
                raster(x, y, triangles, values, (x0, x1, y0, y1), shape, per_cell), copy=False))
            self.drawn = (x0, x1, y0, y1)
        super().draw(renderer)


def cell_colours(ax, triangulation, values, **style):
    """Each triangle filled with the colour of its value (values per triangle; masked or
    NaN ones left out), the colour scale the shown values': where there are more triangles
    than pixels (as_image), a Raster of the triangles' values; else Gouraud triangles of
    constant value on their own vertices, which the renderer fills in one call, where
    tripcolor's flat shading makes a matplotlib Path of every triangle (seconds at 10^5
    cells).  The artist is left out of the tight layout (it lies inside the axes).
    Returns the artist (for a colorbar)."""
    t = triangulation.triangles
    v = np.ma.filled(np.ma.masked_invalid(np.ma.asarray(values, dtype=float)), np.nan)
    shown = np.isfinite(v)
    fill = v[shown].min() if shown.any() else 0.0
    if as_image(ax, len(t)):
        im = Raster(ax, triangulation.x, triangulation.y, t, v, per_cell=True, **style)
        im.set_clim(fill, v[shown].max() if shown.any() else 1.0)
        return im
    own = mtri.Triangulation(triangulation.x[t].ravel(), triangulation.y[t].ravel(),
                             np.arange(t.size).reshape(t.shape))
    own.set_mask(~shown)  # (the hidden ones take a shown value: the colour scale is the shown ones')
    im = ax.tripcolor(own, np.repeat(np.where(shown, v, fill), 3), shading="gouraud", **style)
    im.set_in_layout(False)
    return im


def _field(ax, x, y, triangles, values, **style):
    """A P1 field (values per vertex) in ax: a Raster where as_image, else Gouraud
    tripcolor; out of the tight layout (inside the axes: no need to measure, where
    tripcolor's would make each triangle a Path).  Returns the artist."""
    if as_image(ax, len(triangles)):
        im = Raster(ax, x, y, triangles, values, **style)
        im.set_clim(values.min(), values.max())  # tripcolor's colour scale
        return im
    im = ax.tripcolor(mtri.Triangulation(x, y, triangles), values, shading="gouraud", **style)
    im.set_in_layout(False)
    return im


def _deformation_scale(mesh, d):
    """A factor that shows the largest displacement as 10 % of the body's size."""
    size = float(np.ptp(mesh.p, axis=1).max())
    peak = float(np.abs(d).max())
    return 0.1 * size / peak if peak > 0 else 1.0


def _scalar_panel(fig, ax, f, values):
    im = _field(ax, f.mesh.p[0], f.mesh.p[1], _triangles(f.mesh), values, cmap="viridis")
    fig.colorbar(im, ax=ax, shrink=0.8, label=f.name)
    ax.set_title(f.name)
    ax.set_aspect("equal")


def _vector_panel(fig, ax, f, d):
    """The deformed mesh, coloured by the displacement's magnitude, over the undeformed one
    in grey (its edges; where as_image, its area)."""
    scale = _deformation_scale(f.mesh, d)
    x, y = f.mesh.p
    t = _triangles(f.mesh)
    if as_image(ax, len(t)):
        Raster(ax, x, y, t, np.zeros(len(t)), per_cell=True, cmap=ListedColormap(["0.7"]))
    else:
        ax.triplot(mtri.Triangulation(x, y, t), lw=0.3, color="0.7")
    im = _field(ax, x + scale * d[:, 0], y + scale * d[:, 1], t, np.linalg.norm(d, axis=1),
                cmap="viridis")
    fig.colorbar(im, ax=ax, shrink=0.8, label=f"|{f.name}|")
    ax.set_title(f"{f.name}: deformed shape (x{scale:.3g}; grey: undeformed)")
    ax.set_aspect("equal")


def binned_mean(x, y, values, weights, most=300, per_bin=4, chunk=1 << 18):
    """The weighted mean sum(w v) / sum(w) of scattered values in the bins of a grid over
    their bounding box (square bins, `most` along its longer side, fewer where there are
    fewer than `per_bin` points per bin on average): (image (rows, columns), NaN in empty
    bins; extent (left, right, bottom, top)).  A picture of a million points costs one
    bincount per `chunk` points (memory O(bins + chunk)), where drawing them as markers
    cost seconds each.  Inside nitsche.partition.local each rank gives its own points: the
    box, the count and the bins' sums are reduced over the ranks (the same picture on
    every rank)."""
    lo = partition.smallest([x.min(initial=np.inf), y.min(initial=np.inf)])
    hi = partition.largest([x.max(initial=-np.inf), y.max(initial=-np.inf)])
    (x0, y0), (x1, y1) = lo, hi
    count = partition.summed(x.size)
    side = max(x1 - x0, y1 - y0) or 1.0
    n = int(np.clip(np.sqrt(count / per_bin), 1, most))
    size = side / n
    shape = (max(int(np.ceil((y1 - y0) / size)), 1), max(int(np.ceil((x1 - x0) / size)), 1))
    total, mass = np.zeros(shape[0] * shape[1]), np.zeros(shape[0] * shape[1])
    for s in range(0, x.size, chunk):
        i = np.minimum(((y[s:s + chunk] - y0) / size).astype(int), shape[0] - 1)
        j = np.minimum(((x[s:s + chunk] - x0) / size).astype(int), shape[1] - 1)
        k = i * shape[1] + j
        w = weights[s:s + chunk]
        total += np.bincount(k, w * values[s:s + chunk], total.size)
        mass += np.bincount(k, w, total.size)
    total, mass = partition.summed(total), partition.summed(mass)
    with np.errstate(invalid="ignore", divide="ignore"):
        image = np.where(mass > 0, total / mass, np.nan).reshape(shape)
    return image, (x0, x0 + shape[1] * size, y0, y0 + shape[0] * size)


def multiplier_pictures(problem, x):
    """multiplier_picture of each constraint at x (the values at its quadrature points
    freed on return, before anything is drawn)."""
    values = problem.constraint_values(x)
    return [multiplier_picture(values[c.name]) for c in problem.constraints]


def multiplier_picture(v):
    """What a constraint's panel shows of its values v (Problem.constraint_values): along a
    straight contact line ("line", coordinate axis, its coordinates, lambda_N, the
    tangential traction or None, sorted along the line), else on an area ("area", the
    binned mean of lambda_N, extent).  Inside nitsche.partition.local each rank gives its
    elements' values: the line is gathered, the area binned over the ranks."""
    xq = v["x"].reshape(-1, v["x"].shape[-1])
    vector = v["multiplier"].ndim == 3
    lam = (v["multiplier"][..., 0] if vector else v["multiplier"]).ravel()
    spread = partition.largest(xq.max(axis=0, initial=-np.inf)) \
        - partition.smallest(xq.min(axis=0, initial=np.inf))
    if xq.shape[1] >= 2 and np.sort(spread)[-2] <= 1e-9 * max(spread.max(), 1e-300):
        axis = int(np.argmax(spread))  # a straight contact line: a graph over it
        along, lam = partition.gathered(xq[:, axis]), partition.gathered(lam)
        order = np.argsort(along, kind="stable")
        tangential = None
        if vector:
            tangential = partition.gathered(
                v["multiplier"][..., 1:].reshape(-1, v["multiplier"].shape[2] - 1))[order]
        return "line", axis, along[order], lam[order], tangential
    if xq.shape[1] >= 2:
        return ("area",) + binned_mean(xq[:, 0], xq[:, 1], lam, v["W"].ravel())
    return ("none",)


def _multiplier_panel(fig, ax, name, picture):
    """lambda_N against the coordinate along a contact line (and a frictional constraint's
    tangential traction), or its binned mean on an area (multiplier_picture)."""
    if picture[0] == "line":
        _, axis, along, lam, tangential = picture
        ax.plot(along, lam, ".-", ms=3, label="normal")
        if tangential is not None:
            ax.plot(along, tangential, ".-", ms=3, label="tangential")
            ax.legend()
        ax.set_xlabel("xyz"[axis])
        ax.set_ylabel(r"$\lambda_N$")
        ax.grid(alpha=0.3)
    elif picture[0] == "area":
        _, image, extent = picture
        im = ax.imshow(image, origin="lower", extent=extent, cmap="magma", interpolation="nearest")
        fig.colorbar(im, ax=ax, shrink=0.8, label=r"$\lambda_N$")
        ax.set_aspect("equal")
        ax.set_xlabel("x")
        ax.set_ylabel("y")
    ax.set_title(f"{name}: multiplier $\\lambda_N$ (contact pressure)")


def plot_solution(problem, result, path, title=""):
    """One panel per 2D Lagrange field (scalar: its values; vector: the deformed shape) and
    one per constraint (its discrete multiplier lambda_N at the quadrature points).  Inside
    nitsche.partition.local, problem this rank's part and result.x the whole solution, it
    is collective (the multipliers are this rank's elements', reduced: multiplier_picture)
    and only the ranks given a path draw (the fields from the whole mesh and solution,
    which every rank holds).  Returns the path (None without one)."""
    pictures = multiplier_pictures(problem, result.x)
    if path is None:
        return None
    parts = problem.split(result.x)
    shown = [(f, vertex_values(f, parts[f.name])) for f in problem.fields
             if f.is_lagrange and f.mesh.dim() == 2]
    n = len(shown) + len(problem.constraints)
    fig, axes = plt.subplots(1, max(n, 1), figsize=(4.8 * max(n, 1), 4.2), squeeze=False)
    axes = axes[0]
    for ax, (f, d) in zip(axes, shown):
        (_scalar_panel if d.ndim == 1 else _vector_panel)(fig, ax, f, d)
    for ax, c, picture in zip(axes[len(shown):], problem.constraints, pictures):
        _multiplier_panel(fig, ax, c.name, picture)
    for ax in axes[:len(shown)]:
        ax.set_xlabel("x")
        ax.set_ylabel("y")
    return save_figure(fig, path, title)


def save_figure(fig, path, title=""):
    """Title, tight layout, PNG at 120 dpi, figure closed; returns the path."""
    if title:
        fig.suptitle(title)
    fig.tight_layout()
    return write_figure(fig, path, dpi=DPI)


def write_figure(fig, path, **options):
    """fig.savefig(path, **options), the figure closed and the garbage it left collected;
    returns the path.  Drawn without NumPy's floating-point warnings: OpenBLAS's gemm
    kernels can raise the overflow flag on finite data (mplot3d's projection of a
    surface's faces, np.dot of a 4 x 4 matrix and vectors of size 1), which would print
    "overflow encountered in dot".  The collection: the layout's text parser (pyparsing,
    in tight_layout and savefig) keeps the exceptions it handles in reference cycles with
    their tracebacks, whose frames hold every caller's locals up the stack, e.g. a figure
    hook's arrays of values at all quadrature points (150 MB for the two membranes at 522k
    unknowns), until Python's cycle collector runs."""
    with np.errstate(over="ignore", under="ignore"):
        fig.savefig(path, **options)
    plt.close(fig)
    gc.collect()
    return path


def plot_convergence(rows, path, rate=None, title=""):
    """Successive differences (and errors) against h, log-log, with the reference slope."""
    fig, ax = plt.subplots(figsize=(5.5, 4.2))
    h = np.array([r["h"] for r in rows])
    series = [("difference", "successive difference $E_k$ (energy norm)")]
    series += [(k, k.replace("error_", "error, ") + " norm") for k in rows[0] if k.startswith("error_")]
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
    ax.set_ylabel("error or successive difference")
    ax.set_xticks(h, [f"{v:.3g}" for v in h])
    ax.xaxis.set_minor_formatter(NullFormatter())
    ax.grid(True, which="both", alpha=0.3)
    ax.legend()
    ax.set_title(title)
    fig.tight_layout()
    return write_figure(fig, path, dpi=DPI)


def plot_path(steps, path, title=""):
    """The reactions of a load path against its time: one curve per field, named boundary
    (every fixed dof, 'all', where a field names none) and component that is not zero."""
    done = [s for s in steps if s["converged"]]
    t = [0.0] + [s["time"] for s in done]
    curves = {}
    for s in done:
        for field, regions in s["reactions"].items():
            named = [r for r in regions if r != "all"] or ["all"]
            for region in named:
                for comp, R in regions[region].items():
                    curves.setdefault((field, region, comp), []).append(R)
    peak = max([abs(R) for c in curves.values() for R in c], default=0.0)
    fig, ax = plt.subplots(figsize=(6, 4))
    for (field, region, comp), R in curves.items():
        if max(abs(r) for r in R) > 1e-9 * peak:
            ax.plot(t, [0.0] + R, ".-", label=f"{field} {region} {comp}")
    ax.set_xlabel("time t (load factor)")
    ax.set_ylabel("reaction")
    ax.set_title(title)
    ax.grid(alpha=0.3)
    if ax.get_legend_handles_labels()[0]:
        ax.legend(fontsize=8)
    fig.tight_layout()
    return write_figure(fig, path, dpi=DPI)
