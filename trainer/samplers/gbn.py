"""Gaussian blue noise (Ahmed, Ren, Wonka 2022), toroidal, from white noise."""
from __future__ import annotations

import math

import numpy as np
from scipy.spatial import cKDTree


def gbn_relax(points: np.ndarray, iterations: int = 3000, *, sigma: float = 1.0,
              step: float = 0.25, cutoff: float = 5.8, rebuild: int = 8) -> np.ndarray:
    """Move all points at once by step * sum_j d_ij exp(-n |d_ij|^2 / (2 sigma^2)).

    d_ij is the toroidal difference x_i - x_j. Only pairs within ``cutoff`` sigma / sqrt(n)
    contribute (the kernel is below 1e-7 there); the pair list is rebuilt every ``rebuild``
    iterations with a margin wide enough for the points' motion in between.
    """
    x = np.array(points, dtype=np.float64) % 1.0
    n = x.shape[0]
    radius = cutoff * sigma / math.sqrt(n)
    inv = n / (2.0 * sigma * sigma)
    margin = 0.5 / math.sqrt(n)
    i = j = None
    for it in range(iterations):
        if it % rebuild == 0:
            pairs = cKDTree(x, boxsize=1.0).query_pairs(radius + margin, output_type="ndarray")
            i, j = pairs[:, 0], pairs[:, 1]
        d = x[i] - x[j]
        d -= np.round(d)
        w = np.exp(-inv * np.einsum("ij,ij->i", d, d))[:, None] * d
        force = np.zeros_like(x)
        for c in range(2):
            force[:, c] = (np.bincount(i, w[:, c], minlength=n)
                           - np.bincount(j, w[:, c], minlength=n))
        x = (x + step * force) % 1.0
    return np.where(x >= 1.0, 0.0, x)


def gbn(n: int, count: int, rng: np.random.Generator, iterations: int = 3000) -> np.ndarray:
    """``count`` GBN sets of n points: white noise relaxed by :func:`gbn_relax`.

    3000 iterations: at 1000 (the authors' example) the spectral peak at n = 1024 is still
    ~15 % below the seed paper's GBN curve; at 3000 it matches it (radial-spectrum MAE
    0.015 over 12 sets, measured here).
    """
    return np.stack([gbn_relax(rng.random((n, 2)), iterations) for _ in range(count)])
