"""Sliced optimal transport sampling (Paulin et al. 2020) of the uniform square.

n points are optimised in the unit disk, whose projection on every direction has the same
density (2/pi) sqrt(1 - t^2); each iteration matches the sorted projections on m
directions to that density's quantiles and moves every point by the average of its 1-d
displacements. The disk is finally mapped to the square by the inverse of Shirley and
Chiu's concentric map, which preserves area, so uniform stays uniform.
"""
from __future__ import annotations

from functools import lru_cache

import numpy as np


@lru_cache(maxsize=32)
def disk_quantiles(n: int) -> np.ndarray:
    """t_i = F^-1((2i + 1) / (2n)) for the disk's projected CDF F (exact to ~1e-12)."""
    u = (2 * np.arange(n) + 1) / (2 * n)
    t = np.zeros(n)
    for _ in range(60):  # Newton on F(t) = 1/2 + (t sqrt(1 - t^2) + arcsin t) / pi
        s = np.sqrt(np.clip(1 - t * t, 1e-300, None))
        t = np.clip(t - (0.5 + (t * s + np.arcsin(t)) / np.pi - u) / (2 / np.pi * s),
                    -1 + 1e-15, 1 - 1e-15)
    return t


def disk_to_square(p: np.ndarray) -> np.ndarray:
    """Inverse concentric map (Shirley & Chiu 1997): unit disk -> [0, 1)^2."""
    x, y = p[..., 0], p[..., 1]
    r = np.hypot(x, y)
    with np.errstate(divide="ignore", invalid="ignore"):
        wide = np.abs(x) >= np.abs(y)
        a = np.where(wide, np.sign(x) * r, np.sign(y) * r * 4 / np.pi * np.arctan(x / y))
        b = np.where(wide, np.sign(x) * r * 4 / np.pi * np.arctan(y / x), np.sign(y) * r)
    sq = np.stack([np.nan_to_num(a), np.nan_to_num(b)], axis=-1)
    return np.clip((sq + 1) / 2, 0.0, np.nextafter(1.0, 0.0))


def sot_disk(n: int, count: int, rng: np.random.Generator, *, iterations: int = 4096,
             directions: int = 64) -> np.ndarray:
    """``count`` sets of n SOT points in the unit disk, optimised together."""
    rad = np.sqrt(rng.random((count, n)))
    ang = 2 * np.pi * rng.random((count, n))
    x = np.stack([rad * np.cos(ang), rad * np.sin(ang)], axis=-1)
    target = disk_quantiles(n)
    base = np.arange(directions) * (np.pi / directions)
    for _ in range(iterations):
        theta = base + rng.random() * (np.pi / directions)  # well-spread, randomly rotated
        dirs = np.stack([np.cos(theta), np.sin(theta)], axis=1)  # (m, 2)
        proj = np.einsum("cnk,mk->cmn", x, dirs)  # sort along the contiguous last axis
        order = np.argsort(proj, axis=-1)
        shift = np.empty_like(proj)
        np.put_along_axis(shift, order, target - np.take_along_axis(proj, order, -1), -1)
        x = x + np.einsum("cmn,mk->cnk", shift, dirs) / directions
    return x


def sot(n: int, count: int, rng: np.random.Generator, iterations: int = 4096) -> np.ndarray:
    """``count`` SOT sets of n points in the unit square (disk optimisation, then mapped)."""
    return disk_to_square(sot_disk(n, count, rng, iterations=iterations))
