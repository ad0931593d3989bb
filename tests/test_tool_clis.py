"""The researcher-facing command lines: python -m trainer / python -m export."""
import json
import subprocess
import sys
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

torch = pytest.importorskip("torch")

from trainer.__main__ import main as trainer_main  # noqa: E402

from .conftest import tiny_config  # noqa: E402

# minutes in all: run by the full suite, not by `pytest -m "not slow"`
pytestmark = pytest.mark.slow

ROOT = Path(__file__).resolve().parents[1]


@pytest.mark.parametrize("suffix", ["npy", "txt", "csv"])
def test_trainer_sample(tmp_path, suffix):
    out = tmp_path / f"s.{suffix}"
    assert trainer_main(["sample", "sobol_owen", "64", "--count", "3", "--seed", "5",
                         "-o", str(out)]) == 0
    if suffix == "npy":
        pts = np.load(out)
    else:
        pts = np.loadtxt(out, delimiter="," if suffix == "csv" else None).reshape(3, 64, 2)
    from trainer.samplers import sample
    np.testing.assert_array_equal(pts, sample("sobol_owen", 64, count=3, seed=5))


def test_trainer_sample_bad_name(tmp_path, capsys):
    assert trainer_main(["sample", "nope", "64", "-o", str(tmp_path / "x.npy")]) == 2
    assert "unknown sampler 'nope'" in capsys.readouterr().err


def test_train_then_export_from_the_command_line(tmp_path):
    cfg = replace(tiny_config(), steps=3)
    cfg_path = tmp_path / "tiny.json"
    cfg_path.write_text(json.dumps(cfg.to_dict()))
    run = tmp_path / "run"
    res = subprocess.run([sys.executable, "-m", "trainer", "train", str(cfg_path),
                          "--run-dir", str(run), "--no-progress"],
                         capture_output=True, text=True, cwd=ROOT)
    assert res.returncode == 0, res.stderr
    assert (run / "checkpoint.pt").exists() and (run / "log.csv").exists()
    onnx_path = tmp_path / "tiny.onnx"
    res = subprocess.run([sys.executable, "-m", "export", str(run / "checkpoint.pt"),
                          "-o", str(onnx_path), "--sides", "8", "25"],
                         capture_output=True, text=True, cwd=ROOT)
    assert res.returncode == 0, res.stderr
    assert "parity max|diff| k=8" in res.stdout
    import diffsampler_rt
    m = diffsampler_rt.load(onnx_path)
    assert m.card["training_steps"] == 3
    assert m.generate(64, seed=0, steps=2).shape == (64, 2)


def test_train_fp32_overrides_the_configs_bf16(tmp_path, monkeypatch, capsys):
    import trainer.train
    monkeypatch.setattr(trainer.train, "native_bf16", lambda device: False)
    cfg_path = tmp_path / "tiny.json"
    cfg_path.write_text(json.dumps(replace(tiny_config(), steps=2, bf16=True).to_dict()))
    args = ["train", str(cfg_path), "--no-progress", "--steps", "1", "--run-dir"]
    assert trainer_main(args + [str(tmp_path / "bf16")]) == 0
    err = capsys.readouterr().err.splitlines()  # the warning: one line, as errors are
    assert len(err) == 1 and err[0].startswith("warning: config 'tiny' asks for bf16")
    assert "--fp32" in err[0]
    run = tmp_path / "fp32"
    assert trainer_main(args + [str(run), "--fp32"]) == 0
    assert "bf16" not in capsys.readouterr().err
    from trainer.train import load_checkpoint
    assert load_checkpoint(run / "checkpoint.pt")["config"]["bf16"] is False
    # the run records float32, so resuming it as the bf16 recipe is refused
    assert trainer_main(args + [str(run)]) == 2
    assert "different config" in capsys.readouterr().err


def test_export_missing_checkpoint(tmp_path):
    res = subprocess.run([sys.executable, "-m", "export", str(tmp_path / "none.pt"), "-o",
                          str(tmp_path / "x.onnx")], capture_output=True, text=True, cwd=ROOT)
    assert res.returncode == 2 and "not found" in res.stderr


def test_trainer_prepare_builds_the_pools(tmp_path, monkeypatch, capsys):
    monkeypatch.setenv("DIFFSAMPLER_CACHE", str(tmp_path / "cache"))
    cfg = tiny_config()
    cfg = replace(cfg, data=replace(cfg.data, pool_sizes=(3, 2)))
    path = tmp_path / "c.json"
    path.write_text(json.dumps(cfg.to_dict()))
    assert trainer_main(["prepare", str(path)]) == 0
    assert "k=8 pool (2, 2, 8, 8)" in capsys.readouterr().out
    assert len(list((tmp_path / "cache").glob("*.npy"))) == 2
