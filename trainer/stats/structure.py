"""Net structure: elementary intervals of 2^m-point sets, and 1-d stratification."""
from __future__ import annotations

import numpy as np


def _sets_of_2m(points: np.ndarray, what: str) -> tuple[np.ndarray, int, tuple[int, ...]]:
    """Point sets as (S, n, 2), m with n = 2^m, and the leading shape to restore."""
    pts = np.asarray(points, dtype=np.float64)
    flat = pts.reshape((-1,) + pts.shape[-2:])
    n = flat.shape[1]
    m = n.bit_length() - 1
    if 1 << m != n:
        raise ValueError(f"{what} need n = 2^m points, got n={n}")
    return flat, m, pts.shape[:-2]


def _interval_counts(p: np.ndarray, a: int, b: int) -> np.ndarray:
    """Points in each elementary interval of shape 2^-a x 2^-b."""
    cx = np.minimum((p[:, 0] * (1 << a)).astype(np.int64), (1 << a) - 1)
    cy = np.minimum((p[:, 1] * (1 << b)).astype(np.int64), (1 << b) - 1)
    return np.bincount(cx * (1 << b) + cy, minlength=1 << (a + b))


def empty_elementary_fraction(points: np.ndarray) -> np.ndarray:
    """Fraction of empty elementary intervals, per set of n = 2^m points.

    Over all shapes 2^-a x 2^-b with a + b = m ((m + 1) n intervals in all); 0 for a
    (0, m, 2)-net, whose every elementary interval holds exactly one point.
    """
    flat, m, shape = _sets_of_2m(points, "elementary intervals")
    empty = [sum(int(np.sum(_interval_counts(p, a, m - a) == 0)) for a in range(m + 1))
             for p in flat]
    return (np.array(empty, dtype=np.float64) / ((m + 1) << m)).reshape(shape)


def t_value(points: np.ndarray) -> np.ndarray:
    """Smallest t such that each set of n = 2^m points is a (t, m, 2)-net in base 2.

    A (t, m, 2)-net puts exactly 2^t points in every elementary interval of area 2^(t-m).
    """
    flat, m, shape = _sets_of_2m(points, "t-values")
    out = np.empty(len(flat), dtype=np.int64)
    for s, p in enumerate(flat):
        out[s] = next(t for t in range(m + 1)
                      if all(np.all(_interval_counts(p, a, m - t - a) == 1 << t)
                             for a in range(m - t + 1)))
    return out.reshape(shape)


def stratified_projections(points: np.ndarray) -> np.ndarray:
    """Whether both 1-d projections of each set put exactly one point in every 1/n strip."""
    pts = np.asarray(points, dtype=np.float64)
    flat = pts.reshape((-1,) + pts.shape[-2:])
    n = flat.shape[1]
    out = np.empty(len(flat), dtype=bool)
    for s, p in enumerate(flat):
        strips = np.minimum((p * n).astype(np.int64), n - 1)
        out[s] = all(np.unique(strips[:, c]).size == n for c in range(2))
    return out.reshape(pts.shape[:-2])
