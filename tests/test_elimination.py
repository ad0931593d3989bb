"""Sets of any size: weighted sample elimination from the next square (diffsampler_rt.elimination)."""
import doctest
import shutil

import numpy as np
import pytest

import diffsampler_rt
from diffsampler_rt import elimination
from diffsampler_rt.elimination import eliminate, hexagonal_spacing
from diffsampler_rt.finish.base import value
from diffsampler_rt.finish.pipeline import find
from diffsampler_rt.spectrum import periodogram
from trainer.stats import min_distance


def brute_kept(p: np.ndarray, n: int, torus: bool) -> np.ndarray:
    """Weighted sample elimination written out with the full distance matrix."""
    d = p[:, None] - p[None]
    if torus:
        d -= np.round(d)
    dist = np.sqrt((d ** 2).sum(-1))
    reach = 2 * hexagonal_spacing(n)
    w = np.where(dist < reach, (1 - np.minimum(dist, reach) / reach) ** 8, 0.0)
    np.fill_diagonal(w, 0.0)
    keep = np.ones(len(p), dtype=bool)
    for _ in range(len(p) - n):
        weight = np.where(keep, (w * keep[None, :]).sum(1), -np.inf)
        keep[np.argmax(weight)] = False
    return keep


@pytest.mark.parametrize("m,n,torus", [(64, 50, False), (64, 50, True), (225, 200, False),
                                       (100, 17, True), (36, 35, False)])
def test_matches_the_algorithm_written_out(m, n, torus):
    p = np.random.default_rng(m + n).random((m, 2))
    kept = eliminate(p, n, torus=torus)
    np.testing.assert_array_equal(kept, p[brute_kept(p, n, torus)])


def test_shapes_order_batches_and_the_closest_pairs_going():
    rng = np.random.default_rng(3)
    sets = rng.random((3, 256, 2))
    out = eliminate(sets, 230)
    assert out.shape == (3, 230, 2)
    for s, o in zip(sets, out):  # a subsequence of the input, each set on its own
        np.testing.assert_array_equal(o, eliminate(s, 230))
        pos = [int(np.flatnonzero((s == q).all(1))[0]) for q in o]
        assert pos == sorted(pos)
    # white noise thinned by 10 %: the crowded points go, the smallest distance grows
    assert (min_distance(out) > 1.5 * min_distance(sets)).all()
    same = eliminate(sets, 256)
    np.testing.assert_array_equal(same, sets)
    assert same is not sets


def test_the_crowded_points_go_not_those_of_an_even_set():
    # a 16 x 16 grid and 4 extra points, each crowding a grid point: each removed point is
    # an extra or a grid point next to one, and no close pair is left
    g = (np.stack(np.meshgrid(np.arange(16), np.arange(16)), -1).reshape(-1, 2) + 0.5) / 16
    extra = np.array([[0.2, 0.2], [0.7, 0.3], [0.4, 0.8], [0.9, 0.9]])
    both = np.concatenate([g, extra])
    kept = eliminate(both, 256)
    gone = [q for q in both if not (kept == q).all(1).any()]
    assert len(gone) == 4
    assert all(np.linalg.norm(extra - q, axis=1).min() < 1 / 16 for q in gone)
    assert min_distance(kept) > 0.7 / 16 > 2 * min_distance(both)


@pytest.mark.parametrize("args,match", [
    ((np.zeros((10, 2)), 11), r"n must be an integer in \[1, 10\].*got 11"),
    ((np.zeros((10, 2)), 0), "got 0"),
    ((np.zeros((10, 2)), 5.0), "got 5.0"),
    ((np.zeros((10, 3)), 5), "shape"),
])
def test_bad_arguments(args, match):
    with pytest.raises(ValueError, match=match):
        eliminate(*args)


@pytest.mark.parametrize("model", ["gbn_fast", "poisson_disk_torus_fast", "sot_fast",
                                   "sobol_owen_fast", "rank1", "sot_ramp_fast"])
@pytest.mark.parametrize("n", [17, 150])
def test_any_n_gives_exactly_n_points_and_is_reproducible(model, n):
    m = diffsampler_rt.load(model)
    sets = m.generate(n, 3, seed=5)
    assert sets.shape == (3, n, 2) and np.isfinite(sets).all()
    assert ((sets >= 0) & (sets < 1)).all()
    np.testing.assert_array_equal(sets[1], m.generate(n, 2, seed=5)[1])  # batching
    one = m.generate(n, seed=7)
    assert one.shape == (n, 2)
    blocks = np.concatenate(list(m.iter_sets(n, 3, batch=2, seed=5)))
    np.testing.assert_array_equal(blocks, sets)


def test_blue_noise_keeps_its_spacing_at_any_n():
    # the card's spacing radius at n = 1000 holds, as at the square sizes
    m = diffsampler_rt.load("poisson_disk_fast")
    sets = m.generate(1000, 4, seed=2)
    spacing = find(m.card["pipeline"], "min_spacing")
    assert find(m.card["pipeline"], "thin")["drop"] == "crowded"
    c = value(spacing, "c", 1000)
    assert (min_distance(sets) >= 0.99 * c / np.sqrt(1000)).all()


def test_docstring_examples():
    assert doctest.testmod(elimination).failed == 0


def test_lattice_models_give_a_lattice_of_n_points_at_any_n():
    # one lattice per n: the thinned set is replaced by its nearest rank-1 lattice of n points
    from diffsampler_rt.lattice import fit_rank1_lattice, rank1_lattice
    for model in ("rank1", "lattice"):
        sets = diffsampler_rt.load(model).generate(50, 2, seed=3)
        g, shift, _ = fit_rank1_lattice(sets)
        for s, gi, si in zip(sets, g, shift):
            exact = rank1_lattice(50, int(gi), si)
            np.testing.assert_allclose(np.sort(s, axis=0), np.sort(exact, axis=0), atol=1e-9)
        # without the structure: the thinned net's set, not a lattice
        raw = diffsampler_rt.load(model).generate(50, seed=3, structure=False)
        assert len(np.unique(np.round(raw[:, 0] * 50, 6) % 1)) > 1


def low_power(p: np.ndarray, cut: float = 0.25) -> float:
    """Mean |sum_j exp(-2 pi i f . x_j)|^2 / n over integer 0 < |f| < cut sqrt(n)."""
    fc = cut * np.sqrt(len(p))
    f = np.arange(-int(fc), int(fc) + 1)
    r2 = f[:, None] ** 2 + f[None, :] ** 2
    return float(periodogram(p, int(fc))[(r2 > 0) & (r2 < fc * fc)].mean())


@pytest.mark.parametrize("torus", [False, True])
def test_thinning_holes_are_evened_out_at_large_scales(torus):
    # a jittered 32 x 32 grid is even at large scales; 24 points removed leave holes whose
    # low-frequency power the restore takes out again, with small moves
    rng = np.random.default_rng(4)
    g = (np.stack(np.meshgrid(np.arange(32), np.arange(32)), -1).reshape(-1, 2) + 0.5) / 32
    full = g + rng.uniform(-0.05, 0.05, g.shape) / 32
    kept = eliminate(full, 1000, torus=torus)
    moved = elimination.restore_low_frequencies(kept, full, torus=torus)
    assert moved.shape == (1000, 2) and ((moved >= 0) & (moved < 1)).all()
    assert low_power(kept) > 10 * low_power(full)
    assert low_power(moved) < 0.15 * low_power(kept)
    step = moved - kept
    if torus:
        step -= np.round(step)
    assert np.abs(step).max() < 0.5 / 32  # under half a spacing
    # nothing to restore when nothing was removed: thin is then the identity
    np.testing.assert_array_equal(elimination.thin(full, 1024, torus=torus), full)


def test_a_higher_restore_cut_takes_out_the_holes_power_up_to_it():
    # the default cut restores only the largest scales; a card's cut of 1 (GBN's models) also
    # takes out the holes' power above that (here below 0.5 sqrt(n): 1 sits on this set's
    # spectral peak), where an even set has little
    rng = np.random.default_rng(6)
    g = (np.stack(np.meshgrid(np.arange(15), np.arange(15)), -1).reshape(-1, 2) + 0.5) / 15
    full = g + rng.uniform(-0.1, 0.1, g.shape) / 15
    kept = eliminate(full, 200)
    low = elimination.thin(full, 200)
    high = elimination.thin(full, 200, cut=1.0)
    np.testing.assert_array_equal(high, elimination.restore_low_frequencies(kept, full, cut=1.0))
    np.testing.assert_array_equal(low, elimination.restore_low_frequencies(kept, full))
    assert low_power(high, 0.5) < 0.5 * low_power(low, 0.5)
    assert low_power(low, 0.5) < low_power(kept, 0.5)


def test_thinned_sets_keep_the_samplers_large_scale_character():
    # white noise keeps its white-noise power at large scales: the restore aims at the
    # full set's own density, not at an even one
    full = np.random.default_rng(5).random((1024, 2))
    moved = elimination.thin(full, 1000)
    assert 0.5 < low_power(moved) / low_power(full) < 2


def test_models_without_a_spacing_lose_points_at_random(tmp_path):
    # sobol_owen's sampler puts points close together: its thinned sets keep that (elimination
    # would take the closest pairs apart); the streams make it reproducible. (The bundled
    # card makes such sizes as Sobol' prefixes instead: its dyadic_net's prefix, taken off
    # here.)
    from export.pipeline_edit import edit_pipeline
    path = tmp_path / "owen.onnx"
    shutil.copy(diffsampler_rt.load("sobol_owen_fast").path, path)
    card = edit_pipeline(path, update="dyadic_net", params={"prefix": None})
    assert "prefix" not in find(card["pipeline"], "dyadic_net")
    assert find(card["pipeline"], "thin")["drop"] == "random"
    m = diffsampler_rt.Model(path)
    sets = m.generate(1000, 4, seed=1)
    full = m.generate(1024, 4, seed=1)
    assert abs(min_distance(sets).mean() / min_distance(full).mean() - 1) < 0.3
    assert min_distance(eliminate(full, 1000)).mean() > 2 * min_distance(sets).mean()
    np.testing.assert_array_equal(sets, m.generate(1000, 4, seed=1))
    rngs = [np.random.default_rng(i) for i in range(2)]
    with pytest.raises(ValueError, match="one generator per set"):
        elimination.thin(full, 1000, rngs=rngs)
    with pytest.raises(ValueError, match="got 2000"):
        elimination.thin(full[:2], 2000, rngs=rngs)
    with pytest.raises(ValueError, match="got 500.0"):
        elimination.thin(full[:2], 500.0, rngs=rngs)
