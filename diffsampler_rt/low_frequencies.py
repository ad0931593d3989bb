"""Moving points by a smooth displacement field to set their density at large scales.

The density of a point set (n, 2), low-passed below ``cut`` sqrt(n) cycles across the
square, changes under a small displacement u by -div(u) (the continuity equation), so the
move u = grad psi with laplacian(psi) = (the excess to remove) removes it to first order;
psi comes from one FFT of the points deposited on a grid of 4 cut sqrt(n) + 8 cells a side
or more, and u is interpolated back at the points (first order, and approximate: the
pattern's finer scales alias into the grid's low frequencies a little). On the torus for
toroidal models; otherwise on the square mirrored into [0, 2)^2, whose periodic extension
has no seam, so that no point is pushed across an edge.

Two uses:

- :func:`restore_low_frequencies`: a set thinned from a bigger one
  (:mod:`diffsampler_rt.elimination`) gets the bigger set's large scales back (its holes'
  power taken out), below RESTORE_CUT sqrt(n) or a ``thin`` step's ``"restore_cut"`` (GBN's
  nets, whose sets are even up to their blue-noise peak, restore up to it, 1; sot /
  sot_fast 0.4; :mod:`diffsampler_rt.finish.thin`);
- :func:`even_out`: the pipeline step ``{"step": "even_out", "gain": G, "cut": C}``
  (:mod:`diffsampler_rt.finish.even_out`; G and C numbers or per-size tables, linear in
  log n between the sizes, the end values beyond; :func:`describe` and
  :func:`settings_problem` read the format-1 card field ``"even_out"``) shrinks a set's own density deviations
  by 1 - G, for nets whose sets are less even at large scales than their sampler's (G < 0
  amplifies them, for nets whose sets are more even).
"""
from __future__ import annotations

import math
from functools import lru_cache
from typing import Any

import numpy as np

from . import per_size
from ._cic import deposit
from ._validate import unit_points
from .grid import reflect

#: frequencies restored after thinning: |f| < RESTORE_CUT sqrt(n) (in the radial spectrum's
#: units; the displacement field is smooth over about 1 / RESTORE_CUT point spacings),
#: unless a card says ``"restore_cut"``: higher suits sets even up to a blue-noise peak
#: (GBN), not those with their sampler's white-noise power there (Poisson disk)
RESTORE_CUT = 0.25
#: the most an ``"even_out"`` card may ask for: gains in [-MAX_GAIN, MAX_GAIN], cuts up to
#: MAX_CUT sqrt(n) (beyond the blue-noise peak the move would reshape the pattern itself)
MAX_GAIN, MAX_CUT = 0.9, 2.0


def gain_at(spec: dict, n: int) -> float:
    """The gain at n points of a card's ``"even_out"``."""
    return per_size.gain_at(spec, n)


def describe(spec: dict | None) -> str:
    """The card value in words: "none", or "gain 0.08 / 0.1 at n = 256 / 576 (log-linear)
    below 1 sqrt(n)"."""
    if not spec:
        return "none"
    return f"{per_size.describe_gain(spec)} below {per_size.describe_cut(spec, 'sqrt(n)')}"


def restore_cut_problem(value: Any) -> str | None:
    """Why a card's ``"restore_cut"`` value is invalid, or None."""
    if per_size.finite_number(value) and 0 < value <= MAX_CUT:
        return None
    return f"'restore_cut' must be a number in (0, {MAX_CUT:g}], got {value!r}"


def settings_problem(spec: Any) -> str | None:
    """Why a card's ``"even_out"`` value is invalid, or None."""
    return per_size.gain_table_problem(
        spec, "even_out", lambda c: per_size.finite_number(c) and 0 < c <= MAX_CUT,
        f"a number in (0, {MAX_CUT:g}]",
        lambda g: per_size.finite_number(g) and -MAX_GAIN <= g <= MAX_GAIN,
        f"numbers in [-{MAX_GAIN:g}, {MAX_GAIN:g}]")


def _mirrored(p: np.ndarray) -> np.ndarray:
    """The four reflections of p into [0, 2)^2, scaled to [0, 1)^2: a set whose periodic
    extension has no seam (displacements normal to the square's edges vanish there)."""
    q = np.concatenate([p, p * [-1, 1] + [2, 0], p * [1, -1] + [0, 2], 2 - p])
    return np.minimum(q / 2, np.nextafter(1.0, 0.0))


def restore_low_frequencies(kept: np.ndarray, full: np.ndarray, *, torus: bool = False,
                            cut: float = RESTORE_CUT) -> np.ndarray:
    """Move the points ``kept`` (n, 2), thinned from ``full`` (m, 2), so that their density
    below ``cut`` sqrt(n) cycles across the square is that of ``full``.

    The density difference d (kept's minus full's, each normalised to one, low-passed) is
    undone by the displacement u = grad psi with laplacian(psi) = d, to first order (the
    continuity equation); psi comes from one FFT on a grid, u is interpolated at the points.

    Examples
    --------
    >>> import numpy as np
    >>> from diffsampler_rt.elimination import eliminate
    >>> from diffsampler_rt.low_frequencies import restore_low_frequencies
    >>> full = np.random.default_rng(0).random((225, 2))
    >>> kept = eliminate(full, 200)
    >>> moved = restore_low_frequencies(kept, full)
    >>> moved.shape, bool(np.all((moved >= 0) & (moved < 1)))
    ((200, 2), True)
    """
    return _move(unit_points(kept, name="kept", form="(n, 2)"),
                 unit_points(full, name="full", form="(m, 2)"), 1.0, cut, torus)


def even_out(points: np.ndarray, gain: float, *, cut: float, torus: bool = False) -> np.ndarray:
    """Shrink each set's density deviations from uniform below ``cut`` sqrt(n) by the
    factor 1 - ``gain`` (to first order; gain < 0 amplifies them), by a smooth displacement.

    ``points`` (n, 2) or (sets, n, 2); gain 0 returns them unchanged.

    Examples
    --------
    >>> import numpy as np
    >>> from diffsampler_rt.low_frequencies import even_out
    >>> pts = np.random.default_rng(0).random((3, 256, 2))
    >>> out = even_out(pts, 0.5, cut=1.0)
    >>> out.shape, bool(np.all((out >= 0) & (out < 1)))
    ((3, 256, 2), True)
    >>> even_out(pts, 0.0, cut=1.0) is pts
    True
    """
    pts = unit_points(points)
    if gain == 0:  # bit for bit: a per-size table may pass through 0
        return points
    flat = pts.reshape((-1,) + pts.shape[-2:])
    return np.stack([_move(p, None, gain, cut, torus) for p in flat]).reshape(pts.shape)


@lru_cache(maxsize=16)
def _operator(m: int, fc: float) -> tuple[np.ndarray, ...]:
    """The real-FFT frequencies of an m x m grid cropped to the columns 0 <= fy <= fc (the
    only ones the mask 0 < |f| < fc keeps), the mask, the cloud-in-cell transfer function and
    the Laplacian's symbol there: the same for every set of a size, so made once (read-only,
    shared)."""
    fx = (np.fft.fftfreq(m, 1.0 / m))[:, None]
    fy = (np.fft.rfftfreq(m, 1.0 / m))[None, :_columns(m, fc)]
    r2 = fx * fx + fy * fy
    low = (r2 > 0) & (r2 < fc * fc)
    taper = (np.sinc(fx / m) * np.sinc(fy / m)) ** 2
    laplacian = -4 * np.pi ** 2 * np.where(low, r2, 1)
    for v in (fx, fy, low, taper, laplacian):
        v.flags.writeable = False
    return fx, fy, low, taper, laplacian


@lru_cache(maxsize=16)  # one per size and cut, like _operator: not searched per set
def _grid_side(fc: float) -> int:
    """The FFT grid's side for a cut of fc cycles across it: well beyond the cut (4 fc + 8
    cells, 16 or more), rounded up to a 5-smooth number (2^a 3^b 5^c), which the FFT handles
    as fast as a power of two (a power of two was up to 2x wider: up to 4x the cells)."""
    m = max(16, math.ceil(4 * fc + 8))
    while True:
        rest = m
        for p in (2, 3, 5):
            while rest % p == 0:
                rest //= p
        if rest == 1:
            return m
        m += 1


def _columns(m: int, fc: float) -> int:
    """How many of the m x m grid's real-FFT columns (fy = 0, 1, ...) reach the cut fc."""
    return min(m // 2 + 1, math.floor(fc) + 1)


def _low_rfft2(grid: np.ndarray, k: int) -> np.ndarray:
    """``np.fft.rfft2(grid)[:, :k]``, without transforming the other columns along the first
    axis (rfft2 is that transform of the last axis's rfft: the same numbers, less work)."""
    return np.fft.fft(np.fft.rfft(grid, axis=1)[:, :k], axis=0)


def _low_irfft2(spectra: np.ndarray, m: int) -> np.ndarray:
    """``np.fft.irfft2`` over the last two axes of (..., m, k) spectra zero beyond column k
    (irfft2 is the last axis's irfft of the first's ifft: the zero columns stay zero)."""
    columns = np.fft.ifft(spectra, axis=-2)
    padded = np.zeros(spectra.shape[:-1] + (m // 2 + 1,), dtype=columns.dtype)
    padded[..., :spectra.shape[-1]] = columns
    return np.fft.irfft(padded, m, axis=-1)


def _move(a0: np.ndarray, target: np.ndarray | None, gain: float, cut: float,
          torus: bool) -> np.ndarray:
    """Points a0 (n, 2) moved so that ``gain`` of their low-passed density excess over
    ``target``'s (None: uniform) goes: u = grad psi, laplacian(psi) = gain * excess."""
    n = len(a0)
    a = a0 if torus else _mirrored(a0)
    scale = 1 if torus else 2  # the mirrored square is twice as wide: twice the frequencies
    fc = scale * cut * math.sqrt(n)
    m = _grid_side(fc)
    fx, fy, low, taper, laplacian = _operator(m, fc)
    grid_a, base, w = deposit(a, m)
    k = fy.shape[1]
    diff = _low_rfft2(grid_a, k) / len(a)
    if target is not None:
        b = target if torus else _mirrored(target)
        diff = diff - _low_rfft2(deposit(b, m)[0], k) / len(b)
    psi = gain * np.where(low, diff / taper, 0) / laplacian
    # the cloud-in-cell weights again, to read the grid back at the points
    corners = [((w[:, 0] if dx else 1 - w[:, 0]) * (w[:, 1] if dy else 1 - w[:, 1]),
                (base[:, 0] + dx) % m, (base[:, 1] + dy) % m) for dx in (0, 1) for dy in (0, 1)]
    u = np.zeros_like(a)
    fields = _low_irfft2(np.stack([2j * np.pi * freq * psi for freq in (fx, fy)]), m) * m * m
    for axis, field in enumerate(fields):
        for weight, ix, iy in corners:
            u[:, axis] += weight * field[ix, iy]
    if torus:
        return np.minimum((a0 + u) % 1.0, np.nextafter(1.0, 0.0))
    return reflect(2 * (a + u)[:n])  # the unreflected copy, folded back where it left
