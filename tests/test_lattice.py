"""The nearest rank-1 lattice (diffsampler_rt.lattice) and the lattice models' card structure."""
import doctest
import json
import shutil

import numpy as np
import pytest
from scipy.spatial import cKDTree

import diffsampler_rt
from diffsampler_rt import ModelFormatError, lattice
from diffsampler_rt.finish.pipeline import find
from diffsampler_rt.lattice import fit_rank1_lattice, nearest_rank1_lattice, rank1_lattice
from trainer.samplers.lattice import maxmin_generator, p2_generator, shifted, korobov
from trainer.stats import min_distance


def as_set(pts: np.ndarray) -> np.ndarray:
    """Points sorted lexicographically (x, then y): set equality up to order."""
    return pts[np.lexsort((pts[:, 1], pts[:, 0]))]


@pytest.mark.parametrize("n", [16, 64, 100, 576, 1024])
@pytest.mark.parametrize("choose", [maxmin_generator, p2_generator])
def test_exact_lattices_are_recovered(n, choose):
    g = choose(n)
    sets = shifted(korobov(n, g), 3, np.random.default_rng(n))
    gen, shift, fit = fit_rank1_lattice(sets)
    assert np.all(gen == g) and np.all(fit > 0.95)  # the power comes from a gridded FFT
    out = nearest_rank1_lattice(sets)
    for a, b in zip(out, sets):
        np.testing.assert_allclose(as_set(a), as_set(b), atol=1e-12)


def test_transposed_lattice_is_the_same_set():
    n, g = 1024, 271
    pts = rank1_lattice(n, g, (0.4, 3.7))[:, ::-1]  # y is now the index axis
    gen, _, _ = fit_rank1_lattice(pts)
    assert int(gen) == pow(g, -1, n)
    np.testing.assert_allclose(as_set(nearest_rank1_lattice(pts)), as_set(pts), atol=1e-12)


def test_jittered_lattice_snaps_back():
    n, g = 1024, 271
    exact = shifted(korobov(n, g), 4, np.random.default_rng(0))
    noisy = (exact + np.random.default_rng(1).normal(0, 0.15 / np.sqrt(n), exact.shape)) % 1
    assert min_distance(noisy).mean() < 0.7 * min_distance(exact).mean()
    gen, _, fit = fit_rank1_lattice(noisy)
    assert np.all(gen == g) and np.all((fit > 0.3) & (fit < 1))
    out = nearest_rank1_lattice(noisy)
    np.testing.assert_allclose(min_distance(out), min_distance(exact), rtol=1e-12)
    # the shift follows the set: every snapped point is close to a point of the exact lattice
    for a, b in zip(out, exact):
        assert cKDTree(b, boxsize=1.0).query(a)[0].max() < 0.05 / np.sqrt(n)


def test_any_set_gives_a_valid_lattice():
    n = 576
    pts = np.random.default_rng(2).random((3, n, 2))
    gen, _, fit = fit_rank1_lattice(pts)
    assert np.all(np.gcd(gen, n) == 1) and np.all(fit < 0.05)
    out = nearest_rank1_lattice(pts)
    assert out.shape == pts.shape and out.dtype == np.float64
    assert np.all((out >= 0) & (out < 1)) and np.isfinite(out).all()
    for s in out:  # both projections are permutations of one shifted 1/n grid
        for c in (0, 1):
            assert len(np.unique(np.floor(s[:, c] * n + 1e-9 - s[:, c].min() * n))) == n


def test_random_shifts_are_uniform():
    from scipy import stats
    n, g = 64, 19
    sets = np.broadcast_to(rank1_lattice(n, g), (400, n, 2))
    rngs = [np.random.default_rng(s) for s in range(400)]
    out = nearest_rank1_lattice(sets, rngs)
    assert np.all(fit_rank1_lattice(out)[0] == g)
    # the point with the smallest x sits at (a / n, y): a uniform in [0, 1), y uniform
    first = out[np.arange(400), np.argmin(out[..., 0], axis=1)]
    assert stats.kstest(first[:, 0] * n, "uniform").pvalue > 0.01
    assert stats.kstest(first[:, 1], "uniform").pvalue > 0.01
    with pytest.raises(ValueError, match=r"one generator per set \(400\), got 2"):
        nearest_rank1_lattice(sets, rngs[:2])


def test_single_set_matches_batch():
    pts = np.random.default_rng(3).random((2, 64, 2))
    g, shift, fit = fit_rank1_lattice(pts)
    g0, shift0, fit0 = fit_rank1_lattice(pts[0])
    assert int(g0) == int(g[0]) and float(fit0) == float(fit[0])
    np.testing.assert_array_equal(shift0, shift[0])
    np.testing.assert_array_equal(nearest_rank1_lattice(pts[1]), nearest_rank1_lattice(pts)[1])


def test_bad_input_is_refused():
    with pytest.raises(ValueError, match=r"shape \(n, 2\) or \(sets, n, 2\).*got \(5, 3\)"):
        fit_rank1_lattice(np.zeros((5, 3)))
    with pytest.raises(ValueError, match="n >= 4"):
        fit_rank1_lattice(np.zeros((2, 2)))
    with pytest.raises(ValueError, match="coprime to n = 64, got 6"):
        rank1_lattice(64, 6)


@pytest.mark.slow
def test_card_structure_at_every_side(tiny_onnx, tmp_path):
    from export.pipeline_edit import edit_pipeline
    path = tmp_path / "m.onnx"
    shutil.copy(tiny_onnx, path)
    base = diffsampler_rt.Model(path).card["pipeline"]  # the export's: thinning only
    plain = {n: diffsampler_rt.Model(path).generate(n, 3, seed=6) for n in (25, 64)}
    edit_pipeline(path, add="rank1_lattice", at=0)  # where the lattice models have it
    m = diffsampler_rt.Model(path)
    assert m.card["pipeline"] == [{"step": "rank1_lattice"}, *base]
    for n in (25, 64):  # not only power-of-two sides
        out = m.generate(n, 3, seed=6)
        # the network's lattice under a random shift: same generator, same set up to a shift
        g = fit_rank1_lattice(plain[n])[0]
        np.testing.assert_array_equal(fit_rank1_lattice(out)[0], g)
        for a, b in zip(out, nearest_rank1_lattice(plain[n])):
            moved = (a - a[0] + b[0]) % 1
            assert cKDTree(b, boxsize=1.0).query(moved)[0].max() < 1e-9
        np.testing.assert_array_equal(m.generate(n, 3, seed=6), out)  # same seed, same sets
        np.testing.assert_array_equal(  # batching does not change a set
            np.concatenate(list(m.iter_sets(n, 3, batch=1, seed=6))), out)
        np.testing.assert_array_equal(m.generate(n, 3, seed=6, structure=False), plain[n])
    out_25 = m.generate(25, 3, seed=6)
    before = path.read_bytes()
    with pytest.raises(ValueError, match="cannot steer towards 'rank1_lattice'"):
        edit_pipeline(path, add="structure_guidance", params={"steps": 2})
    assert path.read_bytes() == before  # left as it was
    # limited to listed grid sides: elsewhere the network's sets
    card = edit_pipeline(path, update="rank1_lattice", params={"sides": [5]})
    assert card["pipeline"] == [{"step": "rank1_lattice", "sides": [5]}, *base]
    m = diffsampler_rt.Model(path)
    np.testing.assert_array_equal(m.generate(25, 3, seed=6), out_25)
    np.testing.assert_array_equal(m.generate(64, 3, seed=6), plain[64])
    assert edit_pipeline(path, remove="rank1_lattice")["pipeline"] == base


@pytest.mark.parametrize("pipeline, message", [
    # sides belong to a structure step
    ([{"step": "thin", "sides": [8]}], "step 'thin' has no parameter 'sides'"),
    ([{"step": "rank1_lattice", "sides": [16, 8]}, {"step": "thin"}],
     "'sides' must be a list of increasing grid sides >= 1, got [16, 8]"),
    ([{"step": "rank1_lattice", "sides": 8}, {"step": "thin"}], "got 8"),
    ([{"step": "rank1_lattice", "sides": [0, 8]}, {"step": "thin"}], "got [0, 8]"),
    ([{"step": "rank1_lattice", "sides": [8, 8.5]}, {"step": "thin"}], "got [8, 8.5]"),
])
def test_structure_sides_are_validated(pipeline, message):
    from .conftest import pipeline_card_error
    text = pipeline_card_error("rank1", pipeline, message)
    assert f"pipeline entry 0: step {pipeline[0]['step']!r}" in text


def test_card_structure_needs_no_stratified_embedding():
    from diffsampler_rt.card import CARD_KEY, parse_card
    card = dict(diffsampler_rt.load("rank1").card)
    assert card["embedding"] == "ot" and find(card["pipeline"], "rank1_lattice") is not None
    parse_card({CARD_KEY: json.dumps(card)}, "m")
    guided = {**card, "pipeline": [*card["pipeline"], {"step": "structure_guidance", "steps": 3}]}
    with pytest.raises(ModelFormatError, match="cannot steer towards 'rank1_lattice'"):
        parse_card({CARD_KEY: json.dumps(guided)}, "m")


@pytest.mark.parametrize("name, choose", [("rank1", maxmin_generator), ("lattice", p2_generator)])
def test_bundled_models_give_the_reference_lattice_at_trained_sizes(name, choose):
    # measured: every set at n = 64, 256 and 1024 (benchmarks/results/fidelity.md)
    assert find(diffsampler_rt.load(name).card["pipeline"], "rank1_lattice")["sides"][:2] == \
        [8, 16]
    for n in (64, 256):
        sets = diffsampler_rt.generate(name, n, 2, seed=0)
        gen, _, fit = fit_rank1_lattice(sets)
        assert np.all(gen == choose(n)) and np.all(fit > 0.95)


def test_docstring_examples():
    assert doctest.testmod(lattice).failed == 0


@pytest.mark.slow
def test_pipeline_cli_lattice_structure(tiny_onnx, tmp_path, capsys):
    from export.__main__ import main
    path = tmp_path / "m.onnx"
    shutil.copy(tiny_onnx, path)
    base = diffsampler_rt.Model(path).card["pipeline"]  # the export's: thinning only
    assert main(["pipeline", str(path), "--add", "rank1_lattice", "--at", "0",
                 "--sides", "[8,16,24]"]) == 0
    assert capsys.readouterr().out.startswith(
        "0. rank1_lattice: nearest rank-1 lattice at k in [8, 16, 24], and of n points where "
        "n is not a square\n1. thin: ")
    assert diffsampler_rt.Model(path).card["pipeline"] == [
        {"step": "rank1_lattice", "sides": [8, 16, 24]}, *base]
    before = path.read_bytes()
    for sides, message in (("8,x", "'sides' must be a list of increasing grid sides >= 1, "
                                    "got '8,x'"),
                           ("[16,8]", "'sides' must be a list of increasing grid sides >= 1, "
                                      "got [16, 8]")):
        assert main(["pipeline", str(path), "--update", "rank1_lattice", "--sides", sides]) == 2
        err = capsys.readouterr().err
        assert err.startswith("error: ") and message in err, err
        assert path.read_bytes() == before  # left as it was
