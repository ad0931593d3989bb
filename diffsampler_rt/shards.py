"""One network evaluation of a batch, split across the cores: a session per core, side by side.

onnxruntime parallelises one run inside each operator, and a denoiser evaluation is a long
chain of small operators (a k = 32 grid is 1024 cells), so its threads wait on each other
at every node. Giving each core its own single-thread session and its own slice of the
batch, run side by side, leaves nothing to wait on (benchmarks/results/ort_tuning.md
measures it). The outputs are bit for bit those of one
session on the whole batch: onnxruntime's CPU kernels compute each set on its own and
split no sum across threads (tests/test_shards.py checks it on bundled models). Not
measured: CPUs with more than 2 cores, or with two hardware threads per core (the count
is of the CPUs the OS offers, hardware threads included).
"""
from __future__ import annotations

import os
import threading
from concurrent.futures import ThreadPoolExecutor
from typing import Callable

import numpy as np


#: most sessions a batch is split between: on a many-core CPU each gets several threads
#: instead (64 single-thread sessions would cost 64 copies of the network and their start-up;
#: the split was measured on 2 cores only)
MAX_SHARDS = 8


def layout(cores: int) -> tuple[int, int]:
    """(sessions, intra-op threads each) for a batch on ``cores`` cores: one session per
    core up to :data:`MAX_SHARDS` cores; beyond, the fewest threads per session that keep
    the sessions at most MAX_SHARDS (64 cores: 8 x 8; 12: 6 x 2)."""
    cores = max(1, cores)
    each = -(-cores // MAX_SHARDS)
    return cores // each, each


def usable_cores() -> int:
    """CPUs this process may run on (its affinity mask where the OS has one)."""
    try:
        return len(os.sched_getaffinity(0))
    except (AttributeError, OSError):  # not Linux
        return os.cpu_count() or 1


class Shards:
    """``count`` sessions of one network, made by ``make`` on first use, each running a
    contiguous slice of a batch, in parallel (onnxruntime releases the GIL while it runs).
    Threads may share one Shards: the sessions are made once, under a lock, and
    onnxruntime's ``run`` may be called from several threads at a time.

    Parameters
    ----------
    make : callable
        Returns a new ``onnxruntime.InferenceSession`` of the network (single-thread, or
        a few threads each on a many-core CPU: :func:`layout`).
    count : int
        Number of sessions (>= 2).
    """

    def __init__(self, make: Callable[[], "object"], count: int):
        if count < 2:
            raise ValueError(f"Shards needs count >= 2, got {count}")
        self.count = count
        self._make = make
        self._sessions: list = []
        self._pool: ThreadPoolExecutor | None = None
        self._lock = threading.Lock()

    def _started(self) -> tuple[list, ThreadPoolExecutor]:
        """The sessions and the pool, made by the first caller; a caller that comes while
        they are being made waits for them (two threads would each have made a set of
        sessions, and one could have seen the sessions before the pool)."""
        with self._lock:
            if not self._sessions:
                sessions = [self._make() for _ in range(self.count)]
                self._pool = ThreadPoolExecutor(self.count - 1, thread_name_prefix="diffsampler")
                self._sessions = sessions
            return self._sessions, self._pool

    def run(self, x: np.ndarray, t: np.ndarray) -> np.ndarray:
        """eps for the batch ``x`` (B >= ``count``, float32) at timesteps ``t`` (B,)."""
        if len(x) < self.count:
            raise ValueError(f"a batch of {len(x)} cannot feed {self.count} shards")
        sessions, pool = self._started()
        bounds = np.linspace(0, len(x), self.count + 1).round().astype(int)
        feeds = [{"x": x[a:b], "t": t[a:b]} for a, b in zip(bounds[:-1], bounds[1:])]
        # the calling thread runs the last slice itself
        futures = [pool.submit(s.run, ["eps"], f) for s, f in zip(sessions[:-1], feeds[:-1])]
        last = sessions[-1].run(["eps"], feeds[-1])[0]
        return np.concatenate([f.result()[0] for f in futures] + [last])
