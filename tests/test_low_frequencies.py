"""Smooth moves that set a point set's large scales (diffsampler_rt.low_frequencies)."""
import copy
import doctest
import json

import numpy as np
import pytest

import diffsampler_rt

from .conftest import pipeline_refused
from diffsampler_rt import ModelFormatError, low_frequencies
from diffsampler_rt.finish.pipeline import find
from diffsampler_rt.low_frequencies import even_out, gain_at, settings_problem
from tests.test_elimination import low_power


@pytest.mark.parametrize("torus", [False, True])
def test_even_out_shrinks_the_large_scale_deviations_by_its_gain(torus):
    # white noise: the power below the cut goes down by about (1 - gain)^2 (first order)
    pts = np.random.default_rng(0).random((4, 1024, 2))
    before = np.mean([low_power(p, 0.5) for p in pts])
    for gain in (0.3, -0.3):
        out = even_out(pts, gain, cut=0.5, torus=torus)
        assert out.shape == pts.shape and ((out >= 0) & (out < 1)).all()
        ratio = np.mean([low_power(p, 0.5) for p in out]) / before
        assert abs(ratio - (1 - gain) ** 2) < 0.15, (gain, ratio)
    assert even_out(pts, 0.0, cut=0.5, torus=torus) is pts


def test_card_gain_table_and_validation():
    spec = {"cut": 1.0, "n": [64, 256, 1024], "gain": [0, 0.1, 0]}
    assert settings_problem(spec) is None
    assert [gain_at(spec, n) for n in (16, 64, 256, 1024, 4096)] == [0, 0, 0.1, 0, 0]
    assert gain_at({"cut": 1.0, "gain": 0.2}, 100) == 0.2
    for bad, match in (({"cut": 1.0}, "must be"), ({"cut": 3, "gain": 0.1}, "cut must be"),
                       ({"cut": 1, "gain": 0.95}, "gain must be"),
                       ({"cut": 1, "gain": True}, "gain must be"),
                       ({"cut": 1, "n": [256, 64], "gain": [0, 0]}, "strictly increasing")):
        assert match in settings_problem(bad)
    assert "none" == low_frequencies.describe(None)
    assert low_frequencies.describe(spec) == ("gain 0 / 0.1 / 0 at n = 64 / 256 / 1024 "
                                              "(log-linear) below 1 sqrt(n)")


def test_card_cut_per_size():
    from diffsampler_rt.per_size import cut_at
    spec = {"cut": [1.0, 1.0, 0.5], "n": [256, 1024, 4096], "gain": [0.1, 0, -0.2]}
    assert settings_problem(spec) is None
    assert [cut_at(spec, n) for n in (64, 1024, 2048, 4096, 16384)] == pytest.approx(
        [1, 1, 0.75, 0.5, 0.5])  # log-linear between the sizes, the end values beyond
    assert cut_at({"cut": 0.5, "gain": 0.1}, 64) == 0.5
    assert low_frequencies.describe(spec) == (
        "gain 0.1 / 0 / -0.2 at n = 256 / 1024 / 4096 (log-linear) below 1 / 1 / 0.5 sqrt(n) "
        "at those sizes")
    for bad, match in (({**spec, "cut": [1.0, 0.5]}, "one value per size"),
                       ({**spec, "cut": [1.0, 1.0, 2.5]}, "cut must be"),
                       ({"cut": [1.0], "gain": 0.1}, "cut must be")):  # a list needs "n"
        assert match in settings_problem(bad)


def _entry(path, step: str) -> dict:
    return find(diffsampler_rt.load(path).card["pipeline"], step)


def _with_entry(card: dict, step: str, **change) -> dict:
    """``card`` (a copy) with its ``step`` entry changed."""
    card = copy.deepcopy(card)
    next(e for e in card["pipeline"] if e["step"] == step).update(change)
    return card


def test_card_even_out_is_applied_validated_and_set_by_the_cli(bundled_copy, capsys):
    from export.__main__ import main as export_main
    src = diffsampler_rt.model.resolve("gbn_fast")
    path = bundled_copy("gbn_fast")
    assert export_main(["pipeline", str(path), "--remove", "even_out"]) == 0
    assert _entry(path, "even_out") is None
    plain = diffsampler_rt.generate(path, 256, 2, seed=4)
    capsys.readouterr()
    assert export_main(["pipeline", str(path), "--add", "even_out", "--at", "1", "--gain", "0.3",
                        "--cut", "0.5"]) == 0
    assert ("1. even_out: large scales evened, gain 0.3 below 0.5 sqrt(n)"
            in capsys.readouterr().out)
    card = diffsampler_rt.load(path).card
    assert card["pipeline"][1] == {"step": "even_out", "cut": 0.5, "gain": 0.3}
    evened = diffsampler_rt.generate(path, 256, 2, seed=4)
    assert not np.array_equal(evened, plain)
    assert np.mean([low_power(p, 0.5) for p in evened]) < np.mean([low_power(p, 0.5)
                                                                    for p in plain])
    # structure=False leaves it out
    np.testing.assert_array_equal(diffsampler_rt.generate(path, 256, 2, seed=4, structure=False),
                                  diffsampler_rt.generate(src, 256, 2, seed=4, structure=False))
    pipeline_refused(path, ["--add", "even_out", "--cut", "0.5"], capsys, "step 'even_out' needs 'gain'")
    # a cut per size: the model uses the cut at its n
    assert export_main(["pipeline", str(path), "--update", "even_out", "--gain", "64:0,1024:0.3",
                        "--cut", "64:1,1024:0.5"]) == 0
    assert _entry(path, "even_out") == {"cut": {"n": [64, 1024], "values": [1.0, 0.5]},
                                        "gain": {"n": [64, 1024], "values": [0.0, 0.3]}}
    per_size = diffsampler_rt.generate(path, 1024, 1, seed=4)
    assert export_main(["pipeline", str(path), "--update", "even_out", "--gain", "0.3",
                        "--cut", "0.5"]) == 0
    np.testing.assert_array_equal(per_size, diffsampler_rt.generate(path, 1024, 1, seed=4))
    pipeline_refused(path, ["--update", "even_out", "--cut", "0.5:x"], capsys,
             "step 'even_out': 'cut' must be", "0.5:x")
    pipeline_refused(path, ["--update", "even_out", "--cut", "64:1,1024:3"], capsys,
             "step 'even_out': 'cut' values must each be a number in (0, 2], got 3")
    pipeline_refused(path, ["--update", "even_out", "--gain", "2"], capsys,
             "step 'even_out': 'gain' must be a number in [-0.9, 0.9]")
    assert _entry(path, "even_out") == {"cut": 0.5, "gain": 0.3}  # left as it was
    from diffsampler_rt.card import CARD_KEY, parse_card
    bad = _with_entry(card, "even_out", gain="x")
    with pytest.raises(ModelFormatError, match="pipeline entry 1: step 'even_out': 'gain' must be"):
        parse_card({CARD_KEY: json.dumps(bad)}, "m.onnx")


def test_card_restore_cut_is_applied_validated_and_set_by_the_cli(bundled_copy, capsys):
    from export.__main__ import main as export_main
    path = bundled_copy("gbn_fast")
    capsys.readouterr()
    assert export_main(["pipeline", str(path), "--update", "thin", "--restore-cut", "none"]) == 0
    assert ("thin: thinned to n (crowded points first), large scales restored below 0.25 "
            "sqrt(n)") in capsys.readouterr().out
    assert "restore_cut" not in _entry(path, "thin")
    plain = diffsampler_rt.generate(path, 200, 4, seed=3)
    square = diffsampler_rt.generate(path, 256, 1, seed=3)
    unstructured = diffsampler_rt.generate(path, 200, 2, seed=3, structure=False)
    assert export_main(["pipeline", str(path), "--update", "thin", "--restore-cut", "1"]) == 0
    assert "large scales restored below 1 sqrt(n)" in capsys.readouterr().out
    assert _entry(path, "thin")["restore_cut"] == 1.0
    restored = diffsampler_rt.generate(path, 200, 4, seed=3)
    assert restored.shape == (4, 200, 2) and ((restored >= 0) & (restored < 1)).all()
    assert not np.array_equal(restored, plain)
    # more of the holes' power below the blue-noise peak goes
    assert (np.mean([low_power(p, 0.5) for p in restored])
            < 0.5 * np.mean([low_power(p, 0.5) for p in plain]))
    # square sizes are not thinned: unchanged; structure=False thins with the default cut
    np.testing.assert_array_equal(diffsampler_rt.generate(path, 256, 1, seed=3), square)
    np.testing.assert_array_equal(diffsampler_rt.generate(path, 200, 2, seed=3, structure=False),
                                  unstructured)
    for bad in ("0", "2.5", "nan", "x"):
        pipeline_refused(path, ["--update", "thin", "--restore-cut", bad], capsys,
                 "step 'thin': 'restore_cut' must be a number in (0, 2]", bad)
    assert _entry(path, "thin")["restore_cut"] == 1.0  # left as it was
    from diffsampler_rt.card import CARD_KEY, parse_card
    card = diffsampler_rt.load(path).card
    for bad in (True, "1", 0, -1.0, 3.0):
        with pytest.raises(ModelFormatError,
                           match="step 'thin': 'restore_cut' must be a number in"):
            parse_card({CARD_KEY: json.dumps(_with_entry(card, "thin", restore_cut=bad))},
                       "m.onnx")


def test_docstring_examples():
    assert doctest.testmod(low_frequencies).failed == 0


def test_grid_side_is_the_smallest_5_smooth_side_beyond_the_cut():
    def smooth(m):
        for p in (2, 3, 5):
            while m % p == 0:
                m //= p
        return m == 1

    for fc in (0.5, 1, 7.3, 16, 32, 64, 100.2, 512):
        m = low_frequencies._grid_side(fc)
        least = max(16, 4 * fc + 8)
        assert m >= least and smooth(m)
        assert not any(smooth(j) for j in range(int(np.ceil(least)), m)), (fc, m)
    assert low_frequencies._grid_side(32) == 144  # n = 1024, cut 0.5, mirrored (was 256)
