"""The model card: the JSON metadata every diffsampler ONNX file carries.

Models are data: one generic runtime reads everything model-specific (embedding, noise
schedule, offset scale, default steps, provenance) from here.
"""
from __future__ import annotations

import json
from typing import Any, Mapping

from . import per_size
from .coarse_noise import settings_problem as coarse_problem
from .coarse_noise import temperature_problem
from .density import check_table
from .errors import ModelFormatError
from .guidance import settings_problem as guide_problem
from .low_frequencies import restore_cut_problem
from .low_frequencies import settings_problem as even_problem
from .projections import settings_problem as projection_problem
from .schedule import betas
from .sliced_ot import settings_problem as sliced_problem
from .solvers import SOLVERS
from .structure import ANY_SIDE, STRUCTURES, block_problem

FORMAT_KEY = "diffsampler.format"
CARD_KEY = "diffsampler.card"
FORMAT_VERSION = 1

#: card fields the runtime relies on, with their types
REQUIRED = {"format_version": int, "name": str, "sampler": str, "embedding": str,
            "offset_scale": (int, float), "prediction": str, "schedule": dict,
            "training_steps": int, "trained_sizes": list, "default_steps": int,
            "min_side": int}


#: card fields that refine the card's ``"structure"`` and need one (removed with it)
STRUCTURE_SETTINGS = ("structure_min_side", "structure_guidance", "structure_sides",
                      "structure_temperature", "structure_block", "structure_prefix",
                      "structure_runs")
#: the densest packing (hexagonal) keeps n points at most about sqrt(2 / sqrt(3) / n)
#: = 1.0746 / sqrt(n) apart for large n; a card asking for more could not be met there
MAX_SPACING = 1.07


def _coefficient_ok(c: Any) -> bool:
    return isinstance(c, (int, float)) and not isinstance(c, bool) and 0 < c < MAX_SPACING


def spacing_problem(spec: Any) -> str | None:
    """None if ``spec`` is a valid ``min_spacing`` (a number or a per-size table), else why."""
    if isinstance(spec, dict):
        ns, cs = spec.get("n"), spec.get("c")
        if (set(spec) != {"n", "c"} or not isinstance(ns, list) or not isinstance(cs, list)
                or not ns or len(ns) != len(cs)):
            return (f"min_spacing table must be {{\"n\": [...], \"c\": [...]}} with lists of "
                    f"equal, non-zero length, got {spec!r}")
        if not per_size.sizes_ok(ns):
            return f"min_spacing table's n must be increasing positive integers, got {ns!r}"
        if not all(_coefficient_ok(c) for c in cs):
            return f"min_spacing table's c must be numbers in (0, {MAX_SPACING}), got {cs!r}"
        return None
    if not _coefficient_ok(spec):
        return f"min_spacing must be a number in (0, {MAX_SPACING}) or a table, got {spec!r}"
    return None


def describe_devices(devices: list[str] | None) -> str:
    """"CPU", "GPU" or "GPU and CPU" for a list of torch device types (none given: CPU)."""
    names = {"cpu": "CPU", "cuda": "GPU"}
    return " and ".join(names.get(d, d) for d in devices or ["cpu"])


def parse_card(meta: Mapping[str, str], source: str) -> dict[str, Any]:
    """Validate the ONNX custom metadata of ``source`` and return its card."""
    if CARD_KEY not in meta:
        raise ModelFormatError(f"{source} is an ONNX model without a diffsampler model card "
                               f"(metadata key {CARD_KEY!r}); export it with `python -m export`")
    try:
        card = json.loads(meta[CARD_KEY])
    except json.JSONDecodeError as exc:
        raise ModelFormatError(f"{source}: model card is not valid JSON ({exc})") from None
    if not isinstance(card, dict):
        raise ModelFormatError(f"{source}: model card must be a JSON object")
    version = card.get("format_version")
    if version != FORMAT_VERSION:
        raise ModelFormatError(f"{source}: model card format {version!r} is not supported "
                               f"(this runtime reads format {FORMAT_VERSION})")
    for key, typ in REQUIRED.items():
        if not isinstance(card.get(key), typ) or isinstance(card.get(key), bool):
            raise ModelFormatError(f"{source}: model card field {key!r} is missing or has the "
                                   f"wrong type ({card.get(key)!r})")
    if card["embedding"] not in ("stratified", "ot"):
        raise ModelFormatError(f"{source}: unknown embedding {card['embedding']!r}")
    if card.get("default_solver", "ddim") not in SOLVERS:
        raise ModelFormatError(f"{source}: unknown default solver {card['default_solver']!r}")
    card.setdefault("default_solver", "ddim")  # cards written before the field existed
    structure = card.get("structure")
    if structure is not None and structure not in STRUCTURES:
        raise ModelFormatError(f"{source}: unknown structure {structure!r}; this runtime "
                               f"knows {list(STRUCTURES)}")
    if (structure is not None and structure not in ANY_SIDE
            and card["embedding"] != "stratified"):
        raise ModelFormatError(f"{source}: structure {structure!r} needs the stratified "
                               f"embedding, the card says {card['embedding']!r}")
    for key in STRUCTURE_SETTINGS:
        if card.get(key) is not None and structure is None:
            raise ModelFormatError(f"{source}: model card field {key!r} needs a structure")
    for key, low in (("structure_min_side", 1), ("structure_guidance", 0), ("structure_runs", 2)):
        value = card.get(key)
        if value is not None and (isinstance(value, bool) or not isinstance(value, int)
                                  or value < low):
            raise ModelFormatError(f"{source}: model card field {key!r} must be an integer "
                                   f">= {low}, got {value!r}")
    for key in ("structure_block", "structure_runs"):  # LDBN's strata: n-rooks refinements
        if card.get(key) is not None and structure is not None and structure != "n_rooks":
            raise ModelFormatError(f"{source}: model card field {key!r} needs the "
                                   f"structure 'n_rooks', the card says {structure!r}")
    block = card.get("structure_block")
    prefix = card.get("structure_prefix")
    if prefix is not None and not isinstance(prefix, bool):
        raise ModelFormatError(f"{source}: model card field 'structure_prefix' must be true "
                               f"or false, got {prefix!r}")
    if prefix and structure != "dyadic_net":
        raise ModelFormatError(f"{source}: model card field 'structure_prefix' needs the "
                               f"structure 'dyadic_net', the card says {structure!r}")
    if block is not None and (problem := block_problem(block)):
        raise ModelFormatError(f"{source}: model card field {problem}")
    sides = card.get("structure_sides")
    if sides is not None and not per_size.sizes_ok(sides):
        raise ModelFormatError(f"{source}: model card field 'structure_sides' must be a list of "
                               f"increasing positive integers (grid sides), got {sides!r}")
    if structure in ANY_SIDE and card.get("structure_guidance"):
        raise ModelFormatError(f"{source}: structure {structure!r} cannot guide the solver "
                               "(structure_guidance must be 0 or absent)")
    if "sliced_ot" in card and (problem := sliced_problem(card["sliced_ot"])):
        raise ModelFormatError(f"{source}: model card field {problem}")
    if "guide" in card and (problem := guide_problem(card["guide"])):
        raise ModelFormatError(f"{source}: model card field {problem}")
    if "coarse_noise" in card and (problem := coarse_problem(card["coarse_noise"])):
        raise ModelFormatError(f"{source}: model card field {problem}")
    if "structure_temperature" in card and (
            problem := temperature_problem(card["structure_temperature"])):
        raise ModelFormatError(f"{source}: model card field {problem}")
    if "even_out" in card and (problem := even_problem(card["even_out"])):
        raise ModelFormatError(f"{source}: model card field {problem}")
    if "projection_gain" in card and (problem := projection_problem(card["projection_gain"])):
        raise ModelFormatError(f"{source}: model card field {problem}")
    if "restore_cut" in card and (problem := restore_cut_problem(card["restore_cut"])):
        raise ModelFormatError(f"{source}: model card field {problem}")
    if "min_spacing" in card and (problem := spacing_problem(card["min_spacing"])):
        raise ModelFormatError(f"{source}: {problem}")
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
