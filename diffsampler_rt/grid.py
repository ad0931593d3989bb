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


def strip_bounds(k: int) -> tuple[np.ndarray, np.ndarray]:
    """Smallest and largest float64 x with floor(x * k) == i, for each of the k strips i."""
    col = np.arange(k, dtype=np.float64)
    lo, hi = col / k, np.nextafter((col + 1) / k, 0.0)
    for _ in range(4):  # a few ulps of rounding in x * k at most
        lo = np.where(np.floor(lo * k) < col, np.nextafter(lo, 1.0), lo)
        hi = np.where(np.floor(hi * k) > col, np.nextafter(hi, 0.0), hi)
    return lo, hi


def reflect(values: np.ndarray) -> np.ndarray:
    """Values folded into [0, 1) by reflection at 0 and 1 (period 2): a point pushed 0.01
    past an edge lands 0.01 inside it. Unlike clamping, this puts no mass exactly on the
    border (a clamped coordinate of exactly 0 breaks an inverse-CDF transform downstream,
    and piles up at the edge).

    Examples
    --------
    >>> import numpy as np
    >>> from diffsampler_rt.grid import reflect
    >>> reflect(np.array([-0.25, 0.5, 1.25, 2.5]))
    array([0.25, 0.5 , 0.75, 0.5 ])
    """
    v = np.abs(np.asarray(values, dtype=np.float64)) % 2.0
    return np.minimum(np.where(v >= 1.0, 2.0 - v, v), _BELOW_ONE)


def wrap(points: np.ndarray) -> np.ndarray:
    """Points taken modulo 1 into [0, 1)^2 (the torus), float64."""
    p = np.asarray(points, dtype=np.float64)
    return np.clip(p - np.floor(p), 0.0, _BELOW_ONE)  # -1e-17 mod 1 rounds to 1.0


def decode(grid: np.ndarray, *, stratified: bool = False, toroidal: bool = False) -> np.ndarray:
    """Offsets (..., 2, k, k) in cell units -> points (..., k*k, 2) in [0, 1)^2, float64.

    ``stratified=True`` keeps every point inside its own cell (the embedding of a
    stratified sampler guarantees one point per cell): an offset past the cell's edge is
    reflected back into it; ``toroidal=True`` takes points modulo 1 (a net with circular
    padding works on the torus); otherwise points outside the unit square are reflected
    into it (:func:`reflect`).
    """
    grid = np.asarray(grid, dtype=np.float64)
    k = grid.shape[-1]
    if grid.shape[-3:] != (2, k, k):
        raise ValueError(f"grid must have shape (..., 2, k, k), got {grid.shape}")
    if stratified:
        grid = reflect(grid + 0.5) - 0.5
    centre = np.arange(k, dtype=np.float64) + 0.5
    x = (grid[..., 0, :, :] + centre[None, :]) / k
    y = (grid[..., 1, :, :] + centre[:, None]) / k
    if stratified:
        lo, hi = strip_bounds(k)
        x = np.clip(x, lo[None, :], hi[None, :])
        y = np.clip(y, lo[:, None], hi[:, None])
    pts = np.stack([x, y], axis=-1).reshape(grid.shape[:-3] + (k * k, 2))
    if toroidal and not stratified:
        return wrap(pts)
    return pts if stratified else reflect(pts)


def encode_stratified(points: np.ndarray, k: int) -> np.ndarray:
    """Inverse of ``decode(..., stratified=True)``: points (..., k*k, 2) in row-major cell
    order -> offsets (..., 2, k, k) in cell units."""
    pts = np.asarray(points, dtype=np.float64)
    centre = np.arange(k, dtype=np.float64) + 0.5
    x = pts[..., 0].reshape(pts.shape[:-2] + (k, k)) * k - centre[None, :]
    y = pts[..., 1].reshape(pts.shape[:-2] + (k, k)) * k - centre[:, None]
    return np.stack([x, y], axis=-3)
