"""Sliced optimal transport on the unit disk: the concentric maps between the square and
the disk, the disk projections' quantiles, and one sliced-OT update. Shared by the SOT
reference sampler (``trainer.samplers.sot``) and the runtime's sliced-OT polish
(:mod:`diffsampler_rt.sliced_ot`), so that both run the same update, bit for bit.

Each update works in the unit disk, whose projection on every direction has the same
density (2/pi) sqrt(1 - t^2): the points are projected on evenly spread directions, each
projection's sorted values matched to that density's quantiles, and every point moved by
the mean of its 1-d displacements (Paulin et al. 2020). Shirley and Chiu's concentric map
preserves area, so uniform stays uniform.
"""
from __future__ import annotations

import threading
from concurrent.futures import ThreadPoolExecutor
from functools import lru_cache

import numpy as np

from .grid import reflect

@lru_cache(maxsize=32)
def disk_quantiles(n: int) -> np.ndarray:
    """t_i = F^-1((2i + 1) / (2n)) for the disk's projected CDF F (exact to ~1e-12)."""
    u = (2 * np.arange(n) + 1) / (2 * n)
    t = np.zeros(n)
    for _ in range(60):  # Newton on F(t) = 1/2 + (t sqrt(1 - t^2) + arcsin t) / pi
        s = np.sqrt(np.clip(1 - t * t, 1e-300, None))
        t = np.clip(t - (0.5 + (t * s + np.arcsin(t)) / np.pi - u) / (2 / np.pi * s),
                    -1 + 1e-15, 1 - 1e-15)
    t.flags.writeable = False  # shared by every caller through the cache
    return t


def disk_to_square(p: np.ndarray) -> np.ndarray:
    """Inverse concentric map (Shirley & Chiu 1997): unit disk -> [0, 1)^2."""
    x, y = p[..., 0], p[..., 1]
    r = np.hypot(x, y)
    with np.errstate(divide="ignore", invalid="ignore"):
        wide = np.abs(x) >= np.abs(y)
        a = np.where(wide, np.sign(x) * r, np.sign(y) * r * 4 / np.pi * np.arctan(x / y))
        b = np.where(wide, np.sign(x) * r * 4 / np.pi * np.arctan(y / x), np.sign(y) * r)
    sq = np.stack([np.nan_to_num(a), np.nan_to_num(b)], axis=-1)
    # an update may leave a point just outside the disk: folded back, not onto the border
    return reflect((sq + 1) / 2)


def square_to_disk(p: np.ndarray) -> np.ndarray:
    """Concentric map (Shirley & Chiu 1997): [0, 1]^2 -> unit disk, area-preserving."""
    a, b = 2 * p[..., 0] - 1, 2 * p[..., 1] - 1
    wide = np.abs(a) > np.abs(b)
    with np.errstate(divide="ignore", invalid="ignore"):
        r = np.where(wide, a, b)
        phi = np.where(wide, np.pi / 4 * (b / a), np.pi / 2 - np.pi / 4 * (a / b))
    phi = np.nan_to_num(phi)  # the centre, a = b = 0
    return np.stack([r * np.cos(phi), r * np.sin(phi)], axis=-1)


#: directions per block of an iteration: the displacement is summed block by block in a
#: fixed order, so the blocks can go to threads without changing a bit of the result
BLOCK = 32


#: the 16-bit sort packs each key with its point's index in one 32-bit word, so it needs
#: n <= 2^16; beyond, it sorts the keys indirectly
PACKED_MAX_N = 1 << 16
#: the packed sort goes through the sets in chunks of about this many projections (c * m *
#: n), in buffers each thread keeps for the length of one polish (see :class:`_Buffers`)
CHUNK = 1 << 18
_LOW16 = np.uint32(0xFFFF)


class _Buffers:
    """Each thread's work arrays for the packed step, kept from step to step for as long as
    this object lives (a polish; one call of :func:`sliced_step`) and freed with it: made
    afresh, arrays of a few MiB cost a page fault every 4 KiB, half the polish's time."""

    def __init__(self) -> None:
        self._by_thread: dict[int, dict[str, np.ndarray]] = {}  # one key per live thread

    def get(self, rows: int, n: int) -> dict[str, np.ndarray]:
        """The calling thread's buffers for ``rows`` projections of n points (made, or
        remade larger or for another n, on demand)."""
        key = threading.get_ident()
        work = self._by_thread.get(key)
        if work is None or work["rows"].size < rows or work["index"].size != n:
            size = rows * n
            work = {"proj": np.empty(size, np.float32), "shift": np.empty(size, np.float32),
                    "packed": np.empty(size, np.uint32), "order": np.empty(size, np.intp),
                    "index": np.arange(n, dtype=np.uint32), "rows": np.arange(rows) * n,
                    "target": np.tile(disk_quantiles(n).astype(np.float32), rows)}
            self._by_thread[key] = work
        return work


def _displacement(x: np.ndarray, theta: np.ndarray, exact: bool = True,
                  buffers: _Buffers | None = None) -> np.ndarray:
    """Sum over the angles theta (c, m) of each point's 1-d optimal displacement (c, n, 2).

    ``exact=False`` is the polish's cheaper step: it sorts the projections by 16-bit keys,
    so points closer than 2^-15 along a direction may swap targets, and works in float32
    (half the memory traffic; the keys are far coarser than its rounding); its buffers
    come from ``buffers`` (default: new ones)."""
    c, n = x.shape[0], x.shape[-2]
    m = theta.shape[-1]
    if not exact and n <= PACKED_MAX_N:
        return _packed_displacement(x, theta, _Buffers() if buffers is None else buffers)
    dtype = np.float64 if exact else np.float32
    target = disk_quantiles(n).astype(dtype, copy=False)
    dirs = np.stack([np.cos(theta), np.sin(theta)], axis=-1).astype(dtype)  # (c, m, 2)
    # matmul, not einsum, and one flat scatter, not take/put_along_axis: the sort is then
    # most of the cost
    proj = dirs @ np.swapaxes(x, -1, -2).astype(dtype, copy=False)  # (c, m, n)
    if exact:
        order = np.argsort(proj, axis=-1)
    else:  # numpy's radix sort of 16-bit keys, ~5x faster than argsort on floats
        order = np.argsort(_keys(proj, np.empty_like(proj)).astype(np.uint16), axis=-1,
                           kind="stable")
    order += (np.arange(c * m) * n).reshape(c, m, 1)  # indices into the flat rows
    # each point's target, the quantile of its rank, put where the point is
    shift = np.empty(proj.shape, dtype=dtype)
    shift.reshape(-1)[order.reshape(-1)] = np.tile(target, c * m)
    shift -= proj
    return (np.swapaxes(shift, -1, -2) @ dirs).astype(np.float64, copy=False)


def _keys(proj: np.ndarray, out: np.ndarray) -> np.ndarray:
    """16-bit sort keys of projections in [-1, 1], as float32 in [0, 65535] (in ``out``,
    in place: np.clip with scalars is slow on new arrays)."""
    np.add(proj, np.float32(1), out=out)
    out *= np.float32(32767.5)
    return np.clip(out, 0, 65535, out=out)


def _packed_displacement(x: np.ndarray, theta: np.ndarray, buffers: _Buffers) -> np.ndarray:
    """``_displacement(x, theta, exact=False)`` for n <= PACKED_MAX_N, bit for bit, ~2x
    faster: each key is packed with its point's index (key << 16 | index), so numpy's SIMD
    sort of the distinct words gives the keys' stable order without argsort, and the work
    goes through the sets in chunks, in ``buffers``, which a polish reuses from step to
    step."""
    c, n = x.shape[0], x.shape[-2]
    m = theta.shape[-1]
    sets = max(1, CHUNK // (m * n))  # each set on its own: the chunks do not change a bit
    work = buffers.get(min(c, sets) * m, n)
    out = np.empty((c, n, 2))
    for i in range(0, c, sets):
        th = theta[i:i + sets]
        cc = len(th)
        size = cc * m * n
        dirs = np.stack([np.cos(th), np.sin(th)], axis=-1).astype(np.float32)
        proj = np.matmul(dirs, np.swapaxes(x[i:i + sets], -1, -2).astype(np.float32),
                         out=work["proj"][:size].reshape(cc, m, n))
        shift = work["shift"][:size].reshape(cc, m, n)  # the keys first, then the shifts
        packed = work["packed"][:size].reshape(cc, m, n)
        np.copyto(packed, _keys(proj, shift), casting="unsafe")  # exact: whole numbers
        packed <<= 16
        packed |= work["index"]
        packed.sort(axis=-1)
        packed &= _LOW16
        order = work["order"][:size].reshape(cc, m, n)
        np.copyto(order, packed)
        order += work["rows"][:cc * m].reshape(cc, m, 1)
        shift.reshape(-1)[order.reshape(-1)] = work["target"][:size]
        shift -= proj
        out[i:i + cc] = np.swapaxes(shift, -1, -2) @ dirs
    return out


def _blocks(theta: np.ndarray) -> list[np.ndarray]:
    return [theta[:, i:i + BLOCK] for i in range(0, theta.shape[-1], BLOCK)]


def sliced_step(x: np.ndarray, theta: np.ndarray, *, pool: ThreadPoolExecutor | None = None,
                exact: bool = True, _buffers: _Buffers | None = None) -> np.ndarray:
    """One SOT iteration on sets x (c, n, 2) in the unit disk along the angles theta (c, m)
    (or (m,), shared): each point moves by the mean of its m 1-d optimal displacements.

    The directions go in blocks of :data:`BLOCK`, on ``pool``'s threads if given (numpy's
    sort and matmul release the GIL); the result is the same either way. ``exact=False``
    sorts each projection by 16-bit keys (~3.5x faster than the exact step at n = 1024;
    see :func:`polish`; ``_buffers``: the polish's, kept across its steps)."""
    # the packed step's work arrays, shared by the blocks (the exact step needs none)
    buffers = _Buffers() if _buffers is None and not exact else _buffers
    theta = np.broadcast_to(theta, (x.shape[0],) + np.shape(theta)[-1:])
    blocks = _blocks(theta)

    def part(t: np.ndarray) -> np.ndarray:
        return _displacement(x, t, exact, buffers)

    parts = pool.map(part, blocks) if pool is not None and len(blocks) > 1 else map(part, blocks)
    total = None
    for piece in parts:  # in block order whatever the threads
        total = piece if total is None else total + piece
    return x + total / theta.shape[-1]


