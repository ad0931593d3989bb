import numpy as np
import pytest
from scipy.stats import qmc

from trainer.samplers import sample
from trainer.samplers.lattice import korobov
from trainer.stats import (empty_elementary_fraction, l2_star, min_distance, periodogram,
                           radial_spectrum, spectrum_mae)

from .conftest import REFERENCE_CSV


def test_l2_star_matches_scipy():
    pts = np.random.default_rng(0).random((3, 200, 2))
    ours = l2_star(pts, chunk=64)
    theirs = [qmc.discrepancy(p, method="L2-star") for p in pts]
    np.testing.assert_allclose(ours, theirs, rtol=1e-10)


def test_elementary_intervals():
    assert np.all(empty_elementary_fraction(sample("sobol_owen", 256, count=3, seed=0)) == 0)
    grid = (np.stack(np.meshgrid(np.arange(16), np.arange(16)), -1).reshape(-1, 2) + 0.5) / 16
    # a regular 16x16 grid fills its square cells but leaves 1/256 strips empty
    assert 0 < empty_elementary_fraction(grid) < 1
    with pytest.raises(ValueError, match="2\\^m"):
        empty_elementary_fraction(np.zeros((10, 2)))


def test_periodogram_of_a_lattice_is_n_on_the_dual_lattice_and_0_elsewhere():
    # sum_i exp(-2 pi i i (fx + g fy) / n) is n when fx + g fy = 0 mod n, else 0
    n, g, fmax = 64, 19, 40
    P = periodogram(korobov(n, g), fmax)
    f = np.arange(-fmax, fmax + 1)
    dual = (f[None, :] + g * f[:, None]) % n == 0  # P[fy, fx]
    np.testing.assert_allclose(P[dual], n, rtol=1e-9)
    np.testing.assert_allclose(P[~dual], 0, atol=1e-9)
    x, r = radial_spectrum(korobov(n, g))
    assert x.shape == r.shape == (79,)


def test_rank1_spectrum_matches_seed_curve():
    if not REFERENCE_CSV.exists():
        pytest.skip("shared reference data not available")
    ref = np.loadtxt(REFERENCE_CSV, delimiter=",", skiprows=1)
    x, r = radial_spectrum(sample("rank1", 1024, count=1, seed=0))
    np.testing.assert_allclose(x, ref[:, 0])
    assert spectrum_mae(r, ref[:, 6]) < 1e-3


def test_min_distance():
    pts = np.array([[0.01, 0.5], [0.99, 0.5], [0.5, 0.5]])
    assert min_distance(pts) == pytest.approx(0.49)
    assert min_distance(pts, toroidal=True) == pytest.approx(0.02)
