"""A batch split across single-thread sessions, one per core (diffsampler_rt.shards)."""
import threading
import time
from concurrent.futures import ThreadPoolExecutor

import numpy as np
import onnxruntime as ort
import pytest

import diffsampler_rt
from diffsampler_rt.model import (X64_QUANT_PRECISION, Model, needs_exact_8bit, resolve,
                                  session_options)
from diffsampler_rt.shards import MAX_SHARDS, Shards, layout, usable_cores

from .conftest import session_entry


def _session(path, threads):
    return ort.InferenceSession(str(path), sess_options=session_options(threads),
                                providers=["CPUExecutionProvider"])


def test_usable_cores_counts_at_least_one():
    assert usable_cores() >= 1


@pytest.mark.parametrize("name", ["gbn_fast", "sot"])  # 8-bit convolutions, float
def test_shards_give_one_sessions_eps_bit_for_bit(name):
    path = resolve(name)
    rng = np.random.default_rng(0)
    x = rng.standard_normal((7, 2, 16, 16)).astype(np.float32)
    t = rng.integers(0, 1000, 7).astype(np.float32)  # a timestep per set, as the slices keep
    expected = _session(path, 2).run(["eps"], {"x": x, "t": t})[0]
    for count in (2, 3, 7):
        got = Shards(lambda: _session(path, 1), count).run(x, t)
        np.testing.assert_array_equal(got, expected)


def test_sets_do_not_depend_on_the_cores_used(monkeypatch):
    one = Model("gbn_fast", threads=1)
    assert one._shards is None
    # more shards than this machine may have cores (a model caps threads at the cores)
    monkeypatch.setattr(diffsampler_rt.model, "usable_cores", lambda: 8)
    three = Model("gbn_fast", threads=3)
    np.testing.assert_array_equal(three.generate(256, 5, seed=4), one.generate(256, 5, seed=4))
    assert len(three._shards._sessions) == 3
    for s in three._shards._sessions:  # made with the runtime's options, one thread each
        opts = s.get_session_options()
        assert opts.intra_op_num_threads == 1
        assert session_entry(opts, X64_QUANT_PRECISION) == ("1" if needs_exact_8bit() else None)


def test_a_batch_smaller_than_the_cores_runs_on_the_whole_session(tiny_onnx, monkeypatch):
    monkeypatch.setattr(diffsampler_rt.model, "usable_cores", lambda: 8)
    m = Model(tiny_onnx, threads=4)
    m.generate(64, 3, seed=0)
    assert m._shards._sessions == []  # never made
    m.generate(64, 4, seed=0)
    assert len(m._shards._sessions) == 4


def test_bad_thread_counts_and_shard_counts_are_refused(tiny_onnx):
    for bad in (0, -2):
        with pytest.raises(ValueError, match=f"threads must be >= 1, got {bad}"):
            Model(tiny_onnx, threads=bad)
    with pytest.raises(TypeError, match="threads must be an integer"):
        Model(tiny_onnx, threads=2.0)
    with pytest.raises(ValueError, match="count >= 2, got 1"):
        Shards(lambda: None, 1)
    with pytest.raises(ValueError, match="a batch of 2 cannot feed 3 shards"):
        Shards(lambda: None, 3).run(np.zeros((2, 2, 4, 4), np.float32), np.zeros(2, np.float32))


def test_default_model_uses_every_usable_core():
    m = diffsampler_rt.load("rank1")
    assert (m._shards is None) == (usable_cores() < 2)
    if m._shards is not None:
        assert m._shards.count == layout(usable_cores())[0]


def test_many_cores_share_a_few_sessions():
    assert layout(1) == (1, 1) and layout(2) == (2, 1) and layout(MAX_SHARDS) == (MAX_SHARDS, 1)
    assert layout(64) == (MAX_SHARDS, 64 // MAX_SHARDS)
    assert layout(12) == (6, 2) and layout(9) == (4, 2)  # 9: one core left out of the split


def test_a_polished_models_shards_do_not_spin():
    # the polish and a guide take turns with the network on the same cores (Model's notes)
    m = Model("sot_fast", threads=2)
    m.generate(64, 2, seed=0)
    spin = "session.intra_op.allow_spinning"
    assert [s.get_session_options().get_session_config_entry(spin)
            for s in m._shards._sessions] == ["0", "0"]


class _Doubler:
    """A stand-in session: eps = 2 x."""

    def run(self, names, feed):
        return [feed["x"] * 2]


def test_threads_sharing_shards_make_its_sessions_once():
    # the first batches of several threads at once: before the lock, each made its own
    # sessions and one could find the sessions made but not yet the pool
    made = []

    def make():
        time.sleep(0.02)  # session start-up: the window the threads met in
        made.append(threading.get_ident())
        return _Doubler()

    shards = Shards(make, 3)
    x = np.arange(6 * 2 * 2 * 2, dtype=np.float32).reshape(6, 2, 2, 2)
    t = np.zeros(6, np.float32)
    start = threading.Barrier(4)

    def first_batch(_):
        start.wait()
        return shards.run(x, t)

    with ThreadPoolExecutor(4) as callers:
        outs = list(callers.map(first_batch, range(4)))
    assert len(made) == 3 and len(set(made)) == 1
    for out in outs:
        np.testing.assert_array_equal(out, 2 * x)


@pytest.mark.parametrize("name", ["gbn_fast", "sot_fast"])  # sot_fast: the polish's threads too
def test_threads_sharing_a_model_get_the_sets_they_would_get_alone(name):
    m = Model(name, threads=2)  # split batches whatever this machine's cores
    with ThreadPoolExecutor(3) as callers:
        together = list(callers.map(lambda s: m.generate(256, 4, seed=s), range(3)))
    for s, got in enumerate(together):
        np.testing.assert_array_equal(got, Model(name, threads=2).generate(256, 4, seed=s))
