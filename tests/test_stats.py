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


def test_gl2_closed_form_matches_its_kernel_definition():
    from trainer.stats import gl2
    # D^2 = int int K - 2/n sum_i int K(x_i, .) + 1/n^2 sum_ij K(x_i, x_j), K = prod (2 - max)
    pts = np.random.default_rng(1).random((20, 2))
    g = (np.arange(400) + 0.5) / 400
    grid = np.stack(np.meshgrid(g, g), -1).reshape(-1, 2)
    K = lambda a, b: np.prod(2 - np.maximum(a[:, None, :], b[None, :, :]), axis=2)
    d2 = (4 / 3) ** 2 - 2 * K(pts, grid).mean() + K(pts, pts).mean()
    assert gl2(pts) ** 2 == pytest.approx(d2, abs=1e-5)  # midpoint rule: ~1e-6 error


def test_gaussian_integrals_match_quadrature():
    from scipy.integrate import dblquad
    from trainer.stats import Gaussians
    G = Gaussians.random(3, seed=4)
    exact = G.integrals()
    for j in range(3):
        ref = dblquad(lambda y, x: G(np.array([[x, y]]))[j, 0], 0, 1, 0, 1, epsabs=1e-13)[0]
        assert exact[j] == pytest.approx(ref, abs=1e-12)


def test_heaviside_areas_match_brute_force():
    from trainer.stats import Heavisides
    H = Heavisides.random(6, seed=2)
    g = (np.arange(1000) + 0.5) / 1000
    grid = np.stack(np.meshgrid(g, g), -1).reshape(-1, 2)
    np.testing.assert_allclose(H.integrals(), H(grid).mean(axis=1), atol=2e-5)


def test_integration_mse_is_lower_for_better_points():
    from trainer.stats import Gaussians, integration_mse
    G = Gaussians.random(100, seed=0)
    exact = G.integrals()
    owen = integration_mse(sample("sobol_owen", 256, count=8, seed=0), G, exact).mean()
    white = integration_mse(np.random.default_rng(0).random((8, 256, 2)), G, exact).mean()
    assert owen < white / 10


def test_t_value_and_projections():
    from trainer.stats import stratified_projections, t_value
    assert np.all(t_value(sample("sobol_owen", 256, count=2, seed=0)) == 0)
    grid = (np.stack(np.meshgrid(np.arange(16), np.arange(16)), -1).reshape(-1, 2) + 0.5) / 16
    assert t_value(grid) == 4  # a 16x16 grid only fills the 2^-4 x 2^-4 squares evenly
    assert np.all(stratified_projections(sample("sobol_owen", 64, count=2, seed=0)))
    assert not stratified_projections(grid)


def test_compare_same_and_different_samplers():
    from trainer.stats import compare, format_table
    owen = sample("sobol_owen", 256, count=16, seed=0)
    owen2 = sample("sobol_owen", 256, count=16, seed=1)
    white = np.random.default_rng(0).random((16, 256, 2))
    same = compare(owen, owen2)
    diff = compare(white, owen)
    assert abs(same["l2_star"]["rel_diff"]) < 0.15 and same["l2_star"]["p_value"] > 1e-3
    assert diff["l2_star"]["rel_diff"] > 1.0 and diff["l2_star"]["p_value"] < 1e-6
    assert same["radial_spectrum"]["mae"] < diff["radial_spectrum"]["mae"]
    assert "| l2_star |" in format_table(same)


@pytest.mark.parametrize("k", [4, 7, 16])
def test_ot_energy_of_a_grid_is_one_over_6n(k):
    from trainer.stats import ot_energy
    grid = (np.stack(np.meshgrid(np.arange(k), np.arange(k)), -1).reshape(-1, 2) + 0.5) / k
    assert ot_energy(grid) == pytest.approx(1 / (6 * k * k), rel=1e-12)


def test_ot_energy_converges_and_orders_samplers():
    import warnings
    from trainer.stats import ot_energy
    from trainer.stats.ot_energy import _cells
    white = np.random.default_rng(3).random((2, 128, 2))
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # a non-converged solve would warn
        e_white = ot_energy(white)
        e_owen = ot_energy(sample("sobol_owen", 128, count=2, seed=0))
    assert np.all(e_owen < e_white)
    # hexagonal-like order is the optimum: white noise is several times worse (~0.5/n)
    assert np.all(e_white > 2 * 0.1604 / 128)
    area, moment, _ = _cells(white[0], np.zeros(128))  # Voronoi cells tile the square
    assert area.sum() == pytest.approx(1.0, rel=1e-12)
    # a solve cut short says how far it got, relative to the cell area
    with pytest.warns(RuntimeWarning, match=r"stopped after 1 Newton steps: max cell-area "
                                            r"error \S+ of the cell area 1/n \(tolerance 1e-09\)"):
        ot_energy(white[0], max_iter=1)


def test_ot_energy_near_duplicate_points():
    """Points closer than rounding can separate (a pair 2e-8 apart in a corner, as the
    unwarping of a density near zero makes; exact duplicates) count as one point of their
    summed weight, and a point left out of the triangulation has an empty cell."""
    import warnings
    from trainer.stats import ot_energy
    from trainer.stats.ot_energy import _cells
    k = 16
    x = (np.stack(np.meshgrid(np.arange(k), np.arange(k)), -1).reshape(-1, 2)
         + np.random.default_rng(0).random((k * k, 2))) / k
    x[-1], x[-2] = [1.0, 1 - 3e-8], [1.0, 1 - 2e-8]
    apart = x.copy()
    apart[-1] = [1.0, 1 - 1e-4]
    twin = x.copy()
    twin[-1] = twin[-2]
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # the first stopped short before the merge
        e, e_twin, e_apart = ot_energy(x, max_iter=20), ot_energy(twin), ot_energy(apart)
    assert e == pytest.approx(e_twin, rel=1e-9)
    assert e == pytest.approx(e_apart, rel=1e-4)  # the pair 1e-4 apart: a small move
    # a point whose weight is far below its neighbours' is hidden: no cell, not the whole square
    w = np.zeros(k * k)
    w[k * k // 2 + k // 2] = -1.0
    area, _, _ = _cells(x, w)
    assert area[k * k // 2 + k // 2] == 0 and area.sum() == pytest.approx(1.0, rel=1e-12)


def test_pair_correlation():
    from trainer.stats import pair_correlation
    r, g = pair_correlation(np.random.default_rng(0).random((20, 400, 2)))
    assert np.all(np.abs(g[r > 0.5] - 1) < 0.1)  # white noise: g = 1
    r, g = pair_correlation(sample("poisson_disk", 256, count=4, seed=0))
    assert np.all(g[r < 0.6] < 0.02)  # no pair closer than the disk radius (~0.675 r_max)
    assert g[(r > 0.7) & (r < 1.0)].max() > 1.2  # the first-neighbour peak
