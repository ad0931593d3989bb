import subprocess
import sys

import numpy as np
import pytest

from diffsampler_rt.cli import main


def run(*args):
    return subprocess.run([sys.executable, "-m", "diffsampler_rt", *args],
                          capture_output=True, text=True)


@pytest.mark.parametrize("fmt", ["txt", "npy", "csv"])
def test_generate_formats(tmp_path, fmt):
    out = tmp_path / f"pts.{fmt}"
    assert main(["generate", "rank1", "64", "--count", "8", "--seed", "1", "--steps", "4",
                 "-o", str(out)]) == 0
    if fmt == "npy":
        pts = np.load(out)
    elif fmt == "txt":
        pts = np.loadtxt(out).reshape(8, 64, 2)
    else:
        raw = np.loadtxt(out, delimiter=",", skiprows=1)
        assert np.array_equal(raw[:, 0], np.repeat(np.arange(8), 64))
        pts = raw[:, 1:].reshape(8, 64, 2)
    ref = __import__("diffsampler_rt").generate("rank1", 64, count=8, seed=1, steps=4)
    np.testing.assert_array_equal(pts, ref)  # repr() round-trips float64 exactly


def test_generate_to_stdout(capsys):
    assert main(["generate", "sobol_owen", "16", "--seed", "0", "--steps", "3"]) == 0
    lines = capsys.readouterr().out.strip().splitlines()
    assert len(lines) == 16 and all(len(l.split()) == 2 for l in lines)


def test_npy_to_a_terminal_is_refused(monkeypatch, capsys):
    class Terminal:  # stands in for an interactive stdout
        buffer = None

        def isatty(self):
            return True

    monkeypatch.setattr(sys, "stdout", Terminal())
    assert main(["generate", "rank1", "64", "--format", "npy"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "terminal" in err[0] and "-o" in err[0]


def test_generate_any_n(tmp_path):
    out = tmp_path / "pts.npy"
    assert main(["generate", "gbn_fast", "1000", "--count", "2", "--seed", "3", "-o",
                 str(out)]) == 0
    pts = np.load(out)
    assert pts.shape == (2, 1000, 2)
    np.testing.assert_array_equal(pts, __import__("diffsampler_rt").generate(
        "gbn_fast", 1000, count=2, seed=3))


def test_list_and_info(capsys, monkeypatch, tmp_path):
    import diffsampler_rt
    from diffsampler_rt.model import MODELS_ENV, bundled_models
    monkeypatch.delenv(MODELS_ENV)
    assert main(["list"]) == 0
    out = capsys.readouterr().out.splitlines()
    lines = {line.split()[0]: line for line in out[:-1]}
    assert sorted(lines) == bundled_models()  # one line per shipped model
    assert "network gbn_torus_fast" in lines["gbn"] and "ddim 6 steps" in lines["gbn"]
    assert "ms a 1024-point set" in lines["sobol_owen"] and "speed report" in out[-1]
    # one column each: every line's fields start where the others' do
    assert len({line.index(" network ") for line in lines.values()}) == 1
    # a folder of one's own models: listed by name, with its card's facts
    (tmp_path / "mine.onnx").write_bytes(diffsampler_rt.load("rank1").path.read_bytes())
    monkeypatch.setenv(MODELS_ENV, str(tmp_path))
    assert main(["list"]) == 0
    mine = next(l for l in capsys.readouterr().out.splitlines() if l.startswith("mine "))
    assert "network rank1" in mine and "not timed" in mine
    assert main(["info", "rank1"]) == 0
    out = capsys.readouterr().out
    assert '"sampler": "rank1"' in out
    # the card's finishing pipeline, one step a line, in order (format 2)
    steps = __import__("re").findall(r"(?m)^  (\d+)\. (\w+): ", out)
    assert steps == [("0", "rank1_lattice"), ("1", "thin")]


@pytest.mark.parametrize("args,match", [
    (["generate", "rank1", "15"], "n=15 is too small"),
    (["generate", "rank1", "0"], "n must be positive"),
    (["generate", "rank1", "abc"], "invalid int value: 'abc'"),
    (["generate", "nosuchmodel", "64"], "unknown model 'nosuchmodel'"),
    (["generate", "missing/model.onnx", "64"], "does not exist"),
    (["generate", "rank1", "64", "--steps", "0"], "steps must be between"),
    (["generate", "rank1", "64", "--format", "xml"], "invalid choice: 'xml'"),
    (["info", "nosuchmodel"], "unknown model"),
    (["frobnicate"], "invalid choice"),
])
def test_bad_input_exits_2_with_one_line(args, match):
    res = run(*args)
    assert res.returncode == 2
    assert res.stdout == ""
    lines = res.stderr.strip().splitlines()
    assert len(lines) == 1, res.stderr
    assert __import__("re").search(match, lines[0]), lines[0]


def test_closed_pipe_is_not_an_error():
    """`diffsampler generate ... | head -1`: the reader leaves early; exit 0, nothing on stderr."""
    proc = subprocess.Popen([sys.executable, "-m", "diffsampler_rt", "generate", "rank1", "4096",
                             "--count", "8", "--seed", "0"],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE)
    assert proc.stdout.readline().strip()
    proc.stdout.close()
    err = proc.stderr.read()
    assert proc.wait(timeout=120) == 0 and err == b""


def test_generate_no_structure(tmp_path):
    import diffsampler_rt
    for flag, structure in (([], True), (["--no-structure"], False)):
        out = tmp_path / f"s{structure}.npy"
        assert main(["generate", "sobol_owen", "64", "--count", "2", "--seed", "4", "--steps",
                     "3", "-o", str(out)] + flag) == 0
        ref = diffsampler_rt.generate("sobol_owen", 64, count=2, seed=4, steps=3,
                                      structure=structure)
        np.testing.assert_array_equal(np.load(out), ref)


def test_warnings_are_one_line(capsys):
    # a distilled model asked for other steps warns; the CLI says so on one line
    assert main(["generate", "gbn_fast", "64", "--steps", "4", "--seed", "1"]) == 0
    err = capsys.readouterr().err
    assert err.startswith("diffsampler: warning: model 'gbn_fast' was distilled for ddim")
    assert len(err.splitlines()) == 1


@pytest.mark.parametrize("fmt", ["npy", "txt", "csv"])
def test_generate_streams_block_by_block(tmp_path, monkeypatch, fmt):
    # 64 points a block: 10 sets of 16 points come in 3 blocks, written as they come; the
    # file is the one a whole-array write of generate's sets gives, byte for byte
    import diffsampler_rt.model as model
    monkeypatch.setattr(model, "POINTS_PER_BATCH", 64)
    calls = []
    real = model.Model.iter_sets

    def spy(self, *a, **k):
        for block in real(self, *a, **k):
            calls.append(len(block))
            yield block

    monkeypatch.setattr(model.Model, "iter_sets", spy)
    out = tmp_path / f"pts.{fmt}"
    assert main(["generate", "sobol_owen", "16", "--count", "10", "--seed", "2", "--steps", "3",
                 "-o", str(out)]) == 0
    assert calls == [4, 4, 2]
    ref = model.generate("sobol_owen", 16, count=10, seed=2, steps=3)
    if fmt == "npy":
        import io
        whole = io.BytesIO()
        np.save(whole, ref)
        assert out.read_bytes() == whole.getvalue()
    elif fmt == "txt":
        np.testing.assert_array_equal(np.loadtxt(out).reshape(10, 16, 2), ref)
        assert out.read_text().count("\n\n") == 9  # a blank line between sets
    else:
        raw = np.loadtxt(out, delimiter=",", skiprows=1)
        assert np.array_equal(raw[:, 0], np.repeat(np.arange(10), 16))
        np.testing.assert_array_equal(raw[:, 1:].reshape(10, 16, 2), ref)
    assert not (tmp_path / f"pts.{fmt}.partial").exists()


def test_an_interrupted_generate_leaves_no_file(tmp_path, monkeypatch):
    import diffsampler_rt.model as model

    def failing(self, *a, **k):
        yield np.zeros((1, 16, 2))
        raise OSError("disk gone")

    monkeypatch.setattr(model.Model, "iter_sets", failing)
    out = tmp_path / "pts.npy"
    assert main(["generate", "sobol_owen", "16", "--count", "4", "-o", str(out)]) == 2
    assert list(tmp_path.iterdir()) == []  # neither the file nor its .partial


def test_generate_threads(tmp_path, capsys):
    out = tmp_path / "pts.npy"
    assert main(["generate", "gbn_fast", "64", "--count", "3", "--seed", "5", "--threads", "1",
                 "-o", str(out)]) == 0
    np.testing.assert_array_equal(np.load(out), __import__("diffsampler_rt").generate(
        "gbn_fast", 64, count=3, seed=5))
    assert main(["generate", "gbn_fast", "64", "--threads", "0"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "threads must be >= 1, got 0" in err[0]
