"""A gain on the coarse scales of the solver's starting noise (the pipeline step
``coarse_noise``, :mod:`diffsampler_rt.finish.coarse_noise`).

A small net can make sets that are more even at large scales than its sampler's: the
bundled ldbn's sets had about 25 % less power than the sampler's at the frequencies below
half the grid's (radial spectrum below 0.5 sqrt(n)) and integrated Gaussians 27 % better,
where the aim is the sampler's behaviour, not a better one. A set's large scales follow
those of the noise the solver starts from, so scaling the starting noise's Fourier modes
up to ``cut`` times the grid's Nyquist frequency (k / 2 cycles across the square) by
``gain`` moves them (gain > 1: more large-scale variation, < 1: less) and leaves the finer
scales, where the net's pattern lives, nearly as they were. The starting noise stays a
stationary Gaussian field on the k x k grid, no longer white; its mean (the zero
frequency) is left alone. Each set is shaped on its own, so batching does not change it.

The step's ``"temperature"`` T (a number in (0, 2]; format 1's ``"structure_temperature"``,
where the structure is imposed: an entry with ``"where": "structured"``) scales every other
mode, the mean included, by T: the distilled ldbn_fast's sets, whose
LDBN ripples the n-rooks projection damps, keep them better from a cooler start (spectrum
MAE at n = 1024 0.019 -> 0.015; see :meth:`diffsampler_rt.Model.generate`).

Step parameters: ``{"step": "coarse_noise", "gain": G, "cut": C}``, each a number or a
per-size table ``{"n": [sizes], "values": [...]}``: linear in log n between the listed
sizes, the end values beyond (the format-1 field ``{"cut": C, "n": [...], "gain": [...]}``
is what :func:`shaping`, :func:`describe` and :func:`settings_problem` read). It is chosen by measurement against the reference sampler
(``python -m export pipeline MODEL --add coarse_noise --gain ... --cut ...``).
"""
from __future__ import annotations

from typing import Any

import numpy as np

from . import per_size

#: largest gain a card may ask for (the bundled cards use 1-1.7)
MAX_GAIN = 4.0


def gain_at(spec: dict, n: int) -> float:
    """The gain at n points of a card's ``"coarse_noise"``."""
    return per_size.gain_at(spec, n)


def shaping(spec: dict | None, n: int, temperature: float = 1.0
            ) -> tuple[float, float, float] | None:
    """Arguments of :func:`shape_noise` for the starting noise of an n-point set: (gain of
    the coarse modes, their cut, factor of every other mode) from a card's
    ``"coarse_noise"`` (None: no gain) and a structure's ``temperature``; None where the
    noise stays plain unit noise.

    Examples
    --------
    >>> from diffsampler_rt.coarse_noise import shaping
    >>> shaping({"n": [64, 1024], "gain": [1.5, 1.2], "cut": 0.25}, 1024, 0.9)
    (1.2, 0.25, 0.9)
    >>> shaping(None, 1024) is None, shaping(None, 1024, 0.9)
    (True, (0.9, 1.0, 0.9))
    """
    if spec:
        return gain_at(spec, n), per_size.cut_at(spec, n), temperature
    # every mode at the temperature
    return (temperature, 1.0, temperature) if temperature != 1 else None


def coarse_filter(k: int, gain: float, cut: float, rest: float = 1.0) -> np.ndarray:
    """Multiplier of the (k, k // 2 + 1) real-FFT modes of a k x k field: ``gain`` where
    0 < |frequency| <= cut * k / 2 (frequencies in cycles across the grid), else ``rest``."""
    fy = np.fft.fftfreq(k) * k
    fx = np.fft.rfftfreq(k) * k
    r = np.hypot(fy[:, None], fx[None, :])
    return np.where((r > 0) & (r <= cut * k / 2), gain, rest)


def shape_noise(x: np.ndarray, gain: float, cut: float, rest: float = 1.0) -> np.ndarray:
    """``x`` (..., k, k), white Gaussian noise, with its coarse modes scaled by ``gain``
    and every other mode (the mean included) by ``rest`` (a structure's temperature).

    Examples
    --------
    >>> import numpy as np
    >>> from diffsampler_rt.coarse_noise import shape_noise
    >>> x = np.random.default_rng(0).standard_normal((2, 16, 16))
    >>> y = shape_noise(x, 1.5, 0.25)
    >>> y.shape, bool(np.allclose(y.mean(axis=(-2, -1)), x.mean(axis=(-2, -1))))
    ((2, 16, 16), True)
    >>> shape_noise(x, 1.0, 0.25) is x
    True
    """
    k = x.shape[-1]
    if x.shape[-2] != k:
        raise ValueError(f"noise must be square in its last two axes, got shape {x.shape}")
    if gain == 1 and rest == 1:  # bit for bit: a per-size table may pass through 1
        return x
    if gain == rest:  # one factor for every mode
        return x * gain
    spectrum = np.fft.rfft2(x) * coarse_filter(k, gain, cut, rest)
    return np.fft.irfft2(spectrum, s=(k, k))


def describe(spec: dict | None) -> str:
    """The card value in words: "none", "gain 1.4 up to 0.25 x Nyquist", or
    "gain 1.3 / 1.5 at n = 64 / 1024 (log-linear) up to 0.25 x Nyquist"."""
    if not spec:
        return "none"
    return f"{per_size.describe_gain(spec)} up to {per_size.describe_cut(spec, 'x Nyquist')}"


def settings_problem(spec: Any) -> str | None:
    """Why a card's ``"coarse_noise"`` value is invalid, or None."""
    return per_size.gain_table_problem(
        spec, "coarse_noise", lambda c: per_size.finite_number(c) and 0 < c <= 1,
        "a number in (0, 1]", lambda g: per_size.finite_number(g) and 0 < g <= MAX_GAIN,
        f"numbers in (0, {MAX_GAIN:g}]")


#: the range of a card's ``"structure_temperature"``
TEMPERATURE_RANGE = (0.0, 2.0)


def temperature_problem(value: Any) -> str | None:
    """Why a card's ``"structure_temperature"`` value is invalid, or None."""
    lo, hi = TEMPERATURE_RANGE
    if not (per_size.finite_number(value) and lo < value <= hi):
        return f"'structure_temperature' must be a number in ({lo:g}, {hi:g}], got {value!r}"
    return None
