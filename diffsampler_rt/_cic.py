"""Cloud-in-cell deposit of points on a periodic grid (the lattice fit's and the thinning's
FFTs both start from it)."""
from __future__ import annotations

import numpy as np


def deposit(points: np.ndarray, m: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Bilinear (cloud-in-cell) weights of points (n, 2) in [0, 1)^2 on an m x m torus grid.

    Returns (grid (m, m) whose entries sum to n, lower grid cell per point (n, 2), the
    points' fractional offsets in it (n, 2)): the last two interpolate a grid back at the
    points with the same weights.
    """
    f = points * m
    base = np.floor(f).astype(np.int64)
    w = f - base
    grid = np.zeros(m * m)
    for dx in (0, 1):
        for dy in (0, 1):
            weight = (w[:, 0] if dx else 1 - w[:, 0]) * (w[:, 1] if dy else 1 - w[:, 1])
            cell = ((base[:, 0] + dx) % m) * m + (base[:, 1] + dy) % m
            grid += np.bincount(cell, weight, minlength=m * m)
    return grid.reshape(m, m), base, w
