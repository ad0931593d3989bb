"""Finishing steps chosen from held-in example sets by fixed procedures (never by hand).

``calibrate`` writes a model's pipeline from three findings:

1. **Structure** (:mod:`.analysis`): where every example set is a (0, m, 2)-net, has
   stratified projections, or is a rank-1 lattice, the matching structure step (a lattice at
   the example sizes only: its generator is chosen per n).
2. **Minimum spacing**: per example size, c = the 5th percentile of the sets' smallest
   pairwise distance times sqrt(n) (``trainer.stats.spacing_coefficient``, the procedure
   the bundled blue-noise cards were made with). Sets whose c is at least ``BLUE_NOISE`` at
   every size are blue noise: the model gets ``min_spacing`` with c per size, and its
   thinning drops the most crowded points; other sets get neither (random thinning).
3. **Large-scale evening**: the model's sets (with steps 1-2) are made at each example
   size with the ``even_out`` gains of ``EVEN_GAINS`` (0: none), and each gain's mean radial
   spectrum compared with the held-in sets' (mean absolute difference over every bin, so a
   gain that evens the large scales but disturbs the pattern pays for it). A size gets the
   gain with the smallest difference if it beats no evening by more than the difference's
   noise (half that between two halves of the held-in sets), else none.

Every choice is recorded with its figures in the card (``"calibration"``).
"""
from __future__ import annotations

import math
from typing import Any, Callable

import numpy as np

from diffsampler_rt.spectrum import radial_spectrum

#: 5th-percentile spacing coefficient from which examples count as blue noise (uniform
#: random sets of 64-1024 points have c ~ 0.01-0.05, jittered grids ~0.05-0.1)
BLUE_NOISE = 0.3
SPACING_PERCENTILE = 5.0
#: the large scales the evening calibration compares, in units of sqrt(n)
EVEN_CUT = 0.5
#: sets generated per size to calibrate the evening, and the gains it tries
EVEN_SETS = 64
EVEN_GAINS = (-0.5, -0.25, 0.0, 0.25, 0.5, 0.75, 0.9)


def _table(values: dict[int, float], digits: int = 4) -> Any:
    """A per-size pipeline value: one number for one size, else {"n": ..., "values": ...}."""
    sizes = sorted(values)
    vals = [round(float(values[n]), digits) for n in sizes]
    return vals[0] if len(sizes) == 1 else {"n": sizes, "values": vals}


def spacing(held_in: dict[int, np.ndarray]) -> tuple[dict[int, float], bool]:
    """The spacing coefficient per size, and whether the examples are blue noise."""
    from trainer.stats.distance import spacing_coefficient
    cs = {n: spacing_coefficient(sets, SPACING_PERCENTILE) for n, sets in held_in.items()}
    return cs, all(c >= BLUE_NOISE for c in cs.values())


def structure_entry(name: str | None, sizes: list[int]) -> dict | None:
    if name is None:
        return None
    sides = sorted(math.isqrt(n) for n in sizes)
    if name == "rank1_lattice":
        return {"step": name, "sides": sides}
    return {"step": name, "min_side": sides[0]}


def base_pipeline(structure: dict | None, cs: dict[int, float], blue: bool) -> list[dict]:
    """Structure, thinning and spacing in the order that keeps an imposed structure exact:
    the spacing goes before the structure where it holds and after thinning elsewhere."""
    spaced = {"step": "min_spacing", "c": _table(cs)} if blue else None
    thin = {"step": "thin", "drop": "crowded" if blue else "random"}
    if structure is None:
        return [thin] + ([spaced] if spaced else [])
    if spaced is None:
        return [structure, thin]
    return [{**spaced, "where": "structured"}, structure, thin,
            {**spaced, "where": "unstructured"}]


def evening(generate: Callable[[float], Callable[[int, int], np.ndarray]],
            held_in: dict[int, np.ndarray]) -> tuple[dict[int, float], dict[int, dict]]:
    """The even_out gain per size (0 where no gain beats none by more than the noise) and
    the figures; ``generate(gain)`` makes sets (n, count) with that gain at every size."""
    from diffsampler_rt.spectrum import spectrum_mae
    targets = {}
    for n, sets in held_in.items():
        half = len(sets) // 2
        targets[n] = (radial_spectrum(sets)[1],
                      spectrum_mae(radial_spectrum(sets[:half])[1],
                                   radial_spectrum(sets[half:])[1]) / 2)
    maes: dict[int, dict[float, float]] = {n: {} for n in held_in}
    for gain in EVEN_GAINS:
        make = generate(gain)
        for n in held_in:
            maes[n][gain] = spectrum_mae(radial_spectrum(make(n, EVEN_SETS))[1], targets[n][0])
    gains, figures = {}, {}
    for n in held_in:
        best = min(maes[n], key=maes[n].get)
        noise = targets[n][1]
        gains[n] = best if maes[n][0.0] - maes[n][best] > noise else 0.0
        figures[n] = {"mae": {f"{g:g}": round(v, 5) for g, v in maes[n].items()},
                      "noise": round(noise, 5), "gain": gains[n]}
    return gains, figures


def calibrate(model_path, held_in: dict[int, np.ndarray], structure: str | None,
              structure_sizes: list[int], *, uniform: bool = True, seed: int = 0,
              log: Callable[[str], None] = print) -> dict:
    """Choose the finishing steps of the model in ``model_path`` from ``held_in`` sets (by
    size) and write them into its card; returns the card."""
    import diffsampler_rt
    cs, blue = spacing(held_in)
    notes = [{"step": "min_spacing" if blue else "thin",
              "how": f"{SPACING_PERCENTILE:g}th percentile of the held-in sets' smallest "
                     f"distance x sqrt(n): " + ", ".join(f"{c:.3f} at n = {n}"
                                                         for n, c in sorted(cs.items()))
                     + (f" (>= {BLUE_NOISE} at every size: blue noise, spacing kept, crowded "
                        "points thinned first)" if blue else
                        f" (below {BLUE_NOISE}: no spacing, random thinning)")}]
    entry = structure_entry(structure, structure_sizes)
    if entry:
        notes.append({"step": entry["step"], "how": "every example set has it (checked at "
                      f"n = {', '.join(map(str, structure_sizes))})"})
    pipeline = base_pipeline(entry, cs, blue)
    _write(model_path, pipeline, notes)
    log("calibration: " + "; ".join(n["how"] for n in notes))
    if uniform and entry is None:
        thin_at = next(i for i, e in enumerate(pipeline) if e["step"] == "thin")

        def with_even(gain: Any) -> list[dict]:
            even = {"step": "even_out", "gain": gain, "cut": EVEN_CUT}
            return pipeline[:thin_at + 1] + [even] + pipeline[thin_at + 1:]

        def generator(gain: float):
            model = diffsampler_rt.Model(model_path)
            model.card = {**model.card, "pipeline": with_even(gain)}
            return lambda n, c: model.generate(n, c, seed=seed)

        gains, figures = evening(generator, held_in)
        how = ("radial spectrum, mean absolute difference from the held-in sets' with even_out "
               f"gains {', '.join(f'{g:g}' for g in EVEN_GAINS)}: " + "; ".join(
                   f"at n = {n}: " + ", ".join(f"{v:.4f}" for v in f["mae"].values())
                   + f" (noise {f['noise']:.4f}) -> {f['gain']:g}"
                   for n, f in sorted(figures.items())))
        if any(gains.values()):
            pipeline = with_even(_table(gains, 3))
            notes.append({"step": "even_out", "how": how + "; the gain with the smallest "
                          "difference where it beats none by more than the noise"})
        else:
            notes.append({"step": "even_out", "how": how + ": no gain beats none by more "
                          "than the noise, no evening"})
        log("calibration: " + notes[-1]["how"])
        _write(model_path, pipeline, notes)
    return diffsampler_rt.Model(model_path).card


def _write(path, pipeline: list[dict], notes: list[dict]) -> None:
    from export.defaults import edit_card

    def edit(card: dict) -> None:
        card["pipeline"] = pipeline
        card["calibration"] = notes

    edit_card(path, edit)
