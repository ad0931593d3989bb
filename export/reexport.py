"""Re-export an exported model with a changed attention window, keeping its card.

The weights come back from the ONNX file itself (:func:`trainer.warm_start.net_from_onnx`),
so a bundled model can adopt windowed attention without its training checkpoint. Windows of
``w`` cells per side leave every grid whose attention level is at most ``w`` cells wide
computing exactly what it computed before (the attention is global there).
"""
from __future__ import annotations

import dataclasses
import datetime as _dt
from pathlib import Path

from trainer.unet import UNet
from trainer.warm_start import net_from_onnx

from .onnx_export import export_model
from .parity import check_parity


def reexport(src: str | Path, dst: str | Path, *, attention_window: int | None,
             parity_sides: tuple[int, ...] = (8, 24, 25, 32, 64, 100),
             tolerance: float = 1e-4) -> tuple[Path, dict[int, float]]:
    """Write ``src``'s network to ``dst`` with ``attention_window`` (None: global attention).

    Returns the path and torch-vs-onnxruntime max abs difference per checked side.
    """
    net, cfg, card = net_from_onnx(src)
    unet = dataclasses.replace(cfg.unet, attention_window=attention_window)
    new = UNet(unet)
    new.load_state_dict(net.state_dict())
    new.eval()
    card = dict(card)
    card["config"] = dict(card["config"], unet=unet.to_dict())
    note = (f"; re-exported {_dt.date.today().isoformat()} with "
            + (f"attention windows of {attention_window} cells" if attention_window
               else "global attention"))
    card["provenance"] = card.get("provenance", "") + note
    fp16 = card.get("weights") == "fp16"  # the recovered weights are fp16 values already
    out = export_model(new, card, dst, fp16_weights=fp16)
    diffs = check_parity(new, out, sides=parity_sides, tolerance=tolerance) if parity_sides else {}
    return out, diffs
