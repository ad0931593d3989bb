"""Minimum spacing a sampler keeps by construction, restored on decoded point sets.

Blue-noise samplers keep points apart: a Poisson disk sampler by definition (no two points of
an n-point set closer than r = c / sqrt(n)), GBN and SOT sets in practice (their smallest
distance varies little from set to set). A small net learns the spectrum of such sets but
lets a few pairs come too close, and the smallest distance of a set is set by its single
closest pair. This module pushes apart, symmetrically along the line joining them, only the
pairs closer than r (and the neighbours a push brings too close); every other point keeps its
coordinates bit for bit.

A model card's pipeline asks for it with the step ``{"step": "min_spacing", "c": c}``
(:mod:`diffsampler_rt.finish.min_spacing`; c the coefficient of 1 / sqrt(n)): the Poisson
disk sampler's own radius, or a low percentile of the smallest distance of the sampler's
sets (``python -m trainer spacing CONFIG`` or ``python -m trainer calibrate`` measures it).
Where that coefficient drifts with n (SOT's smallest distance shrinks from ~0.71 / sqrt(n)
at n = 64 to ~0.57 / sqrt(n) at 4096), c may be given per size, ``{"n": [64, 256, 1024],
"values": [...]}``: linear in log n between them, the end values beyond. (:func:`coefficient`,
:func:`describe` and :func:`radius` read the format-1 card field, ``"min_spacing": c`` or
``{"n": [...], "c": [...]}``.) Distances are Euclidean in the unit
square, as in the fidelity statistics; for a toroidal model (circular padding, sets on the
torus) they are measured on the torus (``torus=True``), so pairs across the seam are kept
apart too and a shifted or tiled set keeps its spacing.
"""
from __future__ import annotations

import numpy as np

from . import per_size
from ._validate import unit_points
from .grid import reflect, wrap

_BELOW_ONE = np.nextafter(1.0, 0.0)
#: the densest packing (hexagonal) keeps n points at most about sqrt(2 / sqrt(3) / n)
#: = 1.0746 / sqrt(n) apart for large n; a card asking for more could not be met there
MAX_SPACING = 1.07
#: pushes aim this much past r: pushing to exactly r converges slowly in dense sets (a push
#: starts new close pairs with the neighbours, shortfalls shrink by ~2x a round), 1 % past r
#: resolves Poisson disk sets in <= 10 rounds and raises their smallest distance by < 0.5 %
_OVERSHOOT = 0.01


def coefficient(spec: float | dict, n: int) -> float:
    """c at n points for a card's ``min_spacing``: a number, or a per-size table."""
    return per_size.value_at(spec, "c", n)


def describe(spec: float | dict | None) -> str:
    """The card value in words: "none", "0.6432 / sqrt(n)", or "c / sqrt(n), c = 0.66 at
    n = 64, 0.58 at n = 1024 (log-linear)"."""
    if spec is None:
        return "none"
    if isinstance(spec, dict):
        return ("c / sqrt(n), c = " + ", ".join(f"{c:g} at n = {n}" for n, c in
                                                zip(spec["n"], spec["c"])) + " (log-linear)")
    return f"{spec:g} / sqrt(n)"


def radius(card: dict, n: int) -> float | None:
    """The spacing radius the card asks for at n points (None: the card asks for none)."""
    spec = card.get("min_spacing")
    return None if spec is None else coefficient(spec, n) / np.sqrt(n)


def close_pairs(points: np.ndarray, r: float, *,
                torus: bool = False) -> tuple[np.ndarray, np.ndarray]:
    """Index pairs (i, j), i < j, of the points of one set (m, 2) closer than r (on the
    unit torus with ``torus=True``).

    Points are binned into square buckets of side >= r, so each point is compared with the
    points of its own and the 8 neighbouring buckets only (O(m) for spread-out sets).
    """
    p = unit_points(points, form="(m, 2)")
    return _close_pairs(p, np.zeros(len(p), dtype=np.int64), r, np.arange(len(p)), torus)


def _offsets(d: np.ndarray, torus: bool) -> np.ndarray:
    """Differences of points, the shortest way round the torus where ``torus``."""
    return d - np.round(d) if torus else d


def _close_pairs(p: np.ndarray, set_id: np.ndarray, r: float, query: np.ndarray,
                 torus: bool = False) -> tuple[np.ndarray, np.ndarray]:
    """Close pairs with at least one point among the rows ``query``; ``set_id`` keeps the
    rows of different sets apart (each set gets its own buckets)."""
    g = max(1, int(np.floor(1.0 / r)))  # buckets per side, each at least r wide
    cx = np.clip((p[:, 0] * g).astype(np.int64), 0, g - 1)
    cy = np.clip((p[:, 1] * g).astype(np.int64), 0, g - 1)
    if torus:  # neighbours wrap round within the set's own g x g buckets
        key = (set_id * g + cy) * g + cx
        qx, qy, qs = cx[query], cy[query], set_id[query]
        # with fewer than 3 buckets a side, two of the 3 x 3 neighbours are one bucket: once each
        shifts = sorted({(dy % g, dx % g) for dy in (-1, 0, 1) for dx in (-1, 0, 1)})

        def neighbour(dy: int, dx: int) -> np.ndarray:
            return (qs * g + (qy + dy) % g) * g + (qx + dx) % g
    else:  # bucket key with a one-bucket empty border: neighbours never wrap across rows/sets
        side = g + 2
        key = (set_id * side + cy + 1) * side + cx + 1
        shifts = [(dy, dx) for dy in (-1, 0, 1) for dx in (-1, 0, 1)]

        def neighbour(dy: int, dx: int) -> np.ndarray:
            return key[query] + dy * side + dx
    order = np.argsort(key, kind="stable")
    skey = key[order]
    is_query = np.zeros(len(p), dtype=bool)
    is_query[query] = True
    pairs_i, pairs_j = [], []
    for dy, dx in shifts:
        target = neighbour(dy, dx)
        lo = np.searchsorted(skey, target, side="left")
        count = np.searchsorted(skey, target, side="right") - lo
        if not count.any():
            continue
        # every (query point, bucket member) pair, without a Python loop over points
        i = np.repeat(query, count)
        j = order[np.repeat(lo - np.cumsum(count) + count, count) + np.arange(count.sum())]
        # each pair once: a pair of two query points is kept from its smaller index
        keep = (j > i) | ~is_query[j]
        i, j = i[keep], j[keep]
        close = np.sum(_offsets(p[j] - p[i], torus) ** 2, axis=1) < r * r
        pairs_i.append(np.minimum(i[close], j[close]))
        pairs_j.append(np.maximum(i[close], j[close]))
    if not pairs_i:
        return np.empty(0, dtype=np.int64), np.empty(0, dtype=np.int64)
    return np.concatenate(pairs_i), np.concatenate(pairs_j)


def enforce_min_spacing(points: np.ndarray, r: float, *, rounds: int = 32,
                        torus: bool = False) -> np.ndarray:
    """Push apart the pairs of each set (..., n, 2) closer than r.

    Each close pair moves apart along the line joining its points, both points by half of
    what it takes to bring the pair 1 % past r (a point in several close pairs takes the sum
    of its pushes); points stay in [0, 1). Repeated, since a push can make new close pairs,
    until no pair is closer than r or after ``rounds`` rounds (Poisson disk sets at their
    sampler's radius need <= 10; only sets far denser than r allows keep a close pair).
    A point is returned bit for bit unless it was in a close pair (a push can bring a
    neighbour into a new close pair; it then moves too). With ``torus=True`` distances and
    pushes go the shortest way round the unit torus and pushed points wrap modulo 1.

    Examples
    --------
    >>> import numpy as np
    >>> from diffsampler_rt.spacing import enforce_min_spacing
    >>> pts = np.array([[0.50, 0.5], [0.52, 0.5], [0.1, 0.1]])
    >>> out = enforce_min_spacing(pts, 0.1)
    >>> bool(np.linalg.norm(out[0] - out[1]) >= 0.1), out[2].tolist()
    (True, [0.1, 0.1])
    """
    if not (isinstance(r, (int, float, np.floating)) and np.isfinite(r) and r > 0):
        raise ValueError(f"spacing radius must be a positive number, got {r!r}")
    pts = np.array(unit_points(points, form="(..., n, 2)"))  # a copy: moved in place
    flat = pts.reshape(-1, 2)
    set_id = np.arange(len(flat)) // max(pts.shape[-2], 1)
    query = np.arange(len(flat))  # then only the points the last round moved
    for _ in range(rounds):
        i, j = _close_pairs(flat, set_id, r, query, torus)
        if len(i) == 0:
            break
        d = _offsets(flat[j] - flat[i], torus)
        dist = np.linalg.norm(d, axis=1)
        # coincident points: a fixed direction keeps the result deterministic
        unit = np.where(dist[:, None] > 0, d / np.where(dist > 0, dist, 1.0)[:, None],
                        np.array([1.0, 0.0]))
        push = 0.5 * (r * (1 + _OVERSHOOT) - dist)[:, None] * unit
        move = np.zeros_like(flat)
        np.add.at(move, i, -push)
        np.add.at(move, j, push)
        new = wrap(flat + move) if torus else reflect(flat + move)
        query = np.flatnonzero(np.any(new != flat, axis=1))
        flat = new
        if len(query) == 0:
            break
    return flat.reshape(pts.shape)
