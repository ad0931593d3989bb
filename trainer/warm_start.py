"""Rebuild a torch U-Net from an exported diffsampler ONNX file.

Exported files keep every network weight as an initializer named after its torch
state-dict key (stored as fp16 with a ``__fp16`` suffix when the weights were halved), and
the card keeps the training config, so a bundled model can be fine-tuned or distilled
without its training checkpoint.
"""
from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np
import torch

from .config import TrainConfig
from .unet import UNet

FP16_SUFFIX = "__fp16"


class MissingWeightsError(ValueError):
    """The file holds no tensor for some of the network's parameters (the exporter stores
    equal tensors once: a barely trained net's still-equal initial weights share one)."""


def _folded_constants(model, every_use: bool) -> list[tuple[str, np.ndarray]]:
    """The (C, 1, 1) constants the graph's nodes read, in execution order: at each use, or
    at the first use of each only."""
    from onnx import numpy_helper

    inits = {i.name: i for i in model.graph.initializer}
    consts: list[tuple[str, np.ndarray]] = []
    seen: set[str] = set()
    for node in model.graph.node:
        for name in node.input:
            if name in inits and (every_use or name not in seen) and len(inits[name].dims) == 3:
                seen.add(name)
                consts.append((node.op_type, numpy_helper.to_array(inits[name])))
    return consts


def _group_norms(model, net: UNet, found: dict[str, np.ndarray]) -> None:
    """Recover GroupNorm affine weights, which the exporter folds into (C, 1, 1) constants.

    The decomposed GroupNorm ends in ``Mul(weight)`` then ``Add(bias)``; the graph is in
    execution order, so the n-th such pair belongs to the n-th GroupNorm the forward
    pass calls. A barely trained net's equal constants (weights still 1, biases 0) are
    stored once and read by several layers: they are counted at each use.
    """
    order: list[str] = []
    hooks = [mod.register_forward_hook(lambda m, i, o, name=name: order.append(name))
             for name, mod in net.named_modules() if isinstance(mod, torch.nn.GroupNorm)]
    with torch.no_grad():
        net(torch.zeros(1, 2, 8, 8), torch.zeros(1))
    for h in hooks:
        h.remove()
    consts = _folded_constants(model, every_use=True)
    if len(consts) != 2 * len(order):  # another constant read twice: count first uses
        consts = _folded_constants(model, every_use=False)
    if len(consts) != 2 * len(order):
        raise ValueError(f"found {len(consts)} folded norm constants for {len(order)} "
                         "GroupNorm layers")
    for j, name in enumerate(order):
        (op_w, w), (op_b, b) = consts[2 * j], consts[2 * j + 1]
        if (op_w, op_b) != ("Mul", "Add"):
            raise ValueError(f"unexpected ops {op_w}, {op_b} for {name}")
        found[f"{name}.weight"] = w.reshape(-1).astype(np.float32)
        found[f"{name}.bias"] = b.reshape(-1).astype(np.float32)


def net_from_onnx(path: str | Path) -> tuple[UNet, TrainConfig, dict[str, Any]]:
    """(network in eval mode with float32 weights, its training config, its model card).

    Raises ``ValueError`` if the file's weights do not match the architecture its card
    describes.
    """
    import onnx
    from onnx import numpy_helper

    from diffsampler_rt.card import CARD_KEY

    model = onnx.load(str(path))
    meta = {p.key: p.value for p in model.metadata_props}
    if CARD_KEY not in meta:
        raise ValueError(f"{path} has no diffsampler model card")
    card = json.loads(meta[CARD_KEY])
    if card.get("weights") == "int8":
        raise ValueError(f"{path} has 8-bit quantised convolutions (python -m export quantize); "
                         "start from the float model it was quantised from")
    cfg = TrainConfig.from_dict(card["config"])
    net = UNet(cfg.unet)
    wanted = net.state_dict()
    found: dict[str, np.ndarray] = {}
    for init in model.graph.initializer:
        name = init.name[: -len(FP16_SUFFIX)] if init.name.endswith(FP16_SUFFIX) else init.name
        if name in wanted:
            found[name] = numpy_helper.to_array(init).astype(np.float32)
    _group_norms(model, net, found)
    missing = sorted(set(wanted) - set(found))
    if missing:
        raise MissingWeightsError(f"{path}: weights missing for {len(missing)} parameters "
                         f"(first: {missing[:3]})")
    state = {}
    for name, ref in wanted.items():
        if tuple(found[name].shape) != tuple(ref.shape):
            raise ValueError(f"{path}: {name} has shape {found[name].shape}, "
                             f"the card's architecture needs {tuple(ref.shape)}")
        state[name] = torch.from_numpy(found[name])
    net.load_state_dict(state)
    return net.eval(), cfg, card
