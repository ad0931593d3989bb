import json

import numpy as np
import pytest

torch = pytest.importorskip("torch")
onnx = pytest.importorskip("onnx")

pytestmark = pytest.mark.slow  # the exported fixture alone takes ~20 s

import diffsampler_rt  # noqa: E402
from diffsampler_rt.card import CARD_KEY  # noqa: E402
from diffsampler_rt.schedule import alphas_cumprod  # noqa: E402
from export import ParityError, check_parity  # noqa: E402
from trainer.diffusion import Diffusion  # noqa: E402
from trainer.unet import UNet  # noqa: E402

from .conftest import TINY_ONNX_UNET, tiny_config  # noqa: E402


def _tiny_net(path):
    net = UNet(tiny_config(**TINY_ONNX_UNET).unet).eval()
    net.load_state_dict(torch.load(path.with_suffix(".state")))
    return net


def test_parity_at_trained_unseen_and_odd_sides(tiny_onnx):
    diffs = check_parity(_tiny_net(tiny_onnx), tiny_onnx, sides=(8, 24, 25, 32, 64),
                         tolerance=1e-4)
    assert set(diffs) == {8, 24, 25, 32, 64}
    assert max(diffs.values()) < 1e-4


def test_parity_check_fails_loudly(tiny_onnx):
    net = _tiny_net(tiny_onnx)
    with torch.no_grad():
        net.out.bias.add_(1e-2)
    with pytest.raises(ParityError, match="k=8: max"):
        check_parity(net, tiny_onnx, sides=(8,), tolerance=1e-4)


def test_dynamic_batch_and_side(tiny_onnx):
    import onnxruntime as ort
    sess = ort.InferenceSession(str(tiny_onnx))
    x, t = sess.get_inputs()
    assert x.shape[0] == t.shape[0] and isinstance(x.shape[0], str)
    assert isinstance(x.shape[2], str) and x.shape[2] == x.shape[3]
    for b, k in [(1, 4), (5, 13)]:
        out = sess.run(None, {"x": np.zeros((b, 2, k, k), np.float32),
                              "t": np.zeros(b, np.float32)})[0]
        assert out.shape == (b, 2, k, k)


def test_self_contained_file_with_card(tiny_onnx):
    assert not tiny_onnx.with_suffix(".onnx.data").exists()
    model = onnx.load(str(tiny_onnx))
    props = {p.key: p.value for p in model.metadata_props}
    card = json.loads(props[CARD_KEY])
    for key in ("format_version", "sampler", "schedule", "training_steps", "trained_sizes",
                "embedding", "offset_scale", "padding", "licence", "provenance", "weights"):
        assert key in card, key
    assert card["weights"] == "fp16"
    # no per-node debug text (torch's stack traces) in the shipped file
    assert not any(node.metadata_props for node in model.graph.node)
    assert card["trained_sizes"] == [16, 64]
    assert card["train_devices"] == ["cpu"]


def test_runtime_reads_exported_model(tiny_onnx):
    m = diffsampler_rt.load(tiny_onnx)
    assert m.card["sampler"] == "sobol_owen"
    pts = m.generate(49, count=2, seed=0, steps=3)
    assert pts.shape == (2, 49, 2) and np.all((pts >= 0) & (pts < 1))


def test_runtime_and_trainer_share_the_schedule():
    for spec in ({"kind": "linear", "beta_start": 1e-4, "beta_end": 0.02, "num_steps": 1000},
                 {"kind": "cosine", "num_steps": 500}):
        np.testing.assert_array_equal(Diffusion(spec).alpha_bar.numpy(),
                                      alphas_cumprod(spec).astype(np.float32))


def test_runtime_loop_matches_a_torch_reference_loop(tiny_onnx):
    """The numpy DDIM loop over onnxruntime equals the same loop written in torch."""
    m = diffsampler_rt.load(tiny_onnx)
    net = _tiny_net(tiny_onnx)
    from diffsampler_rt.schedule import timesteps
    ab = alphas_cumprod(m.card["schedule"])
    ts = timesteps(len(ab), 4)
    x0 = np.random.default_rng(5).standard_normal((1, 2, 6, 6))
    x = torch.tensor(x0, dtype=torch.float64)
    for i, t in enumerate(ts):
        with torch.no_grad():
            eps = net(x.float(), torch.tensor([float(t)])).double()
        a, ap = ab[t], (ab[ts[i + 1]] if i + 1 < len(ts) else 1.0)
        pred = (x - np.sqrt(1 - a) * eps) / np.sqrt(a)
        x = np.sqrt(ap) * pred + np.sqrt(1 - ap) * eps
    from diffsampler_rt.solvers import ddim
    got = ddim(m.denoise, x0, ab, ts)
    np.testing.assert_allclose(got, x.numpy(), atol=1e-4)


def test_set_defaults_changes_what_generate_uses(tiny_onnx, tmp_path):
    import shutil
    import subprocess
    import sys
    from export.defaults import set_defaults
    path = tmp_path / "m.onnx"
    shutil.copy(tiny_onnx, path)
    assert diffsampler_rt.load(path).card["default_solver"] == "ddim"
    card = set_defaults(path, solver="dpmpp_2m", steps=6)
    assert (card["default_solver"], card["default_steps"]) == ("dpmpp_2m", 6)
    m = diffsampler_rt.Model(path)
    assert (m.card["default_solver"], m.card["default_steps"]) == ("dpmpp_2m", 6)
    np.testing.assert_array_equal(m.generate(64, 2, seed=3),
                                  m.generate(64, 2, seed=3, solver="dpmpp_2m", steps=6))
    assert not np.array_equal(m.generate(64, 2, seed=3), m.generate(64, 2, seed=3, solver="ddim"))
    with pytest.raises(ValueError, match="unknown solver 'rk4'"):
        set_defaults(path, solver="rk4")
    with pytest.raises(ValueError, match="at most the schedule"):
        set_defaults(path, steps=10**6)
    res = subprocess.run([sys.executable, "-m", "export", "set-defaults", str(path),
                          "--steps", "0"], capture_output=True, text=True)
    assert res.returncode == 2 and "steps must be an integer >= 1, got 0" in res.stderr
    assert res.stderr.strip().splitlines() == [res.stderr.strip()]  # one line
    # the finishing steps are no longer set-defaults' business: python -m export pipeline
    res = subprocess.run([sys.executable, "-m", "export", "set-defaults", str(path),
                          "--structure", "n_rooks"], capture_output=True, text=True)
    assert res.returncode == 2 and "--structure" in res.stderr
    assert diffsampler_rt.Model(path).card["default_steps"] == 6  # the file as it was


@pytest.mark.slow
def test_reexport_with_attention_window(tiny_onnx, tmp_path):
    from export.reexport import reexport
    out, diffs = reexport(tiny_onnx, tmp_path / "w.onnx", attention_window=2,
                          parity_sides=(4, 9, 16))
    assert max(diffs.values()) < 1e-4
    before, after = diffsampler_rt.Model(tiny_onnx), diffsampler_rt.Model(out)
    assert after.card["config"]["unet"]["attention_window"] == 2
    assert "attention windows of 2 cells" in after.card["provenance"]
    assert after.card["default_steps"] == before.card["default_steps"]
    x = np.random.default_rng(0).standard_normal((2, 2, 4, 4))
    # a 4 x 4 grid's attention level is 2 x 2: one window, the very same function
    np.testing.assert_allclose(after.denoise(x, 10), before.denoise(x, 10), atol=1e-6)
    x = np.random.default_rng(0).standard_normal((2, 2, 16, 16))
    assert np.abs(after.denoise(x, 10) - before.denoise(x, 10)).max() > 1e-4


def test_reexport_cli_rejects_bad_window(tiny_onnx, tmp_path, capsys):
    from export.__main__ import main
    assert main(["reexport", str(tiny_onnx), "-o", str(tmp_path / "x.onnx"),
                 "--attention-window", "-1"]) == 2
    assert "attention-window" in capsys.readouterr().err
