"""Property optimisation through a frozen net: optimise the input noise of the reverse process.

The trained denoiser is differentiable, so the map noise -> point set (a short deterministic
DDIM run, or DDPM with its per-step noise) is too. Adam on the initial noise (and optionally
on every step's noise) against a differentiable objective adds a property to a learned
sampler while the net keeps the sets close to its learned distribution (Doignies et al.
2023, sec. 6: SOT sets optimised for L2 discrepancy keep SOT-like OT energy).

Memory stays bounded: every denoising step is gradient-checkpointed, so only the step
inputs are kept and one step's activations are rebuilt at a time in the backward pass.

    python -m trainer optimise runs/sot/checkpoint.pt 256 --count 10 --objective l2_star -o opt.npy
"""
from __future__ import annotations

import math
import time
from dataclasses import dataclass, field
from typing import Callable

import numpy as np
import torch
from torch.utils.checkpoint import checkpoint

from diffsampler_rt.schedule import alphas_cumprod, timesteps

Objective = Callable[[torch.Tensor], torch.Tensor]


# ---- objectives: (B, n, 2) points in [0, 1]^2 -> (B,) values to minimise -------------------

def l2_star_torch(points: torch.Tensor) -> torch.Tensor:
    """Squared star L2 discrepancy per set (Warnock's formula), differentiable, O(n^2)."""
    n, d = points.shape[-2:]
    term1 = torch.prod(1 - points**2, dim=-1).sum(-1) * 2.0 ** (1 - d) / n
    mx = torch.maximum(points[..., :, None, :], points[..., None, :, :])
    term2 = torch.prod(1 - mx, dim=-1).sum((-1, -2)) / n**2
    return 3.0 ** (-d) - term1 + term2


def _uniform_projection_quantiles(theta: torch.Tensor, n: int) -> torch.Tensor:
    """Quantiles (i + 1/2)/n of x cos(theta) + y sin(theta), (x, y) uniform on the unit
    square: a trapezoid distribution, inverted in closed form. (m, n)."""
    c, s = theta.cos().abs(), theta.sin().abs()
    a, b = torch.minimum(c, s).clamp_min(1e-9)[:, None], torch.maximum(c, s)[:, None]
    u = (torch.arange(n, dtype=theta.dtype) + 0.5)[None, :] / n
    # CDF of a U[0, a] + U[0, b] (a <= b): ramp up to a, linear to b, ramp down to a + b
    lo = a / (2 * b)
    t = torch.where(u < lo, torch.sqrt(2 * a * b * u),
                    torch.where(u <= 1 - lo, u * b + a / 2, a + b - torch.sqrt(2 * a * b * (1 - u))))
    # shift for negative cos / sin: the projection of (1 - x) equals -x cos + cos
    offset = torch.clamp(theta.cos(), max=0)[:, None] + torch.clamp(theta.sin(), max=0)[:, None]
    return t + offset


def sliced_ot_uniform(points: torch.Tensor, directions: int = 64,
                      generator: torch.Generator | None = None) -> torch.Tensor:
    """OT-energy proxy: the sliced W2^2 between each set and the uniform square (B,).

    Mean over random directions of the squared distance between the sorted projections and
    the exact quantiles of the projected uniform measure.
    """
    n = points.shape[-2]
    theta = torch.rand(directions, generator=generator, dtype=points.dtype) * math.pi
    dirs = torch.stack([theta.cos(), theta.sin()], dim=-1)  # (m, 2)
    proj = torch.sort(points @ dirs.T, dim=-2).values  # (B, n, m)
    q = _uniform_projection_quantiles(theta, n).T  # (n, m)
    return ((proj - q) ** 2).mean((-1, -2))


OBJECTIVES: dict[str, Objective] = {"l2_star": l2_star_torch, "ot_proxy": sliced_ot_uniform}


# ---- the differentiable reverse process -------------------------------------------------

def decode_torch(grid: torch.Tensor, offset_scale: float, stratified: bool) -> torch.Tensor:
    """Scaled offsets (B, 2, k, k) -> points (B, k*k, 2), as diffsampler_rt.grid.decode
    (reflected into the cell or the square; the gradient's sign flips where a point is)."""
    from .spectral import reflect
    k = grid.shape[-1]
    g = grid / offset_scale
    if stratified:
        g = reflect(g + 0.5) - 0.5
    centre = torch.arange(k, dtype=g.dtype) + 0.5
    x = (g[:, 0] + centre[None, None, :]) / k
    y = (g[:, 1] + centre[None, :, None]) / k
    pts = torch.stack([x, y], dim=-1).reshape(grid.shape[0], k * k, 2)
    return pts.clamp(0.0, 1.0 - 1e-12) if stratified else reflect(pts).clamp(0.0, 1.0 - 1e-12)


def reverse(net: torch.nn.Module, z: torch.Tensor, alpha_bar: torch.Tensor, ts: np.ndarray,
            step_noise: torch.Tensor | None = None, use_checkpoint: bool = True) -> torch.Tensor:
    """DDIM from x_T = z (deterministic) or, with ``step_noise`` (S-1, B, 2, k, k), DDPM
    (eta = 1) with those per-step draws. Returns the clean offsets x_0."""
    x = z
    for i, t in enumerate(ts):
        ab_t = alpha_bar[t]
        ab_prev = alpha_bar[ts[i + 1]] if i + 1 < len(ts) else torch.tensor(1.0, dtype=z.dtype)
        noise = step_noise[i] if step_noise is not None and i + 1 < len(ts) else None

        def step(x, t=int(t), ab_t=ab_t, ab_prev=ab_prev, noise=noise):
            eps = net(x, torch.full((x.shape[0],), float(t), dtype=x.dtype))
            x0 = (x - (1 - ab_t).sqrt() * eps) / ab_t.sqrt()
            if noise is None:
                return ab_prev.sqrt() * x0 + (1 - ab_prev).sqrt() * eps
            sigma = ((1 - ab_prev) / (1 - ab_t) * (1 - ab_t / ab_prev)).sqrt()
            return (ab_prev.sqrt() * x0 + (1 - ab_prev - sigma**2).clamp_min(0).sqrt() * eps
                    + sigma * noise)

        x = checkpoint(step, x, use_reentrant=False) if use_checkpoint and torch.is_grad_enabled() else step(x)
    return x


@dataclass
class OptimiseResult:
    """Optimised sets, the sets from the same noise before optimisation, and the log."""
    points: np.ndarray  # (count, n, 2) float64
    initial_points: np.ndarray  # (count, n, 2): iteration 0
    trajectory: list[dict] = field(default_factory=list)  # per iteration: objective per set
    noise: np.ndarray | None = None  # the optimised initial noise (count, 2, k, k)


def optimise_noise(net: torch.nn.Module, *, schedule: dict, offset_scale: float,
                   embedding: str, n: int, count: int = 1,
                   objective: str | Objective = "l2_star", steps: int = 50,
                   iterations: int = 100, lr: float = 0.05, step_noise: bool = False,
                   seed: int = 0, use_checkpoint: bool = True,
                   callback: Callable[[int, torch.Tensor], None] | None = None,
                   ) -> OptimiseResult:
    """Optimise the reverse process's input noise of a frozen net for ``objective``.

    Parameters
    ----------
    net : torch.nn.Module
        The denoiser eps(x, t) (e.g. from :func:`trainer.train.model_from_checkpoint`).
    schedule, offset_scale, embedding
        The model's noise schedule, offset scale and grid embedding (its config / card).
    n : int
        Points per set, a perfect square k*k.
    count : int
        Sets optimised together (each has its own noise; the objective is summed).
    objective : {"l2_star", "ot_proxy"} or callable
        Minimised; a callable maps (count, n, 2) float64 points in [0, 1]^2 to (count,) values.
    steps : int
        DDIM (or DDPM with ``step_noise``) steps of the differentiable reverse process.
    iterations, lr
        Adam iterations and learning rate on the noise.
    step_noise : bool
        Also optimise every step's noise (DDPM, eta = 1) instead of only the initial one.
    seed : int
        Seeds the initial noise (and the ot_proxy's directions).
    use_checkpoint : bool
        Gradient checkpointing per step (bounded memory); off is faster for small sets.

    Returns
    -------
    OptimiseResult
    """
    k = math.isqrt(n)
    if isinstance(n, bool) or not isinstance(n, int) or k * k != n or k < 4:
        raise ValueError(f"n must be a perfect square k*k with k >= 4, got {n!r}")
    if isinstance(count, bool) or not isinstance(count, int) or count < 1:
        raise ValueError(f"count must be a positive integer, got {count!r}")
    if isinstance(iterations, bool) or not isinstance(iterations, int) or iterations < 0:
        raise ValueError(f"iterations must be a non-negative integer, got {iterations!r}")
    if not (isinstance(lr, (int, float)) and lr > 0):
        raise ValueError(f"lr must be positive, got {lr!r}")
    if isinstance(objective, str):
        if objective not in OBJECTIVES:
            raise ValueError(f"unknown objective {objective!r}; choose one of "
                             f"{list(OBJECTIVES)} or pass a callable")
        name = objective
        objective = OBJECTIVES[objective]
    else:
        name = getattr(objective, "__name__", "callable")
    # the net runs in float32 (as trained and exported); objectives see float64 points
    alpha_bar = torch.tensor(alphas_cumprod(schedule), dtype=torch.float32)
    T = len(alpha_bar)
    if isinstance(steps, bool) or not isinstance(steps, int) or not 1 <= steps <= T:
        raise ValueError(f"steps must be an integer in [1, {T}], got {steps!r}")
    ts = timesteps(T, steps)
    net = net.float().eval()
    for p in net.parameters():
        p.requires_grad_(False)
    gen = torch.Generator().manual_seed(seed)
    z = torch.randn((count, 2, k, k), generator=gen).requires_grad_(True)
    params = [z]
    noises = None
    if step_noise:
        noises = torch.randn((len(ts) - 1, count, 2, k, k), generator=gen).requires_grad_(True)
        params.append(noises)
    opt = torch.optim.Adam(params, lr=lr)
    stratified = embedding == "stratified"
    ot_gen = torch.Generator().manual_seed(seed + 1)

    def points() -> torch.Tensor:
        return decode_torch(reverse(net, z, alpha_bar, ts, noises, use_checkpoint).double(),
                            offset_scale, stratified)

    def evaluate(p: torch.Tensor) -> torch.Tensor:
        if objective is sliced_ot_uniform:
            return sliced_ot_uniform(p, generator=ot_gen)
        return objective(p)

    trajectory = []
    initial = None
    for it in range(iterations + 1):
        t0 = time.perf_counter()
        with torch.set_grad_enabled(it < iterations):
            p = points()
            values = evaluate(p)
        if initial is None:
            initial = p.detach().numpy().copy()
        trajectory.append({"iteration": it, "objective": name,
                           "mean": float(values.detach().mean()), "per_set": values.detach().tolist()})
        if callback is not None:
            callback(it, values.detach())
        if it == iterations:
            break
        opt.zero_grad()
        values.sum().backward()
        opt.step()
        trajectory[-1]["seconds"] = time.perf_counter() - t0
    return OptimiseResult(points=p.detach().numpy().astype(np.float64),
                          initial_points=initial, trajectory=trajectory,
                          noise=z.detach().numpy())
