"""Non-uniform samplers of the seed paper: SOT on a linear ramp, GBN thinned to a blob."""
from __future__ import annotations

from functools import lru_cache

import numpy as np

from .gbn import gbn_relax

#: angles at which the ramp's projected quantiles are tabulated (directions mod pi)
_ANGLES = 512


def ramp_density(p: np.ndarray) -> np.ndarray:
    """p(x, y) = 2x on the unit square."""
    return 2.0 * p[..., 0]


def blob_density(p: np.ndarray) -> np.ndarray:
    """Unnormalised 0.2 exp(-20 (x^2 + y^2)) + 0.2 sin^2(pi x) sin^2(pi y)."""
    x, y = p[..., 0], p[..., 1]
    return 0.2 * np.exp(-20 * (x * x + y * y)) + 0.2 * (np.sin(np.pi * x) * np.sin(np.pi * y)) ** 2


def ramp_cdf(t: np.ndarray, theta: float) -> np.ndarray:
    """Exact P(x cos(theta) + y sin(theta) <= t) for (x, y) with density 2x, theta in [0, pi).

    F(t) = int_0^1 2x L(x) dx with L(x) = clip((t - c x) / s, 0, 1) piecewise linear in x:
    split [0, 1] where L reaches 0 and 1 and integrate each polynomial piece exactly.
    """
    c, s = np.cos(theta), np.sin(theta)
    t = np.asarray(t, dtype=np.float64)
    if s < 1e-12:  # theta = 0: the event is x <= t
        return np.clip(t, 0.0, 1.0) ** 2
    if abs(c) < 1e-12:  # theta = pi/2: the event is y <= t, independent of x
        return np.clip(t / s, 0.0, 1.0)
    cuts = np.sort(np.stack([np.zeros_like(t), np.ones_like(t), np.clip(t / c, 0, 1),
                             np.clip((t - s) / c, 0, 1)]), axis=0)
    total = np.zeros_like(t)
    for k in range(3):
        lo, hi = cuts[k], cuts[k + 1]
        g = (t - c * (lo + hi) / 2) / s  # L's regime on this piece
        full = hi**2 - lo**2  # int 2x dx
        prim = lambda x: (t * x**2 - 2 * c * x**3 / 3) / s  # int 2x (t - c x) / s dx
        total += np.where(g >= 1, full, np.where(g <= 0, 0.0, prim(hi) - prim(lo)))
    return total


@lru_cache(maxsize=8)
def ramp_quantiles(n: int) -> np.ndarray:
    """(ANGLES, n): quantiles (2i+1)/(2n) of <u_theta, X> for X ~ 2x, theta = pi a / ANGLES.

    Exact CDF (:func:`ramp_cdf`) inverted by bisection to machine precision.
    """
    u = (2 * np.arange(n) + 1) / (2 * n)
    out = np.empty((_ANGLES, n))
    for a in range(_ANGLES):
        th = np.pi * a / _ANGLES
        c, s = np.cos(th), np.sin(th)
        lo = np.full(n, min(0.0, c) + min(0.0, s))
        hi = np.full(n, max(0.0, c) + max(0.0, s))
        for _ in range(55):
            mid = (lo + hi) / 2
            below = ramp_cdf(mid, th) < u
            lo, hi = np.where(below, mid, lo), np.where(below, hi, mid)
        out[a] = (lo + hi) / 2
    return out


def sot_ramp_square(n: int, rng: np.random.Generator, *, iterations: int = 4096,
                    directions: int = 64) -> np.ndarray:
    """One SOT set of n points for the density 2x on the square."""
    q = ramp_quantiles(n)
    x = np.column_stack([np.sqrt(rng.random(n)), rng.random(n)])  # exact samples of 2x
    stride = _ANGLES // directions
    for _ in range(iterations):
        idx = np.arange(directions) * stride + rng.integers(stride)
        theta = np.pi * idx / _ANGLES
        dirs = np.stack([np.cos(theta), np.sin(theta)], axis=1)
        proj = x @ dirs.T  # (n, m)
        order = np.argsort(proj, axis=0)
        shift = np.empty_like(proj)
        np.put_along_axis(shift, order, q[idx].T - np.take_along_axis(proj, order, 0), 0)
        x = x + shift @ dirs / directions
    return np.clip(x, 0.0, np.nextafter(1.0, 0.0))


def sot_ramp(n: int, count: int, rng: np.random.Generator) -> np.ndarray:
    """SOT sets for the linear ramp density p(x, y) = 2x (the seed's non-uniform example)."""
    return np.stack([sot_ramp_square(n, rng) for _ in range(count)])


def gbn_blob(n: int, count: int, rng: np.random.Generator, oversample: int = 4,
             iterations: int = 3000) -> np.ndarray:
    """GBN importance-sampled to :func:`blob_density`, exactly n points per set.

    A GBN set of ``oversample`` * n points is thinned by rank: the n points with the
    smallest u_i / p(x_i) (u_i uniform) are kept, i.e. rejection sampling with the
    acceptance threshold chosen so that exactly n survive. p_max / p_mean is ~3.5 for this
    density, so 4x oversampling leaves every region enough candidates.
    """
    out = np.empty((count, n, 2))
    for c in range(count):
        big = gbn_relax(rng.random((oversample * n, 2)), iterations)
        key = rng.random(len(big)) / blob_density(big)
        out[c] = big[np.argsort(key)[:n]]
    return out


def ramp_unwarp(p: np.ndarray) -> np.ndarray:
    """Rosenblatt map of the ramp density 2x to the uniform square: (x, y) -> (x^2, y)."""
    p = np.asarray(p, dtype=np.float64)
    return np.stack([p[..., 0] ** 2, p[..., 1]], axis=-1)


def _gauss_int(t: np.ndarray) -> np.ndarray:
    """int_0^t exp(-20 s^2) ds."""
    from scipy.special import erf
    return np.sqrt(np.pi / 80) * erf(np.sqrt(20.0) * t)


def _sin2_int(t: np.ndarray) -> np.ndarray:
    """int_0^t sin^2(pi s) ds."""
    return t / 2 - np.sin(2 * np.pi * t) / (4 * np.pi)


def blob_unwarp(p: np.ndarray) -> np.ndarray:
    """Rosenblatt map of :func:`blob_density` to the uniform square (exact, closed form).

    u = F_X(x) (the x-marginal's CDF), v = F_Y|X(y | x) (the conditional CDF of y).
    """
    p = np.asarray(p, dtype=np.float64)
    x, y = p[..., 0], p[..., 1]
    g1, s1 = _gauss_int(1.0), _sin2_int(1.0)
    ex, sx = np.exp(-20 * x * x), np.sin(np.pi * x) ** 2
    u = (_gauss_int(x) * g1 + _sin2_int(x) * s1) / (g1 * g1 + s1 * s1)
    v = (ex * _gauss_int(y) + sx * _sin2_int(y)) / (ex * g1 + sx * s1)
    return np.clip(np.stack([u, v], axis=-1), 0.0, np.nextafter(1.0, 0.0))


#: non-uniform samplers -> the map that takes their density to the uniform square
UNWARP = {"sot_ramp": ramp_unwarp, "gbn_blob": blob_unwarp}
