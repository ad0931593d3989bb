"""The minimum spacing the runtime restores on decoded sets (diffsampler_rt.spacing)."""
import copy
import doctest
import json
import re
import shutil

import numpy as np
import pytest

import diffsampler_rt
from diffsampler_rt import ModelFormatError, spacing
from diffsampler_rt import per_size
from diffsampler_rt.finish.pipeline import find
from diffsampler_rt.spacing import close_pairs, enforce_min_spacing
from trainer.stats import min_distance, spacing_coefficient


def brute_pairs(p: np.ndarray, r: float) -> set:
    d = np.linalg.norm(p[:, None] - p[None], axis=-1)
    i, j = np.nonzero(np.triu(d < r, 1))
    return set(zip(i.tolist(), j.tolist()))


@pytest.mark.parametrize("m, scale", [(1, 0.5), (7, 0.5), (300, 0.6), (2000, 1.5)])
def test_close_pairs_match_brute_force(m, scale):
    p = np.random.default_rng(m).random((m, 2))
    r = scale / np.sqrt(m)
    i, j = close_pairs(p, r)
    assert np.all(i < j)
    assert set(zip(i.tolist(), j.tolist())) == brute_pairs(p, r)  # each pair once
    assert len(i) == len(set(zip(i.tolist(), j.tolist())))


def test_close_pairs_at_the_borders_and_with_a_huge_radius():
    p = np.array([[0.0, 0.0], [1 - 1e-12, 1 - 1e-12], [0.0, 1 - 1e-12], [0.5, 0.5]])
    for r in (0.1, 0.9, 1.2, 5.0):
        i, j = close_pairs(p, r)
        assert set(zip(i.tolist(), j.tolist())) == brute_pairs(p, r)


@pytest.mark.parametrize("n, c, jitter", [(64, 0.5, None), (1024, 0.5, None), (4096, 0.5, None),
                                          (1024, 0.7254, 0.15)])
def test_sets_get_the_spacing_and_only_close_points_move(n, c, jitter):
    if jitter is None:  # uniform sets
        pts = np.random.default_rng(n).random((3, n, 2))
    else:  # Poisson disk sets (their sampler's radius) with jittered points, as a net errs
        from trainer.samplers import sample
        pts = sample("poisson_disk", n, count=3, seed=2)
        pts = np.clip(pts + jitter / np.sqrt(n) * np.random.default_rng(3).standard_normal(
            pts.shape), 0, 0.999)
        assert np.all(min_distance(pts) < 0.5 * c / np.sqrt(n))
    r = c / np.sqrt(n)
    out = enforce_min_spacing(pts, r)
    assert out.shape == pts.shape and out.dtype == np.float64
    assert np.all((out >= 0) & (out < 1)) and np.all(np.isfinite(out))
    assert np.all(min_distance(out) >= r * (1 - 1e-9))
    for s in range(3):
        i, j = close_pairs(pts[s], r)
        close = np.unique(np.concatenate([i, j]))
        moved = np.flatnonzero(np.any(out[s] != pts[s], axis=1))
        assert set(close) <= set(moved)
        # the rest is bit for bit, except points a push brought into a new close pair: near
        # the first close pairs
        far = np.linalg.norm(pts[s][:, None] - pts[s][close][None], axis=-1).min(1) > 3 * r
        assert not np.any(far[moved])


def test_sets_do_not_interact_and_spread_sets_are_unchanged():
    pts = np.random.default_rng(1).random((4, 256, 2))
    r = 0.7 / 16
    both = enforce_min_spacing(pts, r)
    for s in range(4):  # the same set alone or in a batch: the same result
        np.testing.assert_array_equal(enforce_min_spacing(pts[s], r), both[s])
    grid = (np.stack(np.meshgrid(np.arange(16), np.arange(16)), -1).reshape(-1, 2) + 0.5) / 16
    np.testing.assert_array_equal(enforce_min_spacing(grid, 0.99 / 16), grid)


def test_coincident_and_corner_points_are_separated_deterministically():
    pts = np.array([[0.3, 0.3], [0.3, 0.3], [0.0, 0.0], [0.0, 0.0], [0.9, 0.9]])
    out = enforce_min_spacing(pts, 0.05)
    assert min_distance(out) >= 0.05
    np.testing.assert_array_equal(out, enforce_min_spacing(pts, 0.05))
    np.testing.assert_array_equal(out[4], pts[4])


def test_bad_arguments_are_refused():
    with pytest.raises(ValueError, match="positive number, got -0.1"):
        enforce_min_spacing(np.zeros((4, 2)), -0.1)
    with pytest.raises(ValueError, match="positive number, got nan"):
        enforce_min_spacing(np.zeros((4, 2)), float("nan"))
    with pytest.raises(ValueError, match=r"shape \(\.\.\., n, 2\), got \(4, 3\)"):
        enforce_min_spacing(np.zeros((4, 3)), 0.1)


def test_spacing_coefficient_of_a_lattice():
    k = 8
    grid = (np.stack(np.meshgrid(np.arange(k), np.arange(k)), -1).reshape(-1, 2) + 0.5) / k
    assert spacing_coefficient(grid[None]) == pytest.approx(1.0)
    with pytest.raises(ValueError, match="percentile must be in"):
        spacing_coefficient(grid[None], 120)


def test_spacing_coefficient_mean():
    pts = np.random.default_rng(3).random((5, 64, 2))
    smallest = min_distance(pts)
    assert spacing_coefficient(pts, mean=True) == pytest.approx(smallest.mean() * 8)
    assert spacing_coefficient(pts, 0) == pytest.approx(smallest.min() * 8)
    assert spacing_coefficient(pts, 0) < spacing_coefficient(pts, mean=True)


def _card_radius(card: dict, n: int) -> float:
    """The radius a card's (first) min_spacing entry asks for at n points."""
    return per_size.value(find(card["pipeline"], "min_spacing")["c"], n) / np.sqrt(n)


def test_card_spacing_is_applied_and_removable(tiny_onnx, tmp_path):
    from export.pipeline_edit import edit_pipeline
    path = tmp_path / "m.onnx"
    shutil.copy(tiny_onnx, path)
    plain = diffsampler_rt.Model(path).generate(256, 3, seed=5)
    c = 0.5
    card = edit_pipeline(path, add="min_spacing", params={"c": c})
    assert find(card["pipeline"], "min_spacing") == {"c": c}
    m = diffsampler_rt.Model(path)
    assert _card_radius(m.card, 256) == c / 16
    spaced = m.generate(256, 3, seed=5)
    np.testing.assert_array_equal(spaced, enforce_min_spacing(plain, c / 16))
    assert np.all(min_distance(spaced) >= c / 16)
    np.testing.assert_array_equal(m.generate(256, 3, seed=5, structure=False), plain)
    blocks = np.concatenate(list(m.iter_sets(256, 3, batch=2, seed=5)))
    np.testing.assert_array_equal(blocks, spaced)
    assert find(edit_pipeline(path, remove="min_spacing")["pipeline"], "min_spacing") is None
    np.testing.assert_array_equal(diffsampler_rt.Model(path).generate(256, 3, seed=5), plain)
    before = path.read_bytes()
    with pytest.raises(ValueError, match=r"step 'min_spacing': 'c' must be a number in \(0, "):
        edit_pipeline(path, add="min_spacing", params={"c": 2.0})
    assert path.read_bytes() == before


def test_card_spacing_is_validated():
    from diffsampler_rt.card import CARD_KEY, parse_card
    card = copy.deepcopy(diffsampler_rt.load("rank1").card)
    at = len(card["pipeline"])

    def with_spacing(c) -> str:
        pipe = [*card["pipeline"], {"step": "min_spacing", "c": c}]
        return json.dumps({**card, "pipeline": pipe})

    for bad in (0, -1, 1.5, "0.7", True):
        with pytest.raises(ModelFormatError, match=re.escape(
                f"pipeline entry {at}: step 'min_spacing': 'c' must be a number in (0, 1.07)")):
            parse_card({CARD_KEY: with_spacing(bad)}, "m")
    table_form = "'c' table must be {\"n\": [increasing sizes], \"values\": [one per size]}"
    for bad, why in (({"n": [64]}, table_form), ({"n": [64, 256], "values": [0.7]}, table_form),
                     ({"n": [64, 64], "values": [0.7, 0.6]}, table_form),
                     ({"n": [64.0], "values": [0.7]}, table_form),
                     ({"n": [64], "c": [0.7]}, table_form),  # format 1's key
                     ({"n": [64], "values": [2.0]},
                      "'c' values must each be a number in (0, 1.07), got 2.0")):
        with pytest.raises(ModelFormatError, match=re.escape(f"step 'min_spacing': {why}")):
            parse_card({CARD_KEY: with_spacing(bad)}, "m")
    with pytest.raises(ModelFormatError, match="step 'min_spacing' needs 'c'"):
        parse_card({CARD_KEY: json.dumps({**card, "pipeline": [{"step": "min_spacing"}]})}, "m")
    table = {"n": [64, 1024], "values": [0.7, 0.6]}
    assert parse_card({CARD_KEY: with_spacing(table)}, "m")["pipeline"][at] == \
        {"step": "min_spacing", "c": table}
    assert parse_card({CARD_KEY: with_spacing(0.7)}, "m")["pipeline"][at]["c"] == 0.7
    with pytest.raises(ModelFormatError, match="field 'min_spacing' belongs to format 1"):
        parse_card({CARD_KEY: json.dumps({**card, "min_spacing": 0.7})}, "m")


def test_pipeline_cli_min_spacing(tiny_onnx, tmp_path, capsys):
    from export.__main__ import main
    path = tmp_path / "m.onnx"
    shutil.copy(tiny_onnx, path)

    def refused(argv, text):
        before = path.read_bytes()
        capsys.readouterr()
        assert main(["pipeline", str(path), *argv]) == 2
        out, err = capsys.readouterr()
        assert err.startswith("error: ") and err.count("\n") == 1 and not out
        assert text in err, err
        assert path.read_bytes() == before

    refused(["--add", "min_spacing", "--c", "wide"],
            "step 'min_spacing': 'c' must be a number in (0, 1.07) or a per-size table "
            "{\"n\": [sizes], \"values\": [...]}, got 'wide'")
    refused(["--add", "min_spacing", "--c", "64:0.7:1"], "got '64:0.7:1'")
    assert main(["pipeline", str(path), "--add", "min_spacing", "--c", "0.6"]) == 0
    assert ("1. min_spacing: pairs pushed to at least c / sqrt(n), c = 0.6\n"
            in capsys.readouterr().out)
    thin = {"step": "thin", "drop": "random"}  # the export's own step comes first
    assert diffsampler_rt.Model(path).card["pipeline"] == [thin, {"step": "min_spacing", "c": 0.6}]
    assert main(["pipeline", str(path), "--update", "min_spacing", "--c", "64:0.7,1024:0.6"]) == 0
    assert ("1. min_spacing: pairs pushed to at least c / sqrt(n), c = 0.7 / 0.6 at n = 64 / "
            "1024 (log-linear)" in capsys.readouterr().out)
    assert diffsampler_rt.Model(path).card["pipeline"] == [
        thin, {"step": "min_spacing", "c": {"n": [64, 1024], "values": [0.7, 0.6]}}]
    refused(["--update", "min_spacing", "--c", "1024:0.7,64:0.6"],
            "'c' table must be {\"n\": [increasing sizes]")


def test_per_size_spacing_table(tiny_onnx, tmp_path):
    from diffsampler_rt.spacing import coefficient, radius
    from export.pipeline_edit import edit_pipeline
    # the format-1 helpers: log-linear between the sizes, the end values beyond them
    old = {"n": [64, 1024], "c": [0.7, 0.6]}
    assert coefficient(old, 256) == pytest.approx(0.65)
    assert coefficient(old, 16) == 0.7 and coefficient(old, 4096) == 0.6
    assert radius({"min_spacing": old}, 256) == pytest.approx(0.65 / 16)
    # the pipeline's table: the same reading
    table = {"n": [64, 1024], "values": [0.7, 0.6]}
    assert per_size.value(table, 256) == pytest.approx(0.65)
    assert per_size.value(table, 16) == 0.7 and per_size.value(table, 4096) == 0.6
    path = tmp_path / "m.onnx"
    shutil.copy(tiny_onnx, path)
    plain = diffsampler_rt.Model(path).generate(256, 2, seed=3)
    edit_pipeline(path, add="min_spacing", params={"c": table})
    assert _card_radius(diffsampler_rt.Model(path).card, 256) == pytest.approx(0.65 / 16)
    np.testing.assert_array_equal(diffsampler_rt.Model(path).generate(256, 2, seed=3),
                                  enforce_min_spacing(plain, per_size.value(table, 256) / 16))


def brute_pairs_torus(p: np.ndarray, r: float) -> set:
    d = p[:, None] - p[None]
    d = np.linalg.norm(d - np.round(d), axis=-1)
    i, j = np.nonzero(np.triu(d < r, 1))
    return set(zip(i.tolist(), j.tolist()))


@pytest.mark.parametrize("m, scale", [(1, 0.5), (7, 0.5), (7, 1.5), (20, 2.5), (300, 0.6),
                                      (2000, 1.5)])
def test_close_pairs_on_the_torus_match_brute_force(m, scale):
    # scale / sqrt(m) from 0.03 to 0.57: 1, 2, 3 and many buckets a side
    p = np.random.default_rng(m).random((m, 2))
    r = scale / np.sqrt(m)
    i, j = close_pairs(p, r, torus=True)
    assert np.all(i < j)
    assert set(zip(i.tolist(), j.tolist())) == brute_pairs_torus(p, r)
    assert len(i) == len(set(zip(i.tolist(), j.tolist())))  # each pair once


def test_spacing_on_the_torus_pushes_pairs_across_the_seam():
    pts = np.array([[0.001, 0.5], [0.999, 0.5], [0.5, 0.5]])
    # 0.002 apart on the torus, 0.998 in the square: only the torus pushes them
    np.testing.assert_array_equal(enforce_min_spacing(pts, 0.1), pts)
    out = enforce_min_spacing(pts, 0.1, torus=True)
    assert min_distance(out, toroidal=True) >= 0.1
    assert out[0, 0] < 0.2 and out[1, 0] > 0.8  # apart round the seam, not across the square
    assert out[2].tolist() == [0.5, 0.5]


@pytest.mark.parametrize("n", [64, 1024])
def test_sets_get_the_spacing_on_the_torus(n):
    pts = np.random.default_rng(n).random((3, n, 2))
    r = 0.5 / np.sqrt(n)
    out = enforce_min_spacing(pts, r, torus=True)
    assert np.all((out >= 0) & (out < 1)) and np.all(np.isfinite(out))
    assert np.all(min_distance(out, toroidal=True) >= r * (1 - 1e-9))
    for s in range(3):  # points far from every close pair keep their bits
        i, j = close_pairs(pts[s], r, torus=True)
        close = pts[s][np.unique(np.concatenate([i, j]))]
        d = pts[s][:, None] - close[None]
        far = np.linalg.norm(d - np.round(d), axis=-1).min(1) > 3 * r
        np.testing.assert_array_equal(out[s][far], pts[s][far])


def test_toroidal_models_keep_their_spacing_on_the_torus():
    m = diffsampler_rt.load("poisson_disk_torus_fast")
    assert m.card["padding"] == "circular"
    pts = m.generate(1024, 4, seed=0)  # with spacing in the square, 3 of these 4 were closer
    assert np.all(min_distance(pts, toroidal=True) >= _card_radius(m.card, 1024))


def test_docstring_examples():
    assert doctest.testmod(spacing).failed == 0


def test_bundled_blue_noise_models_keep_their_card_spacing():
    for name in ("poisson_disk_fast", "sot_fast"):
        m = diffsampler_rt.load(name)
        pts = m.generate(1024, 2, seed=0)
        r = _card_radius(m.card, 1024)
        assert np.all(min_distance(pts) >= r)
        assert np.any(min_distance(m.generate(1024, 2, seed=0, structure=False)) < r)


def test_trainer_spacing_command(tmp_path, monkeypatch, capsys):
    from dataclasses import replace

    from tests.conftest import tiny_config
    from trainer.__main__ import main
    monkeypatch.setenv("DIFFSAMPLER_CACHE", str(tmp_path / "cache"))
    cfg = tiny_config()
    fresh = tmp_path / "fresh.json"
    fresh.write_text(json.dumps(cfg.to_dict()))
    # fresh sets: as many drawn from the sampler with the config's seed, k = 4 first
    assert main(["spacing", str(fresh), "--fresh-sets", "12", "--percentile", "50"]) == 0
    out = capsys.readouterr().out.splitlines()
    from trainer.samplers import sample
    rng = np.random.default_rng(cfg.seed)
    want = [spacing_coefficient(sample("sobol_owen", k * k, count=12, seed=rng), 50)
            for k in (4, 8)]
    assert out[0].startswith("tiny: k=4 (12 sets) spacing coefficient")
    assert out[2] == ("tiny: per size: python -m export pipeline MODEL.onnx --update min_spacing "
                      f"--c 16:{want[0]:.4f},64:{want[1]:.4f}")
    assert main(["spacing", str(fresh), "--fresh-sets", "12", "--mean"]) == 0
    out = capsys.readouterr().out.splitlines()
    rng = np.random.default_rng(cfg.seed)
    want = [spacing_coefficient(sample("sobol_owen", k * k, count=12, seed=rng), mean=True)
            for k in (4, 8)]
    assert "(mean of the sets' smallest distance, times sqrt(n))" in out[0]
    assert out[2] == ("tiny: per size: python -m export pipeline MODEL.onnx --update min_spacing "
                      f"--c 16:{want[0]:.4f},64:{want[1]:.4f}")
    with pytest.raises(SystemExit):  # one or the other
        main(["spacing", str(fresh), "--mean", "--percentile", "50"])
    capsys.readouterr()
    assert main(["spacing", str(fresh), "--fresh-sets", "0"]) == 2
    assert capsys.readouterr().err == "error: --fresh-sets must be >= 1, got 0\n"
    pooled = tmp_path / "pooled.json"
    pooled.write_text(json.dumps(replace(cfg, data=replace(cfg.data, pool_sizes=(20, 10))).to_dict()))
    assert main(["spacing", str(pooled), "--percentile", "50"]) == 0
    out = capsys.readouterr().out.splitlines()
    assert [line.split(":")[1].split()[0] for line in out[:2]] == ["k=4", "k=8"]
    assert out[2].startswith("tiny: per size: python -m export pipeline MODEL.onnx --update "
                             "min_spacing --c 16:")
    from trainer.data import make_pool
    from diffsampler_rt.grid import decode
    pts = decode(make_pool("sobol_owen", "stratified", 8, 10, cfg.seed), stratified=True)
    assert f"spacing coefficient {spacing_coefficient(pts, 50):.4f}" in out[1]
    assert out[2].endswith(f",64:{spacing_coefficient(pts, 50):.4f}")
