"""nitsche.plot's pictures of fields on meshes with more cells than pixels: the raster of
a field sampled at pixel centres (raster), the Raster artist that draws it, and the rule
that picks it over tripcolor (as_image)."""
import tracemalloc

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import matplotlib.tri as mtri  # noqa: E402
import numpy as np  # noqa: E402
from matplotlib.collections import TriMesh  # noqa: E402
from skfem import MeshTri  # noqa: E402

from nitsche.plot import DPI, Raster, as_image, cell_colours, raster  # noqa: E402


def centres(extent, shape):
    (left, right, bottom, top), (rows, columns) = extent, shape
    x = left + (np.arange(columns) + 0.5) * (right - left) / columns
    y = bottom + (np.arange(rows) + 0.5) * (top - bottom) / rows
    return np.meshgrid(x, y)


def test_a_linear_field_is_sampled_exactly_and_outside_the_l_shape_masked():
    mesh = MeshTri.init_lshaped().refined(5)  # [-1, 1]^2 without the quadrant (0, 1]^2
    u = 0.7 * mesh.p[0] - 1.3 * mesh.p[1] + 0.2
    extent, shape = (-1.0, 1.0, -1.0, 1.0), (56, 62)  # no pixel centre on x = 0 or y = 0
    image = raster(mesh.p[0], mesh.p[1], mesh.t.T, u, extent, shape)
    X, Y = centres(extent, shape)
    inside = (X < 0) | (Y < 0)
    assert np.array_equal(np.isfinite(image), inside)
    assert np.abs(image[inside] - (0.7 * X - 1.3 * Y + 0.2)[inside]).max() < 1e-14


def test_a_graded_mesh_leaves_no_hole():
    mesh = MeshTri.init_sqsymmetric()
    for _ in range(9):  # the cells at the corner (0, 0) refined: 4^9 times smaller
        mesh = mesh.refined(np.nonzero((mesh.p[:, mesh.t] ** 2).sum(axis=0).min(axis=0) == 0)[0])
    (ax, bx), (ay, by) = mesh.p[:, mesh.t[1:]] - mesh.p[:, mesh.t[:1]]
    area = np.abs(ax * by - ay * bx) / 2
    assert area.max() > 1e5 * area.min()
    u = mesh.p[0] + 2 * mesh.p[1]
    extent, shape = (0.0, 1.0, 0.0, 1.0), (40, 40)
    image = raster(mesh.p[0], mesh.p[1], mesh.t.T, u, extent, shape)
    X, Y = centres(extent, shape)
    assert np.isfinite(image).all()
    assert np.abs(image - (X + 2 * Y)).max() < 1e-14
    cells = raster(mesh.p[0], mesh.p[1], mesh.t.T, np.arange(mesh.nelements), extent, shape,
                   per_cell=True)
    owner = cells.astype(int).ravel()  # the cell that holds each centre
    lam = np.linalg.solve(  # the centre's barycentric coordinates in its cell
        np.concatenate([mesh.p[:, mesh.t[:, owner]].transpose(2, 0, 1),
                        np.ones((owner.size, 1, 3))], axis=1),
        np.c_[X.ravel(), Y.ravel(), np.ones(owner.size)][..., None])
    assert lam.min() > -1e-12


def test_the_rule_triangles_for_small_meshes_an_image_for_large_ones():
    fig, ax = plt.subplots(figsize=(4.8, 4.2))
    width, height = ax.get_position().size * fig.get_size_inches() * DPI
    pixels = int(width * height)
    assert not as_image(ax, pixels) and as_image(ax, pixels + 1)
    small = MeshTri.init_tensor(np.linspace(0, 1, 11), np.linspace(0, 1, 11))
    large = MeshTri.init_tensor(np.linspace(0, 1, 301), np.linspace(0, 1, 301))
    assert small.nelements < pixels < large.nelements
    for mesh, kind in [(small, TriMesh), (large, Raster)]:
        tri = mtri.Triangulation(mesh.p[0], mesh.p[1], mesh.t.T)
        im = cell_colours(ax, tri, np.arange(mesh.nelements, dtype=float))
        assert isinstance(im, kind) and im.get_clim() == (0.0, mesh.nelements - 1.0)
    plt.close(fig)


def test_the_drawn_raster_shows_each_cell_colour_and_leaves_masked_cells_out():
    mesh = MeshTri.init_tensor(np.linspace(0, 1, 201), np.linspace(0, 1, 201))
    centroid = mesh.p[:, mesh.t].mean(axis=1)
    values = np.floor(4 * centroid[0])  # 0, 1, 2, 3 in vertical strips
    hidden = centroid[1] > 0.75
    fig, ax = plt.subplots(figsize=(2.5, 2.5), dpi=DPI)
    ax.set_facecolor("white")
    im = cell_colours(ax, mtri.Triangulation(mesh.p[0], mesh.p[1], mesh.t.T),
                      np.ma.masked_where(hidden, values), cmap="viridis")
    assert isinstance(im, Raster)
    ax.set_aspect("equal")
    fig.canvas.draw()
    picture = np.asarray(fig.canvas.buffer_rgba())[..., :3] / 255.0
    points = np.array([(0.125, 0.3), (0.375, 0.6), (0.625, 0.1), (0.875, 0.7), (0.5, 0.9)])
    x, y = ax.transData.transform(points).T
    got = picture[(picture.shape[0] - y).astype(int), x.astype(int)]
    expected = plt.get_cmap("viridis")(np.arange(4) / 3)[:, :3]
    assert np.abs(got[:4] - expected).max() < 1.5 / 255
    assert np.abs(got[4] - 1.0).max() == 0  # the background
    left, right, bottom, top = im.get_extent()  # the drawn picture: whole pixels over the mesh
    assert left <= 0 and right >= 1 and bottom <= 0 and top >= 1
    assert im.get_array().shape[1] == round(np.diff(ax.transData.transform([(left, 0), (right, 0)])[:, 0])[0])
    plt.close(fig)


def test_the_raster_memory_is_bounded_by_the_picture_not_the_mesh():
    """tracemalloc peak of a 400 x 400 picture: below 8 bytes x (4 x pixels + 32 x chunk)
    for 500k cells (the triangles alone hold 12 MB), and the same for 4x fewer cells."""
    shape, chunk = (400, 400), 1 << 14
    peaks = []
    for n in (251, 501):
        mesh = MeshTri.init_tensor(np.linspace(0, 1, n), np.linspace(0, 1, n))
        x, y = mesh.p
        t = mesh.t.T
        u = x * y
        tracemalloc.start()
        raster(x, y, t, u, (0.0, 1.0, 0.0, 1.0), shape, chunk=chunk)
        peaks.append(tracemalloc.get_traced_memory()[1])
        tracemalloc.stop()
    assert mesh.nelements == 500000
    assert peaks[1] < 8 * (4 * shape[0] * shape[1] + 32 * chunk)
    assert peaks[1] < 1.1 * peaks[0]
