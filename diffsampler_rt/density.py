"""Non-uniform models: a density learned from the examples, as a map to and from the square.

A model of a non-uniform sampler learns its sets after the Rosenblatt map of their density
(x -> F_X(x), y -> F_Y|X(y | x)), which takes them to the uniform square; the runtime maps
the generated sets back with the inverse. The density lives in the card as a table fitted
to the training sets (``trainer.density``):

- ``x_cdf``: the x-marginal's CDF at x = 0, 1/B, ..., 1 (B + 1 increasing values, 0 to 1);
- ``y_cdf``: for each of the B columns of width 1/B, the CDF of y in that column at
  y = 0, 1/B, ..., 1.

Between the knots each CDF is linear (a density constant per bin); the conditional CDF at
x is interpolated linearly between the column centres, so both maps are continuous and
their pieces invert exactly.
"""
from __future__ import annotations

from typing import Any, Mapping

import numpy as np

from ._validate import unit_points

#: largest table side a card may carry (the card is JSON in the ONNX metadata)
MAX_BINS = 256


def check_table(table: Any) -> str | None:
    """None if ``table`` is a valid density table, else what is wrong with it."""
    if not isinstance(table, Mapping) or set(table) != {"x_cdf", "y_cdf"}:
        return "must be an object with exactly the keys 'x_cdf' and 'y_cdf'"
    try:
        xc = np.asarray(table["x_cdf"], dtype=np.float64)
        yc = np.asarray(table["y_cdf"], dtype=np.float64)
    except (TypeError, ValueError):
        return "x_cdf and y_cdf must be numbers"
    bins = xc.size - 1
    if xc.ndim != 1 or not 1 <= bins <= MAX_BINS:
        return f"x_cdf must hold 2 to {MAX_BINS + 1} numbers"
    if yc.shape != (bins, bins + 1):
        return f"y_cdf must be {bins} rows of {bins + 1} numbers, got shape {yc.shape}"
    for name, c in (("x_cdf", xc[None]), ("y_cdf", yc)):
        if not np.all(np.isfinite(c)) or np.any(c[:, 0] != 0) or np.any(c[:, -1] != 1) \
                or np.any(np.diff(c, axis=1) <= 0):
            return f"each {name} row must increase strictly from 0 to 1"
    return None


def _tables(table: Mapping[str, Any]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    xc = np.asarray(table["x_cdf"], dtype=np.float64)
    yc = np.asarray(table["y_cdf"], dtype=np.float64)
    return np.linspace(0.0, 1.0, xc.size), xc, yc


def _column_weights(x: np.ndarray, bins: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Per x: the two columns whose y-CDFs are blended there and the second one's weight."""
    c = np.clip(x * bins - 0.5, 0.0, bins - 1.0)  # position in column-centre units
    i = np.minimum(c.astype(np.int64), max(bins - 2, 0))
    return i, np.minimum(i + 1, bins - 1), c - i


def _column_cdf_at(yc: np.ndarray, cols: tuple, j: np.ndarray) -> np.ndarray:
    """The blended conditional CDF knot j at each point (one knot per point: no
    (points, bins) array, so big sets and fine tables stay cheap)."""
    i, i1, w = cols
    return yc[i, j] * (1 - w) + yc[i1, j] * w


def unwarp(points: np.ndarray, table: Mapping[str, Any]) -> np.ndarray:
    """Points (..., 2) of the density -> the uniform square (the Rosenblatt map)."""
    knots, xc, yc = _tables(table)
    p = unit_points(points, form="(..., 2)")
    flat = p.reshape(-1, 2)
    u = np.interp(flat[:, 0], knots, xc)
    bins = yc.shape[0]
    cols = _column_weights(flat[:, 0], bins)
    s = np.clip(flat[:, 1], 0.0, 1.0) * bins
    j = np.minimum(s.astype(np.int64), bins - 1)
    lo, hi = _column_cdf_at(yc, cols, j), _column_cdf_at(yc, cols, j + 1)
    v = lo + (s - j) * (hi - lo)
    out = np.clip(np.column_stack([u, v]), 0.0, np.nextafter(1.0, 0.0))
    return out.reshape(p.shape)


def warp(points: np.ndarray, table: Mapping[str, Any]) -> np.ndarray:
    """Points (..., 2) in the uniform square -> the density (inverse of :func:`unwarp`).

    Examples
    --------
    >>> t = {"x_cdf": [0.0, 0.25, 1.0], "y_cdf": [[0.0, 0.5, 1.0], [0.0, 0.5, 1.0]]}
    >>> warp(np.array([[0.25, 0.5]]), t)
    array([[0.5, 0.5]])
    """
    knots, xc, yc = _tables(table)
    p = unit_points(points, form="(..., 2)")
    flat = p.reshape(-1, 2)
    x = np.interp(flat[:, 0], xc, knots)
    bins = yc.shape[0]
    cols = _column_weights(x, bins)
    v = np.clip(flat[:, 1], 0.0, 1.0)
    # the last knot j with CDF_j <= v (knot 0 is 0 <= v), by bisection over the knots
    j, top = np.zeros(len(flat), dtype=np.int64), np.full(len(flat), bins, dtype=np.int64)
    while np.any(top > j):
        mid = (j + top + 1) // 2
        below = _column_cdf_at(yc, cols, mid) <= v
        j, top = np.where(below, mid, j), np.where(below, top, mid - 1)
    j = np.minimum(j, bins - 1)
    lo, hi = _column_cdf_at(yc, cols, j), _column_cdf_at(yc, cols, j + 1)
    y = (j + (v - lo) / (hi - lo)) / bins
    out = np.clip(np.column_stack([x, y]), 0.0, np.nextafter(1.0, 0.0))
    return out.reshape(p.shape)
