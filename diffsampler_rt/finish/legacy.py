"""Format-1 model cards, whose finishing settings were top-level fields applied in an order
fixed by the runtime, converted to format 2's ordered ``"pipeline"`` (on reading: files
written before the pipeline existed still load and make the same sets, bit for bit).

The order written here is the one the format-1 runtime applied, and is used for nothing
else: noise shaping; guidance; structure guidance; where a structure holds, the spacing and
the evening before it; the structure; thinning; the sliced-OT polish; then, where no
structure holds, the evening, the projection gain and the spacing.
"""
from __future__ import annotations

from typing import Any

#: format-1 fields that became pipeline steps (removed from a converted card)
FIELDS = ("structure", "structure_min_side", "structure_guidance", "structure_sides",
          "structure_temperature", "structure_block", "structure_prefix", "structure_runs",
          "coarse_noise", "guide", "min_spacing", "even_out", "sliced_ot", "projection_gain",
          "restore_cut")


def _table(spec: dict, key: str) -> Any:
    """A format-1 value (a number, or a list beside ``spec["n"]``) in format 2's form."""
    v = spec[key]
    return {"n": list(spec["n"]), "values": list(v)} if isinstance(v, list) else v


def _gain_table(spec: dict) -> dict:
    return {"gain": _table(spec, "gain"), "cut": _table(spec, "cut")}


def _number_or_table(spec: Any, key: str) -> Any:
    return _table(spec, key) if isinstance(spec, dict) else spec


def _structure(card: dict) -> dict:
    entry: dict[str, Any] = {"step": card["structure"]}
    for old, new in (("structure_min_side", "min_side"), ("structure_sides", "sides"),
                     ("structure_block", "block"), ("structure_runs", "runs"),
                     ("structure_prefix", "prefix")):
        if card.get(old) is not None:
            entry[new] = card[old]
    return entry


def _noise(card: dict, structured: bool) -> list[dict]:
    coarse = card.get("coarse_noise")
    hot = card.get("structure_temperature", 1.0)
    base = {"step": "coarse_noise", **(_gain_table(coarse) if coarse else {})}
    if structured and hot != 1:  # the temperature applied only where the structure holds
        return ([{**base, "where": "unstructured"}] if coarse else []) + [
            {**base, "temperature": hot, "where": "structured"}]
    return [base] if coarse else []


def to_pipeline(card: dict) -> list[dict]:
    """The format-2 pipeline that does what a format-1 card's fields did."""
    structured = card.get("structure") is not None
    spacing = ({"step": "min_spacing", "c": _number_or_table(card["min_spacing"], "c")}
               if "min_spacing" in card else None)
    even = {"step": "even_out", **_gain_table(card["even_out"])} if "even_out" in card else None
    pipe = _noise(card, structured)
    if guide := card.get("guide"):
        pipe.append({"step": "guide", "model": guide["model"], "weight": _table(guide, "weight"),
                     **{k: v for k, v in guide.items() if k not in ("model", "weight", "n")}})
    if card.get("structure_guidance"):
        pipe.append({"step": "structure_guidance", "steps": card["structure_guidance"]})
    if structured:
        pipe += [{**e, "where": "structured"} for e in (spacing, even) if e]
        pipe.append(_structure(card))
    thin = {"step": "thin", "drop": "crowded" if spacing else "random"}
    if "restore_cut" in card:
        thin["restore_cut"] = card["restore_cut"]
    pipe.append(thin)
    if polish := card.get("sliced_ot"):
        pipe.append({"step": "sliced_ot", "directions": polish["directions"],
                     "iterations": _table(polish, "iterations"),
                     **({"step_size": polish["step"]} if "step" in polish else {})})
    gain = card.get("projection_gain")
    late = [even, {"step": "projection_gain", "gain": _number_or_table(gain, "gain")}
            if gain is not None else None, spacing]
    pipe += [{**e, "where": "unstructured"} if structured else e for e in late if e]
    return pipe


def convert(card: dict) -> dict:
    """A format-1 card as format 2 (a new dict; the input is left alone)."""
    out = {k: v for k, v in card.items() if k not in FIELDS}
    out["pipeline"] = to_pipeline(card)
    out["format_version"] = 2
    return out
