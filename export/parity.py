"""torch vs onnxruntime parity of an exported denoiser."""
from __future__ import annotations

from pathlib import Path

import numpy as np
import onnxruntime as ort
import torch


class ParityError(AssertionError):
    """The exported graph does not compute what the torch model computes."""


def check_parity(net: torch.nn.Module, path: str | Path,
                 sides: tuple[int, ...] = (8, 24, 25, 32, 64), batch: int = 3,
                 tolerance: float = 1e-4, seed: int = 0) -> dict[int, float]:
    """Max abs difference of eps between torch and onnxruntime per grid side.

    Raises :class:`ParityError` naming the side when a difference exceeds ``tolerance``.
    """
    sess = ort.InferenceSession(str(path), providers=["CPUExecutionProvider"])
    gen = torch.Generator().manual_seed(seed)
    diffs: dict[int, float] = {}
    for k in sides:
        x = torch.randn(batch, 2, k, k, generator=gen)
        t = torch.linspace(0, 999, batch)
        with torch.no_grad():
            ref = net(x, t).numpy()
        got = sess.run(["eps"], {"x": x.numpy(), "t": t.numpy()})[0]
        if got.shape != ref.shape:
            raise ParityError(f"k={k}: onnxruntime output shape {got.shape} != torch {ref.shape}")
        diffs[k] = float(np.max(np.abs(got - ref)))
        if not np.isfinite(diffs[k]) or diffs[k] > tolerance:
            raise ParityError(f"k={k}: max |torch - onnxruntime| = {diffs[k]:.3g} "
                              f"exceeds tolerance {tolerance:g}")
    return diffs
