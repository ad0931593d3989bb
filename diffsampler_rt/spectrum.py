"""Power spectrum by exact DFT at integer frequencies (the seed paper's convention).

P(f) = |sum_j exp(-2 pi i f . x_j)|^2 / n for integer f != 0 (white noise gives 1);
radial bin b (label x = b / 16) holds x sqrt(n) <= |f| < (x + 1/16) sqrt(n); 79 bins
labelled 1/16 .. 79/16, each the plain mean of P over its frequencies.
"""
from __future__ import annotations

import numpy as np

BIN_WIDTH = 0.0625
NUM_BINS = 79


def periodogram(points: np.ndarray, fmax: int) -> np.ndarray:
    """Mean periodogram over sets, frequencies -fmax..fmax per axis: (2fmax+1, 2fmax+1).

    Uses exp(-2 pi i (fx x + fy y)) = exp(-2 pi i fx x) exp(-2 pi i fy y): one complex
    matrix product per set instead of (2 fmax + 1)^2 n exponentials.
    """
    pts = np.asarray(points, dtype=np.float64).reshape((-1,) + np.shape(points)[-2:])
    n = pts.shape[1]
    f = np.arange(-fmax, fmax + 1, dtype=np.float64)
    acc = np.zeros((f.size, f.size))
    for p in pts:
        ex = np.exp(-2j * np.pi * f[:, None] * p[None, :, 0])  # (F, n)
        ey = np.exp(-2j * np.pi * f[:, None] * p[None, :, 1])
        s = ey @ ex.T  # s[fy, fx]
        acc += (s.real**2 + s.imag**2) / n
    return acc / len(pts)


def radial_spectrum(points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(bin labels x, radial mean power) of the mean periodogram of ``points`` (..., n, 2)."""
    n = np.shape(points)[-2]
    root = np.sqrt(n)
    fmax = int(np.ceil((NUM_BINS + 1) * BIN_WIDTH * root))
    P = periodogram(points, fmax)
    f = np.arange(-fmax, fmax + 1)
    r = np.hypot(f[:, None], f[None, :]) / root
    b = np.floor(r / BIN_WIDTH + 1e-9).astype(np.int64)  # guard exact edges against rounding
    labels = np.arange(1, NUM_BINS + 1) * BIN_WIDTH
    mask = (b >= 1) & (b <= NUM_BINS)
    sums = np.bincount(b[mask], weights=P[mask], minlength=NUM_BINS + 1)[1:]
    counts = np.bincount(b[mask], minlength=NUM_BINS + 1)[1:]
    return labels, sums / np.maximum(counts, 1)


def spectrum_mae(a: np.ndarray, b: np.ndarray) -> float:
    """Mean absolute difference between two radial spectra (79 bins)."""
    return float(np.mean(np.abs(np.asarray(a) - np.asarray(b))))
