"""Autoguidance: steer a model's denoiser away from a weaker model of the same sampler
(the pipeline step ``guide``, :mod:`diffsampler_rt.finish.guide`).

A small net blurs what it learned: its sets' radial spectrum has the sampler's peak, but
lower and wider. Karras et al. 2024 ("Guiding a diffusion model with a bad version of
itself") guide a net with a worse version of itself, trained on less data or for less
time: where the two differ, the good one is, on average, already right, so moving further
in that direction undoes part of the good net's own error. Each solver step then uses

    eps = (1 + w) * eps_model(x, t) - w * eps_guide(x, t)

(w = 0: the model alone), at the cost of a second network evaluation per step. The
bundled ``sot`` is guided by ``sot_32``, the same network trained on 32 example sets per
size; measured at n = 1024 (128 generated sets against the fidelity report's 512 SOT sets):
spectrum MAE 0.0133 -> 0.0096 / 0.0073 / 0.0092 / 0.0126 at w = 0.5 / 1 / 1.5 / 2. The
guided sets carry more low-frequency power (Gaussian integration error +35 % at w = 1
with the card's 8 sliced-OT iterations, +3 % with 32), so the card's polish is tuned with
it.

Step parameters: ``{"step": "guide", "model": NAME, "weight": W}``, W a number or a
per-size table ``{"n": [sizes], "values": [...]}`` (linear in log n between the sizes, the
end values beyond; the format-1 card field ``"guide"`` had ``"n"`` and ``"weight"`` lists,
which :func:`settings_problem`, :func:`weight_at` and :func:`describe` read), with an
optional ``"network_sha256"`` of the guide's network (its file less the metadata,
:func:`diffsampler_rt.metadata.network_sha256`, so that editing the guide's own card does
not orphan the models it guides): the weights were chosen against that network, and
another one is refused. Cards written before it may carry ``"sha256"``, the digest of the
guide's whole file, which is checked as such. NAME is an ``.onnx`` file next to the
model's own or in a ``guides/`` folder beside it, else a bundled model (the repository's
``sot_32`` is guided by ``models/guides/sot_32_guide.onnx``, a half-width net trained briefly
on its 32 sets); the guide must have
the model's noise schedule, embedding, offset scale, prediction and padding.
"""
from __future__ import annotations

import hashlib
from pathlib import Path
from typing import Any, Callable

import numpy as np

from . import per_size
from .errors import ModelFormatError
from .metadata import network_sha256

#: largest weight a card may ask for (measured on sot: past ~1.5 the spectrum gets worse)
MAX_WEIGHT = 4.0

Denoiser = Callable[[np.ndarray, int], np.ndarray]


def _weight_ok(w: Any) -> bool:
    return per_size.finite_number(w) and 0 <= w <= MAX_WEIGHT


def settings_problem(spec: Any) -> str | None:
    """None if ``spec`` is a valid ``"guide"`` card value, else why (starting with the
    field's name)."""
    form = ("'guide' must be {\"model\": NAME, \"weight\": W} or {\"model\": NAME, \"n\": "
            "[sizes], \"weight\": [W per size]}, optionally with \"network_sha256\"")
    if not isinstance(spec, dict) or not {"model", "weight"} <= set(spec) <= {
            "model", "weight", "n", *DIGESTS}:
        return f"{form}, got {spec!r}"
    name = spec["model"]
    if not isinstance(name, str) or not name or "/" in name or "\\" in name:
        return f"'guide' model must be a model name (no directories), got {name!r}"
    for key in DIGESTS:
        digest = spec.get(key)
        if digest is not None and not (isinstance(digest, str) and len(digest) == 64
                                       and all(c in "0123456789abcdef" for c in digest)):
            return f"'guide' {key} must be 64 lower-case hex digits, got {digest!r}"
    weights = spec["weight"]
    if "n" in spec:
        if not (per_size.sizes_ok(spec["n"]) and isinstance(weights, list)
                and len(weights) == len(spec["n"])):
            return (f"'guide' n and weight must be lists of the same length, n strictly "
                    f"increasing sizes >= 1; got {spec['n']!r}, {weights!r}")
    else:
        weights = [weights]
    if not all(_weight_ok(w) for w in weights):
        return f"'guide' weight must be a number in [0, {MAX_WEIGHT:g}], got {spec['weight']!r}"
    return None


def weight_at(spec: dict, n: int) -> float:
    """The guidance weight at n points of a card's ``"guide"``."""
    if "n" in spec:
        return per_size.at(spec["n"], spec["weight"], n)
    return float(spec["weight"])


def describe(spec: dict | None) -> str:
    """The card value in words: "none", "sot_32, weight 1" or "sot_32, weight 0.5 / 1 at
    n = 64 / 1024 (log-linear)"."""
    if not spec:
        return "none"
    if "n" in spec:
        return (f"{spec['model']}, weight "
                + per_size.describe(spec["n"], [f"{w:g}" for w in spec["weight"]])
                + " (log-linear)")
    return f"{spec['model']}, weight {spec['weight']:g}"


def guide_path(spec: dict, model_path: Path, bundled_dir: Path) -> Path:
    """The guide's file: ``NAME.onnx`` next to the model or in its ``guides/`` folder
    (networks kept only to guide others), else where a bare model name is found (the
    ``DIFFSAMPLER_MODELS`` folders, then the bundled models); its digest checked where the
    card gives one."""
    from .model import search_path  # the model module loads guides: imported on use
    name = spec["model"]
    for folder in (model_path.parent, model_path.parent / "guides", *search_path(),
                   bundled_dir):
        path = folder / f"{name}.onnx"
        if path.is_file():
            break
    else:
        raise ModelFormatError(f"{model_path}: its guide model {name!r} was not found next to "
                               f"it, in guides/ beside it, nor among the bundled models")
    for key, digest_of in DIGESTS.items():
        digest = spec.get(key)
        if digest is not None and (actual := digest_of(path)) != digest:
            raise ModelFormatError(f"{model_path}: its guide {path} has {key} {actual}, the "
                                   f"card was tuned with {digest}")
    return path


def file_sha256(path: Path) -> str:
    """The sha256 of a whole file (the older ``"sha256"`` of a card's ``"guide"``)."""
    return hashlib.sha256(Path(path).read_bytes()).hexdigest()


#: the digests a card's ``"guide"`` may record, and how each is taken of the guide's file
DIGESTS: dict[str, Callable[[Path], str]] = {"network_sha256": network_sha256,
                                             "sha256": file_sha256}


def check_compatible(card: dict, guide_card: dict, source: str) -> None:
    """Raise ModelFormatError unless the guide shares the model's schedule, embedding,
    offset scale, prediction and padding (its eps must mean the same thing at the same x
    and t)."""
    for key in ("schedule", "embedding", "offset_scale", "prediction", "padding"):
        if card.get(key) != guide_card.get(key):
            raise ModelFormatError(f"{source}: guide {guide_card.get('name')!r} has {key} "
                                   f"{guide_card.get(key)!r}, the model {card.get(key)!r}")


def guided(model: Denoiser, guide: Denoiser, weight: float) -> Denoiser:
    """The denoiser (1 + weight) * model - weight * guide."""
    def eps(x: np.ndarray, t: int) -> np.ndarray:
        return (1 + weight) * model(x, t) - weight * guide(x, t)
    return eps
