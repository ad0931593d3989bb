"""Argument validation: clear errors that name the bad value and the valid choices."""
from __future__ import annotations

import math
import numbers

import threading
from contextlib import contextmanager
from typing import Iterator

import numpy as np

MIN_POINTS = 16
#: 512 x 512 grids; beyond that the coarsest-level self-attention needs many GiB
MAX_POINTS = 512 * 512


def integer(name: str, value: object) -> int:
    if isinstance(value, (bool, np.bool_)) or not isinstance(value, numbers.Integral):
        raise TypeError(f"{name} must be an integer, got {value!r} ({type(value).__name__})")
    return int(value)


def flag(name: str, value: object) -> bool:
    """A switch must be a bool: a string such as "false" is truthy and would flip it."""
    if not isinstance(value, (bool, np.bool_)):
        raise TypeError(f"{name} must be True or False, got {value!r} ({type(value).__name__})")
    return bool(value)


def num_points(n: object) -> int:
    """n must be an integer in [MIN_POINTS, MAX_POINTS]; returns the grid side
    k = ceil(sqrt n) (n = k*k: the net's own size; otherwise k*k - n points are thinned
    away, diffsampler_rt.elimination)."""
    n = integer("n", n)
    if n <= 0:
        raise ValueError(f"n must be positive, got {n}")
    if n < MIN_POINTS:
        raise ValueError(f"n={n} is too small: at least {MIN_POINTS} points per set (a 4 x 4 "
                         "grid)")
    if n > MAX_POINTS:
        raise ValueError(f"n={n} is too large: at most {MAX_POINTS} points per set "
                         f"({math.isqrt(MAX_POINTS)}^2)")
    return math.isqrt(n - 1) + 1


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


_TRUST = threading.local()


@contextmanager
def trusted() -> Iterator[None]:
    """Within this block (in this thread) :func:`unit_points` trusts its input: the
    runtime's generation path, whose points come from its own decoding and finishing steps,
    checks them once at its edge instead of once per step."""
    before = getattr(_TRUST, "on", False)
    _TRUST.on = True
    try:
        yield
    finally:
        _TRUST.on = before


def unit_points(points: object, *, name: str = "points", form: str = "(n, 2) or (sets, n, 2)",
                min_n: int = 1) -> np.ndarray:
    """``points`` as a float64 array of one or more sets of 2-d points in [0, 1]^2.

    ``form`` says which shapes are taken, e.g. ``"(n, 2)"``, ``"(sets, n, 2)"``,
    ``"(n, 2) or (sets, n, 2)"``, ``"(..., n, 2)"`` or ``"(..., 2)"`` (points in any layout,
    a lone point too; any names); ``min_n`` is the fewest points a set may have. A ValueError
    names a wrong shape, the count of non-finite coordinates, or the range of coordinates
    outside the unit square: every finishing step and statistic here is defined on the unit
    square (or torus), where a NaN would otherwise pass through as silent garbage.
    Inside :func:`trusted` it only converts.
    """
    if getattr(_TRUST, "on", False):
        return np.asarray(points, dtype=np.float64)
    try:
        pts = np.asarray(points, dtype=np.float64)
    except (TypeError, ValueError):
        raise TypeError(f"{name} must be an array of numbers, "
                        f"got {type(points).__name__}") from None
    ndims = None if "..." in form else {part.count(",") + 1 for part in form.split(" or ")}
    fewest_axes = form.count(",") if ndims is None else 2  # "(..., 2)": a lone point too
    if (pts.ndim < fewest_axes or (ndims is not None and pts.ndim not in ndims)
            or pts.shape[-1] != 2 or (pts.ndim >= 2 and pts.shape[-2] < min_n)):
        at_least = f" with n >= {min_n}" if min_n > 1 else ""
        raise ValueError(f"{name} must have shape {form}{at_least}, got {pts.shape}")
    if not np.all(np.isfinite(pts)):
        bad = int(np.sum(~np.isfinite(pts)))
        raise ValueError(f"{name} has {bad} non-finite coordinate{'s' * (bad != 1)} (NaN or inf)")
    if pts.size and (pts.min() < 0 or pts.max() > 1):
        raise ValueError(f"{name} must lie in the unit square [0, 1]^2, got coordinates from "
                         f"{pts.min():.4g} to {pts.max():.4g}")
    return pts
