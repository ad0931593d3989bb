"""A few iterations of sliced optimal transport (SOT) on generated sets: the SOT sampler's
own update (Paulin et al. 2020), started from the network's set instead of from white noise.

The net learns SOT's look at the scales it sees in a 32 x 32 grid, but at larger n its sets
carry too much power at low frequencies (at n = 4096 the Gaussian integration error of the
bundled ``sot`` model was 18x the sampler's): the whole-set balance that the sampler's
iterations give, a convolutional net does not. Each iteration works in the unit disk, whose
projection on every direction has the same density (2/pi) sqrt(1 - t^2): project the points
on ``directions`` evenly spread, randomly rotated directions, match each projection's sorted
values to that density's quantiles, and move every point by the mean of its 1-d
displacements. The disk and the square are related by Shirley and Chiu's concentric map,
which preserves area, so uniform stays uniform.

A model card asks for it with ``"sliced_ot": {"directions": D, "iterations": K}``, or K per
size: ``{"directions": D, "n": [256, 1024, 4096], "iterations": [0, 4, 16]}`` (linear in
log n between the sizes, the end values beyond). An optional ``"step": s`` (0 < s <= 2,
default 1: the sampler's own update) scales every move: the mean over evenly spread
directions of a displacement's 1-d projections is half of it in 2-d, and the set's coarsest
imbalances shrink by only a fraction per iteration, so an over-relaxed step (s > 1) takes
them out in fewer iterations at the same cost.
"""
from __future__ import annotations

import threading
from concurrent.futures import ThreadPoolExecutor
from functools import lru_cache

import numpy as np

from . import per_size
from ._validate import unit_points
from .shards import usable_cores

#: most directions per iteration a card may ask for (each is a sort of all n points)
MAX_DIRECTIONS = 1024
#: largest relaxation factor a card may ask for (1.5 and 2 were measured; an over-relaxed
#: fixed-point iteration overshoots once the factor is too large)
MAX_STEP = 2.0

#: a thinned set's polish: THINNED_FACTOR times the card's iterations, and at least
#: THINNED_FACTOR * THINNED_MIN (see iterations_at)
THINNED_FACTOR, THINNED_MIN = 3, 4

_BELOW_ONE = np.nextafter(1.0, 0.0)


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
    return np.clip((sq + 1) / 2, 0.0, _BELOW_ONE)


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


def polish(points: np.ndarray, iterations: int, directions: int,
           rngs: list[np.random.Generator], *, workers: int | None = None,
           step: float = 1.0) -> np.ndarray:
    """``iterations`` SOT iterations on each set of ``points`` (c, n, 2) in [0, 1)^2,
    each move scaled by ``step`` (1: the sampler's own update, bit for bit).

    ``rngs`` gives one generator per set (each iteration's rotation of the evenly spread
    directions), so a set's result does not depend on the others in its batch, nor on
    ``workers``: the threads (default: one per CPU this process may run on, its affinity
    mask) that share the sets, or, with fewer sets than threads, each iteration's blocks of
    directions (a set alone, a big n); numpy's sort releases the GIL, so they run in
    parallel.

    Unlike the sampler, the polish sorts each projection by 16-bit keys (resolution
    2^-15 on the disk's [-1, 1]), which halves its cost: points closer than that along a
    direction may swap their targets there. Against the exact sort, 8 iterations of 128
    directions on 1024-point sets move points by 2.5e-5 rms (0.1 % of their spacing) and
    leave the Gaussian integration error as it was. Each step's displacement is computed in
    float32 (the points stay float64), another ~1.5x; with n <= 2^16 the keys are sorted
    packed with their indices, in reused buffers (:func:`_packed_displacement`), another
    ~2x (1024-point sets, 12 iterations of 128 directions, batch of 32 on 2 cores: 7.4
    instead of 14.5-16.5 ms a set; the same sets bit for bit).

    Examples
    --------
    >>> import numpy as np
    >>> from diffsampler_rt.sliced_ot import polish
    >>> pts = np.random.default_rng(0).random((1, 256, 2))  # white noise
    >>> out = polish(pts, 32, 32, [np.random.default_rng(1)])
    >>> out.shape, bool(np.all((out >= 0) & (out < 1)))
    ((1, 256, 2), True)
    """
    x = square_to_disk(unit_points(points, form="(sets, n, 2)"))
    base = np.arange(directions) * (np.pi / directions)
    turns = np.stack([g.random(iterations) for g in rngs]) * (np.pi / directions)  # (c, K)

    buffers = _Buffers()  # each thread's, for every step; freed when the polish returns

    def run(part: slice, pool: ThreadPoolExecutor | None = None) -> np.ndarray:
        y = x[part]
        for i in range(iterations):
            z = sliced_step(y, base[None, :] + turns[part, i:i + 1], pool=pool, exact=False,
                            _buffers=buffers)
            y = z if step == 1 else y + step * (z - y)
        return y

    if workers is not None and (isinstance(workers, bool) or not isinstance(workers, int)
                                or workers < 1):
        raise ValueError(f"workers must be an integer >= 1 or None, got {workers!r}")
    if not _step_ok(step):
        raise ValueError(f"step must be a number in (0, {MAX_STEP:g}], got {step!r}")
    c = len(x)
    w = max(1, usable_cores() if workers is None else workers)
    if w == 1 or iterations == 0:
        return disk_to_square(run(slice(None)))
    if c < w:  # too few sets to go round: the threads share each iteration's directions
        with ThreadPoolExecutor(min(w, -(-directions // BLOCK))) as pool:
            return disk_to_square(run(slice(None), pool))
    edges = np.linspace(0, c, w + 1).astype(int)
    with ThreadPoolExecutor(w) as pool:
        parts = list(pool.map(run, [slice(a, b) for a, b in zip(edges[:-1], edges[1:])]))
    return disk_to_square(np.concatenate(parts))


def iterations_at(spec: dict, n: int, *, thinned: bool = False) -> int:
    """Iterations at n points for a card's ``"sliced_ot"``: ``spec["iterations"]`` is a
    number, or with ``spec["n"]`` a per-size table (linear in log n between its sizes,
    rounded; the end values beyond).

    A ``thinned`` set (n not a square: points removed from the next square's set,
    :mod:`diffsampler_rt.elimination`) gets THINNED_FACTOR times as many, at least
    THINNED_FACTOR * THINNED_MIN: its holes are local, and a sliced-OT iteration, which
    averages each point's move over all directions, fills them slowly (sot_fast at
    n = 1000, Gaussian MSE over the sampler's: +52 / +24 / +20 % with 1 / 2 / 3 times its 12
    iterations; at n = 200 +38 / +17 / +7 % with 4 / 8 / 12)."""
    k = (int(round(per_size.at(spec["n"], spec["iterations"], n))) if "n" in spec
         else int(spec["iterations"]))
    return thinned_iterations(k) if thinned else k


def thinned_iterations(iterations: int) -> int:
    """A thinned set's iterations for a card's ``iterations``: THINNED_FACTOR times as many,
    at least THINNED_FACTOR * THINNED_MIN (see :func:`iterations_at`)."""
    return THINNED_FACTOR * max(iterations, THINNED_MIN)


def describe(spec: dict | None) -> str:
    """The card value in words: "none", "8 iterations of 128 directions", or
    "0 / 8 / 10 iterations at n = 256 / 1024 / 4096 (log-linear, rounded) of 128
    directions", with ", each move scaled by 1.5" where the card sets a step."""
    if not spec:
        return "none"
    if "n" in spec:
        its = (per_size.describe(spec["n"], list(map(str, spec["iterations"])), "iterations")
               + " (log-linear, rounded)")
    else:
        its = f"{spec['iterations']} iterations"
    step = f", each move scaled by {spec['step']:g}" if spec.get("step", 1) != 1 else ""
    return f"{its} of {spec['directions']} directions{step}"


def _step_ok(v) -> bool:
    return (not isinstance(v, bool) and isinstance(v, (int, float)) and np.isfinite(v)
            and 0 < v <= MAX_STEP)


def _count(v, low: int, top: int | None = None) -> bool:
    return (not isinstance(v, bool) and isinstance(v, int) and v >= low
            and (top is None or v <= top))


def settings_problem(spec) -> str | None:
    """Why a card's ``"sliced_ot"`` value is invalid, or None."""
    form = ("'sliced_ot' must be {\"directions\": D, \"iterations\": K} or {\"directions\": D, "
            "\"n\": [sizes], \"iterations\": [K per size]}, with an optional \"step\"")
    if not isinstance(spec, dict) or set(spec) - {"n", "step"} != {"directions", "iterations"}:
        return f"{form}, got {spec!r}"
    if "step" in spec and not _step_ok(spec["step"]):
        return f"'sliced_ot' step must be a number in (0, {MAX_STEP:g}], got {spec['step']!r}"
    if not _count(spec["directions"], 1, MAX_DIRECTIONS):
        return (f"'sliced_ot' directions must be an integer from 1 to {MAX_DIRECTIONS}, "
                f"got {spec['directions']!r}")
    if "n" not in spec:
        return None if _count(spec["iterations"], 0) else \
            f"'sliced_ot' iterations must be an integer >= 0, got {spec['iterations']!r}"
    sizes, its = spec["n"], spec["iterations"]
    if not (per_size.sizes_ok(sizes) and isinstance(its, list) and len(sizes) == len(its)
            and all(_count(v, 0) for v in its)):
        return (f"'sliced_ot' n and iterations must be lists of the same length, n strictly "
                f"increasing sizes >= 1, iterations integers >= 0; got {sizes!r}, {its!r}")
    return None
