"""How a calibration's searches compare candidate values with the held-in example sets, and
decide (the rules ``trainer.fitting.calibrate`` runs; its docstring says them in words).

Every candidate value's sets are made from the same seeds, so values are compared set by
set: a gain's standard error comes from folds (every k-th generated set against every k-th
held-in set) or from per-set differences, and holds the noise of both sides and how the
value's effect varies from set to set.
"""
from __future__ import annotations

import functools
import math
from dataclasses import dataclass, field
from typing import Any, Callable

import numpy as np

from diffsampler_rt.spectrum import radial_spectrum

#: sets generated per size and candidate value; the folds a gain's standard error comes
#: from (fewer where fewer sets are held in), and how many of them a gain must exceed: on
#: candidates that only draw other random sets, 1 false gain in 100 searches of 5 values
SEARCH_SETS, FOLDS, GAIN_SE = 64, 8, 3.0
#: the size up to which a candidate makes :data:`SEARCH_SETS` sets; above it, as many
#: points (each set's spectrum bins hold more frequencies, so fewer sets measure it as well)
SEARCH_POINTS_N = 1024
#: the power added to both spectra before their logarithms are compared: a thousandth of
#: white noise's, below which a difference in the large scales no longer shows in any figure
LOG_FLOOR = 1e-3
#: how much further (relative) than without the step a value's integration figures (mean
#: star L2 discrepancy, mean Gaussian integration error) may stray from the held-in sets'
#: and still be taken, and beyond which a miss is repaired: the fit targets' tolerance
TOLERANCE = 0.05
#: the factor beyond which an integration figure's miss is gross: the spectrum's bins start at
#: 0.0625 sqrt(n), so the largest scales (a density's or the network's leftover power
#: there) show only in these figures, and a gross miss is mended before the spectrum decides
GROSS = 2.0
#: the smooth integrands of the Gaussian integration figure (fixed: every set sees the same)
GAUSSIANS, GAUSSIANS_SEED = 256, 11


@functools.cache
def _gaussians():
    """The Gaussian integrands and their exact integrals, made once per process."""
    from trainer.stats.integration import Gaussians
    f = Gaussians.random(GAUSSIANS, seed=GAUSSIANS_SEED)
    return f, f.integrals()


def gaussian_mse(sets: np.ndarray) -> np.ndarray:
    """Per set: the mean squared error of integrating :data:`GAUSSIANS` random anisotropic
    Gaussians (``trainer.stats.Gaussians``) with the set's points. Smooth integrands'
    error follows the sets' power at the largest scales, which neither the spectrum's
    peak nor the star L2 discrepancy (boxes anchored at the origin) weighs alone."""
    from trainer.stats.integration import integration_mse
    return integration_mse(sets, *_gaussians())


def search_sets(n: int) -> int:
    """Sets a candidate makes at size ``n``: :data:`SEARCH_SETS`, and above
    :data:`SEARCH_POINTS_N` points as many points in all, two sets a fold at least."""
    return max(SEARCH_SETS * SEARCH_POINTS_N // max(n, SEARCH_POINTS_N), 2 * FOLDS)


def fold_spectra(sets: np.ndarray, k: int) -> tuple[np.ndarray, list[np.ndarray]]:
    """The mean radial spectrum of ``sets`` and those of its k folds (every k-th set). The
    spectrum is linear in the sets' periodograms, so the whole is the folds' weighted mean:
    each set is transformed once."""
    parts = [radial_spectrum(sets[i::k])[1] for i in range(k)]
    return np.average(parts, axis=0, weights=[len(sets[i::k]) for i in range(k)]), parts


def log_spectrum_difference(a: np.ndarray, b: np.ndarray) -> float:
    """Mean absolute difference of two radial spectra's logarithms (each + :data:`LOG_FLOOR`).

    On a linear scale the bins around the spectral peak (power about 1) outweigh the large
    scales, whose power is 1e-4 to 1e-2 in blue-noise and stratified sets; yet a two-fold
    excess there is what smooth integrands' error grows with. Ratios weigh every bin alike.
    """
    return float(np.mean(np.abs(np.log(np.asarray(a) + LOG_FLOOR)
                                - np.log(np.asarray(b) + LOG_FLOOR))))


@dataclass(frozen=True)
class Target:
    """One size's held-in sets as the searches compare with them: their mean radial
    spectrum and its folds', their mean star L2 discrepancy and mean smallest distance
    x sqrt(n) (on the torus for a toroidal model), their mean Gaussian integration error
    (:func:`gaussian_mse`; None: not compared), and the standard errors of the held-in
    means of the integration figures (``se``: "l2", "gauss")."""
    spectrum: np.ndarray
    folds: list
    l2: float
    smallest: float
    toroidal: bool = False
    gauss: float | None = None
    se: dict = field(default_factory=dict)


def _mean_se(x: np.ndarray) -> float:
    return float(np.std(x, ddof=1)) / math.sqrt(len(x))


def targets(held_in: dict[int, np.ndarray], toroidal: bool = False) -> dict[int, Target]:
    """Per size: the held-in sets' :class:`Target` (the folds: every k-th set, k =
    :data:`FOLDS` or the number of sets where fewer). Computed once per calibration:
    every search compares with them."""
    from trainer.stats.discrepancy import l2_star
    from trainer.stats.distance import min_distance
    out = {}
    for n, sets in held_in.items():
        whole, parts = fold_spectra(sets, min(FOLDS, len(sets)))
        l2, gauss = l2_star(sets), gaussian_mse(sets)
        out[n] = Target(whole, parts, float(l2.mean()),
                        float(min_distance(sets, toroidal).mean() * math.sqrt(n)), toroidal,
                        float(gauss.mean()), {"l2": _mean_se(l2), "gauss": _mean_se(gauss)})
    return out


@dataclass(frozen=True)
class Measured:
    """One candidate's sets at one size: their spectrum's difference from the held-in
    sets' (:func:`log_spectrum_difference`), the same per fold, each set's star L2,
    smallest distance x sqrt(n) and Gaussian integration error (None: not measured)."""
    difference: float
    folds: np.ndarray
    l2: np.ndarray
    smallest: np.ndarray
    gauss: np.ndarray | None = None


def measure(sets: np.ndarray, goal: Target) -> Measured:
    """``sets`` against one size's :class:`Target`."""
    from trainer.stats.discrepancy import l2_star
    from trainer.stats.distance import min_distance
    whole, parts = fold_spectra(sets, len(goal.folds))
    return Measured(log_spectrum_difference(whole, goal.spectrum),
                    np.array([log_spectrum_difference(s, r) for s, r in zip(parts, goal.folds)]),
                    l2_star(sets), min_distance(sets, goal.toroidal) * math.sqrt(sets.shape[1]),
                    None if goal.gauss is None else gaussian_mse(sets))


def _paired_se(a: np.ndarray, b: np.ndarray) -> float:
    """The standard error of the mean of a - b: per-set figures of two values made from
    the same seeds, which move set by set together (0 for a figure against itself)."""
    return 0.0 if len(a) == len(b) and np.array_equal(a, b) else _mean_se(a - b)


@dataclass(frozen=True)
class Figure:
    """An integration figure of the candidates at one size: its name, the held-in sets'
    mean and that mean's standard error, and each candidate's per-set values."""
    name: str
    ref: float
    ref_se: float
    per_set: dict

    def miss(self, v: Any) -> float:
        return abs(float(self.per_set[v].mean()) - self.ref)

    def relative(self, v: Any) -> float:
        return float(self.per_set[v].mean()) / self.ref - 1

    def log_miss(self, v: Any) -> float:
        """|log| of ``v``'s figure over the held-in sets' (0 where theirs is 0)."""
        mean = float(self.per_set[v].mean())
        return abs(math.log(mean / self.ref)) if mean > 0 and self.ref > 0 else 0.0

    def gross(self, v: Any) -> bool:
        """Whether ``v``'s figure is more than :data:`GROSS` times, or less than 1 /
        :data:`GROSS` times, the held-in sets'."""
        return self.log_miss(v) > math.log(GROSS)

    def allowed(self) -> float:
        """How far a figure may stray before it counts: :data:`TOLERANCE` of the held-in
        sets' figure, or two standard errors of their mean where that is more."""
        return max(TOLERANCE * self.ref, 2 * self.ref_se)


def figures(cands: dict[Any, Measured], goal: Target) -> list[Figure]:
    """The integration figures the candidates are held to: star L2, then the Gaussian
    integration error where it was measured."""
    out = [Figure("star L2", goal.l2, goal.se.get("l2", 0.0),
                  {v: c.l2 for v, c in cands.items()})]
    if goal.gauss is not None and all(c.gauss is not None for c in cands.values()):
        out.append(Figure("Gaussian integration", goal.gauss, goal.se.get("gauss", 0.0),
                          {v: c.gauss for v, c in cands.items()}))
    return out


def _fair(cands: dict[Any, Measured], off: Any, figs: list[Figure]) -> list:
    """The values none of whose integration figures strays more than :data:`TOLERANCE` of
    the held-in sets' figure (and two paired standard errors) further than ``off``'s."""
    def strays(f: Figure, v: Any) -> bool:
        se = _paired_se(f.per_set[v], f.per_set[off])
        return f.miss(v) > f.miss(off) + max(2 * se, TOLERANCE * f.ref)
    return [v for v in cands if not any(strays(f, v) for f in figs)]


def decide(cands: dict[Any, Measured], off: Any, goal: Target) -> tuple[Any, dict]:
    """The value taken at one size (see :func:`choose`) and the figures that decided it."""
    o, figs = cands[off], figures(cands, goal)
    fair = _fair(cands, off, figs)
    best = min(fair, key=lambda v: cands[v].difference)
    gains = o.folds - cands[best].folds
    gain_se = _mean_se(gains)
    spectral = best if o.difference - cands[best].difference > GAIN_SE * gain_se else off
    value, by = off, None
    if any(f.gross(spectral) for f in figs):  # mended first, where a value can
        value, by = _mend_gross(cands, off, fair, figs)
    if value == off:  # where the spectrum cannot tell them apart, mend a missed figure
        value, by = (best, "spectrum") if spectral != off else _mend(cands, off, fair, figs)
    out = {"difference": {f"{v:g}": round(c.difference, 5) for v, c in cands.items()}}
    out.update({_FIGURE_KEYS[f.name]: {f"{v:g}": round(f.relative(v), 4) for v in cands}
                for f in figs})
    return value, {**out, "best": best, "gain_se": round(gain_se, 5),
                   "fold_gains": [round(float(g), 5) for g in gains], "value": value, "by": by}


def _mend(cands: dict[Any, Measured], off: Any, fair: list, figs: list[Figure]
          ) -> tuple[Any, str | None]:
    """The fair value, its spectrum no further off than ``off``'s, that brings the first
    integration figure ``off`` misses (beyond :meth:`Figure.allowed`) closest, if it gains
    more than :data:`GAIN_SE` paired standard errors there, and the figure's name; else
    ``off``."""
    level = [v for v in fair if v != off and _not_worse(cands[v], cands[off])]
    for f in (f for f in figs if f.miss(off) > f.allowed()):
        mended = min(level, key=f.miss, default=off)
        if mended != off and f.miss(off) - f.miss(mended) > GAIN_SE * _paired_se(
                f.per_set[mended], f.per_set[off]):
            return mended, f.name
    return off, None


def _mend_gross(cands: dict[Any, Measured], off: Any, fair: list, figs: list[Figure]
                ) -> tuple[Any, str | None]:
    """Where ``off`` misses an integration figure grossly (:data:`GROSS`), the fair value
    that brings it within that factor and closest (in ratio), if it gains more than
    :data:`GAIN_SE` paired standard errors, and why; else ``off``. Its spectrum may be
    further off: the spectrum does not see the scales such a miss comes from."""
    for f in (f for f in figs if f.gross(off)):
        within = [v for v in fair if v != off and not f.gross(v)]
        mended = min(within, key=f.log_miss, default=off)
        if mended != off and f.miss(off) - f.miss(mended) > GAIN_SE * _paired_se(
                f.per_set[mended], f.per_set[off]):
            return mended, f"{f.name}, missed beyond a factor {GROSS:g}"
    return off, None


#: the keys of the integration figures in a decision's record
_FIGURE_KEYS = {"star L2": "l2_star", "Gaussian integration": "gauss_mse"}


def _not_worse(c: Measured, o: Measured) -> bool:
    """Whether ``c``'s spectrum is no further from the held-in sets' than ``o``'s beyond
    two standard errors of the folds' differences."""
    loss = c.folds - o.folds
    return float(loss.mean()) <= 2 * _mean_se(loss)


def decide_spacing(cands: dict[Any, Measured], off: Any, goal: Target) -> tuple[Any, dict]:
    """The spacing's percentile at one size: the one whose sets' mean smallest distance
    comes closest to the held-in sets', where it gains more than :data:`GAIN_SE` paired
    standard errors over ``off`` (the floor) without a spectrum further off or an
    integration figure that strays (:func:`_fair`)."""
    o = cands[off]
    fair = [v for v in _fair(cands, off, figures(cands, goal))
            if v == off or _not_worse(cands[v], o)]
    miss = {v: abs(float(c.smallest.mean()) - goal.smallest) for v, c in cands.items()}
    best = min(fair, key=miss.get)
    se = _paired_se(cands[best].smallest, o.smallest)
    value = best if miss[off] - miss[best] > GAIN_SE * se else off
    return value, {"smallest": {f"{v:g}": round(float(c.smallest.mean()) / goal.smallest - 1,
                                                 4) for v, c in cands.items()},
                   "difference": {f"{v:g}": round(c.difference, 5) for v, c in cands.items()},
                   "best": best, "se": round(se, 5), "value": value}


def choose(values: tuple, off: Any, generate: Callable[[Any], Callable[[int, int], np.ndarray]],
           held_in: dict[int, np.ndarray], goal: dict | None = None, *,
           memo: dict | None = None, key: Callable[[Any], Any] = repr,
           rule: Callable[[dict, Any, Target], tuple[Any, dict]] | None = None
           ) -> tuple[dict[int, Any], dict[int, dict]]:
    """The value per size and the figures; ``generate(value)`` makes sets (n, count) with
    that value at every size, from the same seeds for every value; ``goal`` is
    :func:`targets` of ``held_in`` where the caller has it already; ``memo`` keeps the
    measurements under (``key(value)``, n) for later searches (whose "off" is often a
    value measured here); ``rule`` decides at each size (:func:`decide`, the default, or
    :func:`decide_spacing`).

    The value with the smallest spectrum difference is taken where its gain over ``off`` is
    more than :data:`GAIN_SE` standard errors, the error from the gains in :data:`FOLDS`
    folds (every k-th generated set against every k-th held-in set). The values share
    their seeds, so the folds see the noise of the gain itself: the held-in sets' and the
    generated sets' noise, and how a value's effect varies from set to set. A value one of
    whose integration figures (:func:`figures`: the sets' mean star L2 discrepancy, their
    mean Gaussian integration error) is further from the held-in sets' than ``off``'s by
    more than :data:`TOLERANCE` (of the held-in sets' figure) and more than two paired
    standard errors is not taken: the spectrum alone would trade away the sets' uniformity
    (e.g. by moving a stratified set's points out of their strata) or their large scales.
    Where no value's spectrum gain is real and ``off`` misses an integration figure by more
    than :data:`TOLERANCE` (and two standard errors of the held-in sets' mean), the value
    that comes closest is taken if it gains more than three paired standard errors there
    without a spectrum further off (beyond two standard errors); star L2 first. Where the
    value the spectrum would take leaves an integration figure more than :data:`GROSS`
    times off (or under 1 / GROSS), the fair value that brings it within that factor and
    closest is taken first, its spectrum further off or not (:func:`_mend_gross`)."""
    goal = goal or targets(held_in)
    memo = {} if memo is None else memo
    rule = rule or decide
    for v in (off, *values):
        make = generate(v)
        for n in held_in:
            if (key(v), n) not in memo:
                memo[key(v), n] = measure(make(n, search_sets(n)), goal[n])
    chosen, records = {}, {}
    for n in held_in:
        cands = {v: memo[key(v), n] for v in (off, *values)}
        chosen[n], records[n] = rule(cands, off, goal[n])
    return chosen, records
