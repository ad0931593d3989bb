"""Net structure a sampler has by construction, imposed on decoded point sets.

A small net learns the look of Sobol'+Owen sets but not their combinatorics: in a (0, m, 2)-net
of n = 2^m points every elementary interval (a dyadic box of area 1/n) holds exactly one point,
while the learned sets leave ~20 % of them empty. When n = k*k with k a power of two and one
point per grid cell, the condition is about which sub-strip of its own cell each point falls in:
inside each column of cells, every aligned block of 2^j rows must put its points into 2^j
distinct x sub-columns of width 1/(k 2^j), for j = 1 .. log2 k (rows likewise for y). So it can
be restored without moving any point out of its cell; a set that already is a net is returned
unchanged.

Only for stratified embeddings. The model card asks for it with ``"structure": "dyadic_net"``;
it is imposed at power-of-two grid sides only (other n are not nets in the reference either).
"""
from __future__ import annotations

import numpy as np

from .grid import strip_bounds

#: card values of ``"structure"`` the runtime knows
STRUCTURES = ("dyadic_net",)


def applies(card: dict, k: int) -> bool:
    """Whether the card asks for a structure that exists at grid side k."""
    return card.get("structure") == "dyadic_net" and k & (k - 1) == 0


def _dyadic_slots(frac: np.ndarray) -> np.ndarray:
    """Sub-strip index (0 .. k-1) per point, from its offset ``frac`` in [0, 1) inside its
    cell, along the last axis (the k cells of one column), such that every aligned block of
    2^j cells holds 2^j distinct j-bit prefixes.

    Built one bit at a time from the smallest blocks up: the two points of a block that
    share a prefix so far (one from each half) are told apart by their offsets, the smaller
    getting bit 0. A column that already satisfies the condition keeps its sub-strips.
    """
    k = frac.shape[-1]
    prefix = np.zeros(frac.shape, dtype=np.int64)
    size = 2
    while size <= k:
        shape = frac.shape[:-1] + (k // size, 2, size // 2)
        f, p = frac.reshape(shape), prefix.reshape(shape)
        order = np.argsort(p, axis=-1, kind="stable")  # each half holds every prefix once
        fs = np.take_along_axis(f, order, axis=-1)
        # of each pair, the point in the second half takes bit 1 if its offset is larger
        upper = (fs[..., 1, :] > fs[..., 0, :]).astype(np.int64)
        bits = np.empty_like(order)
        np.put_along_axis(bits, order, np.stack([1 - upper, upper], axis=-2), axis=-1)
        prefix = (2 * p + bits).reshape(frac.shape)
        size *= 2
    return prefix


def _restratify(coord: np.ndarray, k: int) -> np.ndarray:
    """One coordinate, shape (sets, cell index along it, k cells across) -> imposed."""
    cell = np.arange(k)[None, :, None]
    frac = coord * k - cell  # offset inside the cell, [0, 1)
    strip = cell * k + _dyadic_slots(frac)
    # keep the offset inside the sub-strip (the star discrepancy then matches the
    # reference's); a point already in its sub-strip keeps its coordinate bit for bit
    fine = frac * k - np.floor(frac * k)
    lo, hi = strip_bounds(k * k)
    moved = np.clip((strip + fine) / (k * k), lo[strip], hi[strip])
    return np.where(np.floor(coord * (k * k)) == strip, coord, moved)


def impose_dyadic_net(points: np.ndarray, k: int) -> np.ndarray:
    """Make each set (..., k*k, 2) from a stratified k x k grid a (0, m, 2)-net in base 2.

    Points are in row-major cell order (point ``row * k + col`` lies in cell (row, col)), as
    :func:`diffsampler_rt.grid.decode` returns them; k must be a power of two. Each point
    stays in its cell.

    Examples
    --------
    >>> import numpy as np
    >>> from diffsampler_rt.structure import impose_dyadic_net
    >>> k = 4
    >>> cells = np.stack(np.meshgrid(np.arange(k), np.arange(k)), -1).reshape(-1, 2)
    >>> jittered = (cells + np.random.default_rng(0).random((k * k, 2))) / k
    >>> net = impose_dyadic_net(jittered, k)
    >>> [len(np.unique(np.floor(net[:, c] * k * k))) for c in (0, 1)]  # 1-d stratified
    [16, 16]
    """
    if k < 1 or k & (k - 1):
        raise ValueError(f"a dyadic net needs a power-of-two grid side, got k={k}")
    pts = np.asarray(points, dtype=np.float64)
    if pts.shape[-2:] != (k * k, 2):
        raise ValueError(f"points must have shape (..., {k * k}, 2), got {pts.shape}")
    grid = pts.reshape((-1, k, k, 2))  # (set, row, col, xy)
    cells = np.floor(grid * k)
    if not (np.array_equal(cells[..., 0], np.broadcast_to(np.arange(k), cells.shape[:-1]))
            and np.array_equal(cells[..., 1], np.broadcast_to(np.arange(k)[:, None],
                                                              cells.shape[:-1]))):
        raise ValueError("points must lie one per grid cell in row-major cell order, as "
                         "a stratified decode gives them")
    return _impose(pts, k)


def _impose(pts: np.ndarray, k: int) -> np.ndarray:
    """:func:`impose_dyadic_net` without its checks, for the runtime's generation loop
    (a stratified decode already puts one point per cell in row-major order)."""
    grid = pts.reshape((-1, k, k, 2))  # (set, row, col, xy)
    out = np.empty_like(grid)
    # x: within each column of cells, across its k rows; y: within each row, across columns
    out[..., 0] = _restratify(grid[..., 0].swapaxes(1, 2), k).swapaxes(1, 2)
    out[..., 1] = _restratify(grid[..., 1], k)
    return out.reshape(pts.shape)
