"""Each axis's spread of a point set (diffsampler_rt.projections) and the card's
``"projection_gain"``."""
import copy
import doctest
import json

import numpy as np
import pytest

import diffsampler_rt
from diffsampler_rt import ModelFormatError, projections
from diffsampler_rt.finish.pipeline import find
from diffsampler_rt.projections import gain_at, settings_problem, spread_projections

from .conftest import pipeline_refused


def _deviations(pts: np.ndarray) -> np.ndarray:
    """Sorted coordinates minus (i + 1/2) / n, per set and axis."""
    n = pts.shape[-2]
    return np.sort(pts, axis=-2) - ((np.arange(n) + 0.5) / n)[:, None]


def _jittered(sets: int, k: int, seed: int) -> np.ndarray:
    rng = np.random.default_rng(seed)
    cells = np.stack(np.meshgrid(np.arange(k), np.arange(k)), -1).reshape(-1, 2)
    return (cells[None] + rng.random((sets, k * k, 2))) / k


def _reflected(v: np.ndarray) -> np.ndarray:
    """Coordinates that left [0, 1) by less than 1 folded back in at the edge they crossed."""
    assert ((v > -1) & (v < 2)).all()
    return np.where(v < 0, -v, np.where(v >= 1, 2 - v, v))


def test_gain_scales_each_axis_deviations():
    pts = _jittered(3, 16, 0)
    # below 1 the order along each axis is kept, so the deviations scale exactly
    out = spread_projections(pts, 0.7)
    np.testing.assert_allclose(_deviations(out), 0.7 * _deviations(pts), atol=1e-15)
    # above 1 the projections get less even: the sum of squared deviations grows
    out = spread_projections(pts, 1.2)
    assert out.shape == pts.shape and ((out >= 0) & (out < 1)).all()
    assert np.all((_deviations(out) ** 2).sum(axis=-2) > (_deviations(pts) ** 2).sum(axis=-2))
    # each point moves by (gain - 1) times its own deviation, along the axes only; one that
    # this takes out of the square is reflected back in at the edge it crossed
    n = pts.shape[-2]
    rank = np.argsort(np.argsort(pts, axis=-2, kind="stable"), axis=-2, kind="stable")
    even = (rank + 0.5) / n
    moved = even + 1.2 * (pts - even)
    assert (moved < 0).any()  # some points do leave the square here
    np.testing.assert_allclose(out, _reflected(moved), atol=1e-15)


def test_gain_one_returns_a_copy_and_one_set_keeps_its_shape():
    pts = _jittered(1, 8, 1)[0]
    out = spread_projections(pts, 1.0)
    np.testing.assert_array_equal(out, pts)
    assert out is not pts
    assert spread_projections(pts, 1.3).shape == (64, 2)


def test_coordinates_stay_in_the_square():
    # a point at the edge, far from its even position, is reflected into (0, 1), not clamped
    # onto the border
    pts = np.array([[0.0, 0.999], [0.01, 0.998], [0.02, 0.997], [0.99, 0.0]])
    out = spread_projections(pts, 1.5)
    assert ((out > 0) & (out < 1)).all()
    even = np.array([0.125, 0.375, 0.625, 0.875])
    # x: sorted 0, 0.01, 0.02, 0.99; the first lands at 0.125 - 1.5 * 0.125 = -0.0625
    np.testing.assert_allclose(out[:, 0], _reflected(even + 1.5 * (pts[:, 0] - even)),
                               atol=1e-15)
    assert out[0, 0] == pytest.approx(0.0625)
    # y: sorted 0, 0.997, 0.998, 0.999 (points 3, 2, 1, 0); 0.875 + 1.5 * 0.124 = 1.061
    y_even = np.array([0.875, 0.625, 0.375, 0.125])
    np.testing.assert_allclose(out[:, 1], _reflected(y_even + 1.5 * (pts[:, 1] - y_even)),
                               atol=1e-15)
    assert out[0, 1] == pytest.approx(2 - (0.875 + 1.5 * 0.124))


@pytest.mark.parametrize("gain", [0.4, 1.6, float("nan"), True, "1.1", None])
def test_bad_gain_ispipeline_refused(gain):
    with pytest.raises(ValueError, match=r"gain must be a number in \[0.5, 1.5\], got "):
        spread_projections(_jittered(1, 4, 0), gain)


def test_card_table_validation_and_words():
    spec = {"n": [64, 256, 576], "gain": [1.0, 1.1, 1.0]}
    assert settings_problem(spec) is None and settings_problem(1.2) is None
    assert [gain_at(spec, n) for n in (16, 64, 256, 576, 4096)] == pytest.approx(
        [1, 1, 1.1, 1, 1])  # log-linear between the sizes, the end values beyond
    assert gain_at(spec, 128) == pytest.approx(1.05)
    assert gain_at(1.2, 100) == 1.2
    for bad, match in ((2.0, "must be a number in"), (True, "must be a number in"),
                       ({"gain": [1.1]}, "must be a number in"),
                       ({"n": [256, 64], "gain": [1, 1]}, "strictly increasing"),
                       ({"n": [64, 256], "gain": [1.0]}, "same length"),
                       ({"n": [64, 256], "gain": [1.0, 1.7]}, "gains must be in")):
        assert match in settings_problem(bad), bad
    assert projections.describe(None) == "none"
    assert projections.describe(1.2) == "gain 1.2"
    assert projections.describe(spec) == "gain 1 / 1.1 / 1 at n = 64 / 256 / 576 (log-linear)"


def test_card_projection_gain_is_applied_validated_and_set_by_the_cli(bundled_copy, capsys):
    from export.__main__ import main as export_main
    src = diffsampler_rt.model.resolve("sot_32_fast")
    path = bundled_copy("sot_32_fast")
    steps = [e["step"] for e in diffsampler_rt.load(path).card["pipeline"]]
    at = steps.index("min_spacing")  # after the evening, before the spacing
    plain = diffsampler_rt.generate(path, 256, 2, seed=4)
    assert export_main(["pipeline", str(path), "--add", "projection_gain", "--at", str(at),
                        "--gain", "64:1,256:1.2"]) == 0
    assert (f"{at}. projection_gain: projections spread, gain 1 / 1.2 at n = 64 / 256 "
            "(log-linear)") in capsys.readouterr().out
    assert diffsampler_rt.load(path).card["pipeline"][at] == {
        "step": "projection_gain", "gain": {"n": [64, 256], "values": [1.0, 1.2]}}
    spread = diffsampler_rt.generate(path, 256, 2, seed=4)
    assert spread.shape == (2, 256, 2) and ((spread >= 0) & (spread < 1)).all()
    assert ((_deviations(spread) ** 2).sum() > 1.2 * (_deviations(plain) ** 2).sum())
    # gain 1 at 64; structure=False leaves it out
    np.testing.assert_array_equal(diffsampler_rt.generate(path, 64, 1, seed=4),
                                  diffsampler_rt.generate(src, 64, 1, seed=4))
    np.testing.assert_array_equal(diffsampler_rt.generate(path, 256, 2, seed=4, structure=False),
                                  diffsampler_rt.generate(src, 256, 2, seed=4, structure=False))
    assert export_main(["pipeline", str(path), "--remove", "projection_gain"]) == 0
    assert "projection" not in capsys.readouterr().out
    assert find(diffsampler_rt.load(path).card["pipeline"], "projection_gain") is None
    np.testing.assert_array_equal(diffsampler_rt.generate(path, 256, 2, seed=4), plain)
    assert export_main(["pipeline", str(path), "--add", "projection_gain", "--at", str(at),
                        "--gain", "64:1,256:1.2"]) == 0
    capsys.readouterr()
    for bad in ("2", "x", "64:1,256"):
        pipeline_refused(path, ["--update", "projection_gain", "--gain", bad], capsys,
                 "step 'projection_gain': 'gain' must be a number in [0.5, 1.5]", bad)
    pipeline_refused(path, ["--update", "projection_gain", "--gain", "64:1,256:1.7"], capsys,
             "step 'projection_gain': 'gain' values must each be a number in [0.5, 1.5], got 1.7")
    from diffsampler_rt.card import CARD_KEY, parse_card
    card = copy.deepcopy(diffsampler_rt.load(path).card)
    card["pipeline"][at]["gain"] = "x"
    with pytest.raises(ModelFormatError,
                       match=f"pipeline entry {at}: step 'projection_gain': 'gain' must be"):
        parse_card({CARD_KEY: json.dumps(card)}, "m.onnx")


def test_not_applied_where_a_structure_is_imposed(bundled_copy):
    """An entry that says "where": "unstructured" (as format 1's projection gain became)
    leaves the sizes where the n-rooks structure holds alone, and runs at the others."""
    from export.__main__ import main as export_main
    src = diffsampler_rt.model.resolve("ldbn_fast")  # n-rooks at 256, not at 64 (k < 16)
    path = bundled_copy("ldbn_fast")
    at = [e["step"] for e in diffsampler_rt.load(path).card["pipeline"]].index("n_rooks")
    assert export_main(["pipeline", str(path), "--add", "projection_gain", "--at", str(at + 1),
                        "--gain", "1.3", "--where", "unstructured"]) == 0
    assert diffsampler_rt.load(path).card["pipeline"][at + 1] == {
        "step": "projection_gain", "gain": 1.3, "where": "unstructured"}
    np.testing.assert_array_equal(diffsampler_rt.generate(path, 256, 1, seed=2),
                                  diffsampler_rt.generate(src, 256, 1, seed=2))
    assert not np.array_equal(diffsampler_rt.generate(path, 64, 1, seed=2),
                              diffsampler_rt.generate(src, 64, 1, seed=2))


def test_docstring_examples():
    assert doctest.testmod(projections).failed == 0
