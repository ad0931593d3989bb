"""Argument validation: clear errors that name the bad value and the valid choices."""
from __future__ import annotations

import math
import numbers

import numpy as np

MIN_POINTS = 16
#: 512 x 512 grids; beyond that the coarsest-level self-attention needs many GiB
MAX_POINTS = 512 * 512


def integer(name: str, value: object) -> int:
    if isinstance(value, (bool, np.bool_)) or not isinstance(value, numbers.Integral):
        raise TypeError(f"{name} must be an integer, got {value!r} ({type(value).__name__})")
    return int(value)


def nearest_squares(n: int) -> tuple[int, ...]:
    """The valid sizes (perfect squares in range) closest to n, below and above."""
    k = math.isqrt(max(n, 0))
    below, above = k * k, (k + 1) ** 2
    cands = [s for s in (below, above) if MIN_POINTS <= s <= MAX_POINTS]
    if not cands:
        cands = [MIN_POINTS] if n < MIN_POINTS else [MAX_POINTS]
    return tuple(dict.fromkeys(cands))


def num_points(n: object) -> int:
    """n must be a perfect square in [16, MAX_POINTS]; returns the grid side k."""
    n = integer("n", n)
    if n <= 0:
        raise ValueError(f"n must be positive, got {n}")
    if n > MAX_POINTS:
        raise ValueError(f"n={n} is too large: at most {MAX_POINTS} points per set "
                         f"({math.isqrt(MAX_POINTS)}^2)")
    k = math.isqrt(n)
    if k * k != n or n < MIN_POINTS:
        near = " or ".join(str(s) for s in nearest_squares(n))
        raise ValueError(f"n={n} is not supported: n must be a perfect square >= {MIN_POINTS} "
                         f"(k*k points on a k x k grid); nearest valid sizes: {near}")
    return k


def count(value: object) -> int:
    c = integer("count", value)
    if c < 1:
        raise ValueError(f"count must be >= 1, got {c}")
    return c


def steps(value: object, num_train_steps: int) -> int:
    s = integer("steps", value)
    if not 1 <= s <= num_train_steps:
        raise ValueError(f"steps must be between 1 and {num_train_steps} (the model's training "
                         f"steps), got {s}")
    return s


def rng(seed: object) -> np.random.Generator:
    """None, a non-negative int or a numpy Generator -> Generator (scipy.stats.qmc habit)."""
    if isinstance(seed, np.random.Generator):
        return seed
    if seed is None:
        return np.random.default_rng()
    s = integer("seed", seed)
    if s < 0:
        raise ValueError(f"seed must be a non-negative integer, got {s}")
    return np.random.default_rng(s)
