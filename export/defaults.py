"""Change the sampling defaults (solver, steps, structure, spacing, noise) of a model's card.

The defaults are what ``diffsampler_rt.generate`` uses when the caller gives no ``solver`` /
``steps``, and what it restores on the decoded sets: a net or n-rooks structure
(``diffsampler_rt.structure``; at power-of-two grid sides >= ``structure_min_side``, and
projected onto the clean-set prediction of the last ``structure_guidance`` solver steps), the
nearest rank-1 lattice (``diffsampler_rt.lattice``), a
few sliced-OT iterations (``diffsampler_rt.sliced_ot``) or a minimum spacing
(``diffsampler_rt.spacing``; the coefficient comes from the training sets,
``python -m trainer spacing CONFIG``); with ``guide`` every solver step is steered away
from a weaker model (``diffsampler_rt.guidance``);
and with ``coarse_noise`` the solver's starting noise has its coarse Fourier modes scaled
(``diffsampler_rt.coarse_noise``);
they are chosen by measurement (benchmarks/solver_sweep.py, fidelity.py), after training, so
they are edited in place rather than baked in at export.
"""
from __future__ import annotations

import json
from pathlib import Path

import onnx

from diffsampler_rt.card import CARD_KEY, STRUCTURE_SETTINGS, parse_card
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
    edit(card)
    props[CARD_KEY].value = json.dumps(card, sort_keys=True)
    parse_card({CARD_KEY: props[CARD_KEY].value}, str(path))
    onnx.save(model, str(path))
    return card


def set_defaults(path: str | Path, *, solver: str | None = None,
                 steps: int | None = None, structure: str | None = None,
                 structure_min_side: int | None = None, structure_guidance: int | None = None,
                 structure_sides: list[int] | None = None,
                 structure_temperature: float | str | None = None,
                 structure_block: int | dict | str | None = None,
                 structure_prefix: bool | None = None,
                 structure_runs: int | str | None = None,
                 sliced_ot: dict | str | None = None,
                 min_spacing: float | dict | str | None = None,
                 coarse_noise: dict | str | None = None,
                 even_out: dict | str | None = None,
                 projection_gain: float | dict | str | None = None,
                 restore_cut: float | str | None = None,
                 guide: dict | str | None = None) -> dict:
    """Rewrite ``default_solver`` / ``default_steps`` / ``structure`` (with its
    ``structure_min_side``, ``structure_guidance``, ``structure_sides``,
    ``structure_temperature``, ``structure_block``, ``structure_prefix`` and
    ``structure_runs``) / ``sliced_ot`` / ``min_spacing`` / ``coarse_noise`` / ``even_out`` /
    ``projection_gain`` / ``restore_cut`` / ``guide`` of the card in ``path`` (``"none"`` removes a structure with
    its seven settings, runs,
    a temperature, a
    block, a sliced-OT polish, a spacing, a noise gain, an evening-out, a projection gain,
    a restore cut, which
    then is the runtime's default, or a guide); returns the card. A ``guide`` without a digest gets
    ``"network_sha256"``, that of the guide's network (next to ``path``, else a bundled
    model or guide), which must exist. A ``sliced_ot`` without ``"directions"`` or
    ``"step"`` keeps the card's (else 64 and 1)."""
    if solver is not None and solver not in SOLVERS:
        raise ValueError(f"unknown solver {solver!r}; choose one of {list(SOLVERS)}")
    if steps is not None and (isinstance(steps, bool) or not isinstance(steps, int) or steps < 1):
        raise ValueError(f"steps must be a positive integer, got {steps!r}")

    def edit(card: dict) -> None:
        T = int(card["schedule"]["num_steps"])
        if steps is not None and steps > T:
            raise ValueError(f"steps must be at most the schedule's {T}, got {steps}")
        if solver is not None:
            card["default_solver"] = solver
        if steps is not None:
            card["default_steps"] = steps
        if structure == "none":
            for key in ("structure", *STRUCTURE_SETTINGS):
                card.pop(key, None)
        elif structure is not None:
            card["structure"] = structure
        if structure_min_side is not None:
            card["structure_min_side"] = structure_min_side
        if structure_guidance is not None:
            card["structure_guidance"] = structure_guidance
        if structure_sides is not None:
            card["structure_sides"] = structure_sides
        _put(card, "structure_temperature", structure_temperature)
        _put(card, "structure_block", structure_block)
        _put(card, "structure_runs", structure_runs)
        if structure_prefix:
            card["structure_prefix"] = True
        elif structure_prefix is not None:  # false is the runtime's default: the field goes
            card.pop("structure_prefix", None)
        if sliced_ot == "none":
            card.pop("sliced_ot", None)
        elif sliced_ot is not None:
            # new iterations keep the card's directions and step unless given (else 64, 1)
            kept = {key: value for key, value in card.get("sliced_ot", {}).items()
                    if key in ("directions", "step")}
            card["sliced_ot"] = {"directions": 64, **kept, **sliced_ot}
        _put(card, "coarse_noise", coarse_noise)
        _put(card, "even_out", even_out)
        _put(card, "projection_gain", projection_gain)
        _put(card, "restore_cut", restore_cut)
        if guide == "none":
            card.pop("guide", None)
        elif guide is not None:
            card["guide"] = _with_digest(guide, Path(path))
        _put(card, "min_spacing", min_spacing)

    return edit_card(path, edit)


def _put(card: dict, key: str, value) -> None:
    """Set ``card[key]``; ``"none"`` removes it, ``None`` leaves it as it is."""
    if isinstance(value, str) and value == "none":
        card.pop(key, None)
    elif value is not None:
        card[key] = value


def _with_digest(guide: dict, path: Path) -> dict:
    """``guide`` with the sha256 of its network (checked for form first: a bad name is
    reported as such, not as a missing file)."""
    from diffsampler_rt.guidance import DIGESTS, guide_path, settings_problem
    from diffsampler_rt.metadata import network_sha256
    from diffsampler_rt.model import MODELS_DIR
    if set(DIGESTS) & set(guide) or settings_problem(guide):
        return guide  # the card check that follows reports the problem
    found = guide_path(guide, path.resolve(), MODELS_DIR)
    return {**guide, "network_sha256": network_sha256(found)}


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
