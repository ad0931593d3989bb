"""Minimum and nearest-neighbour distances."""
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


def spacing_coefficient(points: np.ndarray, percentile: float = 5.0, *,
                        mean: bool = False, toroidal: bool = False) -> float:
    """The ``percentile`` of the smallest distance of each set (..., n, 2), times sqrt(n).

    The coefficient c of the spacing radius c / sqrt(n) a model card asks the runtime to
    keep (``"min_spacing"``, :mod:`diffsampler_rt.spacing`): a radius that this share of the
    sampler's sets fall short of. With ``mean=True`` it is the mean smallest distance
    instead (``percentile`` unused): a radius that centres the generated sets' minimum
    distance on the sampler's, for models whose sets have too many close pairs for a low
    percentile to lift (gbn_blob's card at n = 256 and 1024). ``toroidal``: distances on
    the unit torus (for sets a toroidal model keeps spaced across the square's edges).
    """
    pts = np.asarray(points, dtype=np.float64)
    if not 0 <= percentile <= 100:
        raise ValueError(f"percentile must be in [0, 100], got {percentile}")
    smallest = min_distance(pts, toroidal)
    value = smallest.mean() if mean else np.percentile(smallest, percentile)
    return float(value * np.sqrt(pts.shape[-2]))


def nearest_neighbour_distances(points: np.ndarray) -> np.ndarray:
    """Every point's nearest-neighbour distance (Euclidean) times sqrt(n): (..., n)."""
    pts = np.asarray(points, dtype=np.float64)
    flat = pts.reshape((-1,) + pts.shape[-2:])
    d = np.stack([cKDTree(p).query(p, k=2)[0][:, 1] for p in flat])
    return d.reshape(pts.shape[:-1]) * np.sqrt(pts.shape[-2])


def nearest_neighbour_percentile(points: np.ndarray, percentile: float = 1.0) -> float:
    """The ``percentile`` of every point's nearest-neighbour distance (pooled over the sets
    (..., n, 2), Euclidean), times sqrt(n): how close the closest points come, in units of
    the mean spacing.

    Unlike a set's smallest distance, which sinks with n for any process without a hard
    core, this is a property of the process: about 0.057 at the 1st percentile for uniform
    random points at every n, 0.16 for jittered grids, 0.45-0.75 for dart throwing,
    relaxed sets and perturbed lattices.
    """
    if not 0 <= percentile <= 100:
        raise ValueError(f"percentile must be in [0, 100], got {percentile}")
    return float(np.percentile(nearest_neighbour_distances(points), percentile))


def pair_correlation(points: np.ndarray, radii: np.ndarray | None = None,
                     bandwidth: float = 0.05) -> tuple[np.ndarray, np.ndarray]:
    """Pair correlation function on the unit torus, averaged over sets.

    Radii are in units of r_max = sqrt(2 / (sqrt(3) n)) (default 0.05..2.5). Gaussian kernel
    estimator with toroidal distances, so no edge correction is needed:
    g(r) = sum_{i != j} k_h(r - d_ij) / (2 pi r n (n - 1)), with h = bandwidth * r_max.
    Poisson (white) noise gives g = 1.
    """
    pts = np.asarray(points, dtype=np.float64)
    flat = pts.reshape((-1,) + pts.shape[-2:])
    n = flat.shape[1]
    rmax = np.sqrt(2.0 / (np.sqrt(3.0) * n))
    radii = np.linspace(0.05, 2.5, 50) if radii is None else np.asarray(radii, dtype=np.float64)
    r = radii * rmax
    h = bandwidth * rmax
    g = np.zeros_like(r)
    for p in flat:
        tree = cKDTree(p % 1.0, boxsize=1.0)
        d = tree.sparse_distance_matrix(tree, r.max() + 4 * h, output_type="ndarray")["v"]
        d = d[d > 0]
        k = np.exp(-0.5 * ((r[:, None] - d[None, :]) / h) ** 2) / (np.sqrt(2 * np.pi) * h)
        g += k.sum(axis=1) / (2 * np.pi * r * n * (n - 1))
    return radii, g / len(flat)
