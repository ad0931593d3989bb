"""A DDPM U-Net for offset grids of any side k >= 4 (odd sides included).

ResNet blocks with GroupNorm and a sinusoidal time embedding, optional multi-head
self-attention per level, stride-2 convolutions down (ceil(k/2)) and nearest-neighbour
resampling back up to each skip's exact size, so any k works. Architecture only: the
diffusion maths lives in :mod:`trainer.diffusion`.
"""
from __future__ import annotations

import math
from dataclasses import asdict, dataclass

import torch
import torch.nn.functional as F
from torch import nn

PADDINGS = ("zeros", "circular")


@dataclass(frozen=True)
class UNetConfig:
    """Architecture settings; saved in checkpoints and in the exported model card."""

    base_channels: int = 32
    channel_mult: tuple[int, ...] = (1, 2, 2)
    num_res_blocks: int = 2
    #: levels (0 = full resolution) whose res blocks are followed by self-attention.
    #: The seed paper put attention at every level; full-resolution attention is what
    #: makes large grids slow, so the default keeps it to the coarsest level.
    attention_levels: tuple[int, ...] = (2,)
    middle_attention: bool = True
    #: levels whose res blocks are followed by axial attention: each cell attends to its
    #: row, then to its column (O(k^3), cheap at full resolution). Net structure constrains
    #: whole rows and columns of cells (every 1/n strip holds one point).
    axial_levels: tuple[int, ...] = ()
    num_heads: int = 4
    #: self-attention (not axial) attends within windows of at most this many cells per
    #: side: a grid side h <= window is one window (plain global attention), a larger one
    #: is cut into ceil(h / window) near-equal windows per side. Keeps attention linear in
    #: n on big grids, and every window the size the net saw in training. None: global.
    attention_window: int | None = None
    padding: str = "zeros"
    #: extra input channels: bits 0..coord_bits-1 of each cell's column and row index,
    #: as +-1, telling the net where a cell sits in the dyadic hierarchy (net structure).
    coord_bits: int = 0
    groups: int = 8

    def __post_init__(self) -> None:
        if self.padding not in PADDINGS:
            raise ValueError(f"padding must be one of {PADDINGS}, got {self.padding!r}")
        for name in ("attention_levels", "axial_levels"):
            levels = tuple(getattr(self, name))
            if any(not 0 <= l < len(self.channel_mult) for l in levels):
                raise ValueError(f"{name} {levels} outside 0..{len(self.channel_mult) - 1}")
            object.__setattr__(self, name, levels)
        object.__setattr__(self, "channel_mult", tuple(self.channel_mult))
        if self.attention_window is not None and self.attention_window < 1:
            raise ValueError(f"attention_window must be >= 1 or None, got {self.attention_window}")

    def to_dict(self) -> dict:
        return asdict(self)


def timestep_embedding(t: torch.Tensor, dim: int, max_period: float = 10000.0) -> torch.Tensor:
    """Sinusoidal embedding of (B,) float timesteps -> (B, dim)."""
    half = dim // 2
    freqs = torch.exp(-math.log(max_period) * torch.arange(half, dtype=torch.float32,
                                                           device=t.device) / half)
    args = t.float()[:, None] * freqs[None, :]
    return torch.cat([torch.cos(args), torch.sin(args)], dim=1)


def _conv(cin: int, cout: int, padding: str, stride: int = 1) -> nn.Conv2d:
    return nn.Conv2d(cin, cout, 3, stride=stride, padding=1, padding_mode=padding)


class ResBlock(nn.Module):
    def __init__(self, cin: int, cout: int, temb: int, padding: str, groups: int):
        super().__init__()
        self.norm1 = nn.GroupNorm(groups, cin)
        self.conv1 = _conv(cin, cout, padding)
        self.temb = nn.Linear(temb, cout)
        self.norm2 = nn.GroupNorm(groups, cout)
        self.conv2 = _conv(cout, cout, padding)
        nn.init.zeros_(self.conv2.weight)  # start as identity: stabilises early training
        nn.init.zeros_(self.conv2.bias)
        self.skip = nn.Conv2d(cin, cout, 1) if cin != cout else nn.Identity()

    def forward(self, x: torch.Tensor, emb: torch.Tensor) -> torch.Tensor:
        h = self.conv1(F.silu(self.norm1(x)))
        h = h + self.temb(F.silu(emb))[:, :, None, None]
        h = self.conv2(F.silu(self.norm2(h)))
        return self.skip(x) + h


class Attention(nn.Module):
    """Multi-head self-attention over all cells of the grid, or within windows of it."""

    def __init__(self, ch: int, heads: int, groups: int, window: int | None = None):
        super().__init__()
        self.heads = heads
        self.window = window
        self.norm = nn.GroupNorm(groups, ch)
        self.qkv = nn.Conv2d(ch, 3 * ch, 1)
        self.proj = nn.Conv2d(ch, ch, 1)
        nn.init.zeros_(self.proj.weight)
        nn.init.zeros_(self.proj.bias)

    def _attend(self, qkv: torch.Tensor, c: int, bias: torch.Tensor | None) -> torch.Tensor:
        b = qkv.shape[0]  # qkv: (b, 3c, tokens) -> (b, c, tokens)
        qkv = qkv.reshape(b, 3, self.heads, c // self.heads, -1)
        q, k, v = qkv[:, 0], qkv[:, 1], qkv[:, 2]  # (b, heads, d, tokens)
        scale = (c // self.heads) ** -0.5
        logits = torch.einsum("bndi,bndj->bnij", q * scale, k)
        if bias is not None:
            logits = logits + bias
        attn = torch.softmax(logits, dim=-1)
        return torch.einsum("bnij,bndj->bndi", attn, v).reshape(b, c, -1)

    def forward(self, x: torch.Tensor, emb: torch.Tensor | None = None) -> torch.Tensor:
        b, c, h, w = x.shape
        qkv = self.qkv(self.norm(x))
        if self.window is None:
            out = self._attend(qkv.reshape(b, 3 * c, h * w), c, None)
            return x + self.proj(out.reshape(b, c, h, w))
        # m x m windows of side s (grids are square): m = 1 is exactly global attention
        m = (h + self.window - 1) // self.window
        s = (h + m - 1) // m
        pad = m * s - h
        qkv = F.pad(qkv, (0, pad, 0, pad))
        win = (qkv.reshape(b, 3 * c, m, s, m, s).permute(0, 2, 4, 1, 3, 5)
               .reshape(b * m * m, 3 * c, s * s))
        # padded cells may not be attended to
        idx = torch.arange(m * s, device=x.device)
        valid = (idx < h).reshape(m, s)
        keys = (valid[:, None, :, None] & valid[None, :, None, :]).reshape(m * m, s * s)
        bias = torch.where(keys, 0.0, -1e9).to(x.dtype)
        bias = bias[None].expand(b, -1, -1).reshape(b * m * m, 1, 1, s * s)
        out = self._attend(win, c, bias)
        out = (out.reshape(b, m, m, c, s, s).permute(0, 3, 1, 4, 2, 5)
               .reshape(b, c, m * s, m * s))[:, :, :h, :w]
        return x + self.proj(out)


class AxialAttention(nn.Module):
    """Multi-head self-attention within each row of cells, then within each column."""

    def __init__(self, ch: int, heads: int, groups: int):
        super().__init__()
        self.heads = heads
        self.norms = nn.ModuleList([nn.GroupNorm(groups, ch) for _ in range(2)])
        self.qkvs = nn.ModuleList([nn.Conv2d(ch, 3 * ch, 1) for _ in range(2)])
        self.projs = nn.ModuleList([nn.Conv2d(ch, ch, 1) for _ in range(2)])
        for p in self.projs:
            nn.init.zeros_(p.weight)
            nn.init.zeros_(p.bias)

    def _rows(self, x: torch.Tensor, i: int) -> torch.Tensor:
        b, c, h, w = x.shape
        qkv = self.qkvs[i](self.norms[i](x)).reshape(b, 3, self.heads, c // self.heads, h, w)
        q, k, v = qkv[:, 0], qkv[:, 1], qkv[:, 2]  # (b, heads, d, h, w)
        scale = (c // self.heads) ** -0.5
        attn = torch.softmax(torch.einsum("bndhi,bndhj->bnhij", q * scale, k), dim=-1)
        out = torch.einsum("bnhij,bndhj->bndhi", attn, v).reshape(b, c, h, w)
        return x + self.projs[i](out)

    def forward(self, x: torch.Tensor, emb: torch.Tensor | None = None) -> torch.Tensor:
        x = self._rows(x, 0)
        return self._rows(x.transpose(2, 3), 1).transpose(2, 3)


class UNet(nn.Module):
    """eps-prediction U-Net: (B, 2, k, k) noisy offsets and (B,) timesteps -> (B, 2, k, k)."""

    def __init__(self, cfg: UNetConfig):
        super().__init__()
        self.cfg = cfg
        ch = cfg.base_channels
        temb = 4 * ch
        self.time_mlp = nn.Sequential(nn.Linear(ch, temb), nn.SiLU(), nn.Linear(temb, temb))
        self.stem = _conv(2 + 4 * cfg.coord_bits, ch, cfg.padding)
        blk = dict(temb=temb, padding=cfg.padding, groups=cfg.groups)

        self.down = nn.ModuleList()
        skips = [ch]
        cur = ch
        for level, mult in enumerate(cfg.channel_mult):
            for _ in range(cfg.num_res_blocks):
                layers = [ResBlock(cur, ch * mult, **blk)]
                cur = ch * mult
                if level in cfg.attention_levels:
                    layers.append(Attention(cur, cfg.num_heads, cfg.groups, cfg.attention_window))
                if level in cfg.axial_levels:
                    layers.append(AxialAttention(cur, cfg.num_heads, cfg.groups))
                self.down.append(nn.ModuleList(layers))
                skips.append(cur)
            if level < len(cfg.channel_mult) - 1:
                self.down.append(nn.ModuleList([_conv(cur, cur, cfg.padding, stride=2)]))
                skips.append(cur)

        self.middle = nn.ModuleList([ResBlock(cur, cur, **blk)]
                                    + ([Attention(cur, cfg.num_heads, cfg.groups, cfg.attention_window)]
                                       if cfg.middle_attention else [])
                                    + [ResBlock(cur, cur, **blk)])

        self.up = nn.ModuleList()
        for level, mult in reversed(list(enumerate(cfg.channel_mult))):
            for i in range(cfg.num_res_blocks + 1):
                layers = [ResBlock(cur + skips.pop(), ch * mult, **blk)]
                cur = ch * mult
                if level in cfg.attention_levels:
                    layers.append(Attention(cur, cfg.num_heads, cfg.groups, cfg.attention_window))
                if level in cfg.axial_levels:
                    layers.append(AxialAttention(cur, cfg.num_heads, cfg.groups))
                if level > 0 and i == cfg.num_res_blocks:
                    layers.append(_conv(cur, cur, cfg.padding))  # after upsampling
                self.up.append(nn.ModuleList(layers))
        self.out_norm = nn.GroupNorm(cfg.groups, cur)
        self.out = _conv(cur, 2, cfg.padding)
        nn.init.zeros_(self.out.weight)
        nn.init.zeros_(self.out.bias)

    def _coords(self, x: torch.Tensor) -> torch.Tensor:
        b, _, h, w = x.shape
        # float floor/remainder rather than integer shifts: they export to ONNX
        scale = 2.0 ** torch.arange(self.cfg.coord_bits, device=x.device, dtype=torch.float32)

        def bits(n: int) -> torch.Tensor:  # (coord_bits, n) of +-1
            i = torch.arange(n, device=x.device, dtype=torch.float32)
            return torch.remainder(torch.floor(i[None, :] / scale[:, None]), 2.0) * 2 - 1

        col, row = bits(w), bits(h)
        cols = col[:, None, :].expand(-1, h, -1)
        rows = row[:, :, None].expand(-1, -1, w)
        # for both orientations so a transposed grid sees the same kind of input
        grid = torch.cat([cols, rows, cols * rows, -cols * rows], dim=0)
        return grid[None].expand(b, -1, -1, -1)

    def forward(self, x: torch.Tensor, t: torch.Tensor) -> torch.Tensor:
        emb = self.time_mlp(timestep_embedding(t, self.cfg.base_channels))
        if self.cfg.coord_bits:
            x = torch.cat([x, self._coords(x)], dim=1)
        h = self.stem(x)
        hs = [h]
        for layers in self.down:
            for layer in layers:
                h = layer(h, emb) if not isinstance(layer, nn.Conv2d) else layer(h)
            hs.append(h)
        for layer in self.middle:
            h = layer(h, emb)
        for layers in self.up:
            h = torch.cat([h, hs.pop()], dim=1)
            for layer in layers:
                if isinstance(layer, nn.Conv2d):  # upsample to the next skip's exact size
                    h = layer(F.interpolate(h, size=hs[-1].shape[-2:], mode="nearest"))
                else:
                    h = layer(h, emb)
        return self.out(F.silu(self.out_norm(h)))


def widen_stem(w: torch.Tensor, bits: int, new_bits: int) -> torch.Tensor:
    """Stem weights for ``new_bits`` coordinate bits from a net with ``bits`` (< new_bits):
    the new channels get zero weights, so a warm-started net computes the same function at
    step 0 and learns what the added bits are worth."""
    # input channels as UNet.forward stacks them: 2 offsets, then the 4 groups of
    # UNet._coords (cols, rows, cols*rows, -cols*rows) of coord_bits each
    out, _, kh, kw = w.shape
    wide = w.new_zeros((out, 4, new_bits, kh, kw))
    wide[:, :, :bits] = w[:, 2:].reshape(out, 4, bits, kh, kw)
    return torch.cat([w[:, :2], wide.reshape(out, 4 * new_bits, kh, kw)], dim=1)
