"""Each axis's spread of a point set (diffsampler_rt.projections) and the card's
``"projection_gain"``."""
import doctest
import json

import numpy as np
import pytest

import diffsampler_rt
from diffsampler_rt import ModelFormatError, projections
from diffsampler_rt.projections import gain_at, settings_problem, spread_projections


def _deviations(pts: np.ndarray) -> np.ndarray:
    """Sorted coordinates minus (i + 1/2) / n, per set and axis."""
    n = pts.shape[-2]
    return np.sort(pts, axis=-2) - ((np.arange(n) + 0.5) / n)[:, None]


def _jittered(sets: int, k: int, seed: int) -> np.ndarray:
    rng = np.random.default_rng(seed)
    cells = np.stack(np.meshgrid(np.arange(k), np.arange(k)), -1).reshape(-1, 2)
    return (cells[None] + rng.random((sets, k * k, 2))) / k


def test_gain_scales_each_axis_deviations():
    pts = _jittered(3, 16, 0)
    # below 1 the order along each axis is kept, so the deviations scale exactly
    out = spread_projections(pts, 0.7)
    np.testing.assert_allclose(_deviations(out), 0.7 * _deviations(pts), atol=1e-15)
    # above 1 the projections get less even: the sum of squared deviations grows
    out = spread_projections(pts, 1.2)
    assert out.shape == pts.shape and ((out >= 0) & (out < 1)).all()
    assert np.all((_deviations(out) ** 2).sum(axis=-2) > (_deviations(pts) ** 2).sum(axis=-2))
    # each point moves by (gain - 1) times its own deviation, along the axes only
    n = pts.shape[-2]
    rank = np.argsort(np.argsort(pts, axis=-2, kind="stable"), axis=-2, kind="stable")
    even = (rank + 0.5) / n
    np.testing.assert_allclose(out, np.clip(even + 1.2 * (pts - even), 0, 1), atol=1e-15)


def test_gain_one_returns_a_copy_and_one_set_keeps_its_shape():
    pts = _jittered(1, 8, 1)[0]
    out = spread_projections(pts, 1.0)
    np.testing.assert_array_equal(out, pts)
    assert out is not pts
    assert spread_projections(pts, 1.3).shape == (64, 2)


def test_coordinates_stay_in_the_square():
    # a point at the edge, far from its even position, is clipped into [0, 1)
    pts = np.array([[0.0, 0.999], [0.01, 0.998], [0.02, 0.997], [0.99, 0.0]])
    out = spread_projections(pts, 1.5)
    assert ((out >= 0) & (out < 1)).all()


@pytest.mark.parametrize("gain", [0.4, 1.6, float("nan"), True, "1.1", None])
def test_bad_gain_is_refused(gain):
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
    assert export_main(["set-defaults", str(path), "--projection-gain", "none"]) == 0
    assert "projection none" in capsys.readouterr().out
    assert "projection_gain" not in diffsampler_rt.load(path).card
    plain = diffsampler_rt.generate(path, 256, 2, seed=4)
    assert export_main(["set-defaults", str(path), "--projection-gain", "64:1,256:1.2"]) == 0
    assert "projection gain 1 / 1.2 at n = 64 / 256 (log-linear)" in capsys.readouterr().out
    assert diffsampler_rt.load(path).card["projection_gain"] == {"n": [64, 256],
                                                                 "gain": [1.0, 1.2]}
    spread = diffsampler_rt.generate(path, 256, 2, seed=4)
    assert spread.shape == (2, 256, 2) and ((spread >= 0) & (spread < 1)).all()
    assert ((_deviations(spread) ** 2).sum() > 1.2 * (_deviations(plain) ** 2).sum())
    # gain 1 at 64; structure=False leaves it out
    np.testing.assert_array_equal(diffsampler_rt.generate(path, 64, 1, seed=4),
                                  diffsampler_rt.generate(src, 64, 1, seed=4))
    np.testing.assert_array_equal(diffsampler_rt.generate(path, 256, 2, seed=4, structure=False),
                                  diffsampler_rt.generate(src, 256, 2, seed=4, structure=False))
    for bad in ("2", "x", "64:1,256"):
        assert export_main(["set-defaults", str(path), "--projection-gain", bad]) == 2
        assert bad in capsys.readouterr().err
    from diffsampler_rt.card import CARD_KEY, parse_card
    card = diffsampler_rt.load(path).card
    with pytest.raises(ModelFormatError, match="model card field 'projection_gain' must be"):
        parse_card({CARD_KEY: json.dumps({**card, "projection_gain": "x"})}, "m.onnx")


def test_not_applied_where_a_structure_is_imposed(bundled_copy):
    from export.__main__ import main as export_main
    src = diffsampler_rt.model.resolve("ldbn_fast")  # n-rooks at 256
    path = bundled_copy("ldbn_fast")
    assert export_main(["set-defaults", str(path), "--projection-gain", "1.3"]) == 0
    np.testing.assert_array_equal(diffsampler_rt.generate(path, 256, 1, seed=2),
                                  diffsampler_rt.generate(src, 256, 1, seed=2))


def test_docstring_examples():
    assert doctest.testmod(projections).failed == 0
