"""The differentiable radial spectrum (trainer.spectral) against the runtime's figure."""
import numpy as np
import pytest

torch = pytest.importorskip("torch")

from diffsampler_rt.grid import decode  # noqa: E402
from diffsampler_rt.spectrum import NUM_BINS, periodogram, radial_spectrum  # noqa: E402
from trainer.spectral import AxisSpectrum, RadialSpectrum, grid_points  # noqa: E402


@pytest.mark.parametrize("k, bins, stratified, toroidal",
                         [(8, NUM_BINS, False, False), (16, 20, True, False), (8, 30, False, True)])
def test_torch_spectrum_is_the_runtimes_figure(k, bins, stratified, toroidal):
    grid = np.random.default_rng(k).uniform(-0.7, 0.7, (3, 2, k, k))
    pts = grid_points(torch.tensor(grid), stratified=stratified, toroidal=toroidal)
    decoded = decode(grid, stratified=stratified, toroidal=toroidal)
    if not toroidal:
        np.testing.assert_allclose(pts.numpy(), decoded, atol=1e-12)
    got = RadialSpectrum(k * k, bins)(pts).numpy()
    np.testing.assert_allclose(got, radial_spectrum(decoded)[1][:bins], rtol=1e-9, atol=1e-12)


@pytest.mark.parametrize("figure_class, n, size, size_name",
                         [(RadialSpectrum, 64, 10, "bins"), (AxisSpectrum, 16, 6, "count")])
def test_torch_figures_have_gradients_and_check_their_input(figure_class, n, size, size_name):
    pts = torch.rand(2, n, 2, dtype=torch.float64, requires_grad=True)
    figure = figure_class(n, size)
    torch.autograd.gradcheck(lambda p: figure(p), (pts,))
    with pytest.raises(ValueError, match=rf"\(B, {n}, 2\)"):
        figure(torch.rand(2, n - 1, 2, dtype=torch.float64))
    with pytest.raises(ValueError, match=size_name):
        figure_class(n, 0)


def test_axis_spectrum_is_the_2d_spectrum_on_its_axes():
    pts = np.random.default_rng(3).random((4, 100, 2))
    got = AxisSpectrum(100, 12)(torch.tensor(pts)).numpy()
    # the runtime's mean periodogram (rows fy, columns fx, -12..12) at (j, 0) and (0, j)
    P = periodogram(pts, 12)
    want = (P[12, 13:] + P[13:, 12]) / 2
    np.testing.assert_allclose(got, want, rtol=1e-10)
    # a set on a 10 x 10 grid: its projections are 10 stacks, all power at multiples of 10
    g = (np.stack(np.meshgrid(np.arange(10), np.arange(10)), -1).reshape(1, 100, 2) + 0.5) / 10
    p = AxisSpectrum(100, 20)(torch.tensor(g)).numpy()
    assert np.allclose(p[[9, 19]], 100.0) and np.allclose(np.delete(p, [9, 19]), 0.0, atol=1e-20)
