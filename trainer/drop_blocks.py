"""Cut a trained U-Net to fewer res blocks a level, keeping the weights of the blocks left.

A student with fewer res blocks than its teacher's net is faster a step; started from the
trained net with its extra blocks dropped instead of from fresh weights, it begins close to
what it must learn (its first distillation losses are far below a fresh net's).

Which blocks stay: on each down level the first ``num_res_blocks``; on each up level the
first ``num_res_blocks`` and the last, which reads the skip of the level's downsampling (or
the stem) and upsamples. Every kept block then sees inputs of the channel counts it was
trained on. Everything outside the down and up lists (time embedding, stem, middle, output)
is kept as it is.
"""
from __future__ import annotations

from dataclasses import replace

from .unet import UNet


def kept_blocks(levels: int, have: int, keep: int) -> tuple[dict[int, int], dict[int, int]]:
    """For a net of ``levels`` levels cut from ``have`` to ``keep`` res blocks a level: the
    index in the cut net's ``down`` and ``up`` lists -> the index in the full net's."""
    if not 1 <= keep <= have:
        raise ValueError(f"can keep 1 to {have} res blocks a level, not {keep}")
    down: dict[int, int] = {}
    up: dict[int, int] = {}
    s = t = 0
    for level in range(levels):
        for b in range(keep):
            down[s + b] = t + b
        s, t = s + keep, t + have
        if level < levels - 1:  # the downsampling conv
            down[s] = t
            s, t = s + 1, t + 1
    s = t = 0
    for _ in range(levels):
        for b in range(keep):
            up[s + b] = t + b
        up[s + keep] = t + have  # the last block: the downsampling's skip, the upsampling
        s, t = s + keep + 1, t + have + 1
    return down, up


def drop_res_blocks(net: UNet, num_res_blocks: int) -> UNet:
    """A new U-Net like ``net`` with ``num_res_blocks`` res blocks a level, holding ``net``'s
    weights for the blocks kept (see the module docstring).

    Examples
    --------
    >>> from trainer.unet import UNet, UNetConfig
    >>> full = UNet(UNetConfig(base_channels=8, channel_mult=(1, 2), num_res_blocks=2,
    ...                        attention_levels=(1,), num_heads=1, groups=4))
    >>> cut = drop_res_blocks(full, 1)
    >>> cut.cfg.num_res_blocks, len(cut.down), len(full.down)
    (1, 3, 5)
    """
    cfg = replace(net.cfg, num_res_blocks=num_res_blocks)
    down, up = kept_blocks(len(cfg.channel_mult), net.cfg.num_res_blocks, num_res_blocks)
    src = net.state_dict()
    cut = UNet(cfg)
    weights = {}
    for key in cut.state_dict():
        part, rest = key.split(".", 1)
        if part in ("down", "up"):
            index, tail = rest.split(".", 1)
            key_in_net = f"{part}.{(down if part == 'down' else up)[int(index)]}.{tail}"
        else:
            key_in_net = key
        weights[key] = src[key_in_net]
    cut.load_state_dict(weights)  # strict: every tensor found and of the same shape
    return cut
