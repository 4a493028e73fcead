"""The solution figure's binned multiplier image (nitsche.plot.binned_mean); figures written
without spurious floating-point warnings (write_figure)."""
import numpy as np

import warnings

import pytest

from nitsche.plot import binned_mean, write_figure


def test_binned_mean_is_the_weighted_mean_per_bin():
    rng = np.random.default_rng(1)
    x, y = rng.uniform(0, 2, 4000), rng.uniform(0, 1, 4000)
    w = rng.uniform(0.5, 1.5, x.size)
    v = np.where(x < 1, 1.0, 3.0) + y
    image, (left, right, bottom, top) = binned_mean(x, y, v, w, most=8)
    size = (x.max() - x.min()) / 8  # square bins, 8 along the longer side
    assert image.shape == (int(np.ceil((y.max() - y.min()) / size)), 8)
    assert left == x.min() and bottom == y.min() and right >= x.max() and top >= y.max()
    i = np.minimum(((y - bottom) / size).astype(int), image.shape[0] - 1)
    j = np.minimum(((x - left) / size).astype(int), 7)
    for (r, c) in [(0, 0), (2, 5), (3, 7)]:
        inside = (i == r) & (j == c)
        assert np.isclose(image[r, c], (w[inside] * v[inside]).sum() / w[inside].sum(), rtol=1e-14)


def test_binned_mean_leaves_empty_bins_blank_and_adapts_to_few_points():
    x = np.array([0.0, 1.0, 0.0, 1.0])
    y = np.array([0.0, 0.0, 1.0, 1.0])
    image, _ = binned_mean(x, y, np.arange(4.0), np.ones(4), per_bin=1)
    assert image.shape == (2, 2) and np.allclose(image, [[0, 1], [2, 3]])
    ring = np.linspace(0, 2 * np.pi, 20000, endpoint=False)
    image, _ = binned_mean(np.cos(ring), np.sin(ring), np.ones(ring.size), np.ones(ring.size))
    assert np.isnan(image[image.shape[0] // 2, image.shape[1] // 2])  # no point at the centre
    assert np.nanmax(np.abs(image - 1)) == 0


def test_binned_mean_in_chunks_is_the_same_picture():
    rng = np.random.default_rng(2)
    x, y = rng.uniform(-1, 1, 5000), rng.uniform(0, 3, 5000)
    v, w = np.sin(3 * x) * y, rng.uniform(0.5, 1.5, x.size)
    whole, extent = binned_mean(x, y, v, w, most=20)
    pieces, same = binned_mean(x, y, v, w, most=20, chunk=333)
    assert same == extent and np.array_equal(np.isnan(pieces), np.isnan(whole))
    assert np.nanmax(np.abs(pieces - whole)) < 1e-14 * np.nanmax(np.abs(whole))


def test_write_figure_draws_a_3d_surface_without_the_blas_overflow_flag(tmp_path, monkeypatch):
    """mplot3d projects the faces with np.dot, where OpenBLAS can raise the overflow flag on
    finite data ("overflow encountered in dot" printed by `nitsche run`): simulated here by
    an overflow in the projection, which plain savefig reports and write_figure does not."""
    import matplotlib.pyplot as plt
    from mpl_toolkits.mplot3d import proj3d
    project = proj3d._scale_proj_transform_vectors

    def flagged(vecs, axes):
        np.float64(1e308) * np.float64(10.0)  # sets the overflow flag, as the BLAS kernel did
        return project(vecs, axes)
    monkeypatch.setattr(proj3d, "_scale_proj_transform_vectors", flagged)

    def figure():
        fig = plt.figure()
        X, Y = np.meshgrid(np.linspace(0, 1, 5), np.linspace(0, 1, 5))
        fig.add_subplot(projection="3d").plot_surface(X, Y, X * Y)
        return fig
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        fig = figure()
        with pytest.raises(RuntimeWarning, match="overflow"):
            fig.savefig(tmp_path / "plain.png")
        plt.close(fig)
        fig = figure()
        path = write_figure(fig, tmp_path / "written.png", dpi=50)
    assert path.stat().st_size > 0 and not plt.fignum_exists(fig.number)  # written and closed


def test_write_figure_leaves_no_caller_array_held_by_the_layouts_garbage(tmp_path):
    """A tight layout of mathtext labels leaves the text parser's handled exceptions in
    reference cycles whose frames hold the callers' locals (matplotlib 3.11 with pyparsing:
    after plain savefig and close the array below stays alive until the cycle collector
    runs, which is off here, as it is between its runs); after write_figure it is gone."""
    import gc
    import weakref
    import matplotlib.pyplot as plt

    def draw(path):
        values = np.linspace(0.0, 1.0, 1000)  # e.g. the multipliers at all quadrature points
        fig, ax = plt.subplots()
        ax.plot(values)
        ax.set_ylabel(r"$\lambda_N$")
        ax.set_title(r"multiplier $\lambda_N$ (contact pressure)")
        fig.tight_layout()
        write_figure(fig, path)
        return weakref.ref(values)
    gc.collect()
    gc.disable()
    try:
        assert draw(tmp_path / "f.png")() is None
    finally:
        gc.enable()
