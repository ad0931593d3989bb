"""The sliced-OT polish the runtime may finish SOT sets with (diffsampler_rt.sliced_ot)."""
import doctest
import json
import shutil
import tracemalloc

import numpy as np
import pytest

import diffsampler_rt
from diffsampler_rt import ModelFormatError, disk_transport, sliced_ot
from diffsampler_rt.sliced_ot import (disk_to_square, iterations_at, polish, settings_problem,
                                      square_to_disk)


def coarse_chi2(pts: np.ndarray, bins: int = 8) -> float:
    """Chi-square of a bins x bins histogram vs uniform, averaged over sets."""
    idx = np.minimum((pts * bins).astype(int), bins - 1)
    counts = np.stack([np.bincount(i[:, 1] * bins + i[:, 0], minlength=bins * bins)
                       for i in idx.reshape(-1, *pts.shape[-2:])])
    e = pts.shape[-2] / bins**2
    return float(((counts - e) ** 2 / e).sum(-1).mean())


def test_concentric_maps_are_inverse():
    p = np.random.default_rng(0).random((5, 300, 2))
    d = square_to_disk(p)
    assert np.all(np.hypot(d[..., 0], d[..., 1]) <= 1 + 1e-12)
    np.testing.assert_allclose(disk_to_square(d), p, atol=1e-12)
    np.testing.assert_allclose(square_to_disk(np.array([0.5, 0.5])), [0.0, 0.0])


def test_polish_evens_out_white_noise_and_keeps_sets_apart():
    pts = np.random.default_rng(1).random((3, 1024, 2))
    rngs = [np.random.default_rng(s) for s in (5, 6, 7)]
    out = polish(pts, 16, 64, rngs)
    assert out.shape == pts.shape and out.dtype == np.float64
    assert np.all(np.isfinite(out)) and np.all((out >= 0) & (out < 1))
    # white noise: chi-square ~ 63 on 64 bins; SOT sets are far more even
    assert coarse_chi2(pts) > 30 and coarse_chi2(out) < 0.2 * coarse_chi2(pts)
    # one generator per set: a set's result does not depend on its batch
    alone = polish(pts[1:2], 16, 64, [np.random.default_rng(6)])
    np.testing.assert_array_equal(alone, out[1:2])
    # nor on how many threads share the sets
    for workers in (1, 2, 3):
        again = polish(pts, 16, 64, [np.random.default_rng(s) for s in (5, 6, 7)],
                       workers=workers)
        np.testing.assert_array_equal(again, out)
    # a set alone: the threads share each iteration's blocks of directions, same bits
    one = [polish(pts[:1], 4, 3 * disk_transport.BLOCK + 5, [np.random.default_rng(5)],
                  workers=w) for w in (1, 2, 3, None)]
    for other in one[1:]:
        np.testing.assert_array_equal(other, one[0])
    for bad in (0, -1, 1.5, True):
        with pytest.raises(ValueError, match="workers must be an integer"):
            polish(pts, 1, 8, rngs, workers=bad)
    np.testing.assert_array_equal(polish(pts, 0, 64, rngs), disk_to_square(square_to_disk(pts)))


def test_the_sampler_uses_the_same_update():
    from trainer.samplers.sot import sot_disk
    rng = np.random.default_rng(3)
    x = sot_disk(64, 2, np.random.default_rng(3), iterations=3, directions=8)
    rad, ang = np.sqrt(rng.random((2, 64))), 2 * np.pi * rng.random((2, 64))
    y = np.stack([rad * np.cos(ang), rad * np.sin(ang)], axis=-1)
    base = np.arange(8) * (np.pi / 8)
    for _ in range(3):
        y = disk_transport.sliced_step(y, base + rng.random() * (np.pi / 8))
    np.testing.assert_array_equal(x, y)


def test_iterations_per_size():
    spec = {"directions": 64, "n": [256, 1024, 4096], "iterations": [0, 8, 16]}
    assert [iterations_at(spec, n) for n in (64, 256, 512, 1024, 2048, 4096, 65536)] == \
        [0, 0, 4, 8, 12, 16, 16]
    assert iterations_at({"directions": 8, "iterations": 3}, 100) == 3
    # a thinned set (n not a square) is polished 3x as long, at least 12 iterations
    assert [iterations_at(spec, n, thinned=True) for n in (200, 1000, 4000)] == [12, 24, 48]


@pytest.mark.parametrize("spec, message", [
    ({"iterations": 4}, "must be"),
    ({"directions": 64, "iterations": 4, "extra": 1}, "must be"),
    ({"directions": 0, "iterations": 4}, "directions must be an integer from 1 to 1024, got 0"),
    ({"directions": 64, "iterations": -1}, "iterations must be an integer >= 0, got -1"),
    ({"directions": 64, "iterations": True}, "got True"),
    ({"directions": 64, "n": [1024, 256], "iterations": [1, 2]}, "strictly increasing"),
    ({"directions": 64, "n": [256], "iterations": [1, 2]}, "same length"),
    ({"directions": 64, "iterations": 4, "step": 0}, "step must be a number in (0, 2], got 0"),
    ({"directions": 64, "iterations": 4, "step": 2.5}, "got 2.5"),
    ({"directions": 64, "iterations": 4, "step": True}, "got True"),
])
def test_format_1_settings_are_validated(spec, message):
    from diffsampler_rt.card import CARD_KEY, parse_card
    assert message in settings_problem(spec)
    # a format-2 card carrying the old field is refused whatever its value
    card = {**diffsampler_rt.load("rank1").card, "sliced_ot": spec}
    with pytest.raises(ModelFormatError, match="model card field 'sliced_ot' belongs to format 1"):
        parse_card({CARD_KEY: json.dumps(card)}, "m")


@pytest.mark.parametrize("params, message, got", [
    ({"iterations": 4}, "step 'sliced_ot' needs 'directions'", None),
    ({"directions": 64, "iterations": 4, "extra": 1},
     "step 'sliced_ot' has no parameter 'extra'", None),
    ({"directions": 0, "iterations": 4}, "'directions' must be an integer in [1, 1024]", 0),
    ({"directions": 64, "iterations": -1}, "'iterations' must be an integer in [0, inf]", -1),
    ({"directions": 64, "iterations": True}, "'iterations' must be an integer", True),
    ({"directions": 64, "iterations": {"n": [1024, 256], "values": [1, 2]}},
     "'iterations' table must be {\"n\": [increasing sizes]", {"n": [1024, 256], "values": [1, 2]}),
    ({"directions": 64, "iterations": {"n": [256], "values": [1, 2]}},
     "'iterations' table must be", {"n": [256], "values": [1, 2]}),
    ({"directions": 64, "iterations": {"n": [64, 256], "values": [1, 2.5]}},
     "'iterations' values must each be an integer", 2.5),
    ({"directions": 64, "iterations": 4, "step_size": 0},
     "'step_size' must be a number in (0, 2]", 0),
    ({"directions": 64, "iterations": 4, "step_size": 2.5}, "'step_size' must be a number", 2.5),
    ({"directions": 64, "iterations": 4, "step_size": True}, "'step_size' must be a number", True),
])
def test_pipeline_entries_are_validated(params, message, got):
    from .conftest import pipeline_card_error
    entry = {"step": "sliced_ot", **params}
    text = pipeline_card_error("rank1", [{"step": "thin"}, entry], message)
    assert text.startswith("m: pipeline entry 1: step 'sliced_ot'")
    if got is not None:
        assert text.endswith(f"got {got!r}")


def _pipeline(path, *args) -> int:
    from export.__main__ import main as export_main
    return export_main(["pipeline", str(path), *args])


def _refused(path, capsys, args, message) -> None:
    """``python -m export pipeline`` exits 2 with a one-line error naming the problem and
    leaves the file as it was."""
    before = path.read_bytes()
    capsys.readouterr()
    assert _pipeline(path, *args) == 2
    err = capsys.readouterr().err
    assert err.startswith("error: ") and err.count("\n") == 1 and message in err, err
    assert path.read_bytes() == before


def test_card_polish_is_applied(tiny_onnx, tmp_path, capsys):
    path = tmp_path / "m.onnx"
    shutil.copy(tiny_onnx, path)
    base = diffsampler_rt.Model(path).card["pipeline"]  # the export's: thinning only
    plain = {n: diffsampler_rt.Model(path).generate(n, 3, seed=2) for n in (64, 256)}
    assert _pipeline(path, "--add", "sliced_ot", "--iterations", "64:0,256:4",
                     "--directions", "16") == 0
    m = diffsampler_rt.Model(path)
    assert m.card["pipeline"] == [*base, {"step": "sliced_ot", "directions": 16,
                                          "iterations": {"n": [64, 256], "values": [0, 4]}}]
    # a polishing model's session does not spin after a run (the polish wants the cores)
    spin = "session.intra_op.allow_spinning"
    assert m.session.get_session_options().get_session_config_entry(spin) == "0"
    with pytest.raises(RuntimeError):  # not set: onnxruntime's default (spinning)
        diffsampler_rt.Model(tiny_onnx).session.get_session_options().get_session_config_entry(spin)
    np.testing.assert_array_equal(m.generate(64, 3, seed=2), plain[64])  # 0 iterations
    polished = m.generate(256, 3, seed=2)
    assert not np.allclose(polished, plain[256]) and np.all((polished >= 0) & (polished < 1))
    np.testing.assert_array_equal(m.generate(256, 3, seed=2, structure=False), plain[256])
    np.testing.assert_array_equal(np.concatenate(list(m.iter_sets(256, 3, batch=2, seed=2))),
                                  polished)
    _refused(path, capsys, ["--update", "sliced_ot", "--iterations", "1.5"],
             "'iterations' must be an integer in [0, inf]")
    _refused(path, capsys, ["--update", "sliced_ot", "--directions", "2000"],
             "'directions' must be an integer in [1, 1024], got 2000")
    _refused(path, capsys, ["--add", "sliced_ot", "--directions", "8"],
             "step 'sliced_ot' needs 'iterations'")
    assert _pipeline(path, "--update", "sliced_ot", "--iterations", "3") == 0  # keeps the 16
    assert diffsampler_rt.Model(path).card["pipeline"] == [
        *base, {"step": "sliced_ot", "directions": 16, "iterations": 3}]
    assert _pipeline(path, "--remove", "sliced_ot") == 0
    assert diffsampler_rt.Model(path).card["pipeline"] == base
    np.testing.assert_array_equal(diffsampler_rt.Model(path).generate(256, 3, seed=2),
                                  plain[256])


def test_an_over_relaxed_step_evens_out_sets_in_fewer_iterations():
    pts = np.random.default_rng(1).random((4, 1024, 2))

    def run(iterations, **step):
        return polish(pts, iterations, 64, [np.random.default_rng(s) for s in range(4)], **step)

    np.testing.assert_array_equal(run(4, step=1), run(4))  # 1: the sampler's update, bit for bit
    # coarse imbalances (4 x 4 and 8 x 8 bins) shrink faster per iteration
    for bins in (4, 8):
        assert coarse_chi2(run(4, step=1.5), bins) < 0.85 * coarse_chi2(run(4), bins)
        assert coarse_chi2(run(8, step=1.5), bins) < 0.85 * coarse_chi2(run(8), bins)
    out = run(8, step=2)
    assert np.all(np.isfinite(out)) and np.all((out >= 0) & (out < 1))
    for bad in (0, -1.0, 2.5, float("nan"), True, "1"):
        with pytest.raises(ValueError, match="step must be a number in"):
            run(1, step=bad)


def test_card_polish_step(tiny_onnx, tmp_path, capsys):
    path = tmp_path / "m.onnx"
    shutil.copy(tiny_onnx, path)
    base = diffsampler_rt.Model(path).card["pipeline"]  # the export's: thinning only
    assert _pipeline(path, "--add", "sliced_ot", "--iterations", "4", "--directions", "64") == 0
    plain = diffsampler_rt.Model(path).generate(256, 2, seed=3)
    capsys.readouterr()
    assert _pipeline(path, "--update", "sliced_ot", "--step-size", "1.5") == 0
    assert (capsys.readouterr().out.splitlines()[-1]
            == f"{len(base)}. sliced_ot: 4 sliced-OT iterations of 64 directions, "
               "each move x 1.5")
    m = diffsampler_rt.Model(path)
    assert m.card["pipeline"] == [*base, {"step": "sliced_ot", "directions": 64,
                                          "iterations": 4, "step_size": 1.5}]
    relaxed = m.generate(256, 2, seed=3)
    np.testing.assert_array_equal(m.generate(256, 2, seed=3, structure=False),
                                  diffsampler_rt.Model(tiny_onnx).generate(256, 2, seed=3))
    assert not np.allclose(relaxed, plain) and np.all((relaxed >= 0) & (relaxed < 1))
    assert _pipeline(path, "--update", "sliced_ot", "--iterations", "5") == 0  # step kept
    assert diffsampler_rt.Model(path).card["pipeline"] == [
        *base, {"step": "sliced_ot", "directions": 64, "iterations": 5, "step_size": 1.5}]
    _refused(path, capsys, ["--step-size", "1.5"], "parameters need --add, --update or --replace")
    _refused(path, capsys, ["--update", "sliced_ot", "--step-size", "3"],
             "step 'sliced_ot': 'step_size' must be a number in (0, 2], got 3")
    _refused(path, capsys, ["--update", "sliced_ot", "--step-size", "true"],
             "'step_size' must be a number in (0, 2], got True")
    assert _pipeline(path, "--update", "sliced_ot", "--step-size", "none") == 0  # back to 1
    assert diffsampler_rt.Model(path).card["pipeline"] == [
        *base, {"step": "sliced_ot", "directions": 64, "iterations": 5}]


def test_docstring_examples():
    assert doctest.testmod(sliced_ot).failed == 0


def test_sliced_step_matches_the_plain_update():
    # each point moves by the mean over directions of (its quantile - its projection)
    rng = np.random.default_rng(8)
    x = square_to_disk(rng.random((3, 50, 2)))
    theta = rng.random((3, 7)) * np.pi
    want = x.copy()
    t = disk_transport.disk_quantiles(50)
    for c in range(3):
        move = np.zeros((50, 2))
        for a in theta[c]:
            d = np.array([np.cos(a), np.sin(a)])
            proj = x[c] @ d
            rank = np.argsort(np.argsort(proj))
            move += np.outer(t[rank] - proj, d)
        want[c] += move / len(theta[c])
    np.testing.assert_allclose(disk_transport.sliced_step(x, theta), want, atol=1e-13)
    shared = disk_transport.sliced_step(x, theta[0])  # (m,) angles: the same for every set
    np.testing.assert_allclose(shared[0], want[0], atol=1e-13)


def test_the_polish_sorts_by_16_bit_keys_close_to_the_exact_step():
    rng = np.random.default_rng(2)
    for n in (256, 1024, 4096):
        x = square_to_disk(rng.random((4, n, 2)))
        for _ in range(3):
            x = disk_transport.sliced_step(x, np.arange(64) * np.pi / 64 + rng.random() * np.pi / 64)
        theta = np.arange(64) * np.pi / 64 + 0.01
        exact, keyed = disk_transport.sliced_step(x, theta), disk_transport.sliced_step(x, theta, exact=False)
        assert not np.array_equal(exact, keyed)  # some near-ties swap
        spacing = np.sqrt(np.pi / n)  # mean point spacing in the disk
        assert np.abs(exact - keyed).max() < 0.02 * spacing
        assert np.sqrt(np.mean((exact - keyed) ** 2)) < 1e-3 * spacing


def test_the_packed_sort_gives_the_radix_sorts_step_bit_for_bit(monkeypatch):
    # the polish's fast path (keys packed with indices, chunks over sets, reused buffers)
    # against numpy's radix sort of the same 16-bit keys, which runs for n > 2^16
    rng = np.random.default_rng(11)
    cases = []
    for n in (1, 3, 64, 1000, 4096, 64):  # the buffers are remade when n changes
        x = square_to_disk(rng.random((5, n, 2)))
        x[:, n // 2:] = x[:, :n - n // 2]  # duplicate points: tied keys keep index order
        cases.append((x, rng.random((5, 40)) * np.pi))
    packed = [disk_transport._displacement(x, t, exact=False) for x, t in cases]
    monkeypatch.setattr(disk_transport, "CHUNK", 1)  # one set a chunk
    chunked = [disk_transport._displacement(x, t, exact=False) for x, t in cases]
    monkeypatch.setattr(disk_transport, "PACKED_MAX_N", 0)
    radix = [disk_transport._displacement(x, t, exact=False) for x, t in cases]
    for a, b, c in zip(packed, chunked, radix):
        assert a.dtype == np.float64 and np.all(np.isfinite(a))
        np.testing.assert_array_equal(a, c)
        np.testing.assert_array_equal(b, c)


def test_the_fast_step_keeps_no_buffers_once_it_returns():
    # its work arrays (~6 MiB here) live as long as one polish or one sliced_step call;
    # kept per thread, they had outlived a direct sliced_step(exact=False) call
    pts = np.random.default_rng(12).random((4, 4096, 2))
    x = square_to_disk(pts)
    theta = np.arange(32) * np.pi / 32
    calls = [lambda: polish(pts, 2, 32, [np.random.default_rng(i) for i in range(4)], workers=1),
             lambda: polish(pts, 2, 32, [np.random.default_rng(i) for i in range(4)], workers=2),
             lambda: polish(pts[:1], 2, 64, [np.random.default_rng(0)], workers=2),
             lambda: disk_transport.sliced_step(x, theta, exact=False)]
    for call in calls:
        call()  # numpy's and the pools' own first-use allocations
        tracemalloc.start()
        try:
            before = tracemalloc.get_traced_memory()[0]
            out = call()
            after, peak = tracemalloc.get_traced_memory()
        finally:
            tracemalloc.stop()
        # the buffers were made: at least the float32 projections of the 4 sets of 4096
        # points on 32 directions (2 MiB), whatever the thread split
        assert peak - before >= 4 * 4096 * 32 * 4
        assert after - before - out.nbytes < 1 << 20  # and are gone


def test_the_polish_counts_the_cpus_it_may_run_on(monkeypatch):
    """Default workers: the process's affinity mask (as the batch split's sessions), not
    every CPU of the machine; a one-CPU mask runs on the calling thread, same sets."""
    pts = np.random.default_rng(13).random((4, 256, 2))

    def rngs():
        return [np.random.default_rng(i) for i in range(4)]

    want = polish(pts, 2, 32, rngs(), workers=3)
    monkeypatch.setattr(sliced_ot, "usable_cores", lambda: 1)

    def no_pool(*args, **kwargs):
        raise AssertionError("a thread pool with one usable CPU")

    monkeypatch.setattr(sliced_ot, "ThreadPoolExecutor", no_pool)
    np.testing.assert_array_equal(polish(pts, 2, 32, rngs()), want)
