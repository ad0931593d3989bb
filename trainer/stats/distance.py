"""Minimum pairwise distances."""
from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree


def min_distance(points: np.ndarray, toroidal: bool = False) -> np.ndarray:
    """Smallest pairwise distance per set (Euclidean, or on the unit torus)."""
    pts = np.asarray(points, dtype=np.float64)
    flat = pts.reshape((-1,) + pts.shape[-2:])
    out = np.empty(len(flat))
    for s, p in enumerate(flat):
        tree = cKDTree(p % 1.0 if toroidal else p, boxsize=1.0 if toroidal else None)
        d, _ = tree.query(p % 1.0 if toroidal else p, k=2)
        out[s] = d[:, 1].min()
    return out.reshape(pts.shape[:-2])
