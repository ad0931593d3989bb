"""Structure a sampler has by construction, imposed on decoded point sets.

A small net learns the look of Sobol'+Owen sets but not their combinatorics: in a (0, m, 2)-net
of n = 2^m points every elementary interval (a dyadic box of area 1/n) holds exactly one point,
while the learned sets leave ~20 % of them empty. When n = k*k with k a power of two and one
point per grid cell, the condition is about which sub-strip of its own cell each point falls in:
inside each column of cells, every aligned block of 2^j rows must put its points into 2^j
distinct x sub-columns of width 1/(k 2^j), for j = 1 .. log2 k (rows likewise for y). So it can
be restored without moving any point out of its cell; a set that already is a net is returned
unchanged.

A weaker structure, ``"n_rooks"``: both 1-d projections stratified (one point in every 1/n
strip) on top of the one point per grid cell, i.e. a multi-jittered set. Low-discrepancy blue
noise (LDBN) has it at power-of-two sides >= 16; a small net does not learn it (its points
fall in the wrong 1/n strips of their cells: 86-92 % of them move). Inside each column of
cells the k points take the k sub-columns of width 1/n in the order of their x (rows
likewise for y), the 1-d optimal assignment; a point already alone in its strip keeps its
coordinate. LDBN has more: every aligned block of 2^j cells of a column, 2^j >= 16, puts
its points into 2^j distinct sub-columns of width 1/(k 2^j) (its offsets are radical
inverses of 16 consecutive integers per block); ``block`` B imposes that for the blocks of
B cells and up (B = 1 chooses a dyadic net's sub-strips, B = k is plain n-rooks).

These two are for stratified embeddings only and hold at power-of-two grid sides: the model
card asks for one with ``"structure"``; it is imposed at power-of-two sides k >=
``"structure_min_side"`` (default 1): other sides are not nets, and the base-2 samplers with
n-rooks projections lack them there too.

A third, ``"rank1_lattice"``, holds at every size and for either embedding: the set is
replaced by the rank-1 lattice it is closest to (:mod:`diffsampler_rt.lattice`). Each n has
its own lattice, and where the network does not make the reference's, the nearest lattice can
integrate far worse than the network's set; ``"structure_sides": [8, 16, ...]`` limits any
structure to the grid sides listed (those where it was measured to help).
"""
from __future__ import annotations

import numpy as np

from ._validate import unit_points
from .grid import strip_bounds
from .lattice import nearest_rank1_lattice

#: card values of ``"structure"`` the runtime knows
STRUCTURES = ("dyadic_net", "n_rooks", "rank1_lattice")
#: those that hold at every grid side and need no stratified embedding
ANY_SIDE = ("rank1_lattice",)


def describe_block(block: int | dict) -> str:
    """"blocks of 32 cells and up", or per side "blocks of 32 cells and up at k = 64, 64
    cells and up at k = 128"."""
    if isinstance(block, dict):
        return "blocks of " + ", ".join(f"{b} cells and up at k = {k}"
                                        for k, b in zip(block["sides"], block["block"]))
    return f"blocks of {block} cells and up"


def _power_of_two(b) -> bool:
    """Whether ``b`` is an integer (not a bool) 1, 2, 4, ..."""
    return (not isinstance(b, bool) and isinstance(b, (int, np.integer)) and b >= 1
            and b & (b - 1) == 0)


def block_problem(block) -> str | None:
    """Why a card's ``"structure_block"`` value is invalid, or None."""
    if isinstance(block, dict):
        sides, blocks = block.get("sides"), block.get("block")
        if (set(block) == {"sides", "block"} and isinstance(sides, list)
                and isinstance(blocks, list) and len(sides) == len(blocks) > 0
                and all(_power_of_two(v) for v in sides + blocks)
                and all(a < b for a, b in zip(sides, sides[1:]))):
            return None
    elif _power_of_two(block):
        return None
    return ("'structure_block' must be a power of two >= 1, or {\"sides\": [K, ...], "
            "\"block\": [B, ...]} with increasing power-of-two sides and power-of-two blocks, "
            f"got {block!r}")


def _dyadic_slots(frac: np.ndarray, block: int = 1) -> np.ndarray:
    """Sub-strip index (0 .. k-1) per point, from its offset ``frac`` in [0, 1) inside its
    cell, along the last axis (the k cells of one column), such that every aligned block of
    2^j >= ``block`` cells holds 2^j distinct j-bit prefixes.

    The blocks of ``block`` cells take their prefixes in the order of their offsets (the
    sorted matching); then one bit at a time for the larger blocks: the two points of a
    block that share a prefix so far (one from each half) are told apart by their offsets,
    the smaller getting bit 0. A column that already satisfies the condition keeps its
    sub-strips.
    """
    k = frac.shape[-1]
    size = min(block, k)
    prefix = _rook_slots(frac.reshape(frac.shape[:-1] + (k // size, size))).reshape(frac.shape)
    size *= 2
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


def _rook_slots(frac: np.ndarray) -> np.ndarray:
    """Sub-strip index per point: its rank by offset among the k cells of its column (the
    sorted matching, which moves points least; a column with distinct sub-strips keeps them)."""
    return np.argsort(np.argsort(frac, axis=-1, kind="stable"), axis=-1)


#: per structure: whether a moved point keeps its offset inside the sub-strip
#: (Owen-scrambled nets are uniform inside their strips, so the star discrepancy then
#: matches the reference's) or goes to the nearest point of its new sub-strip (the least
#: move: for n-rooks most of the network's points change strip)
_KEEPS_OFFSET = {"dyadic_net": True, "n_rooks": False}


def _restratify(coord: np.ndarray, k: int, name: str = "dyadic_net",
                block: int | None = None) -> np.ndarray:
    """One coordinate, shape (sets, cell index along it, k cells across) -> imposed;
    ``block``: the smallest stratified block of cells (default: 1 for a net, k for
    n-rooks)."""
    keep_offset = _KEEPS_OFFSET[name]
    cell = np.arange(k)[None, :, None]
    frac = coord * k - cell  # offset inside the cell, [0, 1)
    if block is None:
        block = 1 if name == "dyadic_net" else k
    return _into_strips(coord, frac, cell * k + _dyadic_slots(frac, block), k, keep_offset)


def _into_strips(coord: np.ndarray, frac: np.ndarray, strip: np.ndarray, k: int,
                 keep_offset: bool = True) -> np.ndarray:
    """Coordinates ``coord`` (offset ``frac`` inside their cells of width 1/k) moved into the
    1/k^2 strips ``strip``: keeping their position inside the sub-strip they were in, or to
    the nearest point of the new one."""
    lo, hi = strip_bounds(k * k)
    if keep_offset:
        fine = frac * k - np.floor(frac * k)
        moved = np.clip((strip + fine) / (k * k), lo[strip], hi[strip])
    else:
        moved = np.clip(coord, lo[strip], hi[strip])
    # a point already in its sub-strip keeps its coordinate bit for bit
    return np.where(np.floor(coord * (k * k)) == strip, coord, moved)


def _distinct_slots(frac: np.ndarray, run: int) -> np.ndarray:
    """Sub-strip (0 .. run-1) per point of each group of r <= run points (last axis), from
    its offset ``frac`` in [0, 1) inside its cell: r distinct sub-strips in the order of the
    offsets, each as near the point's own as the others allow (a full group: the ranks)."""
    order = np.argsort(frac, axis=-1, kind="stable")
    r = frac.shape[-1]
    place = np.arange(r)
    own = np.minimum(np.floor(np.take_along_axis(frac, order, axis=-1) * run), run - 1)
    # the i-th lowest takes i + max_{j <= i}(own_j - j), capped so that all r fit
    slot = place + np.minimum(np.maximum.accumulate(own - place, axis=-1), run - r)
    out = np.empty_like(order)
    np.put_along_axis(out, order, slot.astype(np.int64), axis=-1)
    return out


def _stratify_runs(coord: np.ndarray, k: int, run: int) -> np.ndarray:
    """One coordinate, shape (sets, cell index along it, k cells across): the cells across
    are cut into runs of ``run`` cells aligned with the first cell or with the last (per
    set, whichever moves the points less); every run, the partial one too, gets its points
    into distinct sub-strips of width 1 / (run k), each to the nearest point of its new
    one."""
    cell = np.arange(k)[None, :, None]
    frac = coord * k - cell
    full = k // run * run
    lo, hi = strip_bounds(k * run)
    best, cost = coord, None
    for start in sorted({0, k - full}):
        slots = np.empty(coord.shape, dtype=np.int64)
        runs = frac[..., start:start + full]
        slots[..., start:start + full] = _distinct_slots(
            runs.reshape(runs.shape[:-1] + (full // run, run)), run).reshape(runs.shape)
        for part in (slice(0, start), slice(start + full, k)):  # the partial run, if any
            if part.stop > part.start:
                slots[..., part] = _distinct_slots(frac[..., part], run)
        strip = cell * run + slots
        out = np.where(np.floor(coord * (k * run)) == strip, coord,
                       np.clip(coord, lo[strip], hi[strip]))
        move = ((out - coord) ** 2).sum(axis=(1, 2))
        if cost is None:
            best, cost = out, move
        else:
            best = np.where((move < cost)[:, None, None], out, best)
    return best


def impose_runs(points: np.ndarray, k: int, run: int) -> np.ndarray:
    """Make every run of ``run`` cells of each column (row) of a stratified k x k set put
    its points into distinct sub-columns (sub-rows) of width 1 / (run k).

    LDBN's sets have this at every grid side: its offsets along each aligned run of 16
    cells are radical inverses of 16 consecutive integers (a permutation's low nibbles). At
    a side that is not a multiple of ``run`` one run per column is partial (its r points
    take r distinct sub-strips of the ``run``, in the order of their offsets, each as near
    its own as the others allow); the runs are aligned with the first cell or with the last
    (LDBN's mirror images), whichever moves the set's points less. Each point stays in its
    cell and moves to the nearest point of its new sub-strip. Points are in row-major cell order, as for :func:`impose_dyadic_net`. At a
    power-of-two k this is :func:`impose_n_rooks` with ``block=run`` (the larger aligned
    blocks, up to whole columns, stratified too, as LDBN's are there).

    Examples
    --------
    >>> import numpy as np
    >>> from diffsampler_rt.structure import impose_runs
    >>> k = 24
    >>> cells = np.stack(np.meshgrid(np.arange(k), np.arange(k)), -1).reshape(-1, 2)
    >>> jittered = (cells + np.random.default_rng(0).random((k * k, 2))) / k
    >>> out = impose_runs(jittered, k, 16)
    >>> col = out.reshape(k, k, 2)[:, 5, 0]  # x of column 5's points, rows 0 .. 23
    >>> runs = [np.floor(col[a:a + 16] * k * 16) for a in (0, 8)]
    >>> max(len(np.unique(r)) for r in runs)  # one of the two alignments is stratified
    16
    """
    if not isinstance(run, (int, np.integer)) or isinstance(run, bool) or not 2 <= run <= k:
        raise ValueError(f"run must be an integer in [2, k={k}], got {run!r}")
    return impose(_checked(points, k), k, "n_rooks", block=int(run))


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
    return impose(_checked(points, k), k)


def impose_n_rooks(points: np.ndarray, k: int, *, block: int | None = None) -> np.ndarray:
    """Make each set (..., k*k, 2) from a stratified k x k grid 1-d stratified in x and y.

    Every 1/n strip of either axis then holds exactly one point, and each point stays in its
    grid cell (a multi-jittered set). Any grid side k >= 1. Points are in row-major cell
    order, as for :func:`impose_dyadic_net`.

    ``block`` (a power of two, with k a power of two): also every aligned block of B cells
    of a column (row), for B = ``block``, 2 ``block``, ... up to k, puts its B points in B
    distinct sub-columns of width 1/(k B), as LDBN's sets do from B = 16 on. At k <=
    ``block`` this is plain n-rooks.

    Examples
    --------
    >>> import numpy as np
    >>> from diffsampler_rt.structure import impose_n_rooks
    >>> k = 3
    >>> cells = np.stack(np.meshgrid(np.arange(k), np.arange(k)), -1).reshape(-1, 2)
    >>> jittered = (cells + np.random.default_rng(0).random((k * k, 2))) / k
    >>> rooks = impose_n_rooks(jittered, k)
    >>> [len(np.unique(np.floor(rooks[:, c] * (k * k)))) for c in (0, 1)]
    [9, 9]
    """
    if k < 1:
        raise ValueError(f"the grid side must be >= 1, got k={k}")
    if block is not None:
        if not _power_of_two(block):
            raise ValueError(f"block must be a power of two >= 1, got {block!r}")
        if block < k and k & (k - 1):
            raise ValueError(f"a block of {block} cells needs a power-of-two grid side, "
                             f"got k={k}")
    return impose(_checked(points, k), k, "n_rooks", block=block)


def _checked(points: np.ndarray, k: int) -> np.ndarray:
    pts = unit_points(points, form="(..., n, 2)")
    if pts.shape[-2] != k * k:
        raise ValueError(f"points must have shape (..., {k * k}, 2), got {pts.shape}")
    grid = pts.reshape((-1, k, k, 2))  # (set, row, col, xy)
    cells = np.floor(grid * k)
    if not (np.array_equal(cells[..., 0], np.broadcast_to(np.arange(k), cells.shape[:-1]))
            and np.array_equal(cells[..., 1], np.broadcast_to(np.arange(k)[:, None],
                                                              cells.shape[:-1]))):
        raise ValueError("points must lie one per grid cell in row-major cell order, as "
                         "a stratified decode gives them")
    return pts


def impose(pts: np.ndarray, k: int, name: str = "dyadic_net",
            rngs: list[np.random.Generator] | None = None,
            block: int | None = None) -> np.ndarray:
    """The structure ``name`` imposed on points it trusts to lie one per grid cell in
    row-major order (as a stratified decode gives them; the finishing steps call it after
    the public edge has checked the input); ``rngs``, one
    per set, draw the lattices' random shifts; ``block``: n-rooks' smallest stratified block
    (the card's ``"structure_block"``)."""
    if name == "rank1_lattice":
        return nearest_rank1_lattice(pts, rngs)
    grid = pts.reshape((-1, k, k, 2))  # (set, row, col, xy)
    out = np.empty_like(grid)
    # x: within each column of cells, across its k rows; y: within each row, across columns
    if name == "n_rooks" and block and block < k and k & (k - 1):  # runs, k not 2^j
        out[..., 0] = _stratify_runs(grid[..., 0].swapaxes(1, 2), k, block).swapaxes(1, 2)
        out[..., 1] = _stratify_runs(grid[..., 1], k, block)
        return out.reshape(pts.shape)
    out[..., 0] = _restratify(grid[..., 0].swapaxes(1, 2), k, name, block).swapaxes(1, 2)
    out[..., 1] = _restratify(grid[..., 1], k, name, block)
    return out.reshape(pts.shape)
