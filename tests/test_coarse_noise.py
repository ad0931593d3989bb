"""The gain on the coarse scales of the solver's starting noise (diffsampler_rt.coarse_noise)."""
from __future__ import annotations

import doctest
import json
import shutil

import numpy as np
import pytest

import diffsampler_rt
from diffsampler_rt import ModelFormatError, coarse_noise
from diffsampler_rt.card import CARD_KEY, parse_card
from diffsampler_rt.coarse_noise import coarse_filter, gain_at, settings_problem, shape_noise
from diffsampler_rt.spectrum import radial_spectrum
from export.__main__ import main as export_main

from .conftest import changed_pipeline_error, pipeline_refused


def test_only_the_coarse_modes_are_scaled():
    x = np.random.default_rng(0).standard_normal((3, 2, 32, 32))
    y = shape_noise(x, 1.5, 0.25)
    X, Y = np.fft.rfft2(x), np.fft.rfft2(y)
    f = np.fft.fftfreq(32) * 32
    r = np.hypot(f[:, None], (np.fft.rfftfreq(32) * 32)[None, :])
    coarse = (r > 0) & (r <= 4)  # 0.25 x the Nyquist frequency of 16 cycles
    np.testing.assert_allclose(Y[..., coarse], 1.5 * X[..., coarse], atol=1e-10)
    np.testing.assert_allclose(Y[..., ~coarse], X[..., ~coarse], atol=1e-10)
    np.testing.assert_allclose(y.mean(axis=(-2, -1)), x.mean(axis=(-2, -1)), atol=1e-12)
    assert np.isrealobj(y) and y.shape == x.shape
    assert shape_noise(x, 1.0, 0.25) is x  # bit for bit where a table passes through 1
    # each set on its own: shaping a batch is shaping its sets one by one
    np.testing.assert_array_equal(shape_noise(x[1:2], 1.5, 0.25), y[1:2])
    # at k = 8 only |frequency| = 1: (0, 1), (1, 0) and (-1, 0) in the real FFT's half-plane
    assert coarse_filter(8, 2.0, 0.25).sum() == 8 * 5 + 3
    with pytest.raises(ValueError, match="square"):
        shape_noise(np.zeros((2, 8, 4)), 1.5, 0.25)


def test_per_size_gain():
    spec = {"cut": 0.25, "n": [64, 1024], "gain": [1.2, 1.6]}
    assert gain_at(spec, 16) == pytest.approx(1.2) and gain_at(spec, 4096) == pytest.approx(1.6)
    assert gain_at(spec, 256) == pytest.approx(1.4)  # log-linear between the listed sizes
    assert gain_at({"cut": 0.5, "gain": 1.3}, 576) == 1.3
    assert coarse_noise.describe(spec) == ("gain 1.2 / 1.6 at n = 64 / 1024 (log-linear) up to "
                                           "0.25 x Nyquist")
    assert coarse_noise.describe(None) == "none"


@pytest.mark.parametrize("spec, message", [
    (1.4, "must be {\"cut\""),
    ({"gain": 1.4}, "must be {\"cut\""),
    ({"cut": 0.25, "gain": 1.4, "step": 1}, "must be {\"cut\""),
    ({"cut": 0, "gain": 1.4}, "cut must be a number in (0, 1], got 0"),
    ({"cut": 1.5, "gain": 1.4}, "got 1.5"),
    ({"cut": 0.25, "gain": 0}, "gain must be numbers in (0, 4], got 0"),
    ({"cut": 0.25, "gain": 5.0}, "got 5.0"),
    ({"cut": 0.25, "gain": True}, "got True"),
    ({"cut": 0.25, "gain": float("nan")}, "got nan"),
    ({"cut": 0.25, "n": [256, 64], "gain": [1, 2]}, "same length"),
    ({"cut": 0.25, "n": [64, 256], "gain": [1]}, "same length"),
    ({"cut": 0.25, "n": [64, 256], "gain": [1, -1]}, "got [1, -1]"),
])
def test_settings_problem(spec, message):
    assert message in settings_problem(spec)
    assert settings_problem({"cut": 0.25, "n": [64, 256], "gain": [1, 1.5]}) is None


_TABLE = "or a per-size table"


@pytest.mark.parametrize("params, message", [
    ({"cut": 0, "gain": 1.4}, "'cut' must be a number in (0, 1] " + _TABLE),
    ({"cut": 1.5, "gain": 1.4}, "got 1.5"),
    ({"cut": 0.25, "gain": 0}, "'gain' must be a number in (0, 4] " + _TABLE),
    ({"cut": 0.25, "gain": 5.0}, "got 5.0"),
    ({"cut": 0.25, "gain": True}, "got True"),
    ({"cut": 0.25, "gain": "1.4"}, "got '1.4'"),
    ({"cut": 0.25, "gain": float("nan")}, "got nan"),
    ({"gain": {"n": [256, 64], "values": [1, 2]}}, "'gain' table must be"),
    ({"gain": {"n": [64, 256], "values": [1]}}, "'gain' table must be"),
    ({"gain": {"n": [64, 256], "gain": [1, 1.5]}}, "'gain' table must be"),  # format 1's keys
    ({"gain": {"n": [64, 256], "values": [1, -1]}},
     "'gain' values must each be a number in (0, 4], got -1"),
    ({"gain": 1.4, "step_size": 1}, "has no parameter 'step_size'"),
])
def test_card_settings_are_validated(params, message):
    """A coarse_noise pipeline entry with a bad value is refused, the entry and the field
    named; a format-2 card with format 1's top-level field is refused too."""
    err = changed_pipeline_error("rank1", lambda pipe: pipe.insert(
        0, {"step": "coarse_noise", **params}), "pipeline entry 0")
    assert "step 'coarse_noise'" in err and message in err
    ok = {"step": "coarse_noise", "cut": 0.25, "gain": {"n": [64, 256], "values": [1, 1.5]}}
    card = {**diffsampler_rt.load("rank1").card}
    card["pipeline"] = [ok, *card["pipeline"]]
    assert parse_card({CARD_KEY: json.dumps(card)}, "m")["pipeline"][0] == ok
    old = {**diffsampler_rt.load("rank1").card, "coarse_noise": {"cut": 0.25, "gain": 1.4}}
    with pytest.raises(ModelFormatError, match="field 'coarse_noise' belongs to format 1"):
        parse_card({CARD_KEY: json.dumps(old)}, "m")


def _steps(model) -> list:
    return [e["step"] for e in model.card["pipeline"]]


def test_card_gain_is_applied(tmp_path, capsys):
    """``python -m export pipeline`` writes the coarse_noise entry; the runtime shapes the
    noise at the sizes where the gain is not 1, batches alike, and ``structure=False``
    starts from white noise."""
    path = tmp_path / "m.onnx"
    shutil.copy(diffsampler_rt.load("ldbn").path, path)
    assert export_main(["pipeline", str(path), "--remove", "coarse_noise"]) == 0
    assert "coarse_noise" not in capsys.readouterr().out
    assert "coarse_noise" not in _steps(diffsampler_rt.Model(path))
    unshaped = diffsampler_rt.Model(path).generate(256, 3, seed=2)
    unshaped64 = diffsampler_rt.Model(path).generate(64, 3, seed=2)
    plain = {n: diffsampler_rt.Model(path).generate(n, 3, seed=2, structure=False)
             for n in (64, 256)}
    assert export_main(["pipeline", str(path), "--add", "coarse_noise", "--at", "0",
                        "--gain", "64:1,256:1.5", "--cut", "0.5"]) == 0
    assert ("0. coarse_noise: starting noise: gain 1 / 1.5 at n = 64 / 256 (log-linear) up "
            "to 0.5 x Nyquist") in capsys.readouterr().out
    m = diffsampler_rt.Model(path)
    assert m.card["pipeline"][0] == {"step": "coarse_noise", "cut": 0.5,
                                     "gain": {"n": [64, 256], "values": [1.0, 1.5]}}
    np.testing.assert_array_equal(m.generate(64, 3, seed=2), unshaped64)  # gain 1 at 64
    np.testing.assert_array_equal(m.generate(64, 3, seed=2, structure=False), plain[64])
    np.testing.assert_array_equal(m.generate(256, 3, seed=2, structure=False), plain[256])
    shaped = m.generate(256, 3, seed=2)
    assert np.all((shaped >= 0) & (shaped < 1)) and shaped.shape == (3, 256, 2)
    np.testing.assert_array_equal(np.concatenate(list(m.iter_sets(256, 3, batch=2, seed=2))),
                                  shaped)
    assert not np.allclose(shaped, unshaped)
    assert export_main(["pipeline", str(path), "--update", "coarse_noise", "--gain", "1.2"]) == 0
    assert diffsampler_rt.Model(path).card["pipeline"][0] == {"step": "coarse_noise",
                                                              "cut": 0.5, "gain": 1.2}
    for bad, err in ((["--cut", "0.5"], "parameters need --add, --update or --replace"),
                     (["--update", "coarse_noise", "--gain", "x"],
                      "step 'coarse_noise': 'gain' must be a number in (0, 4]"),
                     (["--update", "coarse_noise", "--gain", "9"], "got 9"),
                     (["--update", "coarse_noise", "--cut", "0"],
                      "step 'coarse_noise': 'cut' must be a number in (0, 1]"),
                     (["--update", "coarse_noise", "--c", "0.5"],
                      "step 'coarse_noise' has no parameter 'c'")):
        pipeline_refused(path, bad, capsys, err)
    assert export_main(["pipeline", str(path), "--remove", "coarse_noise"]) == 0
    assert "coarse_noise" not in _steps(diffsampler_rt.Model(path))


def _without_coarse_noise(m):
    m.card["pipeline"] = [e for e in m.card["pipeline"] if e["step"] != "coarse_noise"]


@pytest.mark.slow
def test_a_gain_above_one_adds_large_scale_variation():
    """The point of the knob: on the bundled ldbn net, a gain of 1.5 on the coarse quarter of
    the grid's frequencies (below 0.125 sqrt(n) in the radial spectrum's units) raises the
    sets' power there, where the net's sets are more even than the sampler's, and leaves the
    spectrum's peak about as it was."""
    m = diffsampler_rt.Model("ldbn")  # its own instance: the cached one is left alone
    _without_coarse_noise(m)  # the bundled card's own gain, measured below
    plain = m.generate(256, 24, seed=4)
    white = m.generate(256, 24, seed=4, structure=False)
    m.card["pipeline"].insert(0, {"step": "coarse_noise", "cut": 0.25, "gain": 1.5})
    f, p = radial_spectrum(plain)
    _, s = radial_spectrum(m.generate(256, 24, seed=4))
    low = (f > 0) & (f < 0.125)  # the bins below 0.125 sqrt(n)
    assert s[low].mean() > 1.5 * p[low].mean()
    peak = (f >= 0.75) & (f < 1.5)
    assert abs(s[peak].mean() / p[peak].mean() - 1) < 0.1
    np.testing.assert_array_equal(m.generate(256, 24, seed=4, structure=False), white)


def test_docstring_examples():
    assert doctest.testmod(coarse_noise).failed == 0


@pytest.mark.slow
def test_the_bundled_ldbn_gain_brings_its_integration_error_to_the_samplers():
    """Without its card's gain the ldbn net's sets integrate Gaussians ~20 % better than LDBN's
    at n = 256 (fidelity report: a miss of fidelity); with it, within a few percent."""
    from benchmarks.fidelity import integration_errors
    from trainer.samplers import sample
    ref = integration_errors(sample("ldbn", 256, count=128, seed=[7, 256]))["gauss_mse"].mean()
    m = diffsampler_rt.Model("ldbn")  # its own instance: the cached one is left alone
    shaped = integration_errors(m.generate(256, 128, seed=7))["gauss_mse"].mean()
    _without_coarse_noise(m)
    white = integration_errors(m.generate(256, 128, seed=7))["gauss_mse"].mean()
    assert white < 0.9 * ref
    assert abs(shaped / ref - 1) < 0.08


def test_a_temperature_scales_every_other_mode():
    x = np.random.default_rng(1).standard_normal((2, 2, 16, 16))
    y = shape_noise(x, 1.3, 0.25, rest=0.9)
    X, Y = np.fft.rfft2(x), np.fft.rfft2(y)
    coarse = coarse_filter(16, 2.0, 0.25) == 2.0
    np.testing.assert_allclose(Y[..., coarse], 1.3 * X[..., coarse], atol=1e-10)
    np.testing.assert_allclose(Y[..., ~coarse], 0.9 * X[..., ~coarse], atol=1e-10)  # mean too
    np.testing.assert_allclose(shape_noise(x, 0.9, 1.0, rest=0.9), 0.9 * x)  # one factor


def _structured_noise(pipe: list) -> dict:
    """ldbn_fast's coarse_noise entry that runs where its n-rooks structure holds."""
    return next(e for e in pipe if e["step"] == "coarse_noise" and e.get("where") == "structured")


@pytest.mark.parametrize("change, message", [
    ({"where": "structured"},
     "pipeline entry 0 ('coarse_noise') needs a structure step in the pipeline"),
    ({"temperature": 0},
     "pipeline entry 1: step 'coarse_noise': 'temperature' must be a number in (0, 2], got 0"),
    ({"temperature": "0.9"}, "got '0.9'"),
    ({"temperature": True}, "got True"),
    ({"where": "somewhere"}, "'where' must be one of ['structured', 'unstructured']"),
])
def test_structure_temperature_is_validated(change, message):
    """The temperature where the structure holds (format 1's structure_temperature): a
    coarse_noise entry with "where": "structured" needs a structure step, and its
    temperature a number in (0, 2]."""
    def edit(pipe):
        _structured_noise(pipe).update(change)
        if change.get("where") == "structured":  # the entry and thinning, no structure
            return [_structured_noise(pipe), {"step": "thin"}]
    assert message in changed_pipeline_error("ldbn_fast", edit, "pipeline entry")


def test_structure_temperature_applies_where_the_structure_is_imposed(tmp_path, capsys):
    """``python -m export pipeline`` writes it; the runtime starts the solver from cooler
    noise at the sizes where the card imposes its structure (ldbn_fast without its runs:
    power-of-two sides >= 16), only there and only with ``structure=True``; the structure
    cannot be removed while an entry runs only where it holds."""
    path = tmp_path / "m.onnx"
    shutil.copy(diffsampler_rt.load("ldbn_fast").path, path)
    i = diffsampler_rt.Model(path).card["pipeline"].index(
        _structured_noise(diffsampler_rt.Model(path).card["pipeline"]))
    assert export_main(["pipeline", str(path), "--update", str(i), "--temperature", "none"]) == 0
    assert export_main(["pipeline", str(path), "--update", "n_rooks", "--runs", "none"]) == 0
    before = {n: diffsampler_rt.Model(path).generate(n, 2, seed=3) for n in (64, 256, 576)}
    white = diffsampler_rt.Model(path).generate(256, 2, seed=3, structure=False)
    capsys.readouterr()
    assert export_main(["pipeline", str(path), "--update", str(i), "--temperature", "0.8"]) == 0
    assert (f"{i}. coarse_noise: starting noise: gain" in (out := capsys.readouterr().out)
            and "other modes x 0.8 (only where the structure holds)" in out)
    m = diffsampler_rt.Model(path)
    assert m.card["pipeline"][i]["temperature"] == 0.8
    assert m.card["pipeline"][i]["where"] == "structured"
    for n in (64, 576):  # k = 8 below n_rooks' min_side, k = 24 not a power of 2
        np.testing.assert_array_equal(m.generate(n, 2, seed=3), before[n])
    cool = m.generate(256, 2, seed=3)
    assert not np.allclose(cool, before[256])
    np.testing.assert_array_equal(m.generate(256, 2, seed=3, structure=False), white)
    pipeline_refused(path, ["--update", str(i), "--temperature", "x"], capsys,
             "step 'coarse_noise': 'temperature' must be a number in (0, 2], got 'x'")
    pipeline_refused(path, ["--remove", "n_rooks"], capsys, "needs a structure step in the pipeline")
    assert diffsampler_rt.Model(path).card["pipeline"][i]["temperature"] == 0.8
