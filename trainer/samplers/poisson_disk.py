"""Toroidal Poisson disk sampling by dart throwing, exactly n points."""
from __future__ import annotations

import math

import numpy as np


def hex_spacing(n: int) -> float:
    """r_max = sqrt(2 / (sqrt(3) n)): the spacing of a hexagonal packing of n points."""
    return math.sqrt(2.0 / (math.sqrt(3.0) * n))


#: free candidates compared at a time when a batch's candidates are checked against each
#: other (all pairs at once took 37 GiB for the 50 000 candidates of an n = 16384 batch)
PAIR_BLOCK = 1024


def _close(a: np.ndarray, b: np.ndarray, r2: float) -> np.ndarray:
    """(len(a), len(b)) booleans: toroidal squared distance < r2."""
    d = a[:, None, :] - b[None, :, :]
    d -= np.round(d)
    return (d ** 2).sum(-1) < r2


def _kept_in_order(fc: np.ndarray, r2: float) -> np.ndarray:
    """Indices of the candidates ``fc`` kept when taken in order, each unless closer than r
    (torus) to one kept before it; compared block by block (:data:`PAIR_BLOCK`), so the
    memory stays bounded and the outcome is that of all pairs at once."""
    kept: list[int] = []
    kept_pts = fc[:0]
    for a in range(0, len(fc), PAIR_BLOCK):
        part = fc[a:a + PAIR_BLOCK]
        blocked = np.zeros(len(part), dtype=bool)
        for b in range(0, len(kept_pts), PAIR_BLOCK):
            blocked |= _close(part, kept_pts[b:b + PAIR_BLOCK], r2).any(axis=1)
        conflict = _close(part, part, r2)
        local: list[int] = []
        for j in np.flatnonzero(~blocked):
            if not local or not conflict[j, local].any():
                local.append(j)
        kept.extend(a + j for j in local)
        kept_pts = np.concatenate([kept_pts, part[local]])
    return np.asarray(kept, dtype=np.int64)


def dart_throwing(n: int, rng: np.random.Generator, *, start: float = 0.75,
                  patience: int = 1000, shrink: float = 0.9) -> np.ndarray:
    """One set of n points, pairwise toroidal distance >= r (r shrinks when stuck).

    Classic dart throwing: a uniform candidate is kept when no kept point lies within r.
    Starting at r = ``start`` * r_max, after ``patience`` consecutive rejections r is
    multiplied by ``shrink``. Candidates are tested in vectorised batches against a
    background grid; the outcome is the same as testing them one by one in order.
    """
    r = start * hex_spacing(n)
    pts = np.empty((n, 2))
    m = 0
    misses = 0
    while m < n:
        G = int(math.ceil(math.sqrt(2.0) / r))  # cell side <= r / sqrt(2): one point a cell
        grid = np.full((G, G), -1, dtype=np.int64)
        cells = np.floor(pts[:m] * G).astype(np.int64) % G
        grid[cells[:, 1], cells[:, 0]] = np.arange(m)
        reach = int(math.ceil(r * G))
        offs = np.arange(-reach, reach + 1)
        oy, ox = np.meshgrid(offs, offs, indexing="ij")
        r2 = r * r
        relax = False
        while m < n and not relax:
            batch = int(min(50_000, max(64, 4 * (n - m) * (1 + misses / 50))))
            cand = rng.random((batch, 2))
            cc = np.floor(cand * G).astype(np.int64) % G
            nb = grid[(cc[:, 1, None, None] + oy) % G, (cc[:, 0, None, None] + ox) % G]
            nb = nb.reshape(batch, -1)
            d = cand[:, None, :] - pts[np.maximum(nb, 0)]
            d -= np.round(d)
            close = ((d ** 2).sum(-1) < r2) & (nb >= 0)
            free = np.flatnonzero(~close.any(axis=1))
            # among the free candidates, keep them in order unless an earlier kept one is close
            accepted = np.zeros(batch, dtype=bool)
            if free.size:
                accepted[free[_kept_in_order(cand[free], r2)]] = True
            # walk the batch in order: stop at n points or at `patience` misses in a row
            idx = np.flatnonzero(accepted)
            gaps = np.diff(np.concatenate([[-1], idx])) - 1  # misses before each acceptance
            if gaps.size:
                gaps[0] += misses
            stuck = np.flatnonzero(gaps >= patience)
            take = idx[:stuck[0]] if stuck.size else idx
            take = take[:n - m]
            if take.size:
                pts[m:m + take.size] = cand[take]
                tc = cc[take]
                grid[tc[:, 1], tc[:, 0]] = np.arange(m, m + take.size)
                m += take.size
            if m >= n:
                break
            trailing = batch - 1 - idx[-1] if idx.size else batch + misses
            if stuck.size or trailing >= patience:
                relax = True  # rebuild the grid for the smaller radius
                misses = 0
                r *= shrink
            else:
                misses = int(trailing)
    return pts


def poisson_disk(n: int, count: int, rng: np.random.Generator) -> np.ndarray:
    """``count`` toroidal dart-throwing sets of exactly n points (see :func:`dart_throwing`)."""
    return np.stack([dart_throwing(n, rng) for _ in range(count)])
