"""The model card: the JSON metadata every diffsampler ONNX file carries.

Models are data: one generic runtime reads everything model-specific (embedding, noise
schedule, offset scale, default steps, provenance) from here, and what runs around and
after the network from the card's ``"pipeline"``: an ordered list of finishing steps
(:mod:`diffsampler_rt.finish`). Format 2 cards carry it; format 1 cards, whose finishing
settings were top-level fields, are converted on reading (:mod:`diffsampler_rt.finish.legacy`).
"""
from __future__ import annotations

import json
from typing import Any, Mapping

from .density import check_table
from .errors import ModelFormatError
from .finish import legacy
from .finish.pipeline import pipeline_problem
from .schedule import betas
from .solvers import SOLVERS

FORMAT_KEY = "diffsampler.format"
CARD_KEY = "diffsampler.card"
#: the card format this runtime writes; it reads this one and FORMAT_VERSION - 1
FORMAT_VERSION = 2
#: structure steps that keep points in their grid cells, so need the stratified embedding
STRATIFIED_ONLY = ("dyadic_net", "n_rooks")

#: card fields the runtime relies on, with their types
REQUIRED = {"format_version": int, "name": str, "sampler": str, "embedding": str,
            "offset_scale": (int, float), "prediction": str, "schedule": dict,
            "training_steps": int, "trained_sizes": list, "default_steps": int,
            "min_side": int}


def describe_devices(devices: list[str] | None) -> str:
    """"CPU", "GPU" or "GPU and CPU" for a list of torch device types (none given: CPU)."""
    names = {"cpu": "CPU", "cuda": "GPU"}
    return " and ".join(names.get(d, d) for d in devices or ["cpu"])


def _upgraded(card: dict, source: str) -> dict:
    """A format-1 card as format 2; a format-2 card as it is (old fields refused)."""
    version = card.get("format_version")
    if version == 1:
        try:
            return legacy.convert(card)
        except (KeyError, TypeError, AttributeError) as exc:
            raise ModelFormatError(f"{source}: format-1 card has a malformed finishing "
                                   f"setting ({type(exc).__name__}: {exc})") from None
    if version != FORMAT_VERSION:
        raise ModelFormatError(f"{source}: model card format {version!r} is not supported "
                               f"(this runtime reads formats 1 and {FORMAT_VERSION})")
    stale = [k for k in legacy.FIELDS if k in card]
    if stale:
        raise ModelFormatError(f"{source}: model card field {stale[0]!r} belongs to format 1; "
                               "in format 2 it is a step of the card's 'pipeline'")
    return card


def parse_card(meta: Mapping[str, str], source: str) -> dict[str, Any]:
    """Validate the ONNX custom metadata of ``source`` and return its card (format 2)."""
    if CARD_KEY not in meta:
        raise ModelFormatError(f"{source} is an ONNX model without a diffsampler model card "
                               f"(metadata key {CARD_KEY!r}); export it with `python -m export`")
    try:
        card = json.loads(meta[CARD_KEY])
    except json.JSONDecodeError as exc:
        raise ModelFormatError(f"{source}: model card is not valid JSON ({exc})") from None
    if not isinstance(card, dict):
        raise ModelFormatError(f"{source}: model card must be a JSON object")
    card = _upgraded(card, source)
    for key, typ in REQUIRED.items():
        if not isinstance(card.get(key), typ) or isinstance(card.get(key), bool):
            raise ModelFormatError(f"{source}: model card field {key!r} is missing or has the "
                                   f"wrong type ({card.get(key)!r})")
    if card["embedding"] not in ("stratified", "ot"):
        raise ModelFormatError(f"{source}: unknown embedding {card['embedding']!r}")
    if card.get("default_solver", "ddim") not in SOLVERS:
        raise ModelFormatError(f"{source}: unknown default solver {card['default_solver']!r}")
    card.setdefault("default_solver", "ddim")  # cards written before the field existed
    if "pipeline" not in card:
        raise ModelFormatError(f"{source}: a format-{FORMAT_VERSION} model card needs a "
                               "'pipeline' (at least [{\"step\": \"thin\"}])")
    if problem := pipeline_problem(card["pipeline"]):
        raise ModelFormatError(f"{source}: {problem}")
    structures = [e["step"] for e in card["pipeline"] if e["step"] in STRATIFIED_ONLY]
    if structures and card["embedding"] != "stratified":
        raise ModelFormatError(f"{source}: step {structures[0]!r} needs the stratified "
                               f"embedding, the card says {card['embedding']!r}")
    if "density" in card and (problem := check_table(card["density"])) is not None:
        raise ModelFormatError(f"{source}: model card field 'density' {problem}")
    floor = card.get("density_floor")  # informational: the share of uniform mass in the table
    if floor is not None and ("density" not in card or isinstance(floor, bool)
                              or not isinstance(floor, (int, float)) or not 0 < floor < 1):
        raise ModelFormatError(f"{source}: model card field 'density_floor' must be a number in "
                               f"(0, 1) next to a 'density', got {floor!r}")
    if card.get("padding", "zeros") not in ("zeros", "circular"):
        raise ModelFormatError(f"{source}: unknown padding {card['padding']!r} "
                               "(zeros or circular)")
    if card["prediction"] != "eps":
        raise ModelFormatError(f"{source}: unsupported prediction {card['prediction']!r}")
    try:
        betas(card["schedule"])
    except (KeyError, ValueError, TypeError) as exc:
        raise ModelFormatError(f"{source}: invalid noise schedule {card['schedule']!r} ({exc})") from None
    return card
