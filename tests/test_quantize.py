"""8-bit convolutions (export/quantize.py) and the quantised bundled models."""
import json
from pathlib import Path

import numpy as np
import pytest

onnx = pytest.importorskip("onnx")
pytest.importorskip("torch")

import diffsampler_rt  # noqa: E402
from trainer import zoo  # noqa: E402
from diffsampler_rt.card import CARD_KEY  # noqa: E402
from export.__main__ import main as export_main  # noqa: E402
from export.quantize import quantize, solver_inputs  # noqa: E402
from trainer.distil import network_hash  # noqa: E402

from .conftest import session_entry  # noqa: E402

# minutes in all: run by the full suite, not by `pytest -m "not slow"`
pytestmark = pytest.mark.slow

ROOT = Path(__file__).resolve().parents[1]


@pytest.fixture(scope="module")
def tiny_int8(tiny_onnx, tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("int8") / "tiny_int8.onnx"
    quantize(tiny_onnx, out, sets=2, seed=0)
    return out


def test_calibration_sees_every_solver_input_at_the_trained_sides(tiny_onnx):
    card = diffsampler_rt.load(tiny_onnx).card
    feeds = solver_inputs(tiny_onnx, (4, 8), sets=3, seed=0)
    assert len(feeds) == 2 * card["default_steps"]  # one per solver step and side
    assert [f["x"].shape for f in feeds[::card["default_steps"]]] == [(3, 2, 4, 4), (3, 2, 8, 8)]
    # from pure noise down to the last, nearly clean step
    assert feeds[0]["t"][0] > feeds[card["default_steps"] - 1]["t"][0]


def test_quantised_file_keeps_the_card_and_only_the_inner_convolutions_change(tiny_onnx,
                                                                            tiny_int8):
    before = diffsampler_rt.load(tiny_onnx).card
    after = diffsampler_rt.load(tiny_int8).card
    assert after["weights"] == "int8"
    q = after["quantization"]
    assert q["sides"] == [4, 8] and q["sets_per_side"] == 2
    assert q["feeds"] == 2 * before["default_steps"]
    assert q["float_network_sha1"] == network_hash(tiny_onnx)
    assert after["provenance"].startswith(before["provenance"])
    changed = {k for k in set(before) | set(after) if before.get(k) != after.get(k)}
    assert changed == {"weights", "quantization", "provenance"}
    ops = [n.op_type for n in onnx.load(str(tiny_int8)).graph.node]
    float_convs = ops.count("Conv")
    assert float_convs == 2  # the 2-channel stem and the eps head stay float
    assert ops.count("QLinearConv") == [n.op_type for n in
                                        onnx.load(str(tiny_onnx)).graph.node].count("Conv") - 2


def test_quantised_model_generates_valid_reproducible_sets_at_any_side(tiny_int8):
    m = diffsampler_rt.load(tiny_int8)
    for n in (16, 25, 64, 144):
        pts = m.generate(n, 3, seed=1)
        assert pts.shape == (3, n, 2)
        assert np.isfinite(pts).all() and (pts >= 0).all() and (pts < 1).all()
    np.testing.assert_array_equal(m.generate(64, 2, seed=4), m.generate(64, 2, seed=4))


def test_bundled_quantised_network_stays_close_to_its_float_one():
    # gbn_fast's eps prediction along its own 8-step trajectories at the trained k = 32:
    # measured 0.9 % relative RMS error in the noisy steps and 3 % in the last, nearly
    # clean one (benchmarks/results/quantized.md has what that does to the sets)
    f = diffsampler_rt.load(ROOT / "models" / "float" / "gbn_fast.onnx")
    q = diffsampler_rt.load("gbn_fast")
    for feed in solver_inputs(f.path, (32,), sets=2, seed=99):
        x, t = feed["x"].astype(np.float64), int(feed["t"][0])
        ef, eq = f.denoise(x, t), q.denoise(x, t)
        error = np.sqrt(np.mean((eq - ef) ** 2) / np.mean(ef ** 2))
        assert 0 < error < (0.015 if t > 300 else 0.05), (t, error)


def test_sessions_ask_for_exact_8_bit_products_unless_the_cpu_has_vnni():
    # without it, x86 CPUs lacking VNNI (AVX2-only) saturate the 8-bit products: gbn_fast's
    # error above measured 2.0 % in the noisy steps on an AMD EPYC (AVX2) host, 0.9 % with it
    from diffsampler_rt.model import X64_QUANT_PRECISION, needs_exact_8bit
    want = "1" if needs_exact_8bit() else None
    for model in (diffsampler_rt.load("gbn_fast"), diffsampler_rt.load("sot")):
        assert session_entry(model.session.get_session_options(), X64_QUANT_PRECISION) == want


def test_vnni_is_read_from_the_cpu_flags():
    from diffsampler_rt.model import needs_exact_8bit
    epyc = "processor\t: 0\nmodel name\t: AMD EPYC 7763\nflags\t\t: fpu sse4_2 avx2 fma\n"
    xeon = "flags\t\t: fpu avx2 avx512f avx512_vnni amx_int8\nbugs\t\t: spectre_v1\n"
    alder = "flags\t\t: fpu avx2 avx_vnni\n"
    assert needs_exact_8bit(epyc) and not needs_exact_8bit(xeon)
    assert not needs_exact_8bit(alder)
    assert needs_exact_8bit("") and needs_exact_8bit("Features\t: fp asimd\n")  # arm64


@pytest.mark.skipif(diffsampler_rt.model.needs_exact_8bit(), reason="needs a CPU with VNNI")
@pytest.mark.parametrize("name", ["gbn_fast", "sot_fast", "sobol_owen_fast"])
def test_with_vnni_the_exact_option_changes_no_output(name):
    # the grounds for leaving the option off on VNNI CPUs (where it halves the speed)
    import onnxruntime as ort

    from diffsampler_rt.model import X64_QUANT_PRECISION, resolve, session_options
    exact = session_options(1)
    exact.add_session_config_entry(X64_QUANT_PRECISION, "1")
    sessions = [ort.InferenceSession(str(resolve(name)), sess_options=o,
                                     providers=["CPUExecutionProvider"])
                for o in (exact, session_options(1))]
    rng = np.random.default_rng(5)
    for k, t in ((8, 999), (16, 400), (32, 40)):
        feed = {"x": rng.standard_normal((3, 2, k, k)).astype(np.float32),
                "t": np.full(3, t, np.float32)}
        a, b = (s.run(["eps"], feed)[0] for s in sessions)
        np.testing.assert_array_equal(a, b)


def test_exact_8_bit_option_leaves_float_networks_alone(tiny_onnx, monkeypatch):
    from diffsampler_rt import model as M
    with_it = M.Model(tiny_onnx).generate(64, 2, seed=3)
    plain = M.session_options

    def without(threads=None, *, spinning=True):
        opts = plain(threads, spinning=spinning)
        opts.add_session_config_entry(M.X64_QUANT_PRECISION, "0")
        return opts

    monkeypatch.setattr(M, "session_options", without)
    np.testing.assert_array_equal(M.Model(tiny_onnx).generate(64, 2, seed=3), with_it)


def test_quantising_twice_or_warm_starting_from_int8_is_refused(tiny_int8, tmp_path):
    with pytest.raises(ValueError, match="already int8"):
        quantize(tiny_int8, tmp_path / "again.onnx")
    from trainer.warm_start import net_from_onnx
    with pytest.raises(ValueError, match="quantised convolutions"):
        net_from_onnx(tiny_int8)


def test_quantize_cli(tiny_onnx, tmp_path, capsys):
    out = tmp_path / "q.onnx"
    assert export_main(["quantize", str(tiny_onnx), "-o", str(out), "--sets", "1"]) == 0
    assert "calibrated on" in capsys.readouterr().out
    meta = {p.key: p.value for p in onnx.load(str(out)).metadata_props}
    assert json.loads(meta[CARD_KEY])["quantization"]["sets_per_side"] == 1
    assert export_main(["quantize", str(tmp_path / "none.onnx"), "-o", str(out)]) == 2
    assert "not found" in capsys.readouterr().err
    assert export_main(["quantize", str(tiny_onnx), "-o", str(out), "--sets", "0"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "sets must be >= 1, got 0" in err


def test_bundled_quantised_models_come_from_the_float_files_kept_in_the_repo():
    # the float file is what `python -m export quantize` needs to reproduce the bundled one,
    # and what benchmarks/quantized.py compares it with
    quantised = [m for m in zoo.networks()
                 if diffsampler_rt.load(m).card.get("weights") == "int8"]
    assert quantised, "no quantised bundled model"
    for name in quantised:
        card = diffsampler_rt.load(name).card
        source = ROOT / "models" / "float" / f"{name}.onnx"
        assert network_hash(source) == card["quantization"]["float_network_sha1"], name
        float_card = diffsampler_rt.load(source).card
        assert float_card["weights"] in ("fp16", "fp32")
        assert {k: v for k, v in float_card.items() if k not in ("weights", "provenance")} == {
            k: v for k, v in card.items() if k not in ("weights", "provenance", "quantization")}


@pytest.fixture(scope="module")
def circular_pair(tiny_onnx, tmp_path_factory) -> tuple[Path, Path]:
    """The tiny net with circular padding (float, fp16 weights) and its 8-bit file."""
    import torch
    from export.onnx_export import export_model, model_card
    from trainer.unet import UNet
    from .conftest import TINY_ONNX_UNET, tiny_config

    cfg = tiny_config(**TINY_ONNX_UNET, padding="circular")
    net = UNet(cfg.unet).eval()
    net.load_state_dict(torch.load(tiny_onnx.with_suffix(".state")))
    out = tmp_path_factory.mktemp("circular")
    export_model(net, model_card(cfg, training_steps=0), out / "f.onnx", fp16_weights=True)
    quantize(out / "f.onnx", out / "q.onnx", sets=2, seed=0)
    return out / "f.onnx", out / "q.onnx"


def _wrap_pads(model) -> int:
    return sum(n.op_type == "Pad" and any(a.name == "mode" and a.s == b"wrap"
                                          for a in n.attribute) for n in model.graph.node)


def _run(model, x, t):
    import onnxruntime as ort
    sess = ort.InferenceSession(model.SerializeToString(), providers=["CPUExecutionProvider"])
    return sess.run(None, {"x": x, "t": t})[0]


def test_wrap_pads_are_rewritten_exactly(circular_pair):
    from export.wrap_pad import unroll_wrap_pads
    f, q = circular_pair
    model, rewritten = onnx.load(str(f)), onnx.load(str(f))
    assert _wrap_pads(model) and unroll_wrap_pads(rewritten) == _wrap_pads(model)
    assert _wrap_pads(rewritten) == 0
    used = {name for node in rewritten.graph.node for name in node.input}
    assert {i.name for i in rewritten.graph.initializer} <= used  # no dead pads constants
    onnx.checker.check_model(rewritten)
    rng = np.random.default_rng(0)
    for k in (4, 5, 8, 13):  # odd sides, and k = 4's 1 x 1 coarsest level
        x = rng.standard_normal((2, 2, k, k)).astype(np.float32)
        t = np.array([3.0, 900.0], np.float32)
        np.testing.assert_array_equal(_run(model, x, t), _run(rewritten, x, t))
    # quantize() applied both to the 8-bit file: no wrap Pad left, and its card says so
    assert _wrap_pads(onnx.load(str(q))) == 0
    record = diffsampler_rt.load(q).card["quantization"]
    assert "all as Slice and Concat" in record["wrap_pads"]
    assert "quantization" not in diffsampler_rt.load(f).card


def _runtime_run(path, x, t):
    import onnxruntime as ort
    from diffsampler_rt.model import session_options
    sess = ort.InferenceSession(str(path), sess_options=session_options(1),
                                providers=["CPUExecutionProvider"])
    return sess.run(["eps"], {"x": x, "t": t})[0]


def _channels_last_pads(model) -> int:
    return sum(n.op_type == "Transpose" and n.name.endswith("_nhwc") for n in model.graph.node)


def test_wrap_pads_feeding_8_bit_convolutions_are_copied_channels_last(circular_pair, tmp_path,
                                                                        monkeypatch):
    import export.quantize as quantize_module
    from export.quantize import wrap_pads_to_channels_last
    from export.wrap_pad import wrap_pads_channels_last
    f, q = circular_pair
    count = _channels_last_pads(onnx.load(str(q)))
    assert count > 0
    record = diffsampler_rt.load(q).card["quantization"]["wrap_pads"]
    assert record.endswith(f"all as Slice and Concat; {count} of them copied channels-last")
    # the same file with its pads quantised in place, then rewritten: exactly q's outputs
    with monkeypatch.context() as patch:
        patch.setattr(quantize_module, "wrap_pads_channels_last", lambda model: 0)
        quantize(f, tmp_path / "plain.onnx", sets=2, seed=0)
    plain = onnx.load(str(tmp_path / "plain.onnx"))
    assert _channels_last_pads(plain) == 0
    assert diffsampler_rt.load(tmp_path / "plain.onnx").card["quantization"]["wrap_pads"] == (
        record.split("; ")[0] + "; all as Slice and Concat")
    assert wrap_pads_to_channels_last(tmp_path / "plain.onnx", tmp_path / "cl.onnx") == count
    rewritten = onnx.load(str(tmp_path / "cl.onnx"))
    onnx.checker.check_model(rewritten)
    assert diffsampler_rt.load(tmp_path / "cl.onnx").card == diffsampler_rt.load(q).card
    assert wrap_pads_channels_last(rewritten) == 0  # nothing left to rewrite
    used = {name for node in rewritten.graph.node for name in node.input}
    assert {i.name for i in rewritten.graph.initializer} <= used
    rng = np.random.default_rng(2)
    for k in (4, 5, 8, 13):
        x = rng.standard_normal((3, 2, k, k)).astype(np.float32)
        t = np.array([0.0, 400.0, 999.0], np.float32)
        want = _runtime_run(tmp_path / "plain.onnx", x, t)
        np.testing.assert_array_equal(_runtime_run(tmp_path / "cl.onnx", x, t), want)
        np.testing.assert_array_equal(_runtime_run(q, x, t), want)


def test_bundled_circular_8_bit_models_copy_their_pads_channels_last():
    from export.wrap_pad import wrap_pads_channels_last
    names = [m for m in zoo.networks()
             if diffsampler_rt.load(m).card.get("weights") == "int8"
             and diffsampler_rt.load(m).card["config"]["unet"].get("padding") == "circular"]
    assert names
    for name in names:
        model = onnx.load(str(diffsampler_rt.load(name).path))
        assert wrap_pads_channels_last(model) == 0, name
        assert _channels_last_pads(model) > 0, name
        assert "copied channels-last" in diffsampler_rt.load(name).card["quantization"]["wrap_pads"]


def test_channels_last_pads_cli(tiny_onnx, tmp_path, capsys):
    assert export_main(["channels-last-pads", str(tiny_onnx), "-o", str(tmp_path / "o.onnx")]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "has no 8-bit convolutions (weights: fp16)" in err
    assert export_main(["channels-last-pads", str(tmp_path / "none.onnx"), "-o",
                        str(tmp_path / "o.onnx")]) == 2
    assert "none.onnx not found" in capsys.readouterr().err
    (tmp_path / "text.onnx").write_text("not a model")
    for command in ("channels-last-pads", "quantize"):
        assert export_main([command, str(tmp_path / "text.onnx"), "-o",
                            str(tmp_path / "o.onnx")]) == 2
        err = capsys.readouterr().err
        assert err.count("\n") == 1 and "text.onnx is not a readable ONNX model" in err
    assert not (tmp_path / "o.onnx").exists()


def test_padding_after_quantising_gives_the_same_outputs():
    # a Pad(wrap) -> QuantizeLinear -> DequantizeLinear chain, swapped: bit for bit the same
    from onnx import TensorProto, helper, numpy_helper
    from export.wrap_pad import quantize_before_wrap_pads
    pads = numpy_helper.from_array(np.array([0, 0, 1, 1, 0, 0, 1, 1], np.int64), "pads")
    scale = numpy_helper.from_array(np.array(0.02, np.float32), "scale")
    zero = numpy_helper.from_array(np.array(128, np.uint8), "zero")
    graph = helper.make_graph(
        [helper.make_node("Pad", ["x", "pads"], ["p"], mode="wrap", name="pad"),
         helper.make_node("QuantizeLinear", ["p", "scale", "zero"], ["q"], name="quant"),
         helper.make_node("DequantizeLinear", ["q", "scale", "zero"], ["y"], name="deq")],
        "g", [helper.make_tensor_value_info("x", TensorProto.FLOAT, [None, 3, None, None])],
        [helper.make_tensor_value_info("y", TensorProto.FLOAT, [None, 3, None, None])],
        [pads, scale, zero],
        value_info=[helper.make_tensor_value_info("p", TensorProto.FLOAT, [None, 3, None, None])])
    model = helper.make_model(graph, opset_imports=[helper.make_opsetid("", 19)])
    swapped = onnx.load_from_string(model.SerializeToString())
    assert quantize_before_wrap_pads(swapped) == 1
    assert [n.op_type for n in swapped.graph.node] == ["QuantizeLinear", "Pad",
                                                       "DequantizeLinear"]
    onnx.checker.check_model(swapped, full_check=True)
    import onnxruntime as ort
    x = np.random.default_rng(1).standard_normal((2, 3, 5, 7)).astype(np.float32)
    a, b = (ort.InferenceSession(m.SerializeToString(), providers=["CPUExecutionProvider"])
            .run(None, {"x": x})[0] for m in (model, swapped))
    assert a.shape == (2, 3, 7, 9)
    np.testing.assert_array_equal(a, b)


def test_wrap_pads_wider_than_one_are_left_alone():
    # a Slice of the last p entries is the wrap only while p <= the side, unknown until run
    from onnx import TensorProto, helper, numpy_helper
    from export.wrap_pad import unroll_wrap_pads
    pads = numpy_helper.from_array(np.array([0, 0, 2, 1, 0, 0, 2, 1], np.int64), "pads")
    graph = helper.make_graph(
        [helper.make_node("Pad", ["x", "pads"], ["y"], mode="wrap", name="pad")], "g",
        [helper.make_tensor_value_info("x", TensorProto.FLOAT, [None, 1, None, None])],
        [helper.make_tensor_value_info("y", TensorProto.FLOAT, [None, 1, None, None])], [pads])
    model = helper.make_model(graph, opset_imports=[helper.make_opsetid("", 19)])
    assert unroll_wrap_pads(model) == 0
    assert [n.op_type for n in model.graph.node] == ["Pad"]
