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


def _parts(table: np.ndarray, k: int, ox: int, oy: int):
    """Cell indices X, Y and in-cell dyadic offsets u, v of the k*k points (row-major)."""
    X, Y = np.meshgrid(np.arange(k), np.arange(k))
    L = table[(Y + oy) % SIZE, (X + ox) % SIZE].astype(np.int64)
    u = radical_inverse(RUN * (Y // RUN) + (L & 15))
    v = radical_inverse(RUN * (X // RUN) + (L >> 4))
    return X.ravel(), Y.ravel(), u.ravel(), v.ravel()


def points_from_table(table: np.ndarray, k: int, ox: int = 0, oy: int = 0) -> np.ndarray:
    """The k*k LDBN points (row-major cells) of ``table`` read at offset (ox, oy)."""
    X, Y, u, v = _parts(table, k, ox, oy)
    return np.stack([(X + u) / k, (Y + v) / k], axis=-1)


def offset_bits(k: int) -> int:
    """2^b for the b bits of the radical inverses in a k x k set (k for k a power of two
    >= 16, so the points sit on the 1/n lattice)."""
    top = RUN * ((k + RUN - 1) // RUN)  # radical-inverse arguments are < top
    return 1 << (top - 1).bit_length()


def ldbn(n: int, count: int, rng: np.random.Generator) -> np.ndarray:
    """``count`` LDBN sets of n = k*k points (n must be a perfect square)."""
    k = math.isqrt(n)
    if k * k != n:
        raise ValueError(f"ldbn needs a square number of points (k*k), got n={n}")
    table = load_table()
    top = 1 - 1 / offset_bits(k)
    out = np.empty((count, n, 2))
    for c in range(count):
        ox, oy = RUN * rng.integers(SIZE // RUN, size=2)
        X, Y, u, v = _parts(table, k, int(ox), int(oy))
        w = int(rng.integers(8))
        # mirrors act on the integer cell and the dyadic offset separately (both exact), so
        # cells map onto cells and lattice strips onto strips
        if w & 1:
            X, u = k - 1 - X, top - u
        if w & 2:
            Y, v = k - 1 - Y, top - v
        if w & 4:
            X, Y, u, v = Y, X, v, u
        out[c] = np.stack([(X + u) / k, (Y + v) / k], axis=-1)
    return np.clip(out, 0.0, np.nextafter(1.0, 0.0))
