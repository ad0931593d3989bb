"""Training-side diffusion maths: forward process and the eps-prediction loss.

The schedule itself comes from :mod:`diffsampler_rt.schedule` (the runtime's copy is the
single definition), so training and generation use identical alpha_bar values.
"""
from __future__ import annotations

from typing import Any, Mapping

import torch
from torch import nn

from diffsampler_rt.schedule import alphas_cumprod


class Diffusion:
    """DDPM forward process q(x_t | x_0) and the simple eps-MSE loss (Ho et al. 2020)."""

    def __init__(self, schedule: Mapping[str, Any]):
        self.schedule = dict(schedule)
        self.alpha_bar = torch.tensor(alphas_cumprod(schedule), dtype=torch.float32)
        self.num_steps = int(self.alpha_bar.shape[0])

    def q_sample(self, x0: torch.Tensor, t: torch.Tensor, eps: torch.Tensor) -> torch.Tensor:
        """x_t = sqrt(alpha_bar_t) x_0 + sqrt(1 - alpha_bar_t) eps  (eq. 4)."""
        ab = self.alpha_bar[t.cpu()].view(-1, 1, 1, 1).to(x0.device)
        return ab.sqrt() * x0 + (1 - ab).sqrt() * eps

    def loss(self, model: nn.Module, x0: torch.Tensor, gen: torch.Generator) -> torch.Tensor:
        """E_t,eps |eps - eps_theta(x_t, t)|^2 with t uniform over the T steps (eq. 14).

        ``t`` and ``eps`` come from the CPU generator ``gen`` whatever device ``x0`` is on,
        so a run draws the same noise on CPU and GPU (the arithmetic differs slightly).
        """
        t = torch.randint(0, self.num_steps, (x0.shape[0],), generator=gen)
        eps = torch.randn(x0.shape, generator=gen).to(x0.device)
        pred = model(self.q_sample(x0, t, eps), t.float().to(x0.device))
        return torch.mean((pred - eps) ** 2)
