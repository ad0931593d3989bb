"""The grid convention shared by training and generation.

A set of n = k*k points lives on a k x k grid of cells: array ``grid[c, row, col]`` with
``c = 0`` the x offset and ``c = 1`` the y offset, row = y cell index, col = x cell index.
Offsets are in *cell units* (independent of k): the point of cell (row, col) is
``((col + 0.5 + grid[0]) / k, (row + 0.5 + grid[1]) / k)``.
"""
from __future__ import annotations

import numpy as np

_BELOW_ONE = np.nextafter(1.0, 0.0)


def cell_centres(k: int) -> np.ndarray:
    """Centres of the k x k cells in row-major (row = y, col = x) order, shape (k*k, 2)."""
    c = (np.arange(k, dtype=np.float64) + 0.5) / k
    cy, cx = np.meshgrid(c, c, indexing="ij")
    return np.stack([cx.ravel(), cy.ravel()], axis=1)


def decode(grid: np.ndarray, *, stratified: bool = False) -> np.ndarray:
    """Offsets (..., 2, k, k) in cell units -> points (..., k*k, 2) in [0, 1)^2, float64.

    ``stratified=True`` keeps every point inside its own cell (the embedding of a
    stratified sampler guarantees one point per cell); otherwise points are clipped to
    the unit square.
    """
    grid = np.asarray(grid, dtype=np.float64)
    k = grid.shape[-1]
    if grid.shape[-3:] != (2, k, k):
        raise ValueError(f"grid must have shape (..., 2, k, k), got {grid.shape}")
    if stratified:
        grid = np.clip(grid, -0.5, 0.5)
    centre = np.arange(k, dtype=np.float64) + 0.5
    x = (grid[..., 0, :, :] + centre[None, :]) / k
    y = (grid[..., 1, :, :] + centre[:, None]) / k
    if stratified:
        # a point on its cell's upper edge would belong to the next cell: keep it inside
        top = np.nextafter((centre + 0.5) / k, 0.0)
        x = np.minimum(x, top[None, :])
        y = np.minimum(y, top[:, None])
    pts = np.stack([x, y], axis=-1).reshape(grid.shape[:-3] + (k * k, 2))
    return np.clip(pts, 0.0, _BELOW_ONE)
