"""Rank-1 (Korobov) lattices (i/n, i*g/n mod 1) with a random toroidal shift."""
from __future__ import annotations

import math
from functools import lru_cache

import numpy as np


def korobov(n: int, g: int) -> np.ndarray:
    """The unshifted lattice {(i/n, (i*g mod n)/n)}, shape (n, 2), computed exactly."""
    i = np.arange(n, dtype=np.int64)
    return np.stack([i, (i * g) % n], axis=1).astype(np.float64) / n


@lru_cache(maxsize=64)
def maxmin_generator(n: int) -> int:
    """The generator g (coprime to n) that maximises the lattice's toroidal min distance.

    Ties go to the smallest g. Coprimality keeps the y-projection a permutation (a g
    sharing a factor with n stacks points on fewer rows). Cost O(n^2), cached.

    Examples
    --------
    >>> maxmin_generator(1024)
    271
    """
    if n < 3:
        return 1
    cand = np.array([g for g in range(1, n // 2 + 1) if math.gcd(g, n) == 1], dtype=np.int64)
    i = np.arange(1, n, dtype=np.int64)
    dx = np.minimum(i, n - i).astype(np.float64) ** 2
    best = np.empty(cand.size)
    chunk = max(1, 4_000_000 // n)
    for s in range(0, cand.size, chunk):
        y = (cand[s:s + chunk, None] * i[None, :]) % n
        dy = np.minimum(y, n - y).astype(np.float64) ** 2
        best[s:s + chunk] = (dx[None, :] + dy).min(axis=1)
    return int(cand[int(np.argmax(best))])  # argmax returns the first (smallest g) tie


def shifted(base: np.ndarray, count: int, rng: np.random.Generator) -> np.ndarray:
    """``count`` copies of ``base`` (n, 2), each under its own uniform toroidal shift."""
    shifts = rng.random((count, 1, 2))
    return (base[None, :, :] + shifts) % 1.0


def rank1(n: int, count: int, rng: np.random.Generator) -> np.ndarray:
    """Rank-1 Korobov lattice with the max-min-distance generator, randomly shifted."""
    return shifted(korobov(n, maxmin_generator(n)), count, rng)
