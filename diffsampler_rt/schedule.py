"""Noise schedules: the one definition both training and generation use.

A schedule is described by a small dict stored in every model card, e.g.
``{"kind": "linear", "beta_start": 1e-4, "beta_end": 0.02, "num_steps": 1000}``; the
trainer builds its tensors from :func:`alphas_cumprod`, so the two sides cannot drift.
"""
from __future__ import annotations

import math
from typing import Any, Mapping

import numpy as np

SCHEDULE_KINDS = ("linear", "cosine")


def betas(spec: Mapping[str, Any]) -> np.ndarray:
    """The DDPM variances beta_1..beta_T (float64) of a schedule spec."""
    kind = spec.get("kind")
    T = int(spec.get("num_steps", 0))
    if T < 1:
        raise ValueError(f"schedule num_steps must be >= 1, got {spec.get('num_steps')!r}")
    if kind == "linear":  # Ho et al. 2020
        return np.linspace(float(spec["beta_start"]), float(spec["beta_end"]), T,
                           dtype=np.float64)
    if kind == "cosine":  # Nichol & Dhariwal 2021, eq. 17
        s = float(spec.get("offset", 0.008))
        f = np.cos((np.arange(T + 1, dtype=np.float64) / T + s) / (1 + s) * math.pi / 2) ** 2
        return np.clip(1.0 - f[1:] / f[:-1], 0.0, 0.999)
    raise ValueError(f"unknown schedule kind {kind!r}; choose one of {SCHEDULE_KINDS}")


def alphas_cumprod(spec: Mapping[str, Any]) -> np.ndarray:
    """alpha_bar_t = prod_{s<=t} (1 - beta_s) for t = 0..T-1 (float64)."""
    return np.cumprod(1.0 - betas(spec))


def timesteps(num_train_steps: int, num_sample_steps: int) -> np.ndarray:
    """Evenly spaced training-timestep indices, descending from T-1, for a short sampler.

    Returns ``num_sample_steps`` integers starting at T-1 (the "trailing" spacing of
    Lin et al. 2024, so the first step sees pure noise); a solver's last step goes from
    the smallest of them to clean data.
    """
    if not 1 <= num_sample_steps <= num_train_steps:
        raise ValueError(f"steps must be in [1, {num_train_steps}], got {num_sample_steps}")
    t = np.round(np.arange(num_train_steps, 0, -num_train_steps / num_sample_steps)) - 1
    return t.astype(np.int64)
