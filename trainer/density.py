"""Fit the density of a non-uniform sampler from its example sets (see diffsampler_rt.density).

The training sets are pooled into a bins x bins histogram; its x-marginal and per-column
y-CDFs make the table that :func:`diffsampler_rt.density.unwarp` uses to take the sets
to the uniform square before the grid embedding, and that the runtime inverts.
"""
from __future__ import annotations

import numpy as np

from diffsampler_rt.density import MAX_BINS


def fit_density(points: np.ndarray, bins: int, *, floor: float = 1e-3) -> dict[str, list]:
    """Density table of the points (..., 2) on a ``bins`` x ``bins`` histogram.

    ``floor`` (a fraction of the mean count per bin) is added to every bin, so that both
    CDFs increase strictly and the maps invert even where the examples left a bin empty.
    """
    if not isinstance(bins, int) or not 1 <= bins <= MAX_BINS:
        raise ValueError(f"bins must be an integer in [1, {MAX_BINS}], got {bins!r}")
    if not floor > 0:
        raise ValueError(f"floor must be > 0, got {floor!r}")
    p = np.asarray(points, dtype=np.float64).reshape(-1, 2)
    if len(p) == 0 or not np.all((p >= 0) & (p <= 1)):
        raise ValueError("fit_density needs a non-empty set of points in [0, 1]^2")
    edges = np.linspace(0.0, 1.0, bins + 1)
    hist, _, _ = np.histogram2d(p[:, 0], p[:, 1], bins=[edges, edges])
    hist += floor * len(p) / bins**2
    x_cdf = np.concatenate([[0.0], np.cumsum(hist.sum(axis=1))]) / hist.sum()
    y_cdf = np.concatenate([np.zeros((bins, 1)), np.cumsum(hist, axis=1)], axis=1)
    y_cdf /= y_cdf[:, -1:]
    x_cdf[-1] = 1.0  # exact ends despite rounding in the sums
    y_cdf[:, -1] = 1.0
    return {"x_cdf": x_cdf.tolist(), "y_cdf": y_cdf.tolist()}
