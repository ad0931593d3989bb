"""Sets of any size n: thin a k x k set (k = ceil(sqrt n)) down to n points.

The network makes k*k points on a k x k grid. For an n that is not a perfect square the
runtime makes the next square, m = ceil(sqrt n)^2 points (at most 2 sqrt(n) more than n),
and removes m - n of them by weighted sample elimination (Yuksel 2015, "Sample Elimination
for Generating Poisson Disk Sample Sets"): every point carries the weight of its neighbours
closer than 2 r, w(d) = (1 - d / 2r)^8 with r = sqrt(1 / (2 sqrt(3) n)) (the disk radius
of a hexagonal packing of n points, half its spacing), and the point of greatest weight,
the most crowded one, goes first, its neighbours' weights lowered, until n are left. The
removed points are the closest pairs' partners, so the minimum distance does not shrink.
That suits blue noise (a card with a minimum spacing); the runtime thins the other models'
sets at random instead (:func:`thin` with ``rngs``), which keeps their close pairs, and the
lattice models' thinned sets are replaced by their nearest lattice of n points.

Each removed point leaves a hole, and the holes add power at every frequency, about
(m - n) / n of white noise's: for samplers whose sets are very even at large scales (GBN,
SOT, Sobol') that multiplies the error of integrating smooth functions (gbn at n = 1000, 24
points removed from 1024: Gaussian MSE 4.6x the sampler's; at n = 200, 25 of 225: 6.5x).
:func:`restore_low_frequencies` then moves the kept points by a smooth displacement field
so that their density below ``cut`` sqrt(n) is again that of the set they were thinned from
(one Poisson solve by FFT; on the torus for toroidal models, else mirrored, so that no
point is pushed across an edge). The set's own large-scale character stays, whichever it
was: Poisson-disk sets keep their white-noise-like low frequencies, GBN's stay near zero.
The SOT models' polish, which follows, then runs three times as long
(:func:`diffsampler_rt.sliced_ot.iterations_at`). How close all this comes to the samplers'
own sets of such sizes: benchmarks/results/any_n.md.

Pure numpy, deterministic (ties go to the lowest index), one set at a time.
"""
from __future__ import annotations

import math

import numpy as np

from ._validate import unit_points
from .low_frequencies import RESTORE_CUT, restore_low_frequencies
from .spacing import close_pairs

#: the weight's exponent (Yuksel's alpha)
ALPHA = 8.0


def hexagonal_spacing(n: int) -> float:
    """r_max = sqrt(1 / (2 sqrt(3) n)): half the nearest-neighbour distance of n points in a
    hexagonal packing of the unit square (Yuksel's r_max for area 1)."""
    return math.sqrt(1.0 / (2.0 * math.sqrt(3.0) * n))


def eliminate(points: np.ndarray, n: int, *, torus: bool = False) -> np.ndarray:
    """Remove points from each set until ``n`` are left, the most crowded first.

    Parameters
    ----------
    points : array_like, shape (m, 2) or (sets, m, 2)
        Point sets in [0, 1)^2 with m >= n points each.
    n : int
        Points to keep, 1 <= n <= m.
    torus : bool
        Measure distances on the unit torus (the shortest way round), for toroidal models.

    Returns
    -------
    numpy.ndarray
        float64, shape (n, 2) or (sets, n, 2): the kept points, in their original order.

    Examples
    --------
    >>> import numpy as np
    >>> from diffsampler_rt.elimination import eliminate
    >>> pts = np.random.default_rng(0).random((1024, 2))
    >>> kept = eliminate(pts, 1000)
    >>> kept.shape
    (1000, 2)
    >>> # the closest pairs lose a point: the smallest distance grows
    >>> d = lambda p: np.sqrt(((p[:, None] - p[None]) ** 2).sum(-1) + np.eye(len(p))).min()
    >>> bool(d(kept) > d(pts))
    True
    """
    pts = unit_points(points, form="(m, 2) or (sets, m, 2)")
    single = pts.ndim == 2
    pts = pts[None] if single else pts
    m = pts.shape[1]
    _check_n(n, m)
    out = np.stack([p[_kept(p, int(n), torus)] for p in pts]) if n < m else pts.copy()
    return out[0] if single else out


def thin(points: np.ndarray, n: int, *, torus: bool = False,
         rngs: list[np.random.Generator] | None = None,
         cut: float = RESTORE_CUT) -> np.ndarray:
    """:func:`eliminate` down to ``n`` points, or with ``rngs`` (one generator per set) drop
    points at random, then :func:`restore_low_frequencies` from each set's full one (below
    ``cut`` sqrt(n); the runtime passes a card's ``"restore_cut"``): what
    the runtime does at an n that is not a square (blue-noise models, whose card keeps a
    minimum spacing, lose their most crowded points; the others, whose samplers put points
    close together too, lose points at random, which keeps that).

    Examples
    --------
    >>> import numpy as np
    >>> from diffsampler_rt.elimination import thin
    >>> thin(np.random.default_rng(0).random((2, 1024, 2)), 1000).shape
    (2, 1000, 2)
    """
    full = unit_points(points, form="(m, 2) or (sets, m, 2)")
    if rngs is None:
        kept = eliminate(full, n, torus=torus)
    else:
        flat = full.reshape((-1,) + full.shape[-2:])
        if len(rngs) != len(flat):
            raise ValueError(f"rngs must give one generator per set ({len(flat)}), got "
                             f"{len(rngs)}")
        _check_n(n, flat.shape[1])
        keep = [np.sort(g.permutation(flat.shape[1])[:n]) for g in rngs]
        kept = np.stack([p[i] for p, i in zip(flat, keep)]).reshape(
            full.shape[:-2] + (n, 2))
    if kept.shape == full.shape:
        return kept
    if full.ndim == 2:
        return restore_low_frequencies(kept, full, torus=torus, cut=cut)
    return np.stack([restore_low_frequencies(k, f, torus=torus, cut=cut)
                     for k, f in zip(kept, full)])


def _check_n(n: object, m: int) -> None:
    if isinstance(n, bool) or not isinstance(n, (int, np.integer)) or not 1 <= n <= m:
        raise ValueError(f"n must be an integer in [1, {m}] (the points per set), got {n!r}")


def _kept(p: np.ndarray, n: int, torus: bool) -> np.ndarray:
    """Boolean mask of the n points of one set (m, 2) that elimination keeps."""
    m = len(p)
    reach = 2.0 * hexagonal_spacing(n)
    i, j = close_pairs(p, reach, torus=torus)
    d = p[j] - p[i]
    if torus:
        d -= np.round(d)
    w = (1.0 - np.sqrt(np.sum(d * d, axis=1)) / reach) ** ALPHA
    # both directions, grouped by their first point: the neighbours of a are nbr[at[a]:at[a+1]]
    src, nbr, wt = np.concatenate([i, j]), np.concatenate([j, i]), np.concatenate([w, w])
    order = np.argsort(src, kind="stable")
    nbr, wt = nbr[order], wt[order]
    at = np.concatenate([[0], np.cumsum(np.bincount(src, minlength=m))])
    weight = np.bincount(src, weights=np.concatenate([w, w]), minlength=m)
    keep = np.ones(m, dtype=bool)
    for _ in range(m - n):
        a = int(np.argmax(weight))
        keep[a] = False
        weight[a] = -np.inf
        sl = slice(at[a], at[a + 1])
        np.subtract.at(weight, nbr[sl], wt[sl])
    return keep
