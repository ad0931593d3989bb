"""Grid embedding of point sets (the seed method's input representation).

A set of n = k*k points becomes a (2, k, k) array of offsets, in cell units, from each
cell centre to the point assigned to that cell (see :mod:`diffsampler_rt.grid` for the
convention and the inverse, :func:`diffsampler_rt.grid.decode`):

- ``stratified``: the point inside each cell (the sampler must put one point per cell);
- ``ot``: an optimal-transport linear assignment (squared Euclidean cost) between cell
  centres and points, for samplers that are not stratified.
"""
from __future__ import annotations

import math

import numpy as np
from scipy.optimize import linear_sum_assignment

from diffsampler_rt.grid import cell_centres

EMBEDDINGS = ("stratified", "ot")


def grid_side(n: int) -> int:
    """k such that n = k*k, or ValueError."""
    k = math.isqrt(n)
    if k * k != n:
        raise ValueError(f"a grid embedding needs a square number of points, got n={n}")
    return k


def embed_stratified(points: np.ndarray) -> np.ndarray:
    """(n, 2) points with one point per cell of the k x k grid -> (2, k, k) offsets."""
    k = grid_side(points.shape[0])
    scaled = points * k
    cell = np.minimum(np.floor(scaled).astype(np.int64), k - 1)
    flat = cell[:, 1] * k + cell[:, 0]
    counts = np.bincount(flat, minlength=k * k)
    if not np.all(counts == 1):
        raise ValueError(f"point set is not stratified on the {k}x{k} grid: "
                         f"{int(np.sum(counts == 0))} empty cells; use embedding='ot'")
    grid = np.empty((2, k * k))
    grid[:, flat] = (scaled - cell - 0.5).T
    return grid.reshape(2, k, k)


def embed_ot(points: np.ndarray) -> np.ndarray:
    """(n, 2) points -> (2, k, k) offsets of the optimal linear assignment to cell centres."""
    k = grid_side(points.shape[0])
    centres = cell_centres(k)
    cost = ((centres[:, None, :] - points[None, :, :]) ** 2).sum(-1)
    rows, cols = linear_sum_assignment(cost)
    grid = np.empty((2, k * k))
    grid[:, rows] = ((points[cols] - centres[rows]) * k).T
    return grid.reshape(2, k, k)


def embed(points: np.ndarray, kind: str) -> np.ndarray:
    """Point sets (..., n, 2) -> offsets (..., 2, k, k), float64, by ``kind``."""
    if kind not in EMBEDDINGS:
        raise ValueError(f"unknown embedding {kind!r}; choose one of {EMBEDDINGS}")
    one = embed_stratified if kind == "stratified" else embed_ot
    points = np.asarray(points, dtype=np.float64)
    flat = points.reshape((-1,) + points.shape[-2:])
    out = np.stack([one(p) for p in flat])
    k = out.shape[-1]
    return out.reshape(points.shape[:-2] + (2, k, k))


def symmetries(grid: np.ndarray, which: np.ndarray) -> np.ndarray:
    """Apply one of the 8 symmetries of the square to each offset grid (B, 2, k, k).

    ``which[b]`` in 0..7: bit 0 mirrors x, bit 1 mirrors y, bit 2 swaps x and y. The
    offsets transform with the cells, so the decoded set is the transformed point set.
    """
    out = grid.copy()
    for b, w in enumerate(which):
        g = out[b]
        if w & 1:
            g = np.stack([-g[0, :, ::-1], g[1, :, ::-1]])
        if w & 2:
            g = np.stack([g[0, ::-1, :], -g[1, ::-1, :]])
        if w & 4:
            g = np.stack([g[1].T, g[0].T])
        out[b] = g
    return out
