"""Autoguidance (card field "guide"): its card checks, its arithmetic, set-defaults and the
runtime's use of it."""
from __future__ import annotations

import json
import shutil

import numpy as np
import pytest

import diffsampler_rt
from diffsampler_rt.errors import ModelFormatError
from diffsampler_rt.guidance import describe, guided, settings_problem, weight_at

DIGEST = "0" * 64


@pytest.mark.parametrize("spec, message", [
    ("sot_32", "'guide' must be"),
    ({"model": "sot_32"}, "'guide' must be"),
    ({"model": "sot_32", "weight": 1, "extra": 2}, "'guide' must be"),
    ({"model": "", "weight": 1}, "model must be a model name"),
    ({"model": "a/b", "weight": 1}, "model must be a model name"),
    ({"model": 3, "weight": 1}, "model must be a model name"),
    ({"model": "m", "weight": -0.5}, "got -0.5"),
    ({"model": "m", "weight": 5}, "got 5"),
    ({"model": "m", "weight": True}, "got True"),
    ({"model": "m", "weight": float("nan")}, "got nan"),
    ({"model": "m", "n": [256, 64], "weight": [1, 2]}, "same length"),
    ({"model": "m", "n": [64, 256], "weight": [1]}, "same length"),
    ({"model": "m", "weight": 1, "sha256": "ABC"}, "sha256 must be 64 lower-case hex"),
    ({"model": "m", "weight": 1, "network_sha256": DIGEST[1:]}, "network_sha256 must be 64"),
])
def test_card_settings_are_validated(spec, message):
    from diffsampler_rt.card import CARD_KEY, parse_card
    assert message in settings_problem(spec)
    card = {**diffsampler_rt.load("rank1").card, "guide": spec}
    with pytest.raises(ModelFormatError, match="model card field 'guide'"):
        parse_card({CARD_KEY: json.dumps(card)}, "m")
    assert settings_problem({"model": "m", "n": [64, 1024], "weight": [0, 1],
                             "network_sha256": DIGEST}) is None
    assert settings_problem({"model": "m", "weight": 1, "sha256": DIGEST}) is None  # older


def test_per_size_weight_and_words():
    spec = {"model": "m", "n": [64, 1024], "weight": [0, 1]}
    assert weight_at(spec, 64) == 0 and weight_at(spec, 1024) == 1
    assert weight_at(spec, 256) == pytest.approx(0.5)  # log-linear between
    assert weight_at(spec, 16) == 0 and weight_at(spec, 4096) == 1  # end values beyond
    assert weight_at({"model": "m", "weight": 0.7}, 99) == 0.7
    assert describe(None) == "none"
    assert describe({"model": "m", "weight": 1.0}) == "m, weight 1"
    assert describe(spec) == "m, weight 0 / 1 at n = 64 / 1024 (log-linear)"


def test_guided_denoiser_extrapolates_away_from_the_guide():
    model = lambda x, t: x + t  # noqa: E731
    guide = lambda x, t: 2 * x  # noqa: E731
    x = np.arange(6.0).reshape(1, 2, 3, 1)
    np.testing.assert_allclose(guided(model, guide, 0.0)(x, 3), x + 3)
    np.testing.assert_allclose(guided(model, guide, 1.5)(x, 3), 2.5 * (x + 3) - 3 * x)
    np.testing.assert_array_equal(x, np.arange(6.0).reshape(1, 2, 3, 1))  # input untouched


def test_set_defaults_and_generation_with_a_guide(tmp_path, capsys):
    """set-defaults writes the guide with its network's sha256; a model guided by a copy of
    itself makes the unguided sets (to rounding), guided by another net other sets, where
    its weight is not 0; structure=False leaves the guide out; a changed, missing or
    incompatible guide is refused with its name."""
    from export.__main__ import main as export_main
    path = tmp_path / "m.onnx"
    shutil.copy(diffsampler_rt.load("sot").path, path)
    shutil.copy(diffsampler_rt.load("sot").path, tmp_path / "twin.onnx")
    assert export_main(["set-defaults", str(path), "--guide", "none"]) == 0
    plain = diffsampler_rt.Model(path).generate(64, 2, seed=3)
    plain_256 = diffsampler_rt.Model(path).generate(256, 1, seed=3)
    assert export_main(["set-defaults", str(path), "--guide", "twin"]) == 0
    assert "guide twin, weight 1" in capsys.readouterr().out
    m = diffsampler_rt.Model(path)
    assert m.card["guide"]["weight"] == 1 and len(m.card["guide"]["network_sha256"]) == 64
    np.testing.assert_allclose(m.generate(64, 2, seed=3), plain, atol=1e-6)

    assert export_main(["set-defaults", str(path), "--guide", "sot_32",  # the bundled one
                        "--guide-weight", "64:1,256:0"]) == 0
    assert "guide sot_32, weight 1 / 0 at n = 64 / 256 (log-linear)" in capsys.readouterr().out
    m = diffsampler_rt.Model(path)
    assert m.guide().path == diffsampler_rt.load("sot_32").path
    guided_sets = m.generate(64, 2, seed=3)
    assert guided_sets.shape == (2, 64, 2) and np.all((guided_sets >= 0) & (guided_sets < 1))
    assert np.abs(guided_sets - plain).max() > 1e-3
    np.testing.assert_array_equal(m.generate(64, 2, seed=3, structure=False),
                                  diffsampler_rt.Model(path).generate(64, 2, seed=3,
                                                                      structure=False))
    np.testing.assert_array_equal(m.generate(256, 1, seed=3), plain_256)  # weight 0 there

    for bad, err in ((["--guide-weight", "1"], "--guide-weight needs --guide"),
                     (["--guide", "twin", "--guide-weight", "x"], "--guide-weight must be"),
                     (["--guide", "twin", "--guide-weight", "9"], "got 9.0"),
                     (["--guide", "nowhere"], "guide model 'nowhere' was not found")):
        capsys.readouterr()
        assert export_main(["set-defaults", str(path), *bad]) == 2
        assert err in capsys.readouterr().err

    assert export_main(["set-defaults", str(path), "--guide", "twin"]) == 0
    # an edit of the guide's own card leaves it the same network, so still the guide
    assert export_main(["set-defaults", str(tmp_path / "twin.onnx"), "--steps", "12"]) == 0
    np.testing.assert_allclose(diffsampler_rt.Model(path).generate(64, 2, seed=3), plain,
                               atol=1e-6)
    shutil.copy(diffsampler_rt.load("sot_32").path, tmp_path / "twin.onnx")  # another net
    with pytest.raises(ModelFormatError, match="twin.onnx has network_sha256"):
        diffsampler_rt.Model(path).generate(64, 1, seed=0)
    # a card from before the network digest gives the whole file's, checked as such
    from diffsampler_rt.guidance import file_sha256
    from export.defaults import edit_card

    def older(card):
        card["guide"] = {"model": "twin", "weight": 1, "sha256": file_sha256(
            tmp_path / "twin.onnx")}
    edit_card(path, older)
    assert diffsampler_rt.Model(path).guide().path == tmp_path / "twin.onnx"
    assert export_main(["set-defaults", str(tmp_path / "twin.onnx"), "--steps", "12"]) == 0
    with pytest.raises(ModelFormatError, match="twin.onnx has sha256"):
        diffsampler_rt.Model(path).generate(64, 1, seed=0)
    shutil.copy(diffsampler_rt.load("ldbn").path, tmp_path / "twin.onnx")
    assert export_main(["set-defaults", str(path), "--guide", "twin"]) == 0
    with pytest.raises(ModelFormatError, match="has embedding 'stratified', the model 'ot'"):
        diffsampler_rt.Model(path).generate(64, 1, seed=0)
    assert export_main(["set-defaults", str(path), "--guide", "none"]) == 0
    assert "guide" not in diffsampler_rt.Model(path).card


def test_every_bundled_model_finds_its_guide():
    """Each bundled card's guide is found and is the network its weights were tuned with
    (an edit of the guide's own card once orphaned sot: its card held the guide file's
    sha256), and shares the model's schedule and embedding."""
    guided_models = [name for name in diffsampler_rt.list_models()
                     if "guide" in diffsampler_rt.load(name).card]
    assert {"sot", "sot_32"} <= set(guided_models)
    for name in guided_models:
        model = diffsampler_rt.Model(diffsampler_rt.load(name).path)
        assert "network_sha256" in model.card["guide"], name
        assert model.guide().card["name"] == model.card["guide"]["model"]


def test_bundled_guides_are_found_but_not_listed():
    """Networks shipped only to guide others (models/guides/) are found by the cards that
    name them, are each used by some bundled model, and are not offered as models; a guide
    is loaded once and its session does not spin."""
    from diffsampler_rt.errors import UnknownModelError
    from diffsampler_rt.model import MODELS_DIR
    guides = sorted(p.stem for p in (MODELS_DIR / "guides").glob("*.onnx"))
    assert "sot_32_guide" in guides
    assert not set(guides) & set(diffsampler_rt.list_models())
    with pytest.raises(UnknownModelError, match="sot_32_guide"):
        diffsampler_rt.load("sot_32_guide")
    used = {diffsampler_rt.load(name).card.get("guide", {}).get("model")
            for name in diffsampler_rt.list_models()}
    assert set(guides) <= used
    model = diffsampler_rt.Model(diffsampler_rt.load("sot_32").path)
    assert model.guide().path == MODELS_DIR / "guides" / "sot_32_guide.onnx"
    assert diffsampler_rt.Model(diffsampler_rt.load("sot_32").path).guide() is model.guide()
    # the two networks take turns: neither session's idle workers spin
    spin = "session.intra_op.allow_spinning"
    for session in (model.session, model.guide().session):
        assert session.get_session_options().get_session_config_entry(spin) == "0"
