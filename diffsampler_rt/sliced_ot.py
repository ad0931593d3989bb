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

A model card's pipeline asks for it with the step ``{"step": "sliced_ot", "directions": D,
"iterations": K}`` (:mod:`diffsampler_rt.finish.sliced_ot`), K possibly per size
(``{"n": [256, 1024, 4096], "values": [0, 4, 16]}``, linear in log n between the sizes,
rounded, the end values beyond). An optional ``"step_size": s`` (0 < s <= 2, default 1: the
sampler's own update; ``"step"`` in a format-1 card's ``"sliced_ot"`` field, which
:func:`iterations_at`, :func:`describe` and :func:`settings_problem` read) scales every move: the mean over evenly spread
directions of a displacement's 1-d projections is half of it in 2-d, and the set's coarsest
imbalances shrink by only a fraction per iteration, so an over-relaxed step (s > 1) takes
them out in fewer iterations at the same cost.
"""
from __future__ import annotations

from concurrent.futures import ThreadPoolExecutor

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

from .disk_transport import (BLOCK, _Buffers, disk_to_square, sliced_step,
                             square_to_disk)


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
