"""Non-uniform models: the density table, its maps, the fit, training data and the runtime."""
from __future__ import annotations

import json
import shutil
from dataclasses import replace

import numpy as np
import pytest

import diffsampler_rt
from diffsampler_rt.card import CARD_KEY, parse_card
from diffsampler_rt.density import check_table, unwarp, warp
from diffsampler_rt.errors import ModelFormatError
from trainer.density import (FLOOR, choose_degree, choose_degree_across_sizes,
                             choose_log_degree, fit_density, fit_density_legendre,
                             fit_density_log_legendre, refloor)
from trainer.samplers.densities import ramp_unwarp

# minutes in all: run by the full suite, not by `pytest -m "not slow"`
pytestmark = pytest.mark.slow


def random_table(bins: int, seed: int = 0) -> dict:
    rng = np.random.default_rng(seed)
    return fit_density(rng.random((4000, 2)) ** np.array([0.5, 2.0]), bins)


def ramp_points(count: int, seed: int) -> np.ndarray:
    """Exact draws of the density 2x (x = sqrt(u))."""
    u = np.random.default_rng(seed).random((count, 2))
    return np.column_stack([np.sqrt(u[:, 0]), u[:, 1]])


@pytest.mark.parametrize("bins", [1, 2, 7, 16])
def test_warp_and_unwarp_are_inverse(bins):
    table = random_table(bins, seed=bins)
    assert check_table(table) is None
    u = np.random.default_rng(1).random((3, 500, 2))
    p = warp(u, table)
    assert p.shape == u.shape and np.all((p >= 0) & (p < 1))
    np.testing.assert_allclose(unwarp(p, table), u, atol=1e-12)
    np.testing.assert_allclose(warp(unwarp(u, table), table), u, atol=1e-12)


def test_maps_are_continuous_across_bins():
    table = random_table(8)
    x = np.linspace(0, 1, 20001, endpoint=False)
    for line in (np.column_stack([x, np.full_like(x, 0.37)]),
                 np.column_stack([np.full_like(x, 0.61), x])):
        for f in (warp, unwarp):
            assert np.abs(np.diff(f(line, table), axis=0)).max() < 1e-3


def test_fit_recovers_a_known_density():
    table = fit_density(ramp_points(200_000, 0), 16)
    test = ramp_points(5000, 1)
    # the fitted Rosenblatt map is the exact one (x -> x^2, y -> y) up to the histogram's
    # sampling noise (~780 white-noise points in a bin at small x) and its piecewise-constant
    # density (h^2 / 4 = 0.001 at most in x)
    err = np.abs(unwarp(test, table) - ramp_unwarp(test))
    assert err.mean() < 0.002 and np.quantile(err, 0.99) < 0.008
    u = np.random.default_rng(2).random((100_000, 2))
    counts = np.histogram(warp(u, table)[:, 0], bins=4, range=(0, 1))[0] / len(u)
    np.testing.assert_allclose(counts, [1 / 16, 3 / 16, 5 / 16, 7 / 16], atol=0.005)


def test_refloor_matches_a_fit_with_the_new_floor():
    sets = ramp_points(16 * 256, 3).reshape(16, 256, 2)
    for fit in (lambda f: fit_density(sets, 16, floor=f),
                lambda f: fit_density_legendre(sets, 16, max_degree=4, floor=f)[0]):
        got = refloor(fit(1e-3), 1e-3, 1e-6)
        for key in ("x_cdf", "y_cdf"):
            np.testing.assert_allclose(got[key], fit(1e-6)[key], rtol=0, atol=1e-12)
    # the floor mixes that share of uniform mass in: 1e-3 moved the ramp's x-CDF by 2.4e-4
    exact = {"x_cdf": (np.linspace(0, 1, 129) ** 2).tolist(),
             "y_cdf": np.tile(np.linspace(0, 1, 129), (128, 1)).tolist()}
    for floor, shift in ((1e-3, 2.5e-4), (FLOOR, 2.5e-7)):
        moved = np.abs(np.array(refloor(exact, 1e-300, floor)["x_cdf"]) - exact["x_cdf"])
        assert 0.9 * shift < moved.max() < shift
    with pytest.raises(ValueError, match="new floor must be a number in"):
        refloor(exact, 1e-3, 0.0)


def test_smooth_fit_beats_the_histogram_on_a_known_density():
    sets = ramp_points(200_000, 0).reshape(100, 2000, 2)
    table, degree = fit_density_legendre(sets, 64, max_degree=12)
    assert check_table(table) is None and len(table["x_cdf"]) == 65
    assert degree == 1  # the ramp 2x is a degree-1 series; cross-validation finds it
    test = ramp_points(5000, 1)
    err = np.abs(unwarp(test, table) - ramp_unwarp(test))
    hist = np.abs(unwarp(test, fit_density(sets, 16)) - ramp_unwarp(test))
    # measured: mean 1.8e-4 vs the histogram's 1.2e-3, 99 % quantile 3.4e-4 vs 6.1e-3
    assert err.mean() < 0.0005 < hist.mean() and np.quantile(err, 0.99) < 0.001


def test_cross_validation_follows_the_density():
    rng = np.random.default_rng(3)
    bump = rng.normal(0.5, 0.1, (200_000, 2))
    bump = bump[np.all((bump > 0) & (bump < 1), axis=1)][:160_000].reshape(80, 2000, 2)
    degree, risk, se = choose_degree(list(bump), 24)
    assert 8 <= degree <= 16  # a narrow bump needs many terms (measured: 12)
    assert risk.shape == se.shape == (25,) and risk[degree] < risk[2]
    uniform = list(rng.random((16, 500, 2)))
    assert choose_degree(uniform, 8)[0] == 0
    with pytest.raises(ValueError, match="at least 2 example sets"):
        choose_degree(uniform[:1], 4)
    with pytest.raises(ValueError, match="max_degree must be an integer"):
        fit_density_legendre(uniform, 8, max_degree=-1)
    # sets of several sizes mix
    table, _ = fit_density_legendre([np.stack(uniform), rng.random((4, 64, 2))], 8, max_degree=4)
    assert check_table(table) is None


def test_degree_across_sizes_ignores_what_one_size_alone_has():
    # a density 2x shared by two sizes, plus at each size its own bump at a different place
    # (a stand-in for a sampler's edge effects, which depend on n)
    rng = np.random.default_rng(5)
    groups = []
    for centre in (0.2, 0.8):
        pts = ramp_points(60_000, int(10 * centre))
        bump = np.clip(rng.normal(centre, 0.03, (20_000, 2)), 0, 1 - 1e-9)
        groups.append(rng.permutation(np.concatenate([pts, bump]))[:80_000].reshape(40, 2000, 2))
    within = choose_degree(list(groups[0]), 16)[0]
    across, risk, se = choose_degree_across_sizes(groups, 16)
    assert within >= 12 and across <= 3  # measured: 16 and 0 (the bumps also tilt x apart)
    with pytest.raises(ValueError, match="2 or more sizes"):
        choose_degree_across_sizes(groups[:1], 4)


def near_zero_points(count: int, seed: int) -> np.ndarray:
    """Exact draws (rejection) of p ~ exp(-8 (x - 0.2)^2) (y^2 + 0.01): near zero along y = 0
    and a hundredfold range, like the GBN blob's edges."""
    rng = np.random.default_rng(seed)
    out = []
    while sum(map(len, out)) < count:
        p = rng.random((4 * count, 2))
        keep = rng.random(len(p)) * 1.01 < np.exp(-8 * (p[:, 0] - 0.2) ** 2) * (p[:, 1] ** 2 + 0.01)
        out.append(p[keep])
    return np.concatenate(out)[:count]


def exact_near_zero_table(bins: int) -> dict:
    m = 64 * bins
    t = (np.arange(m) + 0.5) / m
    dens = np.exp(-8 * (t[:, None] - 0.2) ** 2) * (t[None, :] ** 2 + 0.01)
    from trainer.density import _table
    return _table(dens.reshape(bins, 64, bins, 64).sum(axis=(1, 3)), 1e-12)


def test_log_fit_follows_a_density_near_zero():
    sets = near_zero_points(120_000, 0).reshape(3, 40, 1000, 2)
    degree, loss, se = choose_log_degree(list(sets), 8)
    assert 2 <= degree <= 8 and loss.shape == se.shape == (9,) and loss[degree] < loss[0]
    table, d = fit_density_log_legendre(list(sets), 64, max_degree=8, sizes=list(sets))
    assert d == degree and check_table(table) is None
    smooth, _ = fit_density_legendre(list(sets), 64, max_degree=8, sizes=list(sets))
    test = near_zero_points(20_000, 1)
    exact = unwarp(test, exact_near_zero_table(64))
    err = np.abs(unwarp(test, table) - exact).max(axis=1)
    lin = np.abs(unwarp(test, smooth) - exact).max(axis=1)
    # where the density is low (y < 0.1: 10x below its mean) the linear series goes astray
    # (measured: mean error 3e-4 vs 8e-4 there)
    low = test[:, 1] < 0.1
    assert err[low].mean() < 0.5 * lin[low].mean() and err.mean() < 0.01


def test_fit_arguments_checked():
    with pytest.raises(ValueError, match="bins must be an integer"):
        fit_density(np.zeros((4, 2)), 0)
    with pytest.raises(ValueError, match="floor must be > 0"):
        fit_density(np.zeros((4, 2)), 4, floor=0)
    with pytest.raises(ValueError, match="points in"):
        fit_density(np.full((4, 2), 1.5), 4)


def test_bad_tables_named():
    good = random_table(4)
    assert "exactly the keys" in check_table({"x_cdf": good["x_cdf"]})
    assert "rows of 5" in check_table({**good, "y_cdf": good["y_cdf"][:3]})
    flat = [0.0, 0.5, 0.5, 0.7, 1.0]
    assert "increase strictly" in check_table({**good, "x_cdf": flat})
    assert "increase strictly" in check_table({**good, "x_cdf": [0.0, 0.2, 0.4, 0.6, 0.9]})
    assert "numbers" in check_table({**good, "x_cdf": ["a"] * 5})
    card = dict(diffsampler_rt.load("rank1").card)
    with pytest.raises(ModelFormatError, match="'density' must be an object"):
        parse_card({CARD_KEY: json.dumps({**card, "density": [1, 2]})}, "m")
    assert parse_card({CARD_KEY: json.dumps({**card, "density": good})}, "m")["density"] == good
    for bad in ({"density": good, "density_floor": 0}, {"density_floor": 1e-6},
                {"density": good, "density_floor": True}):
        with pytest.raises(ModelFormatError, match="'density_floor' must be a number in"):
            parse_card({CARD_KEY: json.dumps({**card, **bad})}, "m")


def _with_card(src, dst, **fields):
    import onnx
    model = onnx.load(str(src))
    prop = next(p for p in model.metadata_props if p.key == CARD_KEY)
    prop.value = json.dumps({**json.loads(prop.value), **fields})
    onnx.save(model, str(dst))
    return dst


def test_runtime_maps_the_sets_to_the_cards_density(tiny_onnx, tmp_path):
    table = random_table(6)
    plain = diffsampler_rt.Model(tiny_onnx).generate(64, 3, seed=4)
    m = diffsampler_rt.Model(_with_card(tiny_onnx, tmp_path / "d.onnx", density=table))
    out = m.generate(64, 3, seed=4)
    np.testing.assert_array_equal(out, warp(plain, table))
    # the density is the model, not an optional repair: structure=False keeps it
    bare = diffsampler_rt.Model(tiny_onnx).generate(64, 3, seed=4, structure=False)
    np.testing.assert_array_equal(m.generate(64, 3, seed=4, structure=False),
                                  warp(bare, table))
    assert np.all((out >= 0) & (out < 1))


def test_training_pools_are_uniformised(monkeypatch, tmp_path):
    from tests.conftest import tiny_config
    from trainer.data import Batches, make_pool
    from diffsampler_rt.grid import decode

    monkeypatch.setenv("DIFFSAMPLER_CACHE", str(tmp_path))
    cfg = tiny_config(sampler="rank1", embedding="ot")
    data = replace(cfg.data, pool_sizes=(6, 3), density_bins=4)
    batches = Batches(data, seed=1)
    raw = {k: decode(make_pool("rank1", "ot", k, p, 1)) for k, p in zip((4, 8), (6, 3))}
    table = fit_density(raw[8], 4)  # the largest side by default
    assert batches.density == table
    both = Batches(replace(data, density_sides=(4, 8)), seed=1).density
    assert both == fit_density(np.concatenate([raw[4].reshape(-1, 2), raw[8].reshape(-1, 2)]), 4)
    with pytest.raises(ValueError, match=r"density_sides \[16\] must be among"):
        Batches(replace(data, density_sides=(16,)), seed=1)
    for k, pts in raw.items():
        got = np.sort(decode(batches.pools[k]), axis=1)
        want = np.sort(unwarp(pts, table), axis=1)
        np.testing.assert_allclose(got, want, atol=1e-6)
    with pytest.raises(ValueError, match="density_bins needs a pool at every size"):
        Batches(replace(data, pool_sizes=(6, 0)), seed=1)
    smooth = Batches(replace(data, density_fit="legendre", density_max_degree=3), seed=1)
    # the degree is cross-validated across the pooled sizes, the fit uses density_sides
    assert smooth.density == fit_density_legendre(raw[8], 4, max_degree=3,
                                                  sizes=[raw[4], raw[8]])[0]
    positive = Batches(replace(data, density_fit="log_legendre", density_max_degree=2), seed=1)
    assert positive.density == fit_density_log_legendre(raw[8], 4, max_degree=2,
                                                        sizes=[raw[4], raw[8]])[0]
    with pytest.raises(ValueError, match="density_fit must be one of"):
        replace(data, density_fit="kde")


def test_mirrored_pools_hold_each_set_and_its_mirror(monkeypatch, tmp_path):
    from tests.conftest import tiny_config
    from trainer.data import Batches, make_pool
    from diffsampler_rt.grid import decode

    monkeypatch.setenv("DIFFSAMPLER_CACHE", str(tmp_path))
    cfg = tiny_config(sampler="rank1", embedding="ot")
    data = replace(cfg.data, pool_sizes=(6, 3), density_bins=4, mirror_diagonal=True)
    batches = Batches(data, seed=1)
    raw = {k: decode(make_pool("rank1", "ot", k, p, 1)) for k, p in zip((4, 8), (6, 3))}
    both = {k: np.concatenate([p, p[..., ::-1]]) for k, p in raw.items()}
    table = fit_density(both[8], 4)  # fitted to the sets and their mirrors
    assert batches.density == table
    for k, pts in both.items():
        assert len(batches.pools[k]) == 2 * len(raw[k])
        got = np.sort(decode(batches.pools[k]), axis=1)
        np.testing.assert_allclose(got, np.sort(unwarp(pts, table), axis=1), atol=1e-6)
    with pytest.raises(ValueError, match="mirror_diagonal needs density_bins"):
        replace(data, density_bins=0)


def test_density_goes_from_training_to_the_card(monkeypatch, tmp_path, capsys):
    from tests.conftest import tiny_config
    from export.onnx_export import export_checkpoint
    from trainer.data import Batches
    from trainer.train import Trainer

    monkeypatch.setenv("DIFFSAMPLER_CACHE", str(tmp_path / "cache"))
    cfg = tiny_config(sampler="rank1", embedding="ot")
    cfg = replace(cfg, steps=2, data=replace(cfg.data, pool_sizes=(4, 2), density_bins=3))
    tr = Trainer(cfg, tmp_path / "run", progress=False)
    ckpt = tr.run()
    out, _ = export_checkpoint(ckpt, tmp_path / "m.onnx", parity_sides=None)
    m = diffsampler_rt.Model(out)
    assert m.card["density"] == tr.batches.density
    assert m.card["density_floor"] == cfg.data.density_floor == FLOOR
    # re-tabulating with another floor gives the table a fit with that floor makes
    from export.__main__ import main as export_main
    assert export_main(["density-floor", str(out), "--floor", "1e-3"]) == 0
    card = diffsampler_rt.Model(out).card
    refit = Batches(replace(cfg.data, density_floor=1e-3), seed=cfg.seed).density
    for key in ("x_cdf", "y_cdf"):
        np.testing.assert_allclose(card["density"][key], refit[key], rtol=0, atol=1e-12)
    assert card["density_floor"] == 1e-3 and "re-floored from 1e-06 to 0.001" in card["provenance"]
    pts = m.generate(16, 2, seed=0)
    assert pts.shape == (2, 16, 2) and np.all((pts >= 0) & (pts < 1))
    from trainer.__main__ import main
    assert main(["optimise", str(ckpt), "16", "--iterations", "1", "-o",
                 str(tmp_path / "o.npy")]) == 2
    assert "non-uniform model" in capsys.readouterr().err
    shutil.rmtree(tmp_path / "cache")


def test_cli_info_summarises_the_table(tiny_onnx, tmp_path, capsys):
    from diffsampler_rt.cli import main
    path = _with_card(tiny_onnx, tmp_path / "d.onnx", density=random_table(5))
    assert main(["info", str(path)]) == 0
    assert '"density": "5 x 5 table (--full prints it)"' in capsys.readouterr().out
    assert main(["info", str(path), "--full"]) == 0
    assert '"x_cdf"' in capsys.readouterr().out


def test_bundled_density_models_follow_their_density_at_an_unseen_size():
    from benchmarks.fidelity import chi2_density  # the fidelity report's density check
    from trainer.samplers.densities import UNWARP
    for name in ("sot_ramp", "gbn_blob"):
        m = diffsampler_rt.load(name)
        assert "density" in m.card
        u = UNWARP[m.card["sampler"]](m.generate(4096, seed=0))  # the exact map to the square
        chi2 = float(chi2_density(u[None])[0])
        # a set that follows the density has chi-square ~63 or less (blue noise: less); the
        # models trained on the raw sets had 492 (sot_ramp) and 2171 (gbn_blob) here
        assert chi2 < 100, (name, chi2)


def test_mean_density_shows_a_bias_every_set_shares():
    from benchmarks.fidelity import density_bias, mean_density
    rng = np.random.default_rng(0)
    c = (np.arange(16) + 0.5) / 16
    grid = np.stack(np.meshgrid(c, c), -1).reshape(-1, 2)  # 4 points in each of 8 x 8 cells
    jitter = (grid[None] + rng.uniform(-0.5, 0.5, (50, 256, 2)) / 16) % 1
    assert np.array_equal(mean_density(jitter), np.ones(64))
    # every set squeezed towards x = 0 by the same map: a bias no single set's spread shows
    biased = jitter.copy()
    biased[..., 0] **= 1.1
    d = density_bias(biased, jitter, jitter[::-1])
    assert d["floor"] == 0 and d["ref"] == 0 and len(d["ref_cells"]) == 64
    assert d["diff"] == d["gen"] > 0.05
