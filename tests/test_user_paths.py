"""The calls and commands a new user makes, and their error paths: the bundled model as
"gbn.onnx", folders, near-miss names, output paths checked before any work, format
conflicts, Ctrl-C / SIGTERM, too many threads, mistyped arguments, execution providers."""
from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
import warnings

import numpy as np
import pytest

import diffsampler_rt
from diffsampler_rt import ModelNotFoundError, UnknownModelError
from diffsampler_rt.cli import main
from diffsampler_rt.model import MODELS_DIR, MODELS_ENV, resolve


def test_the_bundled_model_by_file_name(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    monkeypatch.delenv(MODELS_ENV, raising=False)  # the wheel's models only
    assert resolve("gbn.onnx") == MODELS_DIR / "gbn.onnx"
    assert resolve("models/gbn.onnx") == MODELS_DIR / "gbn.onnx"
    np.testing.assert_array_equal(diffsampler_rt.generate("gbn.onnx", 64, seed=1),
                                  diffsampler_rt.generate("gbn", 64, seed=1))
    # an existing file always wins over the bundled one of its name
    (tmp_path / "gbn.onnx").write_bytes((MODELS_DIR / "rank1.onnx").read_bytes())
    assert resolve("gbn.onnx") == tmp_path / "gbn.onnx"
    # a bare name is the bundled model; "./name" is the file
    (tmp_path / "gbn").write_bytes(b"not a model")
    assert resolve("gbn") == MODELS_DIR / "gbn.onnx" and resolve("./gbn") == tmp_path / "gbn"


def test_a_folder_of_own_models_is_searched_by_name_first(tmp_path, monkeypatch):
    mine, more = tmp_path / "mine", tmp_path / "more"
    mine.mkdir(), more.mkdir()
    (more / "mymodel.onnx").write_bytes((MODELS_DIR / "rank1.onnx").read_bytes())
    (mine / "gbn.onnx").write_bytes((MODELS_DIR / "lattice.onnx").read_bytes())
    monkeypatch.setenv(MODELS_ENV, os.pathsep.join([str(mine), str(more)]))
    assert resolve("mymodel") == more / "mymodel.onnx"
    assert resolve("gbn") == mine / "gbn.onnx"  # the user's folder before the wheel's
    assert resolve("sot") == MODELS_DIR / "sot.onnx"  # not in a folder: the bundled one
    assert diffsampler_rt.load("mymodel").card["name"] == "rank1"
    with pytest.raises(UnknownModelError, match="unknown model 'other'"):
        resolve("other")


def test_folders_and_near_misses_are_named_as_such(tmp_path):
    with pytest.raises(ModelNotFoundError, match="is a folder"):
        resolve(tmp_path)
    with pytest.raises(UnknownModelError, match="did you mean gbn"):
        resolve("gbm")
    with pytest.raises(ModelNotFoundError, match="does not exist"):
        resolve(str(tmp_path / "nope.onnx"))


@pytest.mark.parametrize("argv, message", [
    (["generate", "rank1", "64", "-o", "{tmp}/missing/x.txt"], "does not exist"),
    (["generate", "rank1", "64", "-o", "{tmp}"], "is a folder"),
    (["generate", "rank1", "64", "-o", "{tmp}/x.npy", "--format", "txt"],
     "ends in .npy but --format is txt"),
    (["plot", "rank1", "64", "-o", "{tmp}/x.jpg"], "use .png, .pdf, .svg"),
    (["generate", "rank1", "64", "--provider", "NoSuchExecutionProvider"], "not available"),
])
def test_output_and_option_problems_fail_before_any_work(tmp_path, capsys, argv, message):
    argv = [a.replace("{tmp}", str(tmp_path)) for a in argv]
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert message in err and err.count("\n") == 1
    assert not list(tmp_path.glob("**/*.partial"))


def test_too_many_threads_warn_once_and_are_capped():
    from diffsampler_rt.shards import usable_cores
    with pytest.warns(UserWarning, match="more than the"):
        m = diffsampler_rt.Model("rank1", threads=usable_cores() + 7)
    assert m._threads == usable_cores()


def test_mistyped_arguments_raise_type_errors():
    with pytest.raises(TypeError, match="solver"):
        diffsampler_rt.generate("rank1", 64, solver=3)
    with pytest.raises(TypeError, match="providers"):
        diffsampler_rt.load("rank1", providers="CPUExecutionProvider")


def test_cpu_provider_given_explicitly_gives_the_same_sets():
    m = diffsampler_rt.load("rank1", providers=["CPUExecutionProvider"])
    np.testing.assert_array_equal(m.generate(64, 2, seed=3),
                                  diffsampler_rt.generate("rank1", 64, 2, seed=3))


@pytest.mark.parametrize("sig, code", [(signal.SIGINT, 130), (signal.SIGTERM, 143)])
def test_interrupted_generation_ends_in_one_line_and_leaves_no_file(tmp_path, sig, code):
    out = tmp_path / "sets.txt"
    proc = subprocess.Popen([sys.executable, "-m", "diffsampler_rt", "generate", "gbn_fast",
                             "1024", "--count", "100000", "-o", str(out)],
                            stderr=subprocess.PIPE, text=True,
                            env={**os.environ, "OMP_NUM_THREADS": "1"},
                            # a terminal's defaults, whatever an earlier test (or torch's
                            # elastic launcher) left this process ignoring
                            preexec_fn=lambda: [signal.signal(s, signal.SIG_DFL)
                                                for s in (signal.SIGINT, signal.SIGTERM)])
    try:
        deadline = time.monotonic() + 60
        while not out.with_name("sets.txt.partial").exists() and time.monotonic() < deadline:
            time.sleep(0.1)
        time.sleep(0.5)
        proc.send_signal(sig)
        _, err = proc.communicate(timeout=60)
    finally:  # a child that did not stop must not run on after the test
        proc.kill()
        proc.wait()
    assert proc.returncode == code
    assert err.strip() == "diffsampler: interrupted"
    assert list(tmp_path.iterdir()) == []
