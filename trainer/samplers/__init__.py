"""Reference samplers: the example point sets a model learns from.

Every sampler shares one contract: ``fn(n, count, rng) -> float64 array (count, n, 2)`` in
[0, 1)^2. Use :func:`sample` to reach one by name.
"""
from __future__ import annotations

import contextlib
import multiprocessing
from concurrent.futures import ProcessPoolExecutor
from typing import Callable

import numpy as np

from .densities import gbn_blob, sot_ramp
from .gbn import gbn
from .lattice import p2_lattice, rank1
from .ldbn import ldbn
from .poisson_disk import poisson_disk
from .sot import sot
from .sobol_owen import sobol_owen

SamplerFn = Callable[[int, int, np.random.Generator], np.ndarray]

#: name -> sampler function (n, count, rng) -> (count, n, 2)
SAMPLERS: dict[str, SamplerFn] = {
    "sobol_owen": sobol_owen,
    "rank1": rank1,
    "lattice": p2_lattice,
    "poisson_disk": poisson_disk,
    "gbn": gbn,
    "sot": sot,
    "sot_ramp": sot_ramp,
    "gbn_blob": gbn_blob,
    "ldbn": ldbn,
}

#: name -> what the sampler makes, in plain words (the model catalogue's "imitates")
DESCRIPTIONS: dict[str, str] = {
    "sobol_owen": "Sobol' points, Owen-scrambled (low discrepancy; (0, m, 2)-nets)",
    "rank1": "rank-1 Korobov lattice, max-min-distance generator, random shift",
    "lattice": "rank-1 Korobov lattice, P2-optimal generator, random shift",
    "poisson_disk": "Poisson disk: toroidal dart throwing",
    "gbn": "Gaussian blue noise (GBN) on the torus",
    "sot": "sliced optimal transport (SOT) blue noise",
    "sot_ramp": "SOT for the ramp density p(x, y) = 2x (non-uniform)",
    "gbn_blob": "GBN importance-sampled to a two-part blob density (non-uniform)",
    "ldbn": "low-discrepancy blue noise (LDBN)",
}

#: samplers that take seconds per set (iterative optimisers); tests keep their sizes small
SLOW = frozenset({"poisson_disk", "gbn", "sot", "sot_ramp", "gbn_blob"})

#: samplers whose distribution is invariant under translations of the torus (x + v mod 1):
#: the only ones for which random shifts are a faithful augmentation
TOROIDAL = frozenset({"rank1", "lattice", "poisson_disk", "gbn"})


def _one_set(name: str, n: int, rng: np.random.Generator) -> np.ndarray:
    return SAMPLERS[name](n, 1, rng)[0]


def sample(name: str, n: int, *, count: int = 1,
           seed: int | np.random.Generator | None = None, progress: bool = False,
           workers: int = 1) -> np.ndarray:
    """Draw ``count`` point sets of ``n`` points from the reference sampler ``name``.

    Parameters
    ----------
    name : str
        One of :data:`SAMPLERS`.
    n : int
        Points per set (>= 1).
    count : int, optional
        Number of independent sets.
    seed : int or numpy.random.Generator, optional
        Seeds the sampler; the same seed gives the same sets.
    progress : bool, optional
        Show a progress bar (slow samplers, which run set by set).
    workers : int, optional
        Processes for the slow samplers (:data:`SLOW`); each set has its own random stream,
        so the sets are the same for any number of workers. Ignored by the fast samplers.
        The workers are spawned (they import the calling script afresh), so a script that
        asks for more than one calls this under ``if __name__ == "__main__":``.

    Returns
    -------
    numpy.ndarray
        float64 array of shape ``(count, n, 2)`` in [0, 1)^2.

    Examples
    --------
    >>> sample("sobol_owen", 16, count=2, seed=0).shape
    (2, 16, 2)
    """
    if name not in SAMPLERS:
        raise ValueError(f"unknown sampler {name!r}; choose one of {sorted(SAMPLERS)}")
    for label, value, low in (("n", n, 1), ("count", count, 1), ("workers", workers, 1)):
        if isinstance(value, bool) or not isinstance(value, (int, np.integer)):
            raise TypeError(f"{label} must be an integer, got {value!r}")
        if value < low:
            raise ValueError(f"{label} must be >= {low}, got {value}")
    rng = np.random.default_rng(seed)
    if name in SLOW:
        # set by set, each from its own child stream: a set does not depend on the count
        streams = rng.spawn(int(count))
        parallel = workers > 1 and count > 1
        # spawned, not forked: a fork of a process whose threads (torch's OpenMP,
        # onnxruntime's pool) hold locks can deadlock its workers (seen once in CI)
        with (ProcessPoolExecutor(min(int(workers), int(count)),
                                  mp_context=multiprocessing.get_context("spawn"))
              if parallel else contextlib.nullcontext()) as pool:
            sets = (pool.map if parallel else map)(_one_set, [name] * count, [int(n)] * count,
                                                   streams)
            if progress:
                from tqdm import tqdm
                sets = tqdm(sets, total=count, desc=f"{name} n={n}", unit="set")
            pts = np.stack(list(sets))
    else:
        pts = SAMPLERS[name](int(n), int(count), rng)
    if pts.shape != (count, n, 2):  # a sampler broke the shared contract
        raise RuntimeError(f"sampler {name!r} returned shape {pts.shape}, "
                           f"expected {(count, n, 2)}")
    return pts
