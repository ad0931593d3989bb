"""Owen-scrambled Sobol' nets imposed on k x k sets, and their sequence order
(diffsampler_rt.sobol_orbit; the card pipeline's dyadic_net "prefix")."""
import copy
import doctest
import shutil

import numpy as np
import pytest

import diffsampler_rt
from diffsampler_rt import sobol_orbit
from diffsampler_rt.finish.pipeline import find
from diffsampler_rt.sobol_orbit import _canonical, first_points, impose_sobol_orbit
from trainer.samplers.sobol_owen import sobol_digits
from trainer.stats import empty_elementary_fraction

from .test_structure import jittered


def reverse_bits(v: np.ndarray, bits: int) -> np.ndarray:
    return sum(((v >> b) & 1) << (bits - 1 - b) for b in range(bits))


@pytest.mark.parametrize("h", [1, 2, 3, 5])
def test_canonical_tables_are_the_unscrambled_sobol_net_with_its_order(h):
    k, m = 2 ** h, 2 * h
    digits = sobol_digits(k * k).astype(np.int64) >> (32 - m)  # point i's m-digit x and y
    x, y = digits[:, 0], digits[:, 1]
    col, u, row, v = x >> h, x & (k - 1), y >> h, y & (k - 1)
    u_of, v_of, reverse = _canonical(h)
    np.testing.assert_array_equal(u_of[col, row], u)
    np.testing.assert_array_equal(v_of[col, row], v)
    # the index the runtime gives a point is its place in the sequence
    np.testing.assert_array_equal(reverse[col] + reverse[u] * k, np.arange(k * k))
    np.testing.assert_array_equal(reverse, reverse_bits(np.arange(k), h))


@pytest.mark.parametrize("k", [2, 4, 16, 32])
def test_every_block_of_the_order_is_a_net_and_points_keep_their_cells(k):
    pts = jittered(k, 3)
    out, index = impose_sobol_orbit(pts, k, rng=7)
    assert out.shape == pts.shape and out.dtype == np.float64 and index.shape == pts.shape[:-1]
    assert np.all((out >= 0) & (out < 1))
    np.testing.assert_array_equal(np.floor(out * k), np.floor(pts * k))
    np.testing.assert_array_equal(np.sort(index, axis=-1),
                                  np.broadcast_to(np.arange(k * k), index.shape))
    m = 2 * (k.bit_length() - 1)
    for j in range(m + 1):  # points [a 2^j, (a+1) 2^j) of the sequence: a (0, j, 2)-net
        for a in range(min(3, 2 ** (m - j))):
            block = np.stack([p[(i >> j) == a] for p, i in zip(out, index)])
            assert np.all(empty_elementary_fraction(block) == 0), (j, a)


def test_first_points_are_the_sequence_prefix_and_runs_repeat():
    pts = jittered(8, 2, seed=1)
    out, index = impose_sobol_orbit(pts, 8, rng=3)
    again, same = impose_sobol_orbit(pts, 8, rng=3)
    np.testing.assert_array_equal(out, again)
    np.testing.assert_array_equal(index, same)
    first = first_points(out, index, 40)
    assert first.shape == (2, 40, 2)
    for s in range(2):
        np.testing.assert_array_equal(first[s], out[s][np.argsort(index[s])[:40]])
    # a single set (no batch axis) is imposed as in a batch
    one, one_index = impose_sobol_orbit(pts[0], 8, rng=np.random.default_rng(3).spawn(1)[0])
    assert one.shape == (64, 2) and one_index.shape == (64,)


@pytest.mark.parametrize("call, message", [
    (lambda: impose_sobol_orbit(jittered(6, 1), 6), r"power-of-two grid side, got k=6"),
    (lambda: impose_sobol_orbit(jittered(8, 1)[:, ::-1], 8), "one per grid cell"),
    (lambda: first_points(jittered(4, 1), np.zeros((1, 16)), 17), r"n must be in \[1, 16\]"),
    (lambda: first_points(jittered(4, 1), np.zeros((1, 15)), 3), r"index must have shape"),
])
def test_bad_arguments_are_refused(call, message):
    with pytest.raises(ValueError, match=message):
        call()


def test_card_prefix_makes_sequence_prefixes_at_other_sizes(tiny_onnx, tmp_path):
    from export.pipeline_edit import edit_pipeline
    path = tmp_path / "m.onnx"
    shutil.copy(tiny_onnx, path)
    base = diffsampler_rt.Model(path).card["pipeline"]  # the export's: thinning only
    edit_pipeline(path, add="dyadic_net", at=0)  # where the sobol_owen models have it
    plain = diffsampler_rt.Model(path)
    card = edit_pipeline(path, update="dyadic_net", params={"prefix": True})
    assert card["pipeline"] == [{"step": "dyadic_net", "prefix": True}, *base]
    m = diffsampler_rt.Model(path)
    # at n = 4^h nothing changes: the dyadic_net imposition
    np.testing.assert_array_equal(m.generate(64, 2, seed=4), plain.generate(64, 2, seed=4))
    sets = m.generate(40, 3, seed=4)  # the first 40 of a 64-point net: 32 + 8
    assert sets.shape == (3, 40, 2) and np.all((sets >= 0) & (sets < 1))
    assert np.all(empty_elementary_fraction(sets[:, :32]) == 0)
    assert np.all(empty_elementary_fraction(sets[:, 32:]) == 0)
    assert np.any(empty_elementary_fraction(plain.generate(32, 3, seed=4)) > 0)
    np.testing.assert_array_equal(np.concatenate(list(m.iter_sets(40, 3, batch=2, seed=4))),
                                  sets)
    # without the structure: the network's own thinned set, as before
    np.testing.assert_array_equal(m.generate(40, 2, seed=4, structure=False),
                                  plain.generate(40, 2, seed=4, structure=False))
    card = edit_pipeline(path, update="dyadic_net", params={"prefix": None})
    assert "prefix" not in card["pipeline"][0]
    np.testing.assert_array_equal(diffsampler_rt.Model(path).generate(40, 2, seed=4),
                                  plain.generate(40, 2, seed=4))


@pytest.mark.parametrize("change, message", [
    ({"prefix": "yes"}, "step 'dyadic_net': 'prefix' must be true or false, got 'yes'"),
    # a prefix is dyadic_net's alone: another structure, or no structure step at all
    ({"step": "n_rooks", "prefix": True}, "step 'n_rooks' has no parameter 'prefix'"),
    ({"step": "thin", "prefix": True}, "step 'thin' has no parameter 'prefix'"),
])
def test_card_prefix_is_validated(change, message):
    from .conftest import pipeline_card_error
    pipe = copy.deepcopy(diffsampler_rt.load("sobol_owen").card["pipeline"])
    i = next(i for i, e in enumerate(pipe) if e["step"] == "dyadic_net")
    pipe[i].update(change)
    assert f"pipeline entry {i}: " in pipeline_card_error("sobol_owen", pipe, message)


def test_bundled_sobol_models_make_sequence_prefixes():
    for name in ("sobol_owen", "sobol_owen_fast"):
        assert find(diffsampler_rt.load(name).card["pipeline"], "dyadic_net")["prefix"] is True
    sets = diffsampler_rt.load("sobol_owen_fast").generate(576, 2, seed=0)
    assert np.all(empty_elementary_fraction(sets[:, :512]) == 0)  # 512 + 64, as Sobol's
    assert np.all(empty_elementary_fraction(sets[:, 512:]) == 0)


def test_docstring_examples():
    assert doctest.testmod(sobol_orbit).failed == 0
