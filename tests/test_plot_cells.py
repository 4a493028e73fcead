"""nitsche.plot.cell_colours: each triangle filled with its own value's colour, masked ones
left out, the colour scale that of the shown values (as tripcolor's flat shading)."""
import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import matplotlib.tri as mtri  # noqa: E402
import numpy as np  # noqa: E402
from skfem import MeshTri  # noqa: E402

from nitsche.plot import cell_colours  # noqa: E402


def pixels_at(fig, ax, points):
    fig.canvas.draw()
    image = np.asarray(fig.canvas.buffer_rgba())[..., :3] / 255.0
    xy = ax.transData.transform(points)
    h = image.shape[0]
    return np.array([image[int(h - y), int(x)] for x, y in xy])


def test_each_cell_its_colour_and_masked_cells_left_out():
    mesh = MeshTri.init_tensor(np.linspace(0, 1, 4), np.linspace(0, 1, 4))
    tri = mtri.Triangulation(mesh.p[0], mesh.p[1], mesh.t.T)
    values = np.linspace(-1.0, 3.0, mesh.nelements)
    hidden = np.arange(mesh.nelements) % 5 == 0
    fig, ax = plt.subplots(figsize=(4, 4))
    ax.set_facecolor("white")
    im = cell_colours(ax, tri, np.ma.masked_where(hidden, values), cmap="viridis")
    ax.set_xlim(0, 1)
    ax.set_ylim(0, 1)
    centroids = mesh.p[:, mesh.t].mean(axis=1).T
    got = pixels_at(fig, ax, centroids)
    plt.close(fig)
    shown = values[~hidden]
    assert im.get_clim() == (shown.min(), shown.max())
    expected = plt.get_cmap("viridis")((values - shown.min()) / np.ptp(shown))[:, :3]
    assert np.abs(got[~hidden] - expected[~hidden]).max() < 2.5 / 255
    assert np.abs(got[hidden] - 1.0).max() < 1e-12  # the white background


def test_nan_values_are_left_out_like_masked_ones():
    mesh = MeshTri.init_tensor(np.linspace(0, 1, 3), np.linspace(0, 1, 3))
    tri = mtri.Triangulation(mesh.p[0], mesh.p[1], mesh.t.T)
    values = np.arange(mesh.nelements, dtype=float)
    values[2] = np.nan
    fig, ax = plt.subplots()
    im = cell_colours(ax, tri, values)
    plt.close(fig)
    assert im.get_clim() == (0.0, mesh.nelements - 1.0)
    assert im.get_in_layout() is False
