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
3. **Large-scale evening**: the model's sets (with steps 1-2) are generated at each example
   size and their mean radial power below ``EVEN_CUT`` sqrt(n) compared with the held-in
   sets'. Where the ratio R is off by more than twice its standard error, ``even_out`` gets
   gain 1 - 1 / sqrt(R) at that size (the evening scales the deviations, so the power, by
   (1 - gain)^2 to first order), clipped to [-0.9, 0.9]; sizes within noise get 0. The
   evening is linear only to first order, so the sets are made again with the gains and the
   factor (1 - gain) corrected by the remaining ratio, up to ``EVEN_ROUNDS`` rounds or until
   every size is within noise.

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
#: sets generated per size to calibrate the evening, and the most rounds of it
EVEN_SETS, EVEN_ROUNDS = 64, 3


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


def low_power(sets: np.ndarray, cut: float = EVEN_CUT) -> np.ndarray:
    """Per set: its mean radial power below cut sqrt(n)."""
    out = []
    for s in sets:
        f, p = radial_spectrum(s[None])
        out.append(p[f < cut].mean())
    return np.array(out)


def _ratio(generate, n: int, examples: np.ndarray) -> tuple[float, float]:
    """(generated / example mean power below the cut, standard error of its log)."""
    ex, gen = low_power(examples), low_power(generate(n, EVEN_SETS))
    se = math.sqrt((gen.std(ddof=1) / gen.mean()) ** 2 / len(gen)
                   + (ex.std(ddof=1) / ex.mean()) ** 2 / len(ex))
    return float(gen.mean() / ex.mean()), se


def evening(generate: Callable[[int, int], np.ndarray], held_in: dict[int, np.ndarray], *,
            with_gains: Callable[[dict[int, float]], Callable] | None = None
            ) -> tuple[dict[int, float], dict[int, dict]]:
    """The even_out gain per size (0 where the model is within noise) and the figures.

    ``with_gains(gains)`` returns a generator with those gains applied (for the later
    rounds); without it, one round."""
    gains, figures = {n: 0.0 for n in held_in}, {}
    gen = generate
    for round_ in range(EVEN_ROUNDS if with_gains else 1):
        settled = True
        for n, sets in held_in.items():
            ratio, se = _ratio(gen, n, sets[:256])
            off = abs(math.log(ratio)) > 2 * se
            figures[n] = {"power_ratio": round(ratio, 4), "log_se": round(se, 4),
                          "rounds": round_ + 1}
            if off:
                settled = False
                keep = (1 - gains[n]) / math.sqrt(ratio)  # deviations kept, corrected
                gains[n] = float(np.clip(1 - keep, -0.9, 0.9))
            figures[n]["gain"] = round(gains[n], 3)
        if settled or with_gains is None:
            break
        gen = with_gains(gains)
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

        def with_even(gains: dict[int, float]) -> list[dict]:
            even = {"step": "even_out", "gain": _table(gains, 3), "cut": EVEN_CUT}
            return pipeline[:thin_at + 1] + [even] + pipeline[thin_at + 1:]

        def generator(pipe: list[dict]):
            model = diffsampler_rt.Model(model_path)
            model.card = {**model.card, "pipeline": pipe}
            return lambda n, c: model.generate(n, c, seed=seed)

        gains, figures = evening(generator(pipeline), held_in,
                                 with_gains=lambda g: generator(with_even(g)))
        how = ("mean radial power below 0.5 sqrt(n), generated / held-in, in the last of the "
               "rounds: " + ", ".join(f"{f['power_ratio']:.3f} (+-{f['log_se']:.3f} in log, "
                                      f"round {f['rounds']}) at n = {n}"
                                      for n, f in sorted(figures.items())))
        if any(gains.values()):
            pipeline = with_even(gains)
            notes.append({"step": "even_out", "how": how + "; gain per size "
                          + ", ".join(f"{g:.3f}" for _, g in sorted(gains.items()))
                          + ": the deviations kept, 1 - gain, divided by sqrt(ratio) each "
                          "round where the ratio is off by more than twice its standard "
                          f"error (at most {EVEN_ROUNDS} rounds)"})
        else:
            notes.append({"step": "even_out", "how": how + ": within noise, no evening"})
        log("calibration: " + notes[-1]["how"])
        _write(model_path, pipeline, notes)
    return diffsampler_rt.Model(model_path).card


def _write(path, pipeline: list[dict], notes: list[dict]) -> None:
    from export.defaults import edit_card

    def edit(card: dict) -> None:
        card["pipeline"] = pipeline
        card["calibration"] = notes

    edit_card(path, edit)
