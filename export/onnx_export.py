"""torch U-Net -> ONNX with dynamic batch and grid side, weights optionally stored as fp16.

The file is self-contained (no ``.onnx.data`` side file) and carries a JSON model card in
its metadata (key ``diffsampler.card``): everything :mod:`diffsampler_rt` needs to run it.
"""
from __future__ import annotations

import datetime as _dt
import json
import warnings
from pathlib import Path
from typing import Any

import numpy as np
import onnx
import torch
from onnx import helper, numpy_helper

from diffsampler_rt.card import CARD_KEY, FORMAT_KEY, FORMAT_VERSION, describe_devices
from trainer.config import TrainConfig
from trainer.density import OLD_FLOOR
from trainer.train import load_checkpoint, model_from_checkpoint
from trainer.unet import UNet

OPSET = 19  # circular padding exports as Pad(mode=wrap), valid from opset 19
MIN_SIDE = 4

DEFAULT_LICENCE = ("MIT. Weights trained by diffsampler from synthetic point sets made by "
                   "its own reference samplers; no third-party data.")


def model_card(cfg: TrainConfig, *, training_steps: int, train_seconds: float | None = None,
               train_devices: list[str] | None = None,
               weights: str = "fp32", parameters: int | None = None,
               extra: dict[str, Any] | None = None) -> dict[str, Any]:
    """The metadata the runtime needs, plus provenance. All values are JSON."""
    card = {
        "format_version": FORMAT_VERSION,
        "name": cfg.name,
        "sampler": cfg.data.sampler,
        "embedding": cfg.data.embedding,
        "offset_scale": cfg.data.offset_scale,
        "padding": cfg.unet.padding,
        "prediction": "eps",
        "schedule": dict(cfg.schedule),
        "training_steps": int(training_steps),
        "train_seconds": None if train_seconds is None else round(float(train_seconds)),
        "train_devices": list(train_devices or ["cpu"]),
        "parameters": parameters,
        "trained_sizes": [k * k for k in cfg.data.sizes],
        "trained_sides": list(cfg.data.sizes),
        "min_side": MIN_SIDE,
        "default_steps": cfg.default_sample_steps,
        "default_solver": cfg.default_solver,
        "weights": weights,
        # what runs after the network: thinning to n only, until the fit's calibration or
        # `python -m export pipeline` adds steps
        "pipeline": [{"step": "thin", "drop": "random"}],
        "inputs": {"x": "float32 (batch, 2, k, k) noisy scaled offsets",
                   "t": "float32 (batch,) timestep index in [0, T)"},
        "outputs": {"eps": "float32 (batch, 2, k, k) predicted noise"},
        "licence": DEFAULT_LICENCE,
        "provenance": (f"trained with `python -m trainer train` (config below) for "
                       f"{training_steps} steps"
                       + (f", {train_seconds / 60:.0f} min on "
                          + describe_devices(train_devices)
                          if train_seconds else "")
                       + (f", starting from the weights of {cfg.init_from} (an earlier "
                          "training stage, exported)" if cfg.init_from else "")
                       + f"; exported {_dt.date.today().isoformat()}"),
        "config": cfg.to_dict(),
    }
    if extra:
        card.update(extra)
    return card


def _weights_to_fp16(model: onnx.ModelProto, names: set[str],
                     min_size: int = 16) -> onnx.ModelProto:
    """Store the float32 initializers in ``names`` as float16, each followed by a Cast back.

    Halves the file; compute stays in float32, so speed is unchanged. Only the network's
    own weights are converted: constants the exporter folded (e.g. the sinusoidal
    frequencies) keep full precision.
    """
    graph = model.graph
    casts = []
    keep = []
    for init in graph.initializer:
        arr = numpy_helper.to_array(init)
        if (init.name in names and init.data_type == onnx.TensorProto.FLOAT
                and arr.size >= min_size):
            half = numpy_helper.from_array(arr.astype(np.float16), init.name + "__fp16")
            keep.append(half)
            casts.append(helper.make_node("Cast", [half.name], [init.name],
                                          to=onnx.TensorProto.FLOAT,
                                          name=init.name + "__cast"))
        else:
            keep.append(init)
    del graph.initializer[:]
    graph.initializer.extend(keep)
    nodes = list(graph.node)
    del graph.node[:]
    graph.node.extend(casts + nodes)
    return model


def round_to_fp16(net: torch.nn.Module) -> None:
    """Round parameters and buffers to the nearest fp16 value in place (stay float32)."""
    with torch.no_grad():
        for p in list(net.parameters()) + list(net.buffers()):
            if p.is_floating_point():
                p.copy_(p.half().float())


def export_model(net: UNet, card: dict[str, Any], path: str | Path, *,
                 fp16_weights: bool = False) -> Path:
    """Export ``net`` to ``path`` with dynamic batch and grid side and ``card`` as metadata.

    With ``fp16_weights`` the caller should have applied :func:`round_to_fp16` first so
    that the torch model and the file compute the same function.
    """
    path = Path(path)
    net = net.eval()
    x = torch.randn(2, 2, 8, 8)  # batch >= 2: a batch of 1 would be specialised away
    t = torch.tensor([1.0, 500.0])
    batch = torch.export.Dim("batch", min=1, max=65536)
    side = torch.export.Dim("k", min=MIN_SIDE, max=4096)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        program = torch.onnx.export(
            net, (x, t), dynamo=True, opset_version=OPSET, input_names=["x", "t"],
            output_names=["eps"], external_data=False, verbose=False,
            dynamic_shapes={"x": {0: batch, 2: side, 3: side}, "t": {0: batch}})
    model = program.model_proto
    for node in model.graph.node:  # torch's per-node stack traces: ~0.5 MB of debug text
        del node.metadata_props[:]
    if fp16_weights:
        model = _weights_to_fp16(model, set(net.state_dict()))
    card = dict(card, weights="fp16" if fp16_weights else "fp32")
    helper.set_model_props(model, {FORMAT_KEY: str(FORMAT_VERSION),
                                   CARD_KEY: json.dumps(card, sort_keys=True)})
    onnx.checker.check_model(model)
    path.parent.mkdir(parents=True, exist_ok=True)
    onnx.save_model(model, str(path), save_as_external_data=False)
    return path


def export_checkpoint(checkpoint: str | Path, path: str | Path, *, fp16_weights: bool = True,
                      parity_sides: tuple[int, ...] | None = (8, 24, 25, 32, 64),
                      tolerance: float = 1e-4) -> tuple[Path, dict[int, float]]:
    """Export the EMA weights of a training checkpoint and check parity with torch.

    Returns the path and the max abs difference per checked side; raises
    :class:`export.ParityError` above ``tolerance``.
    """
    from .parity import check_parity

    state = load_checkpoint(checkpoint)
    net, cfg = model_from_checkpoint(state, ema=True)
    if fp16_weights:
        round_to_fp16(net)
    # distilled students (trainer.distil) carry their teacher's training figures and a
    # ``distillation`` record for the card
    card = model_card(cfg, training_steps=state.get("training_steps", state["step"]),
                      train_seconds=state.get("train_seconds", state.get("elapsed_s")),
                      train_devices=state.get("devices"),
                      parameters=sum(p.numel() for p in net.parameters()),
                      extra=state.get("card_extra"))
    if state.get("density") is not None:  # non-uniform: the runtime maps the sets back
        card["density"] = state["density"]
        # the table's floor (trainer.density.FLOOR), which `python -m export density-floor`
        # can change; configs from before the field had OLD_FLOOR
        card["density_floor"] = state["config"]["data"].get("density_floor", OLD_FLOOR)
    out = export_model(net, card, path, fp16_weights=fp16_weights)
    diffs = check_parity(net, out, sides=parity_sides, tolerance=tolerance) if parity_sides else {}
    return out, diffs
