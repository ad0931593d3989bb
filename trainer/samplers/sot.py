"""Sliced optimal transport sampling (Paulin et al. 2020) of the uniform square.

n points are optimised in the unit disk, whose projection on every direction has the same
density (2/pi) sqrt(1 - t^2); each iteration matches the sorted projections on m
directions to that density's quantiles and moves every point by the average of its 1-d
displacements. The disk is finally mapped to the square by the inverse of Shirley and
Chiu's concentric map, which preserves area, so uniform stays uniform.
"""
from __future__ import annotations

import numpy as np

# the runtime polishes generated sets with the same update (diffsampler_rt.sliced_ot)
from diffsampler_rt.disk_transport import disk_quantiles, disk_to_square, sliced_step

__all__ = ["disk_quantiles", "disk_to_square", "sot", "sot_disk"]


def sot_disk(n: int, count: int, rng: np.random.Generator, *, iterations: int = 4096,
             directions: int = 64) -> np.ndarray:
    """``count`` sets of n SOT points in the unit disk, optimised together."""
    rad = np.sqrt(rng.random((count, n)))
    ang = 2 * np.pi * rng.random((count, n))
    x = np.stack([rad * np.cos(ang), rad * np.sin(ang)], axis=-1)
    base = np.arange(directions) * (np.pi / directions)
    for _ in range(iterations):
        # well-spread, randomly rotated directions
        x = sliced_step(x, base + rng.random() * (np.pi / directions))
    return x


def sot(n: int, count: int, rng: np.random.Generator, iterations: int = 4096) -> np.ndarray:
    """``count`` SOT sets of n points in the unit square (disk optimisation, then mapped)."""
    return disk_to_square(sot_disk(n, count, rng, iterations=iterations))
