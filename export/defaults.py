"""Edit an exported model's card in place: its default solver and steps, a non-uniform
model's density floor; every edit checked by the runtime's own card checks before the file
is written (:func:`edit_card`). The finishing pipeline: :mod:`export.pipeline_edit`.
"""
from __future__ import annotations

import json
from pathlib import Path

import onnx

from diffsampler_rt.card import CARD_KEY, parse_card
from diffsampler_rt.finish import legacy
from diffsampler_rt.solvers import SOLVERS


def edit_card(path: str | Path, edit) -> dict:
    """Apply ``edit`` (a function that changes the card dict in place) to the model card in
    ``path``, check the result with the runtime's own card checks (known structure,
    stratified embedding, integer settings, spacing range, density table; ModelFormatError
    is a ValueError) and save the file in place; returns the card."""
    model = onnx.load(str(path))
    props = {p.key: p for p in model.metadata_props}
    if CARD_KEY not in props:
        raise ValueError(f"{path} has no diffsampler model card")
    card = json.loads(props[CARD_KEY].value)
    if card.get("format_version") == 1:  # written before the pipeline: migrated on any edit
        card = legacy.convert(card)
    edit(card)
    props[CARD_KEY].value = json.dumps(card, sort_keys=True)
    parse_card({CARD_KEY: props[CARD_KEY].value}, str(path))
    onnx.save(model, str(path))
    return card


def set_defaults(path: str | Path, *, solver: str | None = None,
                 steps: int | None = None) -> dict:
    """Rewrite ``default_solver`` / ``default_steps`` (None: leave it) in the card in
    ``path``; returns the card. The finishing steps are edited with
    :func:`export.pipeline_edit.edit_pipeline`."""
    if solver is not None and solver not in SOLVERS:
        raise ValueError(f"unknown solver {solver!r}; choose one of {list(SOLVERS)}")
    if steps is not None and (isinstance(steps, bool) or not isinstance(steps, int)
                              or steps < 1):
        raise ValueError(f"steps must be an integer >= 1, got {steps!r}")

    def edit(card: dict) -> None:
        if steps is not None and steps > card["schedule"]["num_steps"]:
            raise ValueError(f"steps must be at most the schedule's "
                             f"{card['schedule']['num_steps']}, got {steps}")
        if solver is not None:
            card["default_solver"] = solver
        if steps is not None:
            card["default_steps"] = steps

    return edit_card(path, edit)


def with_guide_digests(pipeline: list[dict], path: Path) -> None:
    """Give every ``guide`` entry without a digest the sha256 of its guide's network, so
    that a later change of the guide file is caught on loading (a bad entry is left for
    the card check to report)."""
    from diffsampler_rt.finish.pipeline import entry_problem
    from diffsampler_rt.guidance import DIGESTS, guide_path
    from diffsampler_rt.metadata import network_sha256
    from diffsampler_rt.model import MODELS_DIR
    for entry in pipeline:
        if entry.get("step") == "guide" and not set(DIGESTS) & set(entry) \
                and entry_problem(entry) is None:
            found = guide_path(entry, Path(path).resolve(), MODELS_DIR)
            entry["network_sha256"] = network_sha256(found)


def set_density_floor(path: str | Path, floor: float) -> dict:
    """Re-tabulate the density of a non-uniform model in ``path`` with a new floor (the share
    of uniform mass in every cell, ``trainer.density.FLOOR``), in place; returns the card.

    The fitted density is recovered from the table (less its old floor, the card's
    ``density_floor``, 1e-3 if absent); the net is unchanged. Its training sets were mapped
    with the old table, which differs from the new by at most about the old floor in CDF.
    """
    from trainer.density import OLD_FLOOR, refloor

    def edit(card: dict) -> None:
        if "density" not in card:
            raise ValueError(f"{path} is not a non-uniform model (its card has no density)")
        old = card.get("density_floor", OLD_FLOOR)
        card["density"] = refloor(card["density"], old, floor)
        card["density_floor"] = floor
        card["provenance"] = (card.get("provenance", "") + f"; density table re-floored from "
                              f"{old:g} to {floor:g} (python -m export density-floor)")

    return edit_card(path, edit)


def migrate(path: str | Path) -> dict:
    """Rewrite a format-1 card as format 2 (its finishing fields as the ordered pipeline
    that does the same); the sets the model makes do not change."""
    return edit_card(path, lambda card: None)
