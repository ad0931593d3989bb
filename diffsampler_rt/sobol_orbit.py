"""Owen-scrambled Sobol' nets: a k x k set imposed onto them, and their sequence order.

The first n points of an Owen-scrambled Sobol' sequence are a (0, m, 2)-net only at n = 2^m;
at other n they are nets of 2^j points stacked in the sequence's order (576 = a net of 512
and one of 64 from the next 512). A net made at k x k = 4^h points (the network's grid, then
:mod:`diffsampler_rt.structure`) has no such order: two points sharing an elementary
interval of area 2 / k^2 must fall into different halves of the sequence, and the sets the
runtime's ``dyadic_net`` imposition makes contradict that (odd cycles of such pairs in 128 of
128 sets measured), so no prefix of them is a net.

Here a stratified k x k set (k = 2^h, points in row-major cell order, one per cell) is
imposed onto the Owen-scrambled Sobol' sets, which carry the order. In the unscrambled net
the point of index i has x digits = the bits of i (lowest first: van der Corput) and y digits
= P i (P the Pascal matrix mod 2, Sobol's second dimension). With x = (column c, sub-strip
u) and y = (row r, sub-strip v) as h-digit strings, P's triangular form gives
``u = A (r + B c)`` and ``v = D u`` for fixed matrices over GF(2). An Owen scramble permutes
the columns and rows by nested permutations (drawn at random here, as Owen draws them) and
each column's x sub-strips and each row's y sub-strips by nested permutations of their own;
those are fitted to the network's offsets, top digit first (of the two halves of a group,
the one whose points sit lower in their cells takes the lower half). Each point keeps its
cell and its position inside its new sub-strip; its sequence index comes with it.

Measured (benchmarks/results/fidelity.md, any_n.md): the first 576 points of such
1024-point sets are within 1 % of the Sobol' prefixes' Gaussian and Heaviside integration
errors and star discrepancy (the 24 x 24 sets the network makes directly: -58 %, -18 %,
+30 %); at n = 1000 their spectrum is further from the sampler's than thinned network sets
were (MAE 0.010 against 0.006, floor 0.005): the points move ~5x further than the
``dyadic_net`` imposition moves them, so at n = 4^h the runtime keeps that imposition and
uses this one for the other sizes (card ``"structure_prefix"``).
"""
from __future__ import annotations

from functools import lru_cache

import numpy as np

from .structure import _checked, _into_strips

__all__ = ["impose_sobol_orbit", "first_points"]


def _digits(v: np.ndarray, h: int) -> np.ndarray:
    """Integers -> (..., h) binary digits, most significant first."""
    return (v[..., None] >> np.arange(h - 1, -1, -1)) & 1


def _value(d: np.ndarray) -> np.ndarray:
    h = d.shape[-1]
    return (d << np.arange(h - 1, -1, -1)).sum(-1)


def _gf2_inverse(a: np.ndarray) -> np.ndarray:
    n = len(a)
    m = np.concatenate([a % 2, np.eye(n, dtype=np.int64)], axis=1)
    for c in range(n):
        p = c + int(np.argmax(m[c:, c]))  # P's blocks used here are invertible
        m[[c, p]] = m[[p, c]]
        rows = (m[:, c] == 1) & (np.arange(n) != c)
        m[rows] ^= m[c]
    return m[:, n:]


@lru_cache(maxsize=None)
def _canonical(h: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Sub-strip digits (as integers) u[c, r], v[c, r] of the unscrambled 4^h-point Sobol'
    net's point in column c, row r, and the h-bit reversal of 0 .. 2^h - 1."""
    m = 2 * h
    j, r = np.meshgrid(np.arange(m), np.arange(m))
    pascal = ((j & r) == r).astype(np.int64)  # P[r, j] = C(j, r) mod 2 (Lucas' theorem)
    b, a, d = pascal[:h, :h], _gf2_inverse(pascal[:h, h:]), pascal[h:, h:]
    cols = _digits(np.arange(2 ** h), h)
    rhs = (cols[None, :, :] + (cols @ b.T)[:, None, :]) % 2  # [c, r]: row digits + B c
    u = (rhs @ a.T) % 2
    return _value(u), _value((u @ d.T) % 2), _value(cols[:, ::-1])


def _nested_permutation(h: int, rng: np.random.Generator) -> np.ndarray:
    """A random nested (Owen) permutation of 0 .. 2^h - 1, as a table."""
    v = np.arange(2 ** h)
    d = _digits(v, h)
    for level in range(h):  # digit `level` flipped by a bit of its prefix's node
        d[:, level] ^= rng.integers(0, 2, 2 ** level)[v >> (h - level)]
    return _value(d)


def _fit_nested(labels: np.ndarray, offsets: np.ndarray, h: int) -> np.ndarray:
    """tau(labels) for the nested permutation tau fitted top-down to ``offsets``: labels
    (..., 2^h) a permutation of 0 .. 2^h - 1 along the last axis; of the two halves of each
    group of labels sharing a prefix, the one with the smaller mean offset takes the lower
    half of the group's values."""
    k = 2 ** h
    order = np.argsort(labels, axis=-1)  # sorted, the labels are 0 .. k-1 in place
    sorted_offsets = np.take_along_axis(offsets, order, axis=-1)
    place = np.arange(k)
    value = np.zeros(labels.shape, dtype=np.int64)
    for level in range(h):
        groups = sorted_offsets.reshape(labels.shape[:-1] + (2 ** level, 2, k >> (level + 1)))
        mean = groups.mean(axis=-1)
        flip = (mean[..., 0] > mean[..., 1]).astype(np.int64)  # (..., 2^level)
        bit = ((place >> (h - 1 - level)) & 1) ^ flip[..., place >> (h - level)]
        value |= bit << (h - 1 - level)
    out = np.empty_like(value)
    np.put_along_axis(out, order, value, axis=-1)
    return out


def orbit(pts: np.ndarray, k: int, rngs: list[np.random.Generator]
           ) -> tuple[np.ndarray, np.ndarray]:
    """:func:`impose_sobol_orbit` on points it trusts to lie one per cell in row-major
    order (the finishing step's input), one generator per set."""
    h = k.bit_length() - 1
    u_of, v_of, reverse = _canonical(h)
    grid = pts.reshape((-1, k, k, 2))  # (set, row, col, xy)
    # canonical column of each column, row of each row: inverse nested permutations
    cols = np.stack([np.argsort(_nested_permutation(h, g)) for g in rngs])
    rows = np.stack([np.argsort(_nested_permutation(h, g)) for g in rngs])
    c = np.broadcast_to(cols[:, None, :], grid.shape[:-1])
    r = np.broadcast_to(rows[:, :, None], grid.shape[:-1])
    u, v = u_of[c, r], v_of[c, r]
    cell = np.arange(k)
    frac_x = grid[..., 0] * k - cell[None, None, :]
    frac_y = grid[..., 1] * k - cell[None, :, None]
    # x: each column's sub-strips, fitted across its rows; y: each row's, across its columns
    sub_x = _fit_nested(u.swapaxes(1, 2), frac_x.swapaxes(1, 2), h).swapaxes(1, 2)
    sub_y = _fit_nested(v, frac_y, h)
    out = np.empty_like(grid)
    out[..., 0] = _into_strips(grid[..., 0], frac_x, cell[None, None, :] * k + sub_x, k)
    out[..., 1] = _into_strips(grid[..., 1], frac_y, cell[None, :, None] * k + sub_y, k)
    # the index's bits are the unscrambled x digits, lowest first: column, then sub-strip
    index = reverse[c] + reverse[u] * k
    return out.reshape(pts.shape), index.reshape(pts.shape[:-1])


def impose_sobol_orbit(points: np.ndarray, k: int, *,
                       rng: int | np.random.Generator | None = None
                       ) -> tuple[np.ndarray, np.ndarray]:
    """Make each set (..., k*k, 2) from a stratified k x k grid an Owen-scrambled Sobol'
    net, with the sequence index of every point.

    Points are in row-major cell order (point ``row * k + col`` lies in cell (row, col)), as
    :func:`diffsampler_rt.grid.decode` returns them; k must be a power of two. Each point
    stays in its cell. The points of index < 2^j form a (0, j, 2)-net for every j, so
    :func:`first_points` gives a set of any size as the sequence has it.

    Parameters
    ----------
    points : array_like, shape (..., k*k, 2)
    k : int
        The grid side, a power of two.
    rng : int or numpy.random.Generator, optional
        Draws the column and row scrambles (one child stream per set).

    Returns
    -------
    points : ndarray, shape (..., k*k, 2)
    index : ndarray of int, shape (..., k*k)
        Each point's place in the sequence (a permutation of 0 .. k*k - 1 per set).

    Examples
    --------
    >>> import numpy as np
    >>> from diffsampler_rt.sobol_orbit import impose_sobol_orbit, first_points
    >>> k = 8
    >>> cells = np.stack(np.meshgrid(np.arange(k), np.arange(k)), -1).reshape(-1, 2)
    >>> jittered = (cells + np.random.default_rng(0).random((k * k, 2))) / k
    >>> net, index = impose_sobol_orbit(jittered, k, rng=1)
    >>> first = first_points(net, index, 32)  # a (0, 5, 2)-net: 1-d stratified at 1/32
    >>> [len(np.unique(np.floor(first[:, c] * 32))) for c in (0, 1)]
    [32, 32]
    """
    if not isinstance(k, (int, np.integer)) or k < 1 or k & (k - 1):
        raise ValueError(f"a Sobol' net needs a power-of-two grid side, got k={k!r}")
    pts = _checked(points, int(k))
    gen = rng if isinstance(rng, np.random.Generator) else np.random.default_rng(rng)
    flat = pts.reshape((-1, k * k, 2))
    out, index = orbit(flat, int(k), gen.spawn(len(flat)))
    return out.reshape(pts.shape), index.reshape(pts.shape[:-1])


def first_points(points: np.ndarray, index: np.ndarray, n: int) -> np.ndarray:
    """The n points of each set (..., N, 2) with the smallest sequence ``index`` (the
    sequence's first n), in sequence order.

    Examples
    --------
    >>> import numpy as np
    >>> from diffsampler_rt.sobol_orbit import first_points
    >>> pts = np.array([[[0.1, 0.1], [0.6, 0.6], [0.3, 0.8], [0.8, 0.3]]])
    >>> first_points(pts, np.array([[0, 1, 3, 2]]), 3)
    array([[[0.1, 0.1],
            [0.6, 0.6],
            [0.8, 0.3]]])
    """
    index = np.asarray(index)
    if index.shape != points.shape[:-1]:
        raise ValueError(f"index must have shape {points.shape[:-1]}, got {index.shape}")
    if not 1 <= n <= points.shape[-2]:
        raise ValueError(f"n must be in [1, {points.shape[-2]}], got {n}")
    order = np.argsort(index, axis=-1, kind="stable")[..., :n]
    return np.take_along_axis(points, order[..., None], axis=-2)
