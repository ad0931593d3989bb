"""Reverse-diffusion solvers: small pure functions over an eps-prediction denoiser.

Contract: ``eps_fn(x, t) -> eps`` with x float64 (B, 2, k, k) and t an integer timestep
index in [0, T); ``alpha_bar`` the schedule's cumulative products (float64, length T);
``ts`` the descending timestep indices to visit.
"""
from __future__ import annotations

from typing import Callable, Sequence

import numpy as np

Denoiser = Callable[[np.ndarray, int], np.ndarray]


def ddim(eps_fn: Denoiser, x: np.ndarray, alpha_bar: np.ndarray, ts: Sequence[int], *,
         eta: float = 0.0, noise: Callable[[tuple[int, ...]], np.ndarray] | None = None,
         ) -> np.ndarray:
    """DDIM (Song et al. 2021, eq. 12); eta = 0 deterministic, eta = 1 ancestral DDPM.

    ``noise(shape)`` supplies the fresh standard normal draws that eta > 0 needs.
    """
    for i, t in enumerate(ts):
        ab_t = alpha_bar[t]
        ab_prev = alpha_bar[ts[i + 1]] if i + 1 < len(ts) else 1.0
        eps = eps_fn(x, int(t))
        x0 = (x - np.sqrt(1.0 - ab_t) * eps) / np.sqrt(ab_t)  # predicted clean sample
        sigma = eta * np.sqrt((1.0 - ab_prev) / (1.0 - ab_t) * (1.0 - ab_t / ab_prev))
        x = np.sqrt(ab_prev) * x0 + np.sqrt(max(0.0, 1.0 - ab_prev - sigma**2)) * eps
        if sigma > 0.0:
            if noise is None:
                raise ValueError("eta > 0 needs a noise source")
            x = x + sigma * noise(x.shape)
    return x


#: solver name -> eta of :func:`ddim`
SOLVERS = {"ddim": 0.0, "ddpm": 1.0}
