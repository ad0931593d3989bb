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


def dpmpp_2m(eps_fn: Denoiser, x: np.ndarray, alpha_bar: np.ndarray, ts: Sequence[int],
             ) -> np.ndarray:
    """DPM-Solver++(2M) (Lu et al. 2022, alg. 2): multistep, second order in data prediction.

    Works in lambda = log(alpha / sigma); each step reuses the previous step's x0
    prediction for a second-order correction, so it costs one evaluation per step like
    DDIM. The first step and the final step to clean data are first order (the last one
    then returns the x0 prediction, which is stable for few steps).
    """
    alpha = np.sqrt(alpha_bar)
    sigma = np.sqrt(1.0 - alpha_bar)
    lam = np.log(alpha) - np.log(sigma)
    prev_x0, prev_h = None, None
    for i, t in enumerate(ts):
        eps = eps_fn(x, int(t))
        x0 = (x - sigma[t] * eps) / alpha[t]
        if i + 1 == len(ts):
            return x0
        s = ts[i + 1]
        h = lam[s] - lam[t]
        d = x0
        if prev_x0 is not None:
            r = prev_h / h
            d = (1.0 + 0.5 / r) * x0 - (0.5 / r) * prev_x0
        x = (sigma[s] / sigma[t]) * x - alpha[s] * np.expm1(-h) * d
        prev_x0, prev_h = x0, h
    return x


def project_x0(eps_fn: Denoiser, alpha_bar: np.ndarray, project: Callable[[np.ndarray], np.ndarray],
               at: Sequence[int]) -> Denoiser:
    """``eps_fn`` whose clean-sample prediction is replaced by ``project(x0)`` at the
    timestep indices ``at`` (projection guidance: the solver's later steps then denoise
    around a set that has the structure, instead of the structure being forced on the
    finished set alone). Any solver above takes the result as its denoiser.
    """
    late = frozenset(int(t) for t in at)

    def guided(x: np.ndarray, t: int) -> np.ndarray:
        eps = eps_fn(x, t)
        if t not in late:
            return eps
        a, s = np.sqrt(alpha_bar[t]), np.sqrt(1.0 - alpha_bar[t])
        return (x - a * project((x - s * eps) / a)) / s

    return guided


#: solver names accepted by :func:`solve`
SOLVERS = ("ddim", "ddpm", "dpmpp_2m")


def solve(name: str, eps_fn: Denoiser, x: np.ndarray, alpha_bar: np.ndarray,
          ts: Sequence[int], noise: Callable[[tuple[int, ...]], np.ndarray] | None = None,
          ) -> np.ndarray:
    """Run solver ``name`` (one of :data:`SOLVERS`) from x at ts[0] to clean data."""
    if name == "dpmpp_2m":
        return dpmpp_2m(eps_fn, x, alpha_bar, ts)
    if name in ("ddim", "ddpm"):
        return ddim(eps_fn, x, alpha_bar, ts, eta=0.0 if name == "ddim" else 1.0, noise=noise)
    raise ValueError(f"unknown solver {name!r}; choose one of {list(SOLVERS)}")
