"""Held-out split and training pools of a fit: examples -> embedded grids, per size.

Per size, a fixed share of the sets (chosen at random from a seed) is held out: never
trained on, never calibrated on, compared with the model in the report. The training pool
of each size is at most ``pool_cap`` held-in sets, embedded once (the optimal-transport
assignment costs ~50 ms a 1024-point set) and cached under the trainer's cache folder by
the examples' content, so a restarted fit reuses it. Memory stays at the pools' size: the
examples themselves are read a chunk at a time.
"""
from __future__ import annotations

import hashlib
import math
import os
from dataclasses import dataclass

import numpy as np

from diffsampler_rt.density import unwarp

from ..data import cache_dir
from ..embedding import embed, symmetries
from .examples import ExampleError, Examples

#: share of each size's sets held out, and its bounds
HOLD_OUT, MIN_HELD_OUT, MAX_HELD_OUT = 0.2, 8, 512
#: fewest held-in sets a size needs to be trained on
MIN_HELD_IN = 4


@dataclass(frozen=True)
class Split:
    """Indices of the held-in and held-out sets of each size (sorted)."""
    held_in: dict[int, np.ndarray]
    held_out: dict[int, np.ndarray]


def split(ex: Examples, seed: int = 0) -> Split:
    """The held-out split (ExampleError where a size has too few sets for it)."""
    held_in, held_out = {}, {}
    for n in ex.sizes:
        count = ex.count(n)
        out = min(MAX_HELD_OUT, max(MIN_HELD_OUT, round(HOLD_OUT * count)))
        if count < out + MIN_HELD_IN:
            raise ExampleError(f"n = {n}: {count} example sets; a fit needs at least "
                               f"{MIN_HELD_OUT + MIN_HELD_IN} of a size ({MIN_HELD_OUT} held "
                               f"out for the report, {MIN_HELD_IN} to train on)")
        order = np.random.default_rng([seed, n]).permutation(count)
        held_out[n], held_in[n] = np.sort(order[:out]), np.sort(order[out:])
    return Split(held_in, held_out)


def _key(ex: Examples, n: int, index: np.ndarray, embedding: str, extra: str) -> str:
    h = hashlib.sha1(f"{n} {embedding} {extra}".encode())
    h.update(np.ascontiguousarray(index).tobytes())
    for src in ex.sources[n]:
        h.update(src.name.encode())
        if src.array is not None:
            h.update(np.ascontiguousarray(src.array).tobytes())
        else:
            st = src.path.stat()
            h.update(f"{st.st_size} {st.st_mtime_ns}".encode())
    return h.hexdigest()[:16]


def pool(ex: Examples, n: int, index: np.ndarray, embedding: str, *,
         density: dict | None = None, shifts: int = 1, seed: int = 0,
         progress: bool = False) -> np.ndarray:
    """The sets ``index`` of size n embedded on their grid: float32 (m * shifts, 2, k, k),
    cached (with a density table, the sets mapped to the uniform square first; with
    ``shifts`` > 1, toroidal examples, each set also moved by shifts - 1 uniform random
    vectors on the torus, each copy embedded anew)."""
    extra = ("" if density is None else hashlib.sha1(repr(density).encode()).hexdigest()) \
        + f" x{shifts} s{seed}"
    path = cache_dir() / "fit" / f"pool_{_key(ex, n, index, embedding, extra)}.npy"
    if path.exists():
        return np.load(path)
    chunks = range(0, len(index), 64)
    if progress:
        from tqdm import tqdm
        chunks = tqdm(chunks, desc=f"embedding n={n}", unit="chunk", leave=False)
    parts = []
    for start in chunks:
        sets = ex.take(n, index[start:start + 64])
        if density is not None:
            sets = unwarp(sets, density)
        if shifts > 1:
            move = np.random.default_rng([seed, n, start]).random((len(sets), shifts - 1, 1, 2))
            moved = (sets[:, None] + move) % 1.0
            sets = np.concatenate([sets[:, None], np.where(moved >= 1.0, 0.0, moved)], axis=1)
            sets = sets.reshape((-1, n, 2))
        parts.append(embed(sets, embedding).astype(np.float32))
    grids = np.concatenate(parts)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_suffix(f".tmp{os.getpid()}.npy")
    np.save(tmp, grids)
    os.replace(tmp, path)
    return grids


class ExampleBatches:
    """Training batches drawn from the pools of the example sizes (the trainer's
    ``Batches`` interface: ``draw(rng)``, ``pools``, ``density``), with the asserted
    symmetries of the square (toroidal shifts are in the pools: :func:`pool`)."""

    def __init__(self, pools: dict[int, np.ndarray], batch_sizes: dict[int, int],
                 offset_scale: float, symmetry: tuple[int, ...] = (0,),
                 density: dict | None = None, shard: tuple[int, int] = (0, 1)):
        rank, world = shard
        # each data-parallel process draws from its own share of every pool
        self.pools = {k: p[rank::world] for k, p in pools.items()}
        self.batch_sizes, self.offset_scale = batch_sizes, offset_scale
        self.symmetry = np.asarray(symmetry)
        self.density = density

    def draw(self, rng: np.random.Generator) -> list[np.ndarray]:
        out = []
        for k in sorted(self.pools):
            pool, b = self.pools[k], self.batch_sizes[k]
            grid = pool[rng.integers(0, len(pool), size=b)]
            which = rng.choice(self.symmetry, size=b)
            grid = symmetries(grid, which) if np.any(which) else grid
            out.append((grid * self.offset_scale).astype(np.float32))
        return out


def batch_size(k: int) -> int:
    """Sets per step at grid side k: about 16 k points, 8 to 64 sets."""
    return int(min(64, max(8, 16384 // (k * k))))


def training_sides(sizes: list[int], most: int = 3) -> list[int]:
    """The grid sides trained on: the example sizes' (the largest ``most`` of them)."""
    return sorted(math.isqrt(n) for n in sizes)[-most:]
