"""Autoguidance (the card pipeline's "guide" step): its card checks, its arithmetic,
python -m export pipeline and the runtime's use of it."""
from __future__ import annotations

import json
import shutil

import numpy as np
import pytest

import diffsampler_rt
from trainer import zoo
from diffsampler_rt.errors import ModelFormatError
from diffsampler_rt.finish.pipeline import find, pipeline_problem
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
def test_format_1_settings_are_validated(spec, message):
    from diffsampler_rt.card import CARD_KEY, parse_card
    assert message in settings_problem(spec)
    # a format-2 card carrying the old field is refused whatever its value
    card = {**diffsampler_rt.load("rank1").card, "guide": spec}
    with pytest.raises(ModelFormatError, match="model card field 'guide' belongs to format 1"):
        parse_card({CARD_KEY: json.dumps(card)}, "m")
    assert settings_problem({"model": "m", "n": [64, 1024], "weight": [0, 1],
                             "network_sha256": DIGEST}) is None
    assert settings_problem({"model": "m", "weight": 1, "sha256": DIGEST}) is None  # older


@pytest.mark.parametrize("params, message", [
    ({"model": "sot_32"}, "step 'guide' needs 'weight'"),
    ({"weight": 1}, "step 'guide' needs 'model'"),
    ({"model": "sot_32", "weight": 1, "extra": 2}, "step 'guide' has no parameter 'extra'"),
    ({"model": "", "weight": 1}, "'model' must be a model name (no directories), got ''"),
    ({"model": "a/b", "weight": 1}, "'model' must be a model name (no directories), got 'a/b'"),
    ({"model": 3, "weight": 1}, "'model' must be a model name (no directories), got 3"),
    ({"model": "m", "weight": -0.5}, "'weight' must be a number in [0, 4]"),
    ({"model": "m", "weight": 5}, "'weight' must be a number in [0, 4]"),
    ({"model": "m", "weight": True}, "'weight' must be a number in [0, 4]"),
    ({"model": "m", "weight": float("nan")}, "'weight' must be a number in [0, 4]"),
    ({"model": "m", "weight": {"n": [256, 64], "values": [1, 2]}}, "'weight' table must be"),
    ({"model": "m", "weight": {"n": [64, 256], "values": [1]}}, "'weight' table must be"),
    ({"model": "m", "weight": {"n": [64, 256], "values": [1, 9]}},
     "'weight' values must each be a number in [0, 4], got 9"),
    # (the digest messages say "a guide digest", not which of the two keys)
    ({"model": "m", "weight": 1, "sha256": "ABC"},
     "guide digest must be 64 lower-case hex digits, got 'ABC'"),
    ({"model": "m", "weight": 1, "network_sha256": DIGEST[1:]},
     f"guide digest must be 64 lower-case hex digits, got {DIGEST[1:]!r}"),
])
def test_pipeline_entries_are_validated(params, message):
    from .conftest import pipeline_card_error
    entry = {"step": "guide", **params}
    text = pipeline_card_error("sot", [entry, {"step": "thin"}], message)
    assert text.startswith("m: pipeline entry 0: step 'guide'")
    if "weight" in params and "must be a number in [0, 4]" in message:
        assert text.endswith(f"got {params['weight']!r}")


def test_guide_entries_with_a_table_or_either_digest_are_accepted():
    for good in ({"model": "m", "weight": {"n": [64, 1024], "values": [0, 1]},
                  "network_sha256": DIGEST},
                 {"model": "m", "weight": 1, "sha256": DIGEST}):  # older
        assert pipeline_problem([{"step": "guide", **good}, {"step": "thin"}]) is None


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


def _guide(path):
    """The guide step's parameters in the card of the model file ``path`` (None: no guide)."""
    return find(diffsampler_rt.Model(path).card["pipeline"], "guide")


def test_pipeline_edits_and_generation_with_a_guide(tmp_path, capsys):
    """python -m export pipeline writes the guide with its network's sha256; a model guided
    by a copy of itself makes the unguided sets (to rounding), guided by another net other
    sets, where its weight is not 0; structure=False leaves the guide out; bad values are
    refused naming them, the file left as it was; a changed, missing or incompatible guide
    is refused with its name."""
    from export.__main__ import main as export_main

    def pipeline(*args):
        return export_main(["pipeline", str(path), *args])

    def refused(args, err):
        before = path.read_bytes()
        capsys.readouterr()
        assert pipeline(*args) == 2
        assert err in capsys.readouterr().err
        assert path.read_bytes() == before

    path = tmp_path / "m.onnx"
    shutil.copy(diffsampler_rt.load("sot").path, path)
    shutil.copy(diffsampler_rt.load("sot").path, tmp_path / "twin.onnx")
    assert pipeline("--remove", "guide") == 0
    assert _guide(path) is None
    plain = diffsampler_rt.Model(path).generate(64, 2, seed=3)
    plain_256 = diffsampler_rt.Model(path).generate(256, 1, seed=3)
    capsys.readouterr()
    assert pipeline("--add", "guide", "--at", "0", "--model", "twin", "--weight", "1") == 0
    assert "0. guide: guided by twin, weight 1\n" in capsys.readouterr().out
    m = diffsampler_rt.Model(path)
    assert m.card["pipeline"][0]["step"] == "guide"
    assert _guide(path)["weight"] == 1 and len(_guide(path)["network_sha256"]) == 64
    np.testing.assert_allclose(m.generate(64, 2, seed=3), plain, atol=1e-6)

    # another guide: the bundled one (the old digest dropped, the new one recorded)
    assert pipeline("--update", "guide", "--model", "sot_32", "--weight", "64:1,256:0",
                    "--network-sha256", "none") == 0
    assert ("0. guide: guided by sot_32, weight 1 / 0 at n = 64 / 256 (log-linear)"
            in capsys.readouterr().out)
    m = diffsampler_rt.Model(path)
    spec = _guide(path)
    from diffsampler_rt.metadata import network_sha256
    assert spec["network_sha256"] == network_sha256(diffsampler_rt.load("sot_32").path)
    assert m.guide(spec).path == diffsampler_rt.load("sot_32").path
    guided_sets = m.generate(64, 2, seed=3)
    assert guided_sets.shape == (2, 64, 2) and np.all((guided_sets >= 0) & (guided_sets < 1))
    assert np.abs(guided_sets - plain).max() > 1e-3
    np.testing.assert_array_equal(m.generate(64, 2, seed=3, structure=False),
                                  diffsampler_rt.Model(path).generate(64, 2, seed=3,
                                                                      structure=False))
    np.testing.assert_array_equal(m.generate(256, 1, seed=3), plain_256)  # weight 0 there

    for bad, err in ((["--weight", "1"], "parameters need --add, --update or --replace"),
                     (["--update", "guide", "--weight", "x"], "'weight' must be a number in"),
                     (["--update", "guide", "--weight", "x"], "got 'x'"),
                     (["--update", "guide", "--weight", "9"],
                      "step 'guide': 'weight' must be a number in [0, 4]"),
                     (["--update", "guide", "--weight", "9"], "got 9\n"),
                     (["--update", "guide", "--model", "a/b"],
                      "'model' must be a model name (no directories), got 'a/b'"),
                     (["--update", "guide", "--network-sha256", "abc"],
                      "guide digest must be 64 lower-case hex digits, got 'abc'"),
                     (["--add", "guide", "--replace", "guide", "--model", "nowhere",
                       "--weight", "1"], "guide model 'nowhere' was not found")):
        refused(bad, err)

    assert pipeline("--add", "guide", "--replace", "guide", "--model", "twin",
                    "--weight", "1") == 0
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
        card["pipeline"][0] = {"step": "guide", "model": "twin", "weight": 1,
                               "sha256": file_sha256(tmp_path / "twin.onnx")}
    edit_card(path, older)
    assert diffsampler_rt.Model(path).guide(_guide(path)).path == tmp_path / "twin.onnx"
    assert export_main(["set-defaults", str(tmp_path / "twin.onnx"), "--steps", "12"]) == 0
    with pytest.raises(ModelFormatError, match="twin.onnx has sha256"):
        diffsampler_rt.Model(path).generate(64, 1, seed=0)
    shutil.copy(diffsampler_rt.load("ldbn").path, tmp_path / "twin.onnx")
    assert pipeline("--add", "guide", "--replace", "guide", "--model", "twin",
                    "--weight", "1") == 0
    with pytest.raises(ModelFormatError, match="has embedding 'stratified', the model 'ot'"):
        diffsampler_rt.Model(path).generate(64, 1, seed=0)
    assert pipeline("--remove", "guide") == 0
    assert _guide(path) is None


def test_every_bundled_model_finds_its_guide():
    """Each bundled card's guide is found and is the network its weights were tuned with
    (an edit of the guide's own card once orphaned sot: its card held the guide file's
    sha256), and shares the model's schedule and embedding."""
    guided_models = [name for name in zoo.networks()
                     if find(diffsampler_rt.load(name).card["pipeline"], "guide")]
    assert {"sot", "sot_32"} <= set(guided_models)
    for name in guided_models:
        model = diffsampler_rt.Model(diffsampler_rt.load(name).path)
        spec = find(model.card["pipeline"], "guide")
        assert "network_sha256" in spec, name
        assert model.guide(spec).card["name"] == spec["model"]


def test_guides_are_found_but_not_listed():
    """Networks kept only to guide others (models/guides/) are found by the cards that
    name them, are each used by some network, and are not offered as models; a guide
    is loaded once and its session does not spin."""
    from diffsampler_rt.errors import UnknownModelError
    guides = sorted(p.stem for p in (zoo.ZOO_DIR / "guides").glob("*.onnx"))
    assert "sot_32_guide" in guides
    assert not set(guides) & set(zoo.networks())
    with pytest.raises(UnknownModelError, match="sot_32_guide"):
        diffsampler_rt.load("sot_32_guide")
    used = {(find(diffsampler_rt.load(name).card["pipeline"], "guide") or {}).get("model")
            for name in zoo.networks()}
    assert set(guides) <= used
    model = diffsampler_rt.Model(diffsampler_rt.load("sot_32").path)
    spec = find(model.card["pipeline"], "guide")
    assert model.guide(spec).path == zoo.ZOO_DIR / "guides" / "sot_32_guide.onnx"
    assert diffsampler_rt.Model(diffsampler_rt.load("sot_32").path).guide(spec) is \
        model.guide(spec)
    # the two networks take turns: neither session's idle workers spin
    spin = "session.intra_op.allow_spinning"
    for session in (model.session, model.guide(spec).session):
        assert session.get_session_options().get_session_config_entry(spin) == "0"
