"""Static 8-bit quantisation of an exported model's convolutions, calibrated on its own sampling.

On a 2-core x86 CPU the convolutions are over half of a denoiser evaluation
(benchmarks/results/ort_tuning.md); as QLinearConv (8-bit weights per output channel, 8-bit
activations) one evaluation costs about a third less. The activation ranges come from what
the network really sees: every denoiser input of the runtime's own solver, at the card's
default solver and steps, on the trained grid sides (min-max over those feeds), so the late,
nearly clean steps that fix the fine placement are covered, not only pure noise.

Measured choices (benchmarks/results/quantized.md has the numbers):

- the first convolution (2 input channels, cheap) and the last one (the eps head) stay
  float: quantising the head's output to 256 levels alone raised the Gaussian and Heaviside
  integration errors of gbn_fast by ~8 % at n = 1024, with it float they match the float
  model's to 0.1 %;
- a circular net's ``Pad(mode="wrap")`` nodes (export/wrap_pad.py) are moved after the
  QuantizeLinear they feed and written as Slice and Concat: the same values, bit for bit,
  copied as bytes in blocks, channels-last where only 8-bit convolutions read them
  (``python -m export channels-last-pads`` rewrites a file quantised without that);
- weights are unsigned 8-bit (asymmetric, per channel). x86 CPUs without VNNI multiply
  unsigned x signed bytes with an instruction that saturates, and onnxruntime's
  QLinearConv takes that route even for unsigned weights unless the session sets
  ``session.x64quantprecision`` (on an AVX2-only CPU without it, an 8-bit network's noise
  prediction is about twice as far off its float model's), so the
  runtime's sessions set it unless the CPU has VNNI
  (``diffsampler_rt.model.needs_exact_8bit``): with VNNI the fast kernel is exact, and the
  option, which still rewrites the weights for the slower unsigned x unsigned kernel, gave
  the same outputs at half the speed. 7-bit signed weights (``reduce_range``, the other
  cure) wrecked the sets (integration errors x4).

The card keeps everything it had and gains ``"weights": "int8"`` and a ``"quantization"``
record (method, calibration sides, sets and feeds, and the float network's short SHA-1, as
a distilled student records its teacher's). Whether the quantised model keeps its fidelity
is measured, not assumed: ``benchmarks/quantized.py`` compares it with its float model on
the same seeds, and the fidelity report measures it against the reference sampler.
"""
from __future__ import annotations

import datetime as _dt
import json
import math
import tempfile
from pathlib import Path
from typing import Iterable

import numpy as np

from diffsampler_rt.card import CARD_KEY, parse_card
from trainer.distil import network_hash

from .wrap_pad import (channels_last_note, quantize_before_wrap_pads, unroll_wrap_pads,
                       wrap_pads_channels_last)

#: what the card's ``quantization.method`` records
METHOD = ("static QOperator: QLinearConv with per-channel uint8 weights and uint8 "
          "activations, min-max calibration on the model's own solver inputs; first and "
          "last convolutions float")


def solver_inputs(path: str | Path, sides: Iterable[int], sets: int, seed: int
                  ) -> list[dict[str, np.ndarray]]:
    """Every (x, t) the runtime's solver feeds the network while it generates ``sets`` sets
    at each grid side, with the card's default solver, steps and structure guidance."""
    from diffsampler_rt.model import Model
    model = Model(path)
    feeds: list[dict[str, np.ndarray]] = []
    evaluate = model.denoise

    def recording(x: np.ndarray, t: int) -> np.ndarray:
        feeds.append({"x": x.astype(np.float32), "t": np.full(len(x), float(t), np.float32)})
        return evaluate(x, t)

    model.denoise = recording  # the generation loop reads the bound method per call
    for k in sides:
        model.generate(k * k, sets, seed=seed + k)
    return feeds


def float32_file(src: str | Path, dst: str | Path) -> None:
    """``src`` with fp16-stored weights folded to float32 initialisers (the quantiser reads
    float32 weights); onnxruntime's basic optimisations do the folding, metadata kept."""
    import onnxruntime as ort
    opts = ort.SessionOptions()
    opts.graph_optimization_level = ort.GraphOptimizationLevel.ORT_ENABLE_BASIC
    opts.optimized_model_filepath = str(dst)
    ort.InferenceSession(str(src), sess_options=opts, providers=["CPUExecutionProvider"])


def quantize(src: str | Path, dst: str | Path, *, sides: tuple[int, ...] | None = None,
             sets: int = 8, seed: int = 0) -> dict:
    """Write ``src`` with 8-bit convolutions to ``dst``; returns the new card.

    Parameters
    ----------
    src, dst : path
        An exported float model (fp16- or fp32-stored weights) and the output path.
    sides : tuple of int, optional
        Grid sides to calibrate on (default: the card's trained sizes).
    sets : int
        Sets generated per side for calibration.
    seed : int
        Seeds the calibration sets.
    """
    import onnx
    from onnxruntime.quantization import (CalibrationDataReader, QuantFormat, QuantType,
                                          quantize_static)
    src, dst = Path(src), Path(dst)
    source = _load(src)
    meta = {p.key: p.value for p in source.metadata_props}
    card = parse_card(meta, str(src))  # ModelFormatError (a ValueError) names what is wrong
    if card.get("weights") == "int8":
        raise ValueError(f"{src} is already int8-quantised")
    if sets < 1:
        raise ValueError(f"sets must be >= 1, got {sets}")
    if sides is None:  # the card lists trained sizes as point counts k*k
        sides = tuple(math.isqrt(n) for n in card["trained_sizes"])
    sides = tuple(sides)
    if not sides or any(k < 4 for k in sides):
        raise ValueError(f"calibration sides must be grid sides >= 4, got {sides}")
    feeds = solver_inputs(src, sides, sets, seed)

    class Feeds(CalibrationDataReader):
        def __init__(self):
            self._it = iter(feeds)

        def get_next(self):
            return next(self._it, None)

    with tempfile.TemporaryDirectory() as tmp:
        f32 = Path(tmp) / "f32.onnx"
        float32_file(src, f32)
        convs = [node.name for node in onnx.load(str(f32)).graph.node if node.op_type == "Conv"]
        stay_float = [convs[0], convs[-1]]  # nodes are in topological order: stem, eps head
        quantize_static(str(f32), str(dst), Feeds(), quant_format=QuantFormat.QOperator,
                        per_channel=True, activation_type=QuantType.QUInt8,
                        weight_type=QuantType.QUInt8, op_types_to_quantize=["Conv"],
                        nodes_to_exclude=stay_float)
    model = onnx.load(str(dst))
    record = {"method": METHOD, "sides": list(sides), "sets_per_side": sets, "seed": seed,
              "feeds": len(feeds), "float_network_sha1": network_hash(src),
              "date": _dt.date.today().isoformat()}
    # a circular net's padding: moved onto the 8-bit values, then as block copies (exact)
    moved = quantize_before_wrap_pads(model)
    unrolled = unroll_wrap_pads(model)
    if unrolled:
        record["wrap_pads"] = (f"{moved} of {unrolled} moved after their QuantizeLinear; "
                               "all as Slice and Concat")
        record["wrap_pads"] += channels_last_note(wrap_pads_channels_last(model))
    card = dict(card, weights="int8", quantization=record)
    card["provenance"] = (card.get("provenance", "")
                          + f"; convolutions quantised to int8 on {card['quantization']['date']}")
    _save(model, card, set(meta), dst)
    return card


def wrap_pads_to_channels_last(src: str | Path, dst: str | Path) -> int:
    """Write the 8-bit file ``src`` to ``dst`` with its wrap pads copied channels-last
    (:func:`export.wrap_pad.wrap_pads_channels_last`: the same outputs bit for bit, for
    files whose pads were quantised in place); returns how many pads it rewrote (0: ``dst`` is a
    copy). The card's ``quantization.wrap_pads`` says so."""
    src, dst = Path(src), Path(dst)
    model = _load(src)
    meta = {p.key: p.value for p in model.metadata_props}
    card = parse_card(meta, str(src))
    if card.get("weights") != "int8":
        raise ValueError(f"{src} has no 8-bit convolutions (weights: {card.get('weights')})")
    count = wrap_pads_channels_last(model)
    if count:
        record = dict(card["quantization"])
        record["wrap_pads"] = record.get("wrap_pads", "") + channels_last_note(count)
        card = dict(card, quantization=record)
    _save(model, card, set(meta), dst)
    return count


def _load(src: Path):
    """The ONNX model at ``src``; a ValueError naming it if it is not one."""
    import onnx
    try:
        return onnx.load(str(src))
    except Exception as exc:  # protobuf's DecodeError and friends
        raise ValueError(f"{src} is not a readable ONNX model: "
                         f"{str(exc).splitlines()[0][:200]}") from None


def _save(model, card: dict, keys: set[str], dst: Path) -> None:
    """Save ``model`` to ``dst`` with ``card`` as its card and its other metadata in
    ``keys`` kept."""
    import onnx
    text = json.dumps(card, sort_keys=True)
    parse_card({CARD_KEY: text}, str(dst))
    kept = [p for p in model.metadata_props if p.key in keys and p.key != CARD_KEY]
    del model.metadata_props[:]
    for p in kept:
        model.metadata_props.add(key=p.key, value=p.value)
    model.metadata_props.add(key=CARD_KEY, value=text)
    onnx.save(model, str(dst))
