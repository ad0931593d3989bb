"""Fixes applied after the network, measured: why the runtime applies only two of them.

The learned sets miss two things their samplers have exactly: combinatorial structure
(Sobol'+Owen sets are (0, m, 2)-nets; LDBN sets have one point per 1/n strip of each axis)
and the hard-core spacing of blue noise (minimum distance 15-25 % short). Each fix below is
the obvious post-hoc repair; the report shows what it does to the other statistics, against
the reference sampler, in one run:

* ``net projection``: y-strata by rank, then x-halves split level by level between the two
  points of each sibling y-stratum pair (smaller x to the left). Any set becomes a
  (0, m, 2)-net; a net is left unchanged. Fine digits below 1/n are kept. Global: points
  move across many grid cells.
* ``cell-preserving net repair`` (:mod:`diffsampler_rt.structure`, what the runtime does for
  sobol_owen): the same net condition restored inside each column and row of grid cells, so
  no point leaves its cell.
* ``1-d stratification``: each coordinate's 1/n stratum becomes its rank (keeps every point
  in its grid cell for a stratified set).
* ``minimum spacing`` (:mod:`diffsampler_rt.spacing`, what the runtime does for the
  blue-noise models): pairs closer than the card's radius pushed apart, all other points kept.
* ``renoise-denoise``: after sampling, noise the set to a small timestep t and denoise it
  again in one step, a few times (a corrector that sharpens the fine structure).
* ``ancestral DDPM``: stochastic sampling with more steps instead of DPM-Solver++(2M).

Writes benchmarks/results/post_processing.md.

    python benchmarks/post_processing.py [--sets 128]
"""
from __future__ import annotations

import argparse
import datetime as dt
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
from trainer import zoo  # noqa: E402
zoo.use()  # model names are the repository's networks (models/), not the wheel's copies

import diffsampler_rt  # noqa: E402
from benchmarks.common import model_hash  # noqa: E402
from diffsampler_rt.grid import decode  # noqa: E402
from diffsampler_rt.finish.pipeline import find  # noqa: E402
from diffsampler_rt.spacing import enforce_min_spacing  # noqa: E402
from diffsampler_rt.structure import impose_dyadic_net  # noqa: E402
from diffsampler_rt.schedule import timesteps  # noqa: E402
from diffsampler_rt.solvers import solve  # noqa: E402
from trainer.samplers import sample  # noqa: E402
from trainer.stats import (empty_elementary_fraction, l2_star, min_distance,  # noqa: E402
                           radial_spectrum, spectrum_mae, stratified_projections)

_BELOW_ONE = np.nextafter(1.0, 0.0)


def _ranks(v: np.ndarray) -> np.ndarray:
    order = np.argsort(v, axis=-1, kind="stable")
    ranks = np.empty_like(order)
    np.put_along_axis(ranks, order, np.arange(v.shape[-1])[None, :], axis=-1)
    return ranks


def _place(stratum: np.ndarray, v: np.ndarray, n: int) -> np.ndarray:
    """Coordinate in 1/n stratum ``stratum`` keeping v's position inside its own stratum."""
    out = (stratum + (v * n - np.floor(v * n))) / n
    for _ in range(4):  # stratum + frac may round up to the next integer
        out = np.where(np.floor(out * n) > stratum, np.nextafter(out, 0.0), out)
    return np.minimum(out, _BELOW_ONE)


def stratify_1d(sets: np.ndarray) -> np.ndarray:
    n = sets.shape[1]
    return np.stack([_place(_ranks(sets[..., c]), sets[..., c], n) for c in range(2)], -1)


def project_to_net(sets: np.ndarray) -> np.ndarray:
    n = sets.shape[1]
    m = n.bit_length() - 1
    x = sets[..., 0]
    j = _ranks(sets[..., 1])
    prefix = np.zeros_like(j)
    half = np.broadcast_to(np.arange(n) & 1, j.shape)
    for level in range(1, m + 1):
        pair = (prefix << (m - level)) | (j >> level)
        order = np.argsort(pair + x, axis=-1, kind="stable")
        bit = np.empty_like(j)
        np.put_along_axis(bit, order, half, axis=-1)
        prefix = (prefix << 1) | bit
    return np.stack([_place(prefix, x, n), _place(j, sets[..., 1], n)], -1)


def _torus_shift(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    d = np.abs(a - b)
    return np.linalg.norm(np.minimum(d, 1 - d), axis=-1)


def renoise(model, grid: np.ndarray, t: int, times: int, rng) -> np.ndarray:
    """``times`` rounds of: noise the scaled offsets to timestep t, denoise in one step."""
    ab = model.alpha_bar[t]
    for _ in range(times):
        xt = np.sqrt(ab) * grid + np.sqrt(1 - ab) * rng.standard_normal(grid.shape)
        grid = (xt - np.sqrt(1 - ab) * model.denoise(xt, t)) / np.sqrt(ab)
    return grid


def row(label: str, sets: np.ndarray, ref: np.ndarray, spec_ref, moved: str = "") -> str:
    n = sets.shape[1]
    rel = lambda f: 100 * (f(sets).mean() / f(ref).mean() - 1)  # noqa: E731
    extra = []
    if n & (n - 1) == 0:
        extra.append(f"{100 * empty_elementary_fraction(sets).mean():.1f} %")
    extra.append(f"{100 * stratified_projections(sets).mean():.0f} %")
    return (f"| {label} | {spectrum_mae(radial_spectrum(sets), spec_ref):.4f} | "
            f"{rel(l2_star):+.1f} % | {rel(min_distance):+.1f} % | " + " | ".join(extra)
            + f" | {moved} |")


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--sets", type=int, default=128)
    p.add_argument("--n", type=int, default=1024)
    a = p.parse_args()
    n, S = a.n, a.sets
    k = int(np.sqrt(n))
    head = ("| setting | spectrum MAE | L2* | min distance | empty el. intervals | "
            "1-d stratified sets | mean shift (1/k) |\n|---|---|---|---|---|---|---|")
    lines = ["# Post-hoc fixes vs the reference sampler", "",
             f"`python benchmarks/post_processing.py --sets {S} --n {n}` on "
             f"{dt.date.today().isoformat()}. Generated sets: the bundled model at its card's "
             f"defaults, {S} sets; reference batch A ({4 * S} sets) for the comparison, an "
             f"independent batch B ({S} sets) for the noise floor. Relative differences of the "
             "means; *mean shift*: how far the fix moved the points on average, in grid "
             "cells (toroidal).", ""]
    for name, fixes in (("sobol_owen", (("net projection", project_to_net),
                                        ("cell-preserving net repair (runtime)",
                                         lambda g: impose_dyadic_net(g, k)))),
                        ("ldbn", (("1-d stratification", stratify_1d),))):
        # the network's sets as decoded, without the structure a card may ask for
        gen = diffsampler_rt.generate(name, n, S, seed=5, structure=False)
        ref, floor = sample(name, n, count=4 * S, seed=100), sample(name, n, count=S, seed=200)
        spec = radial_spectrum(ref)
        lines += [f"## {name}, n = {n}: {' vs '.join(f for f, _ in fixes)}", "", head,
                  row("reference B (floor)", floor, ref, spec), row("model", gen, ref, spec)]
        for fix, fn in fixes:
            fixed = fn(gen)
            lines.append(row(f"model + {fix}", fixed, ref, spec,
                             f"{k * _torus_shift(fixed, gen).mean():.2f}"))
        lines.append("")
        print(f"{name} done", flush=True)
    name = "poisson_disk"
    m = diffsampler_rt.load(name)
    scale = float(m.card["offset_scale"])
    rng = np.random.default_rng(5)
    grid = solve(m.card["default_solver"], m.denoise, rng.standard_normal((S, 2, k, k)),
                 m.alpha_bar, timesteps(len(m.alpha_bar), m.card["default_steps"]))
    gen = decode(grid / scale)
    ref, floor = sample(name, n, count=2 * S, seed=100), sample(name, n, count=S, seed=200)
    spec = radial_spectrum(ref)
    lines += [f"## {name}, n = {n}: minimum spacing, renoise-denoise and ancestral sampling",
              "",
              f"Model file sha256 {model_hash(m.path)[:12]} ({m.card['training_steps']} steps"
              + (f" from {m.card['config']['init_from']}" if m.card["config"].get("init_from")
                 else "") + ").", "", head,
              row("reference B (floor)", floor, ref, spec),
              row(f"model ({m.card['default_solver']} {m.card['default_steps']})", gen, ref, spec)]
    c = find(m.card["pipeline"], "min_spacing")["c"]  # a number in these models' cards
    spaced = enforce_min_spacing(gen, c / np.sqrt(n))
    lines.append(row(f"+ minimum spacing {c:g} / sqrt(n) (runtime; "
                     f"{100 * np.mean(np.any(spaced != gen, axis=-1)):.1f} % of the points "
                     "moved)", spaced, ref, spec, f"{k * _torus_shift(spaced, gen).mean():.3f}"))
    for t, times in ((30, 1), (30, 4), (60, 1), (60, 4), (120, 4)):
        fixed = decode(renoise(m, grid, t, times, np.random.default_rng(t + times)) / scale)
        lines.append(row(f"+ renoise-denoise at t = {t}, {times}x", fixed, ref, spec,
                         f"{k * _torus_shift(fixed, gen).mean():.2f}"))
    for steps in (100, 250):
        lines.append(row(f"ddpm {steps} steps", m.generate(n, S, seed=5, solver="ddpm",
                                                           steps=steps, structure=False),
                         ref, spec))
    lines.append("")
    out = ROOT / "benchmarks" / "results" / "post_processing.md"
    out.write_text("\n".join(lines))
    print(f"wrote {out}")


if __name__ == "__main__":
    main()
