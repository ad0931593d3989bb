"""Training pools: determinism, prefix reuse, toroidal-shift augmentation."""
import numpy as np
import pytest

from diffsampler_rt.grid import decode
from trainer.data import Batches, make_pool
from trainer.samplers import TOROIDAL

from .conftest import tiny_config


@pytest.fixture
def cache(tmp_path, monkeypatch):
    monkeypatch.setenv("DIFFSAMPLER_CACHE", str(tmp_path))
    return tmp_path


def test_pool_is_cached_and_a_smaller_pool_is_its_prefix(cache):
    big = make_pool("rank1", "ot", 4, 5, seed=3)
    assert big.shape == (5, 2, 4, 4) and big.dtype == np.float32
    assert len(list(cache.glob("*.npy"))) == 1
    small = make_pool("rank1", "ot", 4, 3, seed=3)
    np.testing.assert_array_equal(small, big[:3])
    assert len(list(cache.glob("*.npy"))) == 1  # served from the larger file
    for path in cache.glob("*.npy"):
        path.unlink()
    np.testing.assert_array_equal(make_pool("rank1", "ot", 4, 3, seed=3), small)  # regenerated
    assert not np.array_equal(make_pool("rank1", "ot", 4, 3, seed=4), small)


def test_a_slow_samplers_cached_pool_is_extended_to_the_pool_drawn_whole(cache):
    small = make_pool("gbn", "ot", 4, 2, seed=5)
    grown = make_pool("gbn", "ot", 4, 5, seed=5)  # draws sets 2-4 only
    np.testing.assert_array_equal(grown[:2], small)
    assert len(list(cache.glob("*.npy"))) == 2
    for path in cache.glob("*.npy"):
        path.unlink()
    np.testing.assert_array_equal(make_pool("gbn", "ot", 4, 5, seed=5), grown)


def _is_translate(a: np.ndarray, b: np.ndarray) -> bool:
    """Whether b = a + v (mod 1) as point sets for some vector v."""
    for j in range(len(a)):
        moved = (a + (b[0] - a[j])) % 1.0
        d = np.abs(moved[:, None, :] - b[None, :, :])
        if np.all(np.minimum(d, 1 - d).max(-1).min(axis=1) < 1e-5):
            return True
    return False


def test_shifted_copies_are_translations_of_their_set(cache):
    pool = make_pool("poisson_disk", "ot", 4, 2, seed=0, shifts=3).astype(np.float64)
    assert pool.shape == (6, 2, 4, 4)
    sets = decode(pool).reshape(2, 3, 16, 2)
    for s in sets:
        for copy in s[1:]:
            assert _is_translate(s[0], copy)
            assert not np.allclose(copy, s[0])
    assert not _is_translate(sets[0][0], sets[1][0])


def test_pool_does_not_depend_on_the_workers(tmp_path, monkeypatch):
    monkeypatch.setenv("DIFFSAMPLER_CACHE", str(tmp_path / "a"))
    one = make_pool("gbn", "ot", 4, 3, seed=2, shifts=2)
    monkeypatch.setenv("DIFFSAMPLER_CACHE", str(tmp_path / "b"))
    np.testing.assert_array_equal(make_pool("gbn", "ot", 4, 3, seed=2, shifts=2, workers=2), one)


def test_shifts_refused_for_samplers_that_are_not_toroidal(cache):
    assert "sot" not in TOROIDAL and "gbn" in TOROIDAL
    with pytest.raises(ValueError, match="not translation invariant"):
        make_pool("sot", "ot", 4, 2, seed=0, shifts=2)


def test_batches_scale_and_shapes(cache):
    from dataclasses import replace
    cfg = replace(tiny_config().data, pool_sizes=(3, 0), symmetries=(0, 1, 2, 3))
    draw = Batches(cfg, seed=0).draw(np.random.default_rng(0))
    assert [b.shape for b in draw] == [(4, 2, 4, 4), (2, 2, 8, 8)]
    assert all(np.abs(b).max() <= cfg.offset_scale * 0.5 + 1e-6 for b in draw)  # stratified
