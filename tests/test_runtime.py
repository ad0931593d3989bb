
import numpy as np
import pytest

import diffsampler_rt
from diffsampler_rt import (ModelFormatError, ModelNotFoundError, UnknownModelError, generate,
                            list_models, load)
from diffsampler_rt._validate import MAX_POINTS
from trainer import zoo


def test_bundled_models_present():
    assert {"rank1", "sobol_owen"} <= set(list_models())


@pytest.mark.parametrize("name", ["rank1", "sobol_owen"])
@pytest.mark.parametrize("n", [16, 64, 576, 625])
def test_bundled_models_generate(name, n):
    pts = generate(name, n, seed=1, steps=4)
    assert pts.shape == (n, 2) and pts.dtype == np.float64
    assert np.all(np.isfinite(pts)) and np.all((pts >= 0) & (pts < 1))


@pytest.mark.parametrize("name", list_models() + zoo.networks())
def test_every_bundled_model_runs_at_its_card_defaults(name):
    """Each bundled model makes a set with everything its card asks for (guide, polish,
    structure, density): a card that cannot run (e.g. a guide it no longer matches) fails
    here, not in a user's first call. At 256, where every card's settings are on (sot's
    guide is off at 64)."""
    pts = generate(name, 256, seed=2)
    assert pts.shape == (256, 2) and np.all(np.isfinite(pts)) and np.all((pts >= 0) & (pts < 1))


def test_count_and_determinism():
    a = generate("rank1", 64, count=3, seed=11, steps=5)
    assert a.shape == (3, 64, 2)
    np.testing.assert_array_equal(a, generate("rank1", 64, count=3, seed=11, steps=5))
    assert not np.array_equal(a, generate("rank1", 64, count=3, seed=12, steps=5))
    g = np.random.default_rng(11)
    np.testing.assert_array_equal(a, generate("rank1", 64, count=3, seed=g, steps=5))


def test_sets_do_not_depend_on_batching(monkeypatch):
    from diffsampler_rt import model
    a = generate("rank1", 64, count=4, seed=3, steps=3)
    monkeypatch.setattr(model, "POINTS_PER_BATCH", 64)  # one set per onnxruntime call
    np.testing.assert_allclose(a, generate("rank1", 64, count=4, seed=3, steps=3), atol=1e-6)


def test_ddpm_solver_is_seeded():
    a = generate("rank1", 64, seed=2, steps=4, solver="ddpm")
    np.testing.assert_array_equal(a, generate("rank1", 64, seed=2, steps=4, solver="ddpm"))
    assert not np.array_equal(a, generate("rank1", 64, seed=2, steps=4))


def test_stratified_model_keeps_one_point_per_cell():
    pts = generate("ldbn", 576, seed=0, steps=4)
    cell = np.floor(pts * 24).astype(int)
    assert np.unique(cell[:, 1] * 24 + cell[:, 0]).size == 576


def test_load_returns_reusable_model_with_card():
    m = load("sobol_owen")
    assert m is load("sobol_owen")  # cached
    for key in ("sampler", "schedule", "trained_sizes", "training_steps", "licence"):
        assert key in m.card
    assert m.generate(64, seed=0, steps=3).shape == (64, 2)


@pytest.mark.parametrize("n,exc,match", [
    (0, ValueError, "n must be positive, got 0"),
    (-5, ValueError, "got -5"),
    (15, ValueError, "n=15 is too small: at least 16"),
    (1, ValueError, "n=1 is too small"),
    (MAX_POINTS + 1, ValueError, "too large"),
    (10**12, ValueError, "too large"),
    (576.0, TypeError, "n must be an integer, got 576.0"),
    ("64", TypeError, "got '64'"),
    (True, TypeError, "got True"),
])
def test_bad_n(n, exc, match):
    with pytest.raises(exc, match=match):
        generate("rank1", n)


@pytest.mark.parametrize("kwargs,exc,match", [
    (dict(steps=0), ValueError, "steps must be between 1 and 1000.*got 0"),
    (dict(steps=-3), ValueError, "got -3"),
    (dict(steps=1001), ValueError, "got 1001"),
    (dict(steps=2.5), TypeError, "steps must be an integer"),
    (dict(count=0), ValueError, "count must be >= 1, got 0"),
    (dict(seed=-1), ValueError, "seed must be a non-negative integer, got -1"),
    (dict(seed="x"), TypeError, "seed must be an integer"),
    (dict(solver="euler"), ValueError, "unknown solver 'euler'"),
    (dict(structure="false"), TypeError, "structure must be True or False, got 'false'"),
    (dict(structure=None), TypeError, "structure must be True or False, got None"),
    (dict(progress=1), TypeError, "progress must be True or False, got 1"),
])
def test_bad_arguments(kwargs, exc, match):
    with pytest.raises(exc, match=match):
        generate("rank1", 64, **kwargs)


def test_bad_models(tmp_path):
    with pytest.raises(UnknownModelError, match="unknown model 'gbnx'.*rank1"):
        load("gbnx")
    with pytest.raises(ModelNotFoundError, match="missing.onnx"):
        load(tmp_path / "missing.onnx")
    corrupt = tmp_path / "corrupt.onnx"
    corrupt.write_bytes(b"not an onnx file at all")
    with pytest.raises(ModelFormatError, match="not a readable ONNX model"):
        load(corrupt)
    with pytest.raises(TypeError, match="model must be"):
        load(3)
    # errors subclass the built-ins users already catch
    assert issubclass(UnknownModelError, ValueError)
    assert issubclass(ModelNotFoundError, FileNotFoundError)


def test_onnx_without_card(tmp_path):
    onnx = pytest.importorskip("onnx")
    from onnx import TensorProto, helper
    graph = helper.make_graph([helper.make_node("Identity", ["x"], ["eps"])], "g",
                              [helper.make_tensor_value_info("x", TensorProto.FLOAT, None)],
                              [helper.make_tensor_value_info("eps", TensorProto.FLOAT, None)])
    model = helper.make_model(graph, opset_imports=[helper.make_opsetid("", 19)], ir_version=9)
    path = tmp_path / "plain.onnx"
    onnx.save(model, str(path))
    with pytest.raises(ModelFormatError, match="without a diffsampler model card"):
        load(path)


def test_card_validation():
    from diffsampler_rt.card import CARD_KEY, parse_card
    good = dict(load("rank1").card)
    with pytest.raises(ModelFormatError, match="format 99"):
        parse_card({CARD_KEY: __import__("json").dumps({**good, "format_version": 99})}, "m")
    with pytest.raises(ModelFormatError, match="schedule"):
        parse_card({CARD_KEY: __import__("json").dumps({**good, "schedule": {"kind": "x",
                                                                             "num_steps": 3}})}, "m")
    with pytest.raises(ModelFormatError, match="not valid JSON"):
        parse_card({CARD_KEY: "{"}, "m")


def test_docstring_examples():
    import doctest
    from diffsampler_rt import model
    assert doctest.testmod(model).failed == 0
    assert doctest.testmod(diffsampler_rt).failed == 0


def test_iter_sets_streams_the_same_sets_in_blocks():
    m = diffsampler_rt.load("rank1")
    blocks = list(m.iter_sets(64, 7, batch=3, seed=5, steps=4))
    assert [len(b) for b in blocks] == [3, 3, 1]
    np.testing.assert_array_equal(np.concatenate(blocks), m.generate(64, 7, seed=5, steps=4))
    with pytest.raises(ValueError, match="batch must be >= 1, got 0"):
        m.iter_sets(64, 7, batch=0)  # checked at the call, before iterating
    with pytest.raises(ValueError, match="count must be >= 1"):
        m.iter_sets(64, 0)


def test_circular_padding_makes_toroidal_sets(tiny_onnx, tmp_path):
    import json
    import onnx
    from diffsampler_rt.card import CARD_KEY
    model = onnx.load(str(tiny_onnx))
    prop = next(p for p in model.metadata_props if p.key == CARD_KEY)
    card = json.loads(prop.value)
    for padding in ("circular", "reflect"):
        prop.value = json.dumps({**card, "padding": padding})
        onnx.save(model, str(tmp_path / f"{padding}.onnx"))
    with pytest.raises(ModelFormatError, match="unknown padding 'reflect'"):
        load(tmp_path / "reflect.onnx")
    plain = generate(tiny_onnx, 64, 4, seed=3)
    torus = generate(tmp_path / "circular.onnx", 64, 4, seed=3)
    assert torus.shape == plain.shape and np.all((torus >= 0) & (torus < 1))
    np.testing.assert_array_equal(torus, generate(tmp_path / "circular.onnx", 64, 4, seed=3))
    # the untrained net's offsets leave their cells: decoding reflects them back into the
    # cell (one point a cell), clamping none onto a cell's edge or the square's
    from diffsampler_rt.grid import strip_bounds
    cells = np.stack(np.meshgrid(np.arange(8), np.arange(8)), -1).reshape(-1, 2)
    assert np.array_equal(np.floor(plain * 8), np.broadcast_to(cells, plain.shape))
    assert not np.isin(plain, np.concatenate(strip_bounds(8))).any()
    # the same sets on the torus, each shifted by its own random vector (every point)
    for s in range(4):
        d = np.mod(torus[s] - plain[s], 1.0)
        spread = np.abs(((d - d[0] + 0.5) % 1.0) - 0.5).max()
        assert spread < 1e-9 and len(d) == 64
    assert len({tuple(np.round(np.mod(torus[s, 0] - plain[s, 0], 1.0), 6)) for s in range(4)}) == 4
    # the shift is part of the model, like a density: structure=False keeps it
    bare = generate(tmp_path / "circular.onnx", 64, 4, seed=3, structure=False)
    np.testing.assert_array_equal(bare, torus)
