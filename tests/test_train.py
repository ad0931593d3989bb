import csv
import warnings

import pytest

torch = pytest.importorskip("torch")

from trainer.config import TrainConfig  # noqa: E402
from trainer.train import Trainer, load_checkpoint, lr_at  # noqa: E402

from .conftest import recipe_stage, tiny_config  # noqa: E402

# minutes in all: run by the full suite, not by `pytest -m "not slow"`
pytestmark = pytest.mark.slow


def test_exact_resume_after_stop(tmp_path):
    cfg = tiny_config()
    straight = Trainer(cfg, tmp_path / "a", progress=False)
    straight.run()
    first = Trainer(cfg, tmp_path / "b", progress=False)
    first.run(until_step=3)
    del first  # as if killed after its checkpoint
    resumed = Trainer(cfg, tmp_path / "b", progress=False)
    assert resumed.step == 3
    resumed.run()
    a = load_checkpoint(tmp_path / "a" / "checkpoint.pt")
    b = load_checkpoint(tmp_path / "b" / "checkpoint.pt")
    assert a["step"] == b["step"] == cfg.steps
    assert a["devices"] == b["devices"] == ["cpu"]  # for the card: where the run trained
    for key in ("model", "ema"):
        for name in a[key]:
            assert torch.equal(a[key][name], b[key][name]), f"{key}.{name} differs"


def test_loss_log_and_config_round_trip(tmp_path):
    cfg = tiny_config(sampler="rank1", embedding="ot")
    Trainer(cfg, tmp_path, progress=False).run()
    rows = list(csv.DictReader(open(tmp_path / "log.csv")))
    assert [int(r["step"]) for r in rows] == list(range(1, cfg.steps + 1))
    assert all(float(r["loss"]) > 0 for r in rows)
    assert TrainConfig.from_dict(load_checkpoint(tmp_path / "checkpoint.pt")["config"]) == cfg


def test_resume_with_other_config_refused(tmp_path):
    Trainer(tiny_config(), tmp_path, progress=False).run(until_step=1)
    with pytest.raises(ValueError, match="different config"):
        Trainer(tiny_config(name="other"), tmp_path, progress=False)


def test_loss_goes_down_on_a_tiny_problem(tmp_path):
    from dataclasses import replace
    cfg = replace(tiny_config(), steps=60, lr=2e-3, warmup_steps=5)
    Trainer(cfg, tmp_path, progress=False).run()
    loss = [float(r["loss"]) for r in csv.DictReader(open(tmp_path / "log.csv"))]
    assert sum(loss[-10:]) < 0.6 * sum(loss[:10])


def test_learning_rate_schedule():
    cfg = tiny_config()
    assert lr_at(cfg, 0) < lr_at(cfg, 1) <= cfg.lr
    assert lr_at(cfg, cfg.steps) == pytest.approx(0.1 * cfg.lr)


def test_unknown_config_key():
    with pytest.raises(ValueError, match="unknown config keys"):
        TrainConfig.from_dict({"name": "x", "data": {"sampler": "rank1", "embedding": "ot"},
                               "stepz": 3})


def test_sampling_defaults_validated():
    base = {"name": "x", "data": {"sampler": "rank1", "embedding": "ot"}}
    cfg = TrainConfig.from_dict(base)
    assert (cfg.default_solver, cfg.default_sample_steps) == ("dpmpp_2m", 20)
    with pytest.raises(ValueError, match="default_solver 'rk4'"):
        TrainConfig.from_dict({**base, "default_solver": "rk4"})
    with pytest.raises(ValueError, match="default_sample_steps must be >= 1, got 0"):
        TrainConfig.from_dict({**base, "default_sample_steps": 0})


def test_bundled_recipes_load():
    from pathlib import Path
    for path in Path("trainer/configs").glob("*.json"):
        cfg = TrainConfig.load(path)
        # later training stages (NAME_stageN.json) share their model's name and start from
        # the previous stage's export in that stage's run directory
        stem, _, previous = recipe_stage(path)
        assert cfg.name == stem
        if previous:
            assert cfg.init_from == f"runs/{previous}/{cfg.name}.onnx"
            assert cfg.unet == TrainConfig.load(path.with_name(f"{previous}.json")).unet


def test_recipes_starting_from_bundled_models_load_them():
    # a bundled model re-exported with another architecture (e.g. attention windows) must
    # not silently break the recipes that start from it (gbn_blob's did, for a while)
    from pathlib import Path
    from trainer.train import initial_weights
    from trainer.unet import UNet
    starts = [TrainConfig.load(p) for p in sorted(Path("trainer/configs").glob("*.json"))]
    starts = [c for c in starts if c.init_from and Path(c.init_from).is_file()]
    assert {c.name for c in starts} >= {"gbn_blob", "gbn_torus", "sot_ramp"}
    for cfg in starts:
        UNet(cfg.unet).load_state_dict(initial_weights(cfg))  # strict: every weight fits


def test_second_stage_starts_from_the_exported_weights(tiny_onnx, tmp_path):
    from dataclasses import replace
    from .conftest import TINY_ONNX_UNET
    ref = torch.load(tiny_onnx.with_suffix(".state"))
    cfg = replace(tiny_config(**TINY_ONNX_UNET), init_from=str(tiny_onnx))
    tr = Trainer(cfg, tmp_path / "stage2", progress=False)
    for net in (tr.model, tr.ema):
        for name, value in net.state_dict().items():
            assert torch.equal(value, ref[name]), name
    tr.run(until_step=2)
    assert load_checkpoint(tmp_path / "stage2" / "checkpoint.pt")["config"]["init_from"] \
        == str(tiny_onnx)
    # a checkpoint works as a source too (its EMA weights)
    ckpt_cfg = replace(cfg, init_from=str(tmp_path / "stage2" / "checkpoint.pt"))
    again = Trainer(ckpt_cfg, tmp_path / "stage3", progress=False)
    for name, value in again.model.state_dict().items():
        assert torch.equal(value, tr.ema.state_dict()[name]), name


def test_a_circular_net_starts_from_zero_padded_weights(tiny_onnx, tmp_path):
    from dataclasses import replace
    from .conftest import TINY_ONNX_UNET
    ref = torch.load(tiny_onnx.with_suffix(".state"))
    cfg = replace(tiny_config(**TINY_ONNX_UNET, padding="circular"), init_from=str(tiny_onnx))
    tr = Trainer(cfg, tmp_path / "torus", progress=False)  # padding has no weights
    for name, value in tr.model.state_dict().items():
        assert torch.equal(value, ref[name]), name
    assert tr.model.cfg.padding == "circular"


def test_second_stage_refuses_another_architecture(tiny_onnx, tmp_path):
    from dataclasses import replace
    cfg = replace(tiny_config(), init_from=str(tiny_onnx))  # no coord bits, no axial attention
    with pytest.raises(ValueError, match="architecture"):
        Trainer(cfg, tmp_path, progress=False)
    with pytest.raises(FileNotFoundError, match="does not exist"):
        Trainer(replace(cfg, init_from=str(tmp_path / "nope.onnx")), tmp_path / "b",
                progress=False)


def test_second_stage_may_add_coordinate_bits(tiny_onnx, tmp_path):
    """More coord bits than the source: the new input channels start at zero weight, so the
    warm-started net computes the source's function (and fewer bits are refused)."""
    from dataclasses import replace
    from trainer.unet import UNet
    from .conftest import TINY_ONNX_UNET
    src = UNet(tiny_config(**TINY_ONNX_UNET).unet).eval()
    src.load_state_dict(torch.load(tiny_onnx.with_suffix(".state")))
    wider = {**TINY_ONNX_UNET, "coord_bits": TINY_ONNX_UNET["coord_bits"] + 2}
    tr = Trainer(replace(tiny_config(**wider), init_from=str(tiny_onnx)), tmp_path / "a",
                 progress=False)
    x, t = torch.randn(3, 2, 8, 8), torch.tensor([3.0, 400.0, 900.0])
    with torch.no_grad():
        torch.testing.assert_close(tr.ema.eval()(x, t), src(x, t), rtol=0, atol=1e-6)
    fewer = {**TINY_ONNX_UNET, "coord_bits": 1}
    with pytest.raises(ValueError, match="architecture"):
        Trainer(replace(tiny_config(**fewer), init_from=str(tiny_onnx)), tmp_path / "b",
                progress=False)


def test_bf16_autocast_trains(tmp_path):
    from dataclasses import replace
    cfg = replace(tiny_config(), bf16=True, steps=3)
    with warnings.catch_warnings():  # this CPU may lack native bf16 (tested below)
        warnings.simplefilter("ignore")
        tr = Trainer(cfg, tmp_path, progress=False)
    tr.run()
    assert tr.step == 3
    assert all(p.dtype == torch.float32 and torch.isfinite(p).all()
               for p in tr.model.parameters())


@pytest.mark.parametrize("native", [True, False])
def test_bf16_on_a_cpu_without_it_warns(tmp_path, monkeypatch, native):
    """Emulated bf16 autocast is ~16-20x slower than float32: say so, and how to avoid it."""
    from dataclasses import replace

    import trainer.train
    monkeypatch.setattr(trainer.train, "native_bf16", lambda device: native)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        Trainer(replace(tiny_config(), bf16=True), tmp_path / "a", progress=False)
        Trainer(tiny_config(), tmp_path / "b", progress=False)  # float32: never a warning
    messages = [str(w.message) for w in caught]
    if native:
        assert not any("bf16" in m for m in messages)
    else:
        assert sum("bf16" in m for m in messages) == 1
        assert "'tiny'" in messages[0] and "--fp32" in messages[0]


def test_native_bf16_answers():
    from trainer.train import native_bf16
    assert isinstance(native_bf16(torch.device("cpu")), bool)
