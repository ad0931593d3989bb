import numpy as np
import pytest

from trainer.samplers import SAMPLERS, SLOW, sample
from trainer.samplers.lattice import korobov, maxmin_generator
from trainer.samplers.sobol_owen import sobol_digits


@pytest.mark.parametrize("name", sorted(SAMPLERS))
@pytest.mark.parametrize("n", [16, 64, 100, 1024])
def test_contract(name, n):
    if name == "ldbn" and n == 100:
        n = 121  # ldbn makes square sizes only
    if name in SLOW and n > 16:
        pytest.skip("slow sampler: checked at small n")
    pts = sample(name, n, count=3, seed=7)
    assert pts.shape == (3, n, 2) and pts.dtype == np.float64
    assert np.all(pts >= 0) and np.all(pts < 1)
    np.testing.assert_array_equal(pts, sample(name, n, count=3, seed=7))
    assert not np.array_equal(pts, sample(name, n, count=3, seed=8))


@pytest.mark.parametrize("m", [2, 4, 7, 10, 12])
def test_owen_sets_are_0m2_nets(m):
    n = 1 << m
    for pts in sample("sobol_owen", n, count=4, seed=m):
        for a in range(m + 1):
            b = m - a
            cell = np.floor(pts[:, 0] * 2**a).astype(int) * 2**b + np.floor(pts[:, 1] * 2**b).astype(int)
            assert np.unique(cell).size == n, f"elementary interval 2^-{a} x 2^-{b} not filled"


def test_unscrambled_sobol_is_the_known_sequence():
    x = sobol_digits(8).astype(float) / 2**32
    np.testing.assert_array_equal(x[:, 0], [0, .5, .25, .75, .125, .625, .375, .875])
    # direction numbers 1/2, 3/4, 5/8 (m = 1, 3, 5), natural (not Gray-code) order
    np.testing.assert_array_equal(x[:, 1], [0, .5, .75, .25, .625, .125, .375, .875])


def test_owen_scramble_is_nonlinear_and_uniform():
    pts = sample("sobol_owen", 64, count=4000, seed=0)
    # every point of a nested uniform scramble is uniform: mean 1/2, variance 1/12
    assert abs(pts.mean() - 0.5) < 0.005
    assert abs(pts.var() - 1 / 12) < 0.002
    # a digital shift would keep x_1 - x_0 mod 1 fixed at 1/2 in the top bit; Owen does not
    d = (pts[:, 1, 0] - pts[:, 0, 0]) % 1.0
    assert 0.1 < d.std()


@pytest.mark.parametrize("n,g", [(64, 19), (256, 71), (576, 155), (1024, 271), (4096, 671)])
def test_maxmin_generator(n, g):
    assert maxmin_generator(n) == g


@pytest.mark.parametrize("n,g", [(64, 27), (256, 75), (576, 241), (1024, 275), (4096, 1557)])
def test_p2_generator(n, g):
    from trainer.samplers.lattice import p2_generator
    assert p2_generator(n) == g


def test_rank1_is_a_shifted_lattice():
    n = 1024
    base = korobov(n, 271)
    pts = sample("rank1", n, count=2, seed=3)
    for p in pts:
        shift = (p[0] - base[0]) % 1.0
        np.testing.assert_allclose((base + shift) % 1.0, p, atol=1e-12)


def test_unknown_sampler_and_bad_sizes():
    with pytest.raises(ValueError, match="unknown sampler 'nope'"):
        sample("nope", 16)
    with pytest.raises(ValueError, match="n must be >= 1"):
        sample("rank1", 0)
    with pytest.raises(TypeError, match="count must be an integer"):
        sample("rank1", 16, count=1.5)
    with pytest.raises(ValueError, match="workers must be >= 1, got 0"):
        sample("sot", 16, workers=0)


def test_poisson_disk_keeps_its_radius():
    from trainer.samplers.poisson_disk import hex_spacing
    from trainer.stats import min_distance
    pts = sample("poisson_disk", 256, count=3, seed=0)
    d = min_distance(pts, toroidal=True) / hex_spacing(256)
    # starts at 0.75 r_max and relaxes by 0.9 when stuck: 0.675 after one relaxation
    assert np.all(d >= 0.75 * 0.9**2) and np.all(d <= 0.80)


def test_dart_throwing_checks_a_batch_block_by_block_as_all_pairs_at_once(monkeypatch):
    # all pairs at once took 37 GiB at n = 16384; the blocks must keep the same candidates
    import importlib
    pd = importlib.import_module("trainer.samplers.poisson_disk")
    fc = np.random.default_rng(3).random((700, 2))
    r2 = 0.03 ** 2
    close = pd._close(fc, fc, r2)
    greedy: list[int] = []
    for j in range(len(fc)):
        if not greedy or not close[j, greedy].any():
            greedy.append(j)
    monkeypatch.setattr(pd, "PAIR_BLOCK", 64)  # 11 blocks, kept points across blocks
    np.testing.assert_array_equal(pd._kept_in_order(fc, r2), greedy)
    assert 64 < len(greedy) < 700


def test_gbn_spreads_points_out():
    from trainer.samplers.gbn import gbn_relax
    from trainer.stats import min_distance
    white = np.random.default_rng(0).random((256, 2))
    relaxed = gbn_relax(white, 200)
    assert min_distance(relaxed, toroidal=True) > 5 * min_distance(white, toroidal=True)


def test_sot_disk_quantiles_and_concentric_map():
    from trainer.samplers.sot import disk_quantiles, disk_to_square
    t = disk_quantiles(1000)
    F = 0.5 + (t * np.sqrt(1 - t * t) + np.arcsin(t)) / np.pi
    np.testing.assert_allclose(F, (2 * np.arange(1000) + 1) / 2000, atol=1e-12)
    # Shirley-Chiu forward map of square points, then our inverse, is the identity
    a, b = np.random.default_rng(0).uniform(-1, 1, (2, 5000))
    wide = np.abs(a) > np.abs(b)
    r = np.where(wide, a, b)
    phi = np.where(wide, np.pi / 4 * b / a, np.pi / 2 - np.pi / 4 * a / b)
    disk = np.stack([r * np.cos(phi), r * np.sin(phi)], -1)
    np.testing.assert_allclose(disk_to_square(disk), (np.stack([a, b], -1) + 1) / 2, atol=1e-12)


def test_slow_samplers_give_the_same_sets_whatever_the_count():
    a = sample("poisson_disk", 16, count=3, seed=9)
    b = sample("poisson_disk", 16, count=2, seed=9)
    np.testing.assert_array_equal(a[:2], b)


def test_slow_samplers_give_the_same_sets_whatever_the_workers():
    one = sample("sot", 16, count=3, seed=5)
    np.testing.assert_array_equal(sample("sot", 16, count=3, seed=5, workers=2), one)


def test_ramp_cdf_is_exact():
    from trainer.samplers.densities import ramp_cdf
    # theta = pi/4: P(x + y <= t sqrt 2) for density 2x; at t sqrt2 = 1 it is int_0^1 2x (1-x) = 1/3
    assert ramp_cdf(np.array([1 / np.sqrt(2)]), np.pi / 4)[0] == pytest.approx(1 / 3, abs=1e-14)
    assert ramp_cdf(np.array([0.5]), 0.0)[0] == pytest.approx(0.25)
    th = 2.0
    lo, hi = min(0, np.cos(th)), np.sin(th)
    assert ramp_cdf(np.array([lo, hi]), th) == pytest.approx([0, 1], abs=1e-14)


@pytest.mark.slow
def test_non_uniform_samplers_follow_their_density():
    ramp = sample("sot_ramp", 64, count=2, seed=0)
    assert abs(ramp[..., 0].mean() - 2 / 3) < 0.01 and abs(ramp[..., 1].mean() - 0.5) < 0.01
    from trainer.samplers.densities import blob_density
    blob = sample("gbn_blob", 64, count=2, seed=0)
    white = np.random.default_rng(0).random((2, 64, 2))
    assert blob_density(blob).mean() > 1.5 * blob_density(white).mean()


def test_ldbn_table_and_stratification():
    from trainer.samplers.ldbn import check_table, load_table
    from trainer.stats import stratified_projections
    check_table(load_table())
    for k in (16, 32, 64):
        assert np.all(stratified_projections(sample("ldbn", k * k, count=4, seed=k)))
    # one point per grid cell at every size and under all 8 symmetries (sizes where the
    # points are not on the 1/n lattice once broke the mirrors)
    for k in (8, 16, 24, 40):
        cells = np.floor(sample("ldbn", k * k, count=32, seed=k) * k).astype(int)
        ids = cells[..., 1] * k + cells[..., 0]
        assert all(len(np.unique(i)) == k * k for i in ids), k
    with pytest.raises(ValueError, match="ldbn needs a square number of points"):
        sample("ldbn", 1000)
    bad = load_table().copy()
    bad[0, 0] = bad[1, 0]
    with pytest.raises(ValueError, match="not permutations"):
        check_table(bad)


@pytest.mark.parametrize("name", ["sot_ramp", "gbn_blob"])
def test_unwarping_maps_the_density_to_the_uniform_square(name):
    """Points drawn exactly from the density (rejection) come out uniform (chi-square)."""
    from trainer.samplers.densities import UNWARP, blob_density, ramp_density
    dens, top = (ramp_density, 2.0) if name == "sot_ramp" else (blob_density, 0.4)
    rng = np.random.default_rng(0)
    x = rng.random((200_000, 2))
    x = x[rng.random(len(x)) * top < dens(x)]
    u = UNWARP[name](x)
    assert np.all((u >= 0) & (u < 1))
    h, _, _ = np.histogram2d(u[:, 0], u[:, 1], bins=8, range=[[0, 1], [0, 1]])
    e = len(u) / 64
    assert ((h - e) ** 2 / e).sum() < 110  # chi-square, 63 dof: p ~ 2e-4
    # monotone in x along a row (the first coordinate is the x-marginal's CDF)
    t = np.linspace(0, 1, 50, endpoint=False)
    assert np.all(np.diff(UNWARP[name](np.column_stack([t, np.full(50, 0.3)]))[:, 0]) > 0)


def test_concentric_map_commutes_with_the_square_symmetries():
    """Why SOT may be augmented with all 8 symmetries: the disk process is isotropic and the
    map to the square carries the disk's mirrors and diagonal swap to the square's."""
    from trainer.samplers.sot import disk_to_square
    rng = np.random.default_rng(0)
    r, a = np.sqrt(rng.random(500)), 2 * np.pi * rng.random(500)
    p = np.stack([r * np.cos(a), r * np.sin(a)], 1)
    q = disk_to_square(p)
    np.testing.assert_allclose(disk_to_square(p * [-1, 1]), np.stack([1 - q[:, 0], q[:, 1]], 1),
                               atol=1e-12)
    np.testing.assert_allclose(disk_to_square(p * [1, -1]), np.stack([q[:, 0], 1 - q[:, 1]], 1),
                               atol=1e-12)
    np.testing.assert_allclose(disk_to_square(p[:, ::-1]), q[:, ::-1], atol=1e-12)


def test_half_turn_maps_a_shifted_lattice_to_a_shifted_lattice():
    """Why the lattices are augmented with the half-turn only: (1 - x, 1 - y) of the lattice
    with generator g is the same lattice, shifted; a mirror gives generator n - g."""
    from trainer.samplers.lattice import p2_lattice
    pts = p2_lattice(64, 1, np.random.default_rng(0))[0]
    turned = 1.0 - pts
    d = (turned - turned[0]) % 1.0
    base = (pts - pts[0]) % 1.0
    key = lambda z: set(map(tuple, np.round(z * 64).astype(int) % 64))
    assert key(d) == key(base)
    mirrored = np.stack([1.0 - pts[:, 0], pts[:, 1]], 1)
    assert key((mirrored - mirrored[0]) % 1.0) != key(base)
