"""Finishing steps chosen from held-in example sets by fixed procedures (never by hand).

``calibrate`` writes a model's pipeline from these findings, in order:

1. **Structure** (:mod:`.analysis`): where every example set is a (0, m, 2)-net, has
   stratified projections, or is a rank-1 lattice, the matching structure step (a lattice at
   the example sizes only: its generator is chosen per n). Nets whose points are listed in
   (0, 2)-sequence order (every first 2^j points a net) make other n the first points of
   the next net (``prefix``).
2. **Minimum spacing and thinning**: every model keeps the examples' floor, ``min_spacing``
   with c per size = the 5th percentile of the sets' smallest pairwise distance times
   sqrt(n) (``trainer.stats.spacing_coefficient``; on the torus for a toroidal model): a
   generated pair closer than 95 % of the example sets' closest pairs is pushed apart. A
   hard core (dart throwing, a thinned blue-noise set, trees that keep their trunks apart)
   is kept where the network would let two points meet; for sets without one (uniform
   random, jittered, clustered) the floor is far below the typical spacing and moves only
   the closest pairs. Sets with coinciding points (c = 0) get none. The examples are blue
   noise where their points keep apart: the 1st percentile of every point's
   nearest-neighbour distance, times sqrt(n), is at least ``BLUE_NOISE`` at every size
   (``trainer.stats.nearest_neighbour_percentile``; uniform random sets have 0.057 at any n,
   jittered grids 0.16, clustered sets less; dart throwing, relaxed sets and perturbed
   lattices 0.45-0.75), a statistic of the process, not of the set's extreme; blue-noise
   models' thinning drops the most crowded points, other models' drops points at random.
   With a net or stratified projections the spacing runs before the structure step (which
   keeps points in their cells); a lattice, which replaces the set, gets it only where the
   lattice does not hold. After the searches (3.), c is raised where the network lets points
   come closer than the examples do: to the 15th, 30th or 50th percentile of their smallest
   distance, size by size, where that brings the sets' mean smallest distance closer to the
   held-in sets' by more than three standard errors (values from the same seeds, their
   spectrum no further off, their integration figures not straying).
3. **Searched steps** (:data:`SEARCHES`, in that order): the starting noise's temperature (a
   gain on every mode: a colder start gives more ordered sets), its coarse-mode gain, the
   structure imposed on the last solver steps' predictions (where a structure holds), sliced
   optimal-transport iterations, and the large-scale evening. For each, the model's sets
   (with every step chosen so far) are made at each example size with each of the step's
   candidate values, and their mean radial spectrum compared with the held-in sets' (mean
   absolute difference of their logarithms over every bin: the large scales, whose power is
   small but sets how well smooth functions are integrated, weigh as much as the peak; a
   value that fixes them but disturbs the pattern pays for it). A size gets the candidate
   with the smallest difference where its gain over the pipeline without the step is real:
   every candidate is made from the same seeds, and the gain must exceed three standard
   errors, taken from the gains in eight folds (every eighth generated set against every
   eighth held-in set); else none. A step no size gets is left out. The sets' integration
   figures hold the spectrum to account: a value whose sets' mean star L2 discrepancy or
   mean Gaussian integration error (random anisotropic Gaussians: smooth integrands, whose
   error follows the largest scales) is more than 5 % further from the held-in sets' than
   without the step (and beyond two standard errors) is not taken. Where the spectrum cannot
   tell the values apart and the sets miss one of these figures by more than 5 % (and two
   standard errors of the held-in sets' mean), the value that brings it closest (by more
   than three standard errors, its spectrum no further off) is taken, star L2 first. A
   gross miss (a figure more than twice the held-in sets', or under half) is mended first,
   where the spectrum's own choice leaves it: the value that brings it within that factor
   and closest is taken, its spectrum further off or not. The spectrum's bins start at
   0.0625 sqrt(n), so what sits at the largest scales (a density's or the network's
   leftover power, at 4096 points the first four frequencies) shows only there. Steps
   acting on the points are not searched where a structure step holds (they would move
   points off it).

A model with a density map (non-uniform examples) is calibrated in the uniform square: the
held-in sets and the model's sets are unwarped by its map first, where its point steps act.
Every choice is recorded with its figures in the card (``"calibration"``).
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, Callable

import numpy as np

from .choice import GAIN_SE, TOLERANCE, Target, choose, decide_spacing, targets

#: the 1st percentile of the nearest-neighbour distance x sqrt(n) from which examples count
#: as blue noise: halfway (in ratio) between jittered grids' 0.16 and perturbed lattices' 0.45
BLUE_NOISE, NN_PERCENTILE = 0.3, 1.0
SPACING_PERCENTILE = 5.0
#: the percentiles of the held-in sets' smallest distance the spacing's c is searched
#: among, after every other step (the first: the floor every spacing starts from)
SPACING_PERCENTILES = (SPACING_PERCENTILE, 15.0, 30.0, 50.0)
@dataclass(frozen=True)
class Search:
    """A step whose parameter ``param`` is chosen per size among ``values``; ``entry`` holds
    its other parameters, ``off`` is the value that leaves the sets as they are; ``what``
    names the search in its note where the step's name alone would not."""
    entry: dict
    param: str
    values: tuple
    off: Any
    what: str = ""

    @property
    def step(self) -> str:
        return self.entry["step"]


#: the searched steps, in the order they are chosen
SEARCHES = (
    Search({"step": "coarse_noise", "cut": 1.0}, "gain", (0.8, 0.9, 1.1), 1.0,
           "temperature (a gain on every mode of the starting noise)"),
    Search({"step": "coarse_noise", "cut": 0.25}, "gain", (0.8, 1.25, 1.5), 1.0,
           "coarse-mode gain (up to 0.25 x Nyquist)"),
    Search({"step": "structure_guidance"}, "steps", (1, 2, 3), 0),
    Search({"step": "sliced_ot", "directions": 128}, "iterations", (2, 5, 12, 24), 0),
    Search({"step": "even_out", "cut": 0.5}, "gain", (-0.5, -0.25, 0.25, 0.5, 0.75, 0.9), 0.0),
)
#: the evening's candidates with "off"
EVEN_GAINS = tuple(sorted((SEARCHES[-1].off, *SEARCHES[-1].values)))


def _table(values: dict[int, float], digits: int = 4) -> Any:
    """A per-size pipeline value: one number for one size, else {"n": ..., "values": ...}."""
    sizes = sorted(values)
    vals = [v if isinstance(v := values[n], int) else round(float(v), digits) for n in sizes]
    return vals[0] if len(sizes) == 1 else {"n": sizes, "values": vals}


def spacing(held_in: dict[int, np.ndarray], toroidal: bool = False
            ) -> tuple[dict[int, float], bool, dict[int, float]]:
    """Per size: the spacing coefficient (the examples' floor, which ``min_spacing`` keeps;
    on the torus for a toroidal model, whose step keeps it there), whether the examples
    are blue noise, and the nearest-neighbour statistic that decided it."""
    from trainer.stats.distance import nearest_neighbour_percentile
    cs = {n: floor_c(sets, SPACING_PERCENTILE, toroidal) for n, sets in held_in.items()}
    core = {n: nearest_neighbour_percentile(sets, NN_PERCENTILE) for n, sets in held_in.items()}
    # sets with coinciding points (c = 0) have no spacing to keep, whatever the rest does
    blue = all(v >= BLUE_NOISE for v in core.values()) and min(cs.values()) > 0
    return cs, blue, core


def floor_c(sets: np.ndarray, percentile: float, toroidal: bool = False) -> float:
    """The spacing coefficient at ``percentile`` of the sets' smallest distance, as a card
    holds it: rounded to 4 digits (0 where coinciding points leave nothing to keep) and
    under the runtime's limit (a hexagonal lattice's 1.0746 in the limit of large n)."""
    from trainer.stats.distance import spacing_coefficient
    return _card_c(spacing_coefficient(sets, percentile, toroidal=toroidal))


def _card_c(c: float) -> float:
    """A spacing coefficient as a card holds it (see :func:`floor_c`)."""
    from diffsampler_rt.spacing import MAX_SPACING
    return min(round(float(c), 4), round(MAX_SPACING - 1e-3, 4))


def in_sequence_order(sets: np.ndarray) -> bool:
    """Whether every set's first 2^j points are a (0, j, 2)-net for every j: points listed
    in the order of a (0, 2)-sequence (Sobol'), so that a set's first points are a good
    smaller set."""
    from trainer.stats.structure import t_value
    m = sets.shape[1].bit_length() - 1
    return all(bool(np.all(t_value(sets[:, :1 << j]) == 0)) for j in range(1, m))


def structure_entry(name: str | None, sizes: list[int],
                    held_in: dict[int, np.ndarray] | None = None) -> dict | None:
    """The structure step: a lattice at the example sides; a net from the smallest one,
    with ``prefix`` (n between powers of four: the first n points of the next net) where
    the held-in sets list their points in sequence order."""
    if name is None:
        return None
    sides = sorted(math.isqrt(n) for n in sizes)
    if name == "rank1_lattice":
        return {"step": name, "sides": sides}
    entry = {"step": name, "min_side": sides[0]}
    if name == "dyadic_net" and held_in and all(in_sequence_order(held_in[n]) for n in sizes):
        entry["prefix"] = True
    return entry


def base_pipeline(structure: dict | None, cs: dict[int, float], blue: bool) -> list[dict]:
    """Structure, thinning and spacing in the order that keeps an imposed structure exact:
    the spacing goes before a structure that keeps the points in their cells (a net,
    stratified projections) where it holds, and after thinning elsewhere. A lattice
    replaces the set, spacing and all: spacing its points first would only change which
    lattice they are closest to. Blue-noise sets thin their most crowded points first."""
    spaced = {"step": "min_spacing", "c": _table(cs)} if min(cs.values()) > 0 else None
    thin = {"step": "thin", "drop": "crowded" if blue else "random"}
    if structure is None:
        return [thin] + ([spaced] if spaced else [])
    if spaced is None:
        return [structure, thin]
    before = [{**spaced, "where": "structured"}] if _projects(structure) else []
    return before + [structure, thin, {**spaced, "where": "unstructured"}]


def base_notes(cs: dict[int, float], blue: bool, core: dict[int, float],
               toroidal: bool) -> list[dict]:
    """How the thinning and the spacing were chosen (:func:`spacing`'s figures)."""
    per_size = ", ".join(f"{core[n]:.3f} at n = {n}" for n in sorted(core))
    notes = [{"step": "thin", "how": f"{NN_PERCENTILE:g}st percentile of the held-in points' "
              f"nearest-neighbour distance x sqrt(n): {per_size} "
              + (f"(>= {BLUE_NOISE} at every size: blue noise, crowded points thinned first)"
                 if blue else f"(below {BLUE_NOISE}: not blue noise, random thinning)")}]
    floor = ", ".join(f"{c:.4g} at n = {n}" for n, c in sorted(cs.items()))
    notes.append({"step": "min_spacing", "how": f"c = the {SPACING_PERCENTILE:g}th "
                  "percentile of the held-in sets' smallest distance"
                  + (" on the torus" if toroidal else "") + f" x sqrt(n): {floor}"
                  + ("" if min(cs.values()) > 0 else " (coinciding points: no spacing)")})
    return notes


def evening(generate, held_in):
    """:func:`choose` for the even_out gain (candidates :data:`EVEN_GAINS`)."""
    chosen, figures = choose(tuple(g for g in EVEN_GAINS if g), 0.0, generate, held_in)
    for f in figures.values():
        f["gain"] = f.pop("value")
    return chosen, figures


def _insert(pipeline: list[dict], entry: dict, phase: str) -> list[dict]:
    """``entry`` where its phase runs: noise steps first, point steps after thinning (and
    after the point steps already chosen), before the minimum spacing."""
    if phase != "points":
        return [entry] + pipeline
    spaced = [i for i, e in enumerate(pipeline) if e["step"] == "min_spacing"]
    at = spaced[-1] if spaced else len(pipeline)
    return pipeline[:at] + [entry] + pipeline[at:]


def _maker(model_path, seed: int, unwarp_sets: Callable[[np.ndarray], np.ndarray]):
    """``maker(pipeline)(n, count)``: the model's sets with that pipeline, from ``seed``."""
    import diffsampler_rt
    model = diffsampler_rt.Model(model_path)

    def maker(pipeline: list[dict]) -> Callable[[int, int], np.ndarray]:
        def make(n: int, count: int) -> np.ndarray:
            model.card = {**model.card, "pipeline": pipeline}
            return unwarp_sets(model.generate(n, count, seed=seed))
        return make
    return maker


def _key(pipeline: list[dict]) -> str:
    """A pipeline's measurements' key in a calibration's memo."""
    import json
    return json.dumps(pipeline, sort_keys=True)


def search(model_path, pipeline: list[dict], how: Search, held_in, goal: dict, seed: int,
           unwarp_sets: Callable[[np.ndarray], np.ndarray], memo: dict | None = None
           ) -> tuple[list[dict], dict]:
    """The pipeline with ``how``'s step where it helps, and the note of how it was chosen;
    ``memo`` keeps every pipeline's measurements across the searches of one calibration."""
    from diffsampler_rt.finish import STEPS
    phase = STEPS[how.step].phase
    maker = _maker(model_path, seed, unwarp_sets)

    def with_value(v: Any) -> list[dict]:
        if v == how.off:
            return pipeline
        return _insert(pipeline, {**how.entry, how.param: v}, phase)

    chosen, figures = choose(how.values, how.off, lambda v: maker(with_value(v)), held_in,
                             goal, memo=memo, key=lambda v: _key(with_value(v)))
    text = ((f"{how.what}: " if how.what else "")
            + f"log radial spectrum, mean absolute difference from the held-in sets' with "
            f"{how.param} {', '.join(f'{v:g}' for v in (how.off, *how.values))}: "
            + "; ".join(f"at n = {n}: " + _decision_text(f, how.off)
                        for n, f in sorted(figures.items())))
    if all(v == how.off for v in chosen.values()):
        return pipeline, {"step": how.step, "how": text + ": no value taken (none gains over "
                          f"none by more than {GAIN_SE:g} standard errors with its "
                          "integration figures in bounds, nor mends one), left out"}
    return with_value(_table(chosen, 3)), {"step": how.step, "how": text + "; the value with "
                                           "the smallest difference where its gain over none "
                                           f"exceeds {GAIN_SE:g} standard errors; where none "
                                           "does and an integration figure misses by more "
                                           f"than {100 * TOLERANCE:g} %, the value that mends it"}


#: how a decision's integration figures are named in a note
_FIGURE_NAMES = {"l2_star": "star L2", "gauss_mse": "Gaussian integration"}


def _decision_text(f: dict, off: Any) -> str:
    """One size's decision in a search's note: the differences, the best value and its
    error, each integration figure against the held-in sets', the value and why."""
    figs = "; ".join(_FIGURE_NAMES[k] + " " + ", ".join(f"{100 * d:+.1f} %" for d in
                                                         f[k].values())
                     for k in _FIGURE_NAMES if k in f)
    return (", ".join(f"{m:.4f}" for m in f["difference"].values())
            + (f" (best {f['best']:g}: its gain's standard error {f['gain_se']:.4f}; "
               if f["best"] != off else " (none closer than leaving it out; ")
            + figs + f") -> {f['value']:g}" + (f" (by {f['by']})" if f["by"] not in
                                                (None, "spectrum") else ""))


def spacing_search(model_path, pipeline: list[dict], held_in, goal: dict[int, Target],
                   seed: int, unwarp_sets: Callable[[np.ndarray], np.ndarray],
                   memo: dict | None = None) -> tuple[list[dict], dict | None]:
    """The pipeline with its spacing's c raised, size by size, to the percentile of the
    held-in sets' smallest distance (:data:`SPACING_PERCENTILES`) that brings the sets'
    mean smallest distance closest to theirs (:func:`decide_spacing`), and the note; no
    change (and no note) without a spacing."""
    if not any(e["step"] == "min_spacing" for e in pipeline):
        return pipeline, None
    toroidal = next(iter(goal.values())).toroidal
    from trainer.stats.distance import min_distance
    # each size's smallest distances once, their percentiles from them (= floor_c)
    smallest = {n: min_distance(sets, toroidal) * math.sqrt(n) for n, sets in held_in.items()}
    table = {p: {n: _card_c(np.percentile(d, p)) for n, d in smallest.items()}
             for p in SPACING_PERCENTILES}
    floor, *higher = SPACING_PERCENTILES

    def with_c(cs: dict[int, float]) -> list[dict]:
        return [{**e, "c": _table(cs)} if e["step"] == "min_spacing" else e for e in pipeline]

    maker = _maker(model_path, seed, unwarp_sets)
    chosen, figures = choose(tuple(higher), floor, lambda p: maker(with_c(table[p])), held_in,
                             goal, memo=memo, key=lambda p: _key(with_c(table[p])),
                             rule=decide_spacing)
    text = ("c: the held-in sets' smallest distance at its "
            + ", ".join(f"{p:g}th" for p in (floor, *higher)) + " percentile; the sets' mean "
            "smallest distance against the held-in sets' with each: " + "; ".join(
                f"at n = {n}: " + ", ".join(f"{100 * d:+.1f} %" for d in f["smallest"].values())
                + f" -> {f['value']:g}th (c = {table[f['value']][n]:.4g})"
                for n, f in sorted(figures.items()))
            + f"; the percentile that comes closest where it gains more than {GAIN_SE:g} "
            "standard errors over the floor, its spectrum no further off and its integration "
            "figures not straying")
    return with_c({n: table[p][n] for n, p in chosen.items()}), {"step": "min_spacing",
                                                                  "how": text}


def calibrate(model_path, held_in: dict[int, np.ndarray], structure: str | None,
              structure_sizes: list[int], *, seed: int = 0, searches: tuple = SEARCHES,
              log: Callable[[str], None] = print) -> dict:
    """Choose the finishing steps of the model in ``model_path`` from ``held_in`` sets (by
    size) and write them into its card; returns the card. A model with a density map is
    calibrated in the square, its held-in sets unwarped by that map."""
    import diffsampler_rt
    from diffsampler_rt.density import unwarp
    card = diffsampler_rt.Model(model_path).card
    density, toroidal = card.get("density"), card.get("padding") == "circular"
    to_square = (lambda sets: sets) if density is None else (lambda sets: unwarp(sets, density))
    held_in = {n: to_square(np.asarray(sets, dtype=np.float64)) for n, sets in held_in.items()}
    few = {n: len(sets) for n, sets in held_in.items() if len(sets) < 2}
    if few:  # the gains' standard errors need two sets at least
        raise ValueError("calibration needs at least 2 example sets at each size, got "
                         + ", ".join(f"{c} at n = {n}" for n, c in sorted(few.items())))
    cs, blue, core = spacing(held_in, toroidal)
    notes = base_notes(cs, blue, core, toroidal)
    entry = structure_entry(structure, structure_sizes, held_in)
    if entry:
        notes.append({"step": entry["step"], "how": "every example set has it at "
                      f"n = {', '.join(map(str, structure_sizes))} (from the smallest on)"
                      + ("; every set's first 2^j points are a (0, j, 2)-net, so other n "
                         "take the first points of the next net" if entry.get("prefix")
                         else "")})
    pipeline = base_pipeline(entry, cs, blue)
    _write(model_path, pipeline, notes)
    log("calibration: " + "; ".join(n["how"] for n in notes))
    from diffsampler_rt.finish import STEPS
    goal, memo = (targets(held_in, toroidal) if searches else {}), {}
    for how in searches:
        if entry is not None and STEPS[how.step].phase == "points":
            continue
        if STEPS[how.step].needs_structure and not _projects(entry):
            continue
        pipeline, note = search(model_path, pipeline, how, held_in, goal, seed, to_square,
                                memo)
        notes.append(note)
        log(f"calibration: {how.step}: {note['how']}")
        _write(model_path, pipeline, notes)
    if searches and (entry is None or _projects(entry)):  # a lattice holds at every example size
        pipeline, note = spacing_search(model_path, pipeline, held_in, goal, seed, to_square,
                                        memo)
        if note:
            notes.append(note)
            log(f"calibration: min_spacing: {note['how']}")
            _write(model_path, pipeline, notes)
    return diffsampler_rt.Model(model_path).card


def _projects(entry: dict | None) -> bool:
    """Whether the structure step can impose itself on a predicted set (nets and
    stratified projections can; a lattice replaces the set and cannot)."""
    from diffsampler_rt.finish import STEPS
    from diffsampler_rt.finish.base import Step
    return entry is not None and type(STEPS[entry["step"]]).project is not Step.project


def _write(path, pipeline: list[dict], notes: list[dict]) -> None:
    from export.defaults import edit_card

    def edit(card: dict) -> None:
        card["pipeline"] = pipeline
        card["calibration"] = notes

    edit_card(path, edit)
