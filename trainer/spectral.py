"""The radial power spectrum in torch, differentiable in the points.

The same figure as :func:`diffsampler_rt.spectrum.radial_spectrum` (the seed paper's
convention: P(f) = |sum_j exp(-2 pi i f . x_j)|^2 / n at integer f != 0, radial bins of
width sqrt(n) / 16), for its first bins only: a distillation loss
(:mod:`trainer.distil`, ``spectrum_weight``) matches a student's mean spectrum to its
teacher's, where a per-set regression loss leaves the student's sets blurred.
"""
from __future__ import annotations

import math

import numpy as np
import torch

from diffsampler_rt.spectrum import BIN_WIDTH, NUM_BINS


class RadialSpectrum(torch.nn.Module):
    """Mean radial spectrum of batches of n-point sets, bins 1 .. ``bins`` (labels b / 16).

    Only the half plane f_y >= 0 is evaluated (P(f) = P(-f)); each frequency with f_y > 0
    stands for itself and its mirror, so the bin means are the full plane's.
    """

    def __init__(self, n: int, bins: int):
        super().__init__()
        if not 1 <= bins <= NUM_BINS:
            raise ValueError(f"bins must be in 1..{NUM_BINS}, got {bins}")
        root = math.sqrt(n)
        fmax = math.ceil((bins + 1) * BIN_WIDTH * root)
        fx = np.arange(-fmax, fmax + 1)
        fy = np.arange(0, fmax + 1)
        r = np.hypot(fy[:, None], fx[None, :]) / root
        b = np.floor(r / BIN_WIDTH + 1e-9).astype(np.int64)  # as the numpy figure
        weight = np.where(fy[:, None] > 0, 2.0, 1.0) * ((b >= 1) & (b <= bins))
        # (bins, Fy * Fx): each bin's weighted mean over its frequencies
        member = (b.ravel()[None, :] == np.arange(1, bins + 1)[:, None]) * weight.ravel()
        total = member.sum(axis=1, keepdims=True)
        member /= np.where(total > 0, total, 1.0)  # a bin with no frequency reads 0, as there
        self.n, self.bins = n, bins
        # float64, cast to the points' type at use: 2 pi f rounded to float32 first would
        # not give float64 points their float64 figure
        self.register_buffer("fx", torch.tensor(2 * np.pi * fx, dtype=torch.float64))
        self.register_buffer("fy", torch.tensor(2 * np.pi * fy, dtype=torch.float64))
        self.register_buffer("member", torch.tensor(member, dtype=torch.float64))

    def forward(self, points: torch.Tensor) -> torch.Tensor:
        """points (B, n, 2) -> the batch's mean radial spectrum, shape (bins,)."""
        if points.shape[-2:] != (self.n, 2):
            raise ValueError(f"points must have shape (B, {self.n}, 2), got {tuple(points.shape)}")
        fx, fy, member = (b.to(points.dtype) for b in (self.fx, self.fy, self.member))
        ax = fx[None, :, None] * points[:, None, :, 0]  # (B, Fx, n)
        ay = fy[None, :, None] * points[:, None, :, 1]  # (B, Fy, n)
        cx, sx, cy, sy = ax.cos(), ax.sin(), ay.cos(), ay.sin()
        cxt, sxt = cx.transpose(1, 2), sx.transpose(1, 2)
        re = cy @ cxt - sy @ sxt  # cos(ay + ax) summed over the points
        im = sy @ cxt + cy @ sxt
        power = (re ** 2 + im ** 2).mean(dim=0) / self.n  # (Fy, Fx)
        return member @ power.reshape(-1)


class AxisSpectrum(torch.nn.Module):
    """Mean power spectrum of a batch's coordinate projections, frequencies 1 .. ``count``.

    P(j) = |sum_i exp(-2 pi i j x_i)|^2 / n over each set's x and over its y coordinates,
    averaged over both and over the sets: the 2-d spectrum on its axes, f = (j, 0) and
    (0, j), which the radial bins mix with every other direction. It is what a set's
    projections carry, and what the star discrepancy L2* weighs most.
    """

    def __init__(self, n: int, count: int):
        super().__init__()
        if count < 1:
            raise ValueError(f"count must be >= 1, got {count}")
        self.n, self.count = n, count
        self.register_buffer("f", torch.tensor(2 * np.pi * np.arange(1, count + 1),
                                               dtype=torch.float64))

    def forward(self, points: torch.Tensor) -> torch.Tensor:
        """points (B, n, 2) -> the batch's mean axis spectrum, shape (count,)."""
        if points.shape[-2:] != (self.n, 2):
            raise ValueError(f"points must have shape (B, {self.n}, 2), got {tuple(points.shape)}")
        a = self.f.to(points.dtype)[None, :, None, None] * points[:, None, :, :]  # (B, J, n, 2)
        power = a.cos().sum(dim=2) ** 2 + a.sin().sum(dim=2) ** 2  # (B, J, 2)
        return power.mean(dim=(0, 2)) / self.n


def reflect(values: torch.Tensor) -> torch.Tensor:
    """:func:`diffsampler_rt.grid.reflect` in torch, differentiable (slope +-1): values
    folded into [0, 1] by reflection at 0 and 1."""
    v = torch.remainder(values.abs(), 2.0)
    return torch.where(v >= 1.0, 2.0 - v, v)


def grid_points(grid: torch.Tensor, *, stratified: bool = False,
                toroidal: bool = False) -> torch.Tensor:
    """Offsets (B, 2, k, k) in cell units -> points (B, k*k, 2), as
    :func:`diffsampler_rt.grid.decode` (row-major cells), differentiable: a stratified
    embedding's offsets reflected into their cells, other points reflected into the unit
    square, except on the torus, where they are left as they are (the spectrum is periodic:
    the same figure as the points taken modulo 1)."""
    k = grid.shape[-1]
    if stratified:
        grid = reflect(grid + 0.5) - 0.5
    centre = torch.arange(k, dtype=grid.dtype, device=grid.device) + 0.5
    x = (grid[:, 0] + centre[None, None, :]) / k
    y = (grid[:, 1] + centre[None, :, None]) / k
    pts = torch.stack([x, y], dim=-1).reshape(grid.shape[0], k * k, 2)
    return pts if stratified or toroidal else reflect(pts)
