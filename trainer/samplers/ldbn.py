"""Low-discrepancy blue noise (Ahmed et al. 2016) from a 128 x 128 permutation table.

Cell (X, Y) of a k x k grid holds ((X + u) / k, (Y + v) / k) with
L = table[Y mod 128, X mod 128], u = phi(16 floor(Y / 16) + (L & 15)),
v = phi(16 floor(X / 16) + (L >> 4)), phi the base-2 radical inverse. Along every aligned
run of 16 cells of a column the low nibbles are a permutation of 0..15 (and the high nibbles
along rows), so for k a power of two >= 16 both 1-d projections are stratified (one point
per 1/n strip). The table is ours: made by ``benchmarks/make_ldbn_table.py`` (swaps that keep
the permutation structure, toward a low Gaussian repulsion energy) and stored as data.
Variety between sets: a random table offset (multiples of 16) and one of the 8 symmetries
of the square (mirrors reflect the 1/n strip lattice onto itself).
"""
from __future__ import annotations

import math
from functools import lru_cache
from pathlib import Path

import numpy as np

TABLE_PATH = Path(__file__).parent / "data" / "ldbn_table.npy"
SIZE = 128
RUN = 16


def radical_inverse(j: np.ndarray) -> np.ndarray:
    """Base-2 radical inverse (van der Corput) of non-negative integers < 2^32."""
    j = np.asarray(j, dtype=np.uint64)
    out = np.zeros(j.shape)
    scale = 0.5
    for _ in range(32):
        out += (j & np.uint64(1)).astype(np.float64) * scale
        j = j >> np.uint64(1)
        scale /= 2
    return out


@lru_cache(maxsize=1)
def load_table() -> np.ndarray:
    return np.load(TABLE_PATH)


def check_table(table: np.ndarray) -> None:
    """Raise ValueError unless nibbles are permutations along the aligned runs of 16."""
    if table.shape != (SIZE, SIZE) or table.dtype != np.uint8:
        raise ValueError(f"table must be uint8 {SIZE}x{SIZE}, got {table.dtype} {table.shape}")
    lo = (table & 15).reshape(SIZE // RUN, RUN, SIZE)  # runs down each column
    hi = (table >> 4).reshape(SIZE, SIZE // RUN, RUN)  # runs along each row
    if not (np.all(np.sort(lo, axis=1) == np.arange(RUN)[None, :, None])
            and np.all(np.sort(hi, axis=2) == np.arange(RUN)[None, None, :])):
        raise ValueError("table nibbles are not permutations along aligned runs of 16")


def points_from_table(table: np.ndarray, k: int, ox: int = 0, oy: int = 0) -> np.ndarray:
    """The k*k LDBN points (row-major cells) of ``table`` read at offset (ox, oy)."""
    X, Y = np.meshgrid(np.arange(k), np.arange(k))
    L = table[(Y + oy) % SIZE, (X + ox) % SIZE].astype(np.int64)
    u = radical_inverse(RUN * (Y // RUN) + (L & 15))
    v = radical_inverse(RUN * (X // RUN) + (L >> 4))
    return np.stack([(X + u) / k, (Y + v) / k], axis=-1).reshape(-1, 2)


def ldbn(n: int, count: int, rng: np.random.Generator) -> np.ndarray:
    """``count`` LDBN sets of n = k*k points (n must be a perfect square)."""
    k = math.isqrt(n)
    if k * k != n:
        raise ValueError(f"ldbn needs a square number of points (k*k), got n={n}")
    table = load_table()
    out = np.empty((count, n, 2))
    for c in range(count):
        ox, oy = RUN * rng.integers(SIZE // RUN, size=2)
        p = points_from_table(table, k, int(ox), int(oy))
        w = int(rng.integers(8))
        if w & 1:
            p[:, 0] = ((n - 1) / n - p[:, 0]) % 1.0
        if w & 2:
            p[:, 1] = ((n - 1) / n - p[:, 1]) % 1.0
        if w & 4:
            p = p[:, ::-1]
        out[c] = p
    return np.clip(out, 0.0, np.nextafter(1.0, 0.0))
