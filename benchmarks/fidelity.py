"""Fidelity of the networks (models/): generated vs reference sets side by side, in one run.

For every model and n in --sizes: the radial-spectrum mean absolute difference (79 bins)
between generated and reference sets, and the means of the OT energy, star L2 discrepancy,
Gaussian and Heaviside integration MSE and minimum distance with their relative
differences. Each figure stands next to its noise floor: the same figure between two
independent batches of reference sets (batch A is the one compared with the model).
Structure checks: empty elementary intervals (sobol_owen), 1-d stratified projections
(ldbn), the share of sets that are the reference's lattice (rank1, lattice). Non-uniform
models are measured after the exact Rosenblatt map of their density to the uniform square,
plus a density check (chi-square of an 8 x 8 histogram of the unwarped points; its expected
value is 63 for a set that follows the density) and the mean density over the sets in those
cells against the reference's (a bias every set shares, which the per-set chi-square hides).

Reference sets and their statistics are cached under ~/.cache/diffsampler/reference (they
are deterministic in their seeds); generated sets are made in the run. Each model's results
are kept in benchmarks/results/fidelity/<model>.json together with the hash of the model file
and the run's settings, so models can be measured one at a time (e.g. as they finish
training) and the report always covers every network in models/: a model whose file changed since
its measurement is listed as not measured. A runtime change can move a file's sets too:
--check-kept regenerates the first sets of every kept row and notes in the report the rows
the current runtime no longer reproduces. Writes benchmarks/results/fidelity.md,
fidelity.json and fidelity/<model>.png.

    python benchmarks/fidelity.py [--models gbn sot] [--sets 128] [--workers 2]
    python benchmarks/fidelity.py --report-only   # rebuild the report from kept results
    python benchmarks/fidelity.py --check-kept    # which kept rows the runtime still makes
    python benchmarks/fidelity.py --models sot_fast --stored-reference   # the kept references
    python benchmarks/fidelity.py --models sot_ramp_fast --stored-reference sot_ramp  # teacher's
"""
from __future__ import annotations

import argparse
import datetime as dt
import json
import os
import sys
import time
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
from trainer import zoo  # noqa: E402
zoo.use()  # model names are the repository's networks (models/), not the wheel's copies

import diffsampler_rt  # noqa: E402
from diffsampler_rt.card import describe_devices  # noqa: E402
from diffsampler_rt.finish.pipeline import describe as describe_pipeline  # noqa: E402
from benchmarks.common import (SEED_COLUMNS, cache_dir, cached_sets,  # noqa: E402
                               example_reference, model_hash, reference_path, seed_curve)
from diffsampler_rt.lattice import fit_rank1_lattice  # noqa: E402
from trainer.samplers import SLOW  # noqa: E402
from trainer.samplers.lattice import maxmin_generator, p2_generator  # noqa: E402
from trainer.density import OLD_FLOOR  # noqa: E402
from trainer.samplers.densities import UNWARP  # noqa: E402
from trainer.stats import (Gaussians, Heavisides, empty_elementary_fraction,  # noqa: E402
                           integration_mse, l2_star, min_distance, ot_energy, radial_spectrum,
                           spectrum_mae, stratified_projections)

SIZES = (64, 256, 576, 1024, 4096)
#: the sizes whose spectra a model's plot shows; its example sets come from the first measured
PLOT_SIZES = (1024, 4096)
#: the zoo's target: at most half of the seed paper's own net's spectrum MAE at n = 1024
TARGET_MAE = {"poisson_disk": 0.055, "gbn": 0.032, "sot": 0.007, "sot_32": 0.007,
              "ldbn": 0.006, "sobol_owen": 0.004, "rank1": 0.17, "lattice": 0.17}


def target_mae(name: str) -> float | None:
    """The spectrum target of a network: its own, or for a distilled student
    (``<base>_fast``) its base model's (the students are held to the zoo's targets)."""
    return TARGET_MAE.get(name, TARGET_MAE.get(name.removesuffix("_fast")))


#: the lattice samplers' generator choice per size
GENERATORS = {"rank1": maxmin_generator, "lattice": p2_generator}
#: per-set statistics whose means must agree within TOL_MEAN (min distance: TOL_MIND)
STATS = ("ot_energy", "l2_star", "gauss_mse", "heaviside_mse", "min_distance")
TOL_MEAN, TOL_MIND = 0.05, 0.10
INTEGRANDS = 512  # per family; fixed seeds so every set sees the same integrands

_GAUSS = Gaussians.random(INTEGRANDS, seed=11)
_HEAVI = Heavisides.random(INTEGRANDS, seed=12)
_EXACT: dict = {}


def integration_errors(pts: np.ndarray) -> dict[str, np.ndarray]:
    """Per-set Gaussian and Heaviside MSE of (S, n, 2) sets on the report's fixed integrands."""
    if not _EXACT:  # computed once per process
        _EXACT["g"], _EXACT["h"] = _GAUSS.integrals(), _HEAVI.integrals()
    return {"gauss_mse": integration_mse(pts, _GAUSS, _EXACT["g"]),
            "heaviside_mse": integration_mse(pts, _HEAVI, _EXACT["h"])}


def _stats_chunk(pts: np.ndarray) -> dict[str, np.ndarray]:
    return {"ot_energy": ot_energy(pts), "l2_star": l2_star(pts), **integration_errors(pts),
            "min_distance": min_distance(pts)}


def set_stats(pool, pts: np.ndarray) -> dict[str, np.ndarray]:
    """Per-set statistics of (S, n, 2) sets, computed in chunks on the executor."""
    step = max(1, len(pts) // 8)
    parts = list(pool.map(_stats_chunk, [pts[i:i + step] for i in range(0, len(pts), step)]))
    return {k: np.concatenate([p[k] for p in parts]) for k in STATS}


def cached_stats(pool, key: str, pts: np.ndarray) -> dict[str, np.ndarray]:
    path = cache_dir() / "reference" / f"{key}_stats_v1.npz"
    if path.exists():
        z = np.load(path)
        if all(k in z for k in STATS) and len(z[STATS[0]]) == len(pts):
            return {k: z[k] for k in STATS}
    out = set_stats(pool, pts)
    np.savez(path, **out)
    return out


def jittered(n: int, count: int) -> np.ndarray:
    """Jittered (one uniform point per grid cell) sets: the baseline for net structure."""
    k = int(round(np.sqrt(n)))
    cells = np.stack(np.meshgrid(np.arange(k), np.arange(k)), -1).reshape(-1, 2)
    return (cells[None] + np.random.default_rng(n).random((count, n, 2))) / k


def _histograms(unwarped: np.ndarray, bins: int) -> np.ndarray:
    """Per set: the counts of its points in the bins x bins cells of the square,
    shape (sets, bins^2)."""
    idx = np.minimum((unwarped * bins).astype(int), bins - 1)
    cells = (idx[..., 1] * bins + idx[..., 0]).reshape(-1, unwarped.shape[-2])
    # one bincount for all sets: set s counts into its own block of bins^2 cells
    at = cells + bins * bins * np.arange(len(cells))[:, None]
    return np.bincount(at.ravel(), minlength=len(cells) * bins * bins).reshape(len(cells), -1)


def mean_density(unwarped: np.ndarray, bins: int = 8) -> np.ndarray:
    """The sets' mean count in each of the bins x bins cells of the unwarped square over the
    expected count: 1 everywhere for sets that follow the density on average. Where a
    per-set chi-square (:func:`chi2_density`) mixes each set's spread with a bias that every
    set shares, this shows the bias alone (what a sum over many sets inherits)."""
    return _histograms(unwarped, bins).mean(0) / (unwarped.shape[-2] / bins**2)


def density_bias(gen: np.ndarray, ref_a: np.ndarray, ref_b: np.ndarray) -> dict:
    """The rms differences of :func:`mean_density` of unwarped generated sets and of
    reference batch A ("diff"; its floor: batch B against A), and of each against the
    density itself ("gen", "ref"); A's cells are kept ("ref_cells") to measure against."""
    g, a, b = (mean_density(p) for p in (gen, ref_a, ref_b))
    return {"diff": _rms(g, a), "floor": _rms(b, a), "gen": _rms(g, 1.0), "ref": _rms(a, 1.0),
            "ref_cells": a.tolist()}


def _rms(u: np.ndarray, v: np.ndarray | float) -> float:
    return float(np.sqrt(np.mean((u - v) ** 2)))


def chi2_density(unwarped: np.ndarray, bins: int = 8) -> np.ndarray:
    """Per set: chi-square of the bins x bins histogram of unwarped points vs uniform."""
    counts = _histograms(unwarped, bins)
    e = unwarped.shape[-2] / bins**2
    return ((counts - e) ** 2 / e).sum(-1)


def ref_count(sampler: str, n: int, sets: int, slow_sets: int, slow_4096: int) -> int:
    """Reference sets per batch (two batches are drawn: A to compare, B for the floor)."""
    if sampler not in SLOW:
        return sets
    if n >= 4096:
        return slow_4096
    return sets if n == 1024 else slow_sets


def spectrum_count(sampler: str, n: int, count: int, a) -> int:
    """Sets per side for the spectrum: more at n = 1024 for fast samplers with tight targets
    (sobol_owen, ldbn: 0.004, 0.006), so that the noise floor sits well below them."""
    tight = TARGET_MAE.get(sampler, 1.0) < 0.02
    return max(count, a.spectrum_sets) if n == 1024 and tight and sampler not in SLOW else count


def parse_ref_pool(spec: str) -> tuple[str, int, int, tuple[int, ...]]:
    """``SAMPLER:N:COUNT:SEEDS`` (SEEDS ``a-b`` or ``a,b,...``) -> (sampler, n, count, seeds):
    cached reference files of ``count`` sets each, one per seed, added to a size's pool."""
    try:
        sampler, n, count, seeds = spec.split(":")
        if "-" in seeds:
            lo, hi = (int(x) for x in seeds.split("-"))
            seed_list = tuple(range(lo, hi + 1))
        else:
            seed_list = tuple(int(x) for x in seeds.split(","))
        n, count = int(n), int(count)
    except ValueError:
        raise argparse.ArgumentTypeError(
            f"--ref-pool {spec!r}: expected SAMPLER:N:COUNT:SEEDS, e.g. sot:1024:32:2-29") from None
    if n < 1 or count < 1 or not seed_list or min(seed_list) < 2:
        raise argparse.ArgumentTypeError(
            f"--ref-pool {spec!r}: n and count must be positive and seeds at least 2 "
            "(seed 1 is the report's own reference file)")
    return sampler, n, count, seed_list


def add_pool_options(p: argparse.ArgumentParser) -> None:
    """``--ref-pool`` and ``--pool-only`` (fidelity.py and any_n.py)."""
    p.add_argument("--ref-pool", type=parse_ref_pool, action="append", metavar="SAMPLER:N:COUNT:SEEDS",
                   help="pool cached reference files of COUNT sets from these seeds (a-b or "
                        "a,b,...) with the seed-1 draw at that size; A and B are its halves "
                        "(repeatable; files missing from the cache are drawn)")
    p.add_argument("--pool-only", action="store_true",
                   help="with --ref-pool: the pooled files alone, without the seed-1 draw "
                        "(when those sets were used to choose a card's settings)")


def check_pool_options(p: argparse.ArgumentParser, a) -> None:
    """Refuse ``--pool-only`` without ``--ref-pool`` (one line, exit 2)."""
    if a.pool_only and not a.ref_pool:
        p.error("--pool-only: no --ref-pool files to measure against")


def pool_text(st: dict) -> str:
    """The pool options of kept settings, as typed (empty without)."""
    return ("".join(f" --ref-pool {q}" for q in st.get("ref_pool", []))
            + (" --pool-only" if st.get("pool_only") else ""))


def settings_pools(a, sampler: str) -> dict:
    """``{"ref_pool": [...], "pool_only": True}`` for this sampler's pools, or {}."""
    # only this sampler's pools: another model's run need not repeat them
    pools = [f"{sampler}:{n}:{c}:{_seeds_text(seeds)}"
             for (s, n), files in ref_pools(a).items() if s == sampler for c, seeds in files]
    if not pools:
        return {}
    return {"ref_pool": pools, **({"pool_only": True} if getattr(a, "pool_only", False) else {})}


def ref_pools(a) -> dict[tuple[str, int], list[tuple[int, tuple[int, ...]]]]:
    """The extra reference files of ``--ref-pool``, by (sampler, n)."""
    out: dict[tuple[str, int], list] = {}
    # solver_sweep.py passes its own namespace of reference sizes, without --ref-pool
    for sampler, n, count, seeds in getattr(a, "ref_pool", None) or []:
        out.setdefault((sampler, n), []).append((count, seeds))
    return out


def _seeds_text(seeds: tuple[int, ...]) -> str:
    contiguous = seeds == tuple(range(seeds[0], seeds[0] + len(seeds)))
    return f"{seeds[0]}-{seeds[-1]}" if contiguous and len(seeds) > 1 else ",".join(map(str, seeds))


def reference(pool, sampler: str, n: int, a):
    """Reference batches A and B (one cached draw, seed 1) and the per-set statistics of
    their first ``count`` sets (after unwarping for non-uniform samplers), cached.

    With ``--ref-pool`` files for this sampler and size, the seed-1 draw and those files are
    pooled and split in halves: A and B are then each half of the pool, all of it used for
    the spectrum and the statistics; with ``--pool-only`` the pool is those files alone
    (e.g. when the seed-1 sets were used to choose a card's settings). The time per
    reference set stays the seed-1 draw's (pooled files may have been drawn on another
    machine, or beside other jobs); with ``--pool-only`` and no seed-1 draw cached, the
    pooled files' own (not drawn just for a time: slow samplers take hours).

    Returns (count, spectrum count, A, B, seconds per reference set, stats A, stats B).
    """
    count = ref_count(sampler, n, a.sets, a.slow_sets, a.slow_4096)
    scount = spectrum_count(sampler, n, count, a)
    extra = ref_pools(a).get((sampler, n), [])
    only = bool(extra) and getattr(a, "pool_only", False)
    key = f"{sampler}_n{n}_c{2 * scount}_s1"
    if only and not reference_path(sampler, n, 2 * scount, 1).exists():
        ref = per_set = None  # not drawn just for its time: the pooled files' times stand in
    else:
        ref, per_set, _ = cached_sets(pool, sampler, n, 2 * scount, 1)
    if extra:
        files = [cached_sets(pool, sampler, n, c, s) for c, seeds in extra for s in seeds]
        pooled = [pts for pts, _, _ in files]
        if per_set is None:  # the pool's mean time per set
            per_set = sum(len(pts) * t for pts, t, _ in files) / sum(map(len, pooled))
        ref = np.concatenate(pooled if only else [ref] + pooled)
        count = scount = len(ref) // 2
        ref = ref[:2 * count]
        key = (f"{sampler}_n{n}_pool" if only else key) + "".join(
            f"+c{c}_s{_seeds_text(seeds)}" for c, seeds in extra)
    ref_a, ref_b = ref[:scount], ref[scount:]
    unwarp = UNWARP.get(sampler) or (lambda p: p)
    both = np.concatenate([ref_a[:count], ref_b[:count]])
    st = cached_stats(pool, f"{key}_first{count}" + ("_unwarped" if sampler in UNWARP else ""),
                      unwarp(both))
    return (count, scount, ref_a, ref_b, per_set, {k: v[:count] for k, v in st.items()},
            {k: v[count:] for k, v in st.items()})


def stored_reference(out: Path, name: str, sizes: list[int], sampler: str,
                     source: str | None = None) -> dict[int, dict]:
    """The kept rows of ``source`` (default ``name``) at ``sizes``, whose reference side
    (``--stored-reference [MODEL]``) stands in for batches A and B: their mean spectrum, the
    per-set statistics of A, every floor, the counts and the time per reference set. Each
    records under ``"reference"`` the run it is from (and the model, when another one's).
    ``source`` must model the same ``sampler`` (e.g. a distilled student's teacher). Read
    once, and every size checked before any set is made."""
    source = source or name
    path = out / "fidelity" / f"{source}.json"
    old = json.loads(path.read_text()) if path.exists() else {"rows": {}}
    if old["rows"] and old["sampler"] != sampler:
        raise SystemExit(f"error: {source} models {old['sampler']!r}, not {name}'s sampler "
                         f"{sampler!r}; its reference figures do not apply")
    rows = {}
    for n in sizes:
        row = old["rows"].get(str(n))
        if row is None:
            raise SystemExit(f"error: {source} has no kept row at n = {n} to take the "
                             "reference figures from; measure it without --stored-reference")
        row["spec_ref"] = np.asarray(row["spec_ref"])
        # the run that drew the references: a row may itself be kept (--merge) or stored
        ran = (row.get("reference") or row.get("measured")
               or {"date": old["date"], "settings": old["settings"]})
        row["reference"] = {k: ran[k] for k in ("date", "settings")}
        if "model" in ran or source != name:
            row["reference"]["model"] = ran.get("model", source)
        rows[n] = row
    return rows


def evaluate(pool, name: str, a) -> dict:
    model = diffsampler_rt.load(name)
    card = model.card
    sampler = card["sampler"]
    unwarp = UNWARP.get(sampler)
    res = {"name": name, "sampler": sampler, "card": card, "rows": {},
           "model_sha256": model_hash(name), "settings": settings(a, sampler),
           "date": dt.date.today().isoformat()}
    # solver_sweep passes its own namespace, without the option
    source = getattr(a, "stored_reference", None)
    stored = (stored_reference(a.out, name, a.sizes, sampler,
                               None if source is True else source) if source else None)
    # one reference set for the plot's examples (cached where it can): at the size the plot
    # prefers
    example_n = next((n for n in PLOT_SIZES if n in a.sizes), a.sizes[0] if a.sizes else None)
    for n in a.sizes:
        if stored:
            res["rows"][n] = against_stored(pool, model, n, a, stored[n],
                                            example=n == example_n)
            _print_row(name, n, res["rows"][n])
            continue
        count, scount, ref_a, ref_b, ref_per_set, stats_a, stats_b = reference(pool, sampler, n, a)
        gen, gu, gstats, sg, gen_per_set = generated(pool, model, n, count, scount, a)
        ru_a, ru_b = (unwarp(ref_a), unwarp(ref_b)) if unwarp else (ref_a, ref_b)
        sa, sb = (radial_spectrum(p)[1] for p in (ru_a, ru_b))
        ref_a = ref_a[:count]
        row = {"count": count, "spectrum_count": scount, "gen_count": len(gen),
               "gen_ms": 1000 * gen_per_set, "ref_ms": 1000 * ref_per_set,
               "mae": spectrum_mae(sg, sa), "floor": spectrum_mae(sb, sa),
               "spec_gen": sg, "spec_ref": sa, "example_gen": gen[0], "example_ref": ref_a[0]}
        for k in STATS:
            ma, mb = stats_a[k].mean(), stats_b[k].mean()
            row[k] = _statistic(gstats[k], float(ma), float(mb / ma - 1), _per_set(stats_a[k]))
        if n == 1024 and seed_curve(sampler) is not None:
            row["mae_seed_gen"] = spectrum_mae(sg, seed_curve(sampler))
            row["mae_seed_ref"] = spectrum_mae(sa, seed_curve(sampler))
        if sampler == "sobol_owen" and n & (n - 1) == 0:
            row["empty"] = (float(empty_elementary_fraction(gen).mean()),
                            float(empty_elementary_fraction(ref_a).mean()),
                            float(empty_elementary_fraction(jittered(n, count)).mean()))
        if sampler == "ldbn":
            row["strat"] = (float(stratified_projections(gen).mean()),
                            float(stratified_projections(ref_a).mean()))
        if sampler in GENERATORS:  # is it the reference's lattice (generator)?
            g = GENERATORS[sampler](n)
            row["lattice"] = (float(np.mean(fit_rank1_lattice(gen)[0] == g)),
                              float(np.mean(fit_rank1_lattice(ref_a)[0] == g)))
        if unwarp:
            row["chi2"] = (float(chi2_density(gu).mean()), float(chi2_density(ru_a).mean()))
            row["mean_density"] = density_bias(gu, ru_a[:count], ru_b[:count])
        res["rows"][n] = row
        _print_row(name, n, row)
    return res


def generated(pool, model, n: int, count: int, scount: int, a):
    """The generated side of a row: (sets whose statistics are kept, all sets unwarped,
    their per-set statistics, the mean spectrum of all, seconds per set). Generation is
    cheap: more generated than reference sets (--gen-sets) cuts the generated side's noise,
    the floor (B vs A) stays the reference's."""
    unwarp = UNWARP.get(model.card["sampler"])
    gcount = max(scount, a.gen_sets)
    t = time.perf_counter()
    gen = model.generate(n, gcount, seed=a.seed)  # set i does not depend on the count
    gen_per_set = (time.perf_counter() - t) / gcount
    gu = unwarp(gen) if unwarp else gen
    kept = max(count, a.gen_sets)  # generated sets whose per-set statistics are kept
    return gen[:kept], gu, set_stats(pool, gu[:kept]), radial_spectrum(gu)[1], gen_per_set


def _per_set(values: np.ndarray) -> list[float]:
    """Per-set values to 6 significant digits, as kept: for the violins and the intervals."""
    return [float(f"{v:.6g}") for v in values]


def _statistic(gen: np.ndarray, ref: float, floor: float, ref_sets: list[float]) -> dict:
    """One statistic of a row: the generated sets' per-set values against the reference mean
    ``ref`` of batch A (its per-set values ``ref_sets``) and the floor (B vs A)."""
    return {"gen": float(gen.mean()), "ref": ref, "rel": float(gen.mean() / ref - 1),
            "floor": floor, "gen_sets": _per_set(gen), "ref_sets": ref_sets}


def _print_row(name: str, n: int, row: dict) -> None:
    print(f"{name} n={n}: MAE {row['mae']:.4f} (floor {row['floor']:.4f}); "
          + ", ".join(f"{k} {100 * row[k]['rel']:+.1f}%" for k in STATS), flush=True)


def against_stored(pool, model, n: int, a, kept: dict, example: bool) -> dict:
    """A row of ``model`` at n measured now against the reference side of the kept row
    ``kept`` (:func:`stored_reference`): the same counts, the generated sets made now.
    ``example``: one reference set for the plot (the kept row has none; a cached one)."""
    sampler = model.card["sampler"]
    count, scount = kept["count"], kept["spectrum_count"]
    gen, gu, gstats, sg, gen_per_set = generated(pool, model, n, count, scount, a)
    row = {"count": count, "spectrum_count": scount, "gen_count": len(gen),
           "gen_ms": 1000 * gen_per_set, "ref_ms": kept["ref_ms"],
           "mae": spectrum_mae(sg, kept["spec_ref"]), "floor": kept["floor"],
           "spec_gen": sg, "spec_ref": kept["spec_ref"], "reference": kept["reference"]}
    if example:
        row["example_gen"] = gen[0]
        row["example_ref"] = example_reference(sampler, n, a.seed)
    for k in STATS:
        row[k] = _statistic(gstats[k], kept[k]["ref"], kept[k]["floor"], kept[k]["ref_sets"])
    if "mae_seed_ref" in kept:
        row["mae_seed_gen"] = spectrum_mae(sg, seed_curve(sampler))
        row["mae_seed_ref"] = kept["mae_seed_ref"]
    # structure and density checks: the generated side now, the reference side as kept
    if "empty" in kept:
        row["empty"] = (float(empty_elementary_fraction(gen).mean()), *kept["empty"][1:])
    if "strat" in kept:
        row["strat"] = (float(stratified_projections(gen).mean()), kept["strat"][1])
    if "lattice" in kept:
        g = GENERATORS[sampler](n)
        row["lattice"] = (float(np.mean(fit_rank1_lattice(gen)[0] == g)), kept["lattice"][1])
    if "chi2" in kept:
        row["chi2"] = (float(chi2_density(gu).mean()), kept["chi2"][1])
    if "mean_density" in kept:
        g, a = mean_density(gu), np.asarray(kept["mean_density"]["ref_cells"])
        row["mean_density"] = {**kept["mean_density"], "diff": _rms(g, a), "gen": _rms(g, 1.0)}
    return row


#: relative agreement of the kept per-set minimum distances that counts as the same sets
REPRODUCE_RTOL = 1e-4


def reproduced(model, row: dict, n: int, seed: int, unwarp, sets: int = 4) -> bool:
    """Whether ``model`` makes the sets a kept ``row`` was measured on: the first ``sets``
    generated sets' minimum distances (kept per set to 6 digits) agree to REPRODUCE_RTOL.

    An equivalent graph (e.g. windowed attention wider than the grid) sums in another order:
    coordinates move by ~1e-7, which iterative finishing (sliced-OT, spacing) can grow to
    ~2e-5 in a minimum distance; an independent set differs by several per cent."""
    kept = np.asarray(row["min_distance"]["gen_sets"][:sets])
    gen = model.generate(n, len(kept), seed=seed)
    return bool(np.allclose(min_distance(unwarp(gen) if unwarp else gen), kept,
                            rtol=REPRODUCE_RTOL, atol=0))


def stop_if_stale(name: str, sizes: list[int], out: Path, seed: int) -> None:
    """SystemExit if a kept row of model ``name`` at a size not in ``sizes`` is not reproduced
    by the current file (run before any model is measured, so a long run does not stop
    half-way)."""
    path = out / "fidelity" / f"{name}.json"
    if not path.exists():
        return
    old = json.loads(path.read_text())
    model, unwarp = diffsampler_rt.load(name), UNWARP.get(old["sampler"])
    stale = [n for n, row in ((int(n), row) for n, row in old["rows"].items())
             if n not in sizes and (old.get("settings", {}).get("seed") != seed
                                    or not reproduced(model, row, n, seed, unwarp))]
    if stale:
        raise SystemExit(f"{name}: the kept rows at n = {' '.join(map(str, stale))} are not "
                         "reproduced by the current model file; measure those sizes again")


def check_kept(name: str, out: Path) -> list[int]:
    """Check every kept row of model ``name`` (when its file is the current one) against
    the current runtime: each row gets ``"reproduced": {"date", "ok"}``; returns the sizes
    not reproduced. A runtime change, not only a new file, can move the generated sets
    (e.g. a finishing step's numerics); the report then says which rows predate it."""
    path = out / "fidelity" / f"{name}.json"
    if not path.exists():
        return []
    kept = json.loads(path.read_text())
    if kept.get("model_sha256") != model_hash(name):
        return []  # the report lists it as not measured anyway
    model, unwarp = diffsampler_rt.load(name), UNWARP.get(kept["sampler"])
    today, seed, bad = dt.date.today().isoformat(), kept["settings"]["seed"], []
    for n, row in kept["rows"].items():
        ok = reproduced(model, row, int(n), seed, unwarp)
        row["reproduced"] = {"date": today, "ok": ok}
        if not ok:
            bad.append(int(n))
    path.write_text(json.dumps(kept, indent=1))
    return bad


def merge_kept(r: dict, out: Path, seed: int) -> dict:
    """``r`` with the rows of the kept result for this model at the sizes not measured now,
    which :func:`stop_if_stale` checked before the run (the file does not change in it).
    A row taken over records the file and run it came from under ``"measured"``."""
    path = out / "fidelity" / f"{r['name']}.json"
    if not path.exists():
        if not r["rows"]:
            raise SystemExit(f"{r['name']}: no kept result to keep; measure it with --sizes N")
        return r
    old = json.loads(path.read_text())
    rows = {}
    for n, row in ((int(n), row) for n, row in old["rows"].items()):
        if n in r["rows"]:
            continue
        row.setdefault("measured", {"date": old["date"], "settings": old["settings"],
                                    "model_sha256": old["model_sha256"]})
        row.pop("reproduced", None)  # stop_if_stale has just checked it again
        rows[n] = row
    # the kept rows have no example sets; the measured ones have. Unless a size the plot
    # shows is measured now, they are made anew for the plot at the first kept size it shows
    # (e.g. after a re-measure at 64 only), or at the smallest size when nothing is measured
    # now (``--sizes`` with no size: the file changed where no square size's sets do, e.g. a
    # card's restore cut); the reference one comes from the cache where it can
    shown = [n for n in PLOT_SIZES if n in rows]
    n = shown[0] if shown else (min(rows) if rows and not r["rows"] else None)
    if n is not None and not any(m in r["rows"] for m in PLOT_SIZES):
        model = diffsampler_rt.load(r["name"])
        rows[n] = {**rows[n], "example_gen": model.generate(n, 1, seed=seed)[0],
                   "example_ref": example_reference(r["sampler"], n, seed)}
    rows.update(r["rows"])
    return {**r, "rows": dict(sorted(rows.items()))}


def settings(a, sampler: str) -> dict:
    """The run's options as kept with a result of a model of ``sampler``."""
    out = {"sets": a.sets, "slow_sets": a.slow_sets, "slow_4096": a.slow_4096,
           "spectrum_sets": a.spectrum_sets, "gen_sets": a.gen_sets, "seed": a.seed}
    source = getattr(a, "stored_reference", None)
    if source:
        out["stored_reference"] = source  # True: the model's own kept run
    return {**out, **settings_pools(a, sampler)}


def _jsonable(v):
    if isinstance(v, np.ndarray):
        return v.tolist()
    if isinstance(v, (np.floating, np.integer)):
        return v.item()
    if isinstance(v, dict):
        return {str(k): _jsonable(x) for k, x in v.items()}
    if isinstance(v, (list, tuple)):
        return [_jsonable(x) for x in v]
    return v


def save_result(r: dict, out: Path) -> None:
    """Keep one model's result (its plot is drawn now: the example sets are not kept)."""
    plot(r, out / "fidelity" / f"{r['name']}.png")
    rows = {n: {k: v for k, v in row.items() if not k.startswith("example_")}
            for n, row in r["rows"].items()}
    (out / "fidelity").mkdir(parents=True, exist_ok=True)
    (out / "fidelity" / f"{r['name']}.json").write_text(
        json.dumps(_jsonable({**r, "rows": rows}), indent=1))


def kept_results(out: Path, models: list[str]) -> tuple[list[dict], list[str]]:
    """Kept results of ``models`` whose model file is unchanged, and the names without one."""
    found, missing = [], []
    for m in models:
        path = out / "fidelity" / f"{m}.json"
        r = json.loads(path.read_text()) if path.exists() else None
        if r is None or r.get("model_sha256") != model_hash(m):
            missing.append(m)
            continue
        r["rows"] = {int(n): row for n, row in r["rows"].items()}
        for row in r["rows"].values():
            for k in ("spec_gen", "spec_ref"):
                row[k] = np.asarray(row[k])
        found.append(r)
    return found, missing


def _gen(row: dict) -> str:
    """", gen 256" where more sets were generated than drawn from the reference."""
    g = row.get("gen_count", row["count"])
    return f", gen {g}" if g > max(row["count"], row["spectrum_count"]) else ""


def two_se(d: dict) -> float | None:
    """Two standard errors of a statistic's relative difference (generated / reference - 1),
    from the per-set values kept on both sides (delta method); None without them."""
    g, a = (np.asarray(d.get(k, []), dtype=np.float64) for k in ("gen_sets", "ref_sets"))
    if len(g) < 2 or len(a) < 2 or g.mean() == 0 or a.mean() == 0:
        return None
    var = g.var(ddof=1) / (len(g) * g.mean() ** 2) + a.var(ddof=1) / (len(a) * a.mean() ** 2)
    return float(2 * (1 + d["rel"]) * np.sqrt(var))


def miss_mark(d: dict, tol: float) -> str:
    """"" within the tolerance, " ✗" a miss beyond its noise (the tolerance is outside the
    difference's two-standard-error interval), " ✗?" a miss that noise could explain."""
    return _mark(d["rel"], two_se(d), tol)


def _mark(rel: float, pm: float | None, tol: float) -> str:
    if abs(rel) <= tol:
        return ""
    return " ✗" if pm is None or abs(rel) - pm > tol else " ✗?"


def tolerance(stat: str) -> float:
    """The issue's tolerance on a statistic's relative difference."""
    return TOL_MIND if stat == "min_distance" else TOL_MEAN


def tally(results: list[dict]) -> dict[str, dict[str, int]]:
    """Per model, its figures in STATS over all sizes counted by mark: "within" the
    tolerance, "noise" (✗?, a miss noise could explain), "beyond" (✗)."""
    names = {"": "within", " ✗?": "noise", " ✗": "beyond"}
    out = {}
    for r in results:
        count = dict.fromkeys(names.values(), 0)
        for row in r["rows"].values():
            for k in STATS:
                count[names[miss_mark(row[k], tolerance(k))]] += 1
        out[r["name"]] = count
    return out


def _tally_lines(results: list[dict]) -> list[str]:
    counts = tally(results)
    total = {k: sum(c[k] for c in counts.values()) for k in ("within", "noise", "beyond")}
    lines = ["## Misses counted", "",
             "The mean-statistic figures above (OT energy, L2*, Gaussian and Heaviside MSE, "
             "minimum distance; every size), counted by their mark.", "",
             "| model | figures | within tolerance | ✗? (within noise) | ✗ (beyond noise) |",
             "|---|---|---|---|---|"]
    for name, c in [*counts.items(), ("**all**", total)]:
        lines.append(f"| {name} | {sum(c.values())} | {c['within']} | {c['noise']} | "
                     f"{c['beyond']} |")
    return lines


def _fmt_rel(d: dict, tol: float) -> str:
    pm = two_se(d)
    spread = "" if pm is None else f" ±{100 * pm:.1f}"
    return f"{100 * d['rel']:+.1f}{spread} %{_mark(d['rel'], pm, tol)} ({100 * d['floor']:+.1f})"


def _train_time(secs: float, card: dict, cfg: dict) -> str:
    """", 44 min with 1 CPU thread(s)" or ", 9 min on GPU" (cards before train_devices: CPU)."""
    devices = card.get("train_devices", ["cpu"])
    if devices != ["cpu"]:
        return f", {secs / 60:.0f} min on {describe_devices(devices)}"
    return f", {secs / 60:.0f} min with {cfg.get('threads', 1)} CPU thread(s)"


def model_card_text(c: dict) -> str:
    """The model card in a sentence or three: data, architecture, training, sampling."""
    cfg = c.get("config", {})
    d, u = cfg.get("data", {}), cfg.get("unet", {})
    pools = d.get("pool_sizes") or []
    if any(pools):
        data = ", ".join(f"{p} sets at k = {k}" for k, p in zip(d.get("sizes", []), pools))
        if d.get("shifts", 1) > 1:
            data += f", each also under {d['shifts'] - 1} random toroidal shifts"
        if d.get("mirror_diagonal"):
            data += ", each also mirrored in the diagonal (x <-> y)"
    else:
        data = "fresh sets every step"
    sym = d.get("symmetries", [0])
    data += f"; symmetries of the square used: {sym}" if len(sym) > 1 else "; no symmetries"
    if d.get("density_bins"):
        b = d["density_bins"]
        fit = {"legendre": f"as a Legendre series (tabulated {b} x {b})",
               "log_legendre": f"as the exp of a Legendre series (tabulated {b} x {b})"}.get(
                   d.get("density_fit", "histogram"), f"on a {b} x {b} histogram")
        floor = c.get("density_floor", OLD_FLOOR)
        data += (f"; learned after the Rosenblatt map of the density fitted to these sets "
                 f"{fit}, mapped back at generation with a table floor of {floor:g} "
                 "(diffsampler_rt.density)")
    params = c.get("parameters")
    arch = (f"U-Net base {u.get('base_channels')}, levels {u.get('channel_mult')}, attention at "
            f"{u.get('attention_levels')}" + (f", axial attention at {u['axial_levels']}"
                                              if u.get("axial_levels") else "")
            + (f", {u['coord_bits']} dyadic coordinate bits" if u.get("coord_bits") else "")
            + (f", {params / 1e6:.2f} M parameters" if params else ""))
    secs = c.get("train_seconds")
    train = (f"{c['training_steps']} steps (batches {d.get('batch_sizes')} at k = "
             f"{d.get('sizes')})" + (_train_time(secs, c, cfg) if secs else "")
             + (", bf16 autocast" if cfg.get("bf16") else "")
             + (f", from the weights of `{cfg['init_from']}`" if cfg.get("init_from") else ""))
    return (f"sampler `{c['sampler']}`, embedding `{c['embedding']}`. Data: {data}. "
            f"Net: {arch}. Training: {train}, seed {cfg.get('seed')}. "
            + (f"Distillation: {c['provenance']}. " if c.get("distillation") else "")
            + "Sampling: "
            f"{c.get('default_solver', 'ddim')}, {c['default_steps']} steps"
            + "; then the card's pipeline, in order: "
            + "; ".join(f"{i}. {line}" for i, line in enumerate(describe_pipeline(c["pipeline"])))
            + " (diffsampler_rt.finish).")


def _taken_over(r: dict) -> list[str]:
    """A note on rows kept from an earlier run (``--merge``), of this file or an earlier one."""
    old = {n: row["measured"] for n, row in r["rows"].items() if "measured" in row}
    if not old:
        return []
    by_run: dict[tuple, list[int]] = {}
    for n, m in old.items():
        by_run.setdefault((m["date"], m["model_sha256"]), []).append(n)
    new = [n for n in r["rows"] if n not in old]
    same = [f"n = {', '.join(map(str, ns))} in an earlier run on {d}"
            for (d, h), ns in sorted(by_run.items()) if h == r["model_sha256"]]
    other = [f"n = {', '.join(map(str, ns))} on {d} (sha256 {h[:12]}...)"
             for (d, h), ns in sorted(by_run.items()) if h != r["model_sha256"]]
    parts = [f"n = {', '.join(map(str, new))} on {r['date']} with the current file"] if new else []
    if same:
        parts.append("; ".join(same) + " with the same file")
    if other:
        # the clause first: after a list of several earlier files it would read as the last's
        files = len({h for _, h in by_run} - {r["model_sha256"]})
        parts.append(("earlier files" if files > 1 else "an earlier file") + " of this model"
                     + ", whose generated sets the current file reproduces (the first 4 sets' "
                     f"minimum distances agree to {REPRODUCE_RTOL:.0e}): ".replace("e-0", "e-")
                     + "; ".join(other))
    checked = "" if new else f"; every row checked on {r['date']}"  # every row kept
    return ["", "Measured: " + "; ".join(parts) + f" (`--merge`{checked})."]


def _stale_note(r: dict) -> list[str]:
    """A note on rows that the current runtime no longer reproduces (``--check-kept``)."""
    bad = {n: row["reproduced"]["date"] for n, row in r["rows"].items()
           if not row.get("reproduced", {}).get("ok", True)}
    if not bad:
        return []
    return ["", f"**Not reproduced by the current runtime** at n = {', '.join(map(str, bad))} "
            f"(checked on {', '.join(sorted(set(bad.values())))}): the runtime has changed "
            "since these rows were measured, and the model file's sets with it, so their "
            "figures are those of the earlier runtime's sets (rerun the model's rows)."]


def _stored_note(r: dict) -> list[str]:
    """A note on rows measured against stored reference figures (``--stored-reference``)."""
    by_run: dict[tuple[str, str], list[int]] = {}
    for n, row in r["rows"].items():
        if "reference" in row:
            ref = row["reference"]
            by_run.setdefault((ref.get("model", ""), ref["date"]), []).append(n)
    if not by_run:
        return []
    runs = "; ".join(f"n = {', '.join(map(str, ns))} from " + (m + "'s" if m else "the")
                     + f" run of {d}" for (m, d), ns in sorted(by_run.items()))
    return ["", f"Reference side stored (`--stored-reference`): {runs}. The generated sets "
            "were made and measured anew against that run's kept reference figures (mean "
            "spectrum, per-set statistics of batch A, floors, time per set); the example "
            "reference set in the plot is a cached reference set of its size, or a fresh draw "
            "where none is cached."]


def _stored_option(source: bool | str | None) -> str:
    """The ``--stored-reference`` option as a run kept it (True: the model's own run)."""
    if not source:
        return ""
    return " --stored-reference" + ("" if source is True else f" {source}")


def _row_runs(r: dict):
    """The runs that measured a result's rows: a row taken over from an earlier run names it
    under ``"measured"``, a stored reference side under ``"reference"``; a ``--merge`` run
    that measured no size (a check that the kept rows reproduce) is not one of them."""
    for row in r["rows"].values():
        yield row.get("measured", r)
        if "reference" in row:
            yield row["reference"]


def report(results: list[dict], missing: list[str], out: Path) -> None:
    runs = sorted({(run["date"], json.dumps(run["settings"], sort_keys=True))
                   for r in results for run in _row_runs(r)})
    how = "; ".join(
        f"`python benchmarks/fidelity.py --sets {st['sets']} --slow-sets {st['slow_sets']} "
        f"--slow-4096 {st['slow_4096']} --spectrum-sets {st['spectrum_sets']}"
        + (f" --gen-sets {st['gen_sets']}" if st.get("gen_sets") else "")
        + pool_text(st) + _stored_option(st.get("stored_reference")) + f"` on {d}"
        for d, st in ((d, json.loads(j)) for d, j in runs))
    lines = [
        "# Fidelity of the networks (models/) vs their reference samplers",
        "",
        f"{how} ({os.cpu_count()} cores). "
        "Generated sets (default solver and steps of each model card) and reference sets are "
        "compared in the same run; *sets* is the number per side. Reference batch A is "
        "compared with the model; batch B, drawn independently, gives the **noise floor**: "
        "the same figure between B and A, shown in brackets; with `--gen-sets G` at least G "
        "sets are generated (shown as *gen G*), which cuts the generated side's noise but "
        "not the floor. Slow reference samplers (the "
        "iterative optimisers) use fewer sets at sizes other than 1024; fast samplers with tight "
        "spectrum targets use more sets at n = 1024 for the spectrum (the per-set statistics use the first ones). "
        "With `--ref-pool SAMPLER:N:COUNT:SEEDS`, cached reference files of further seeds join "
        "that size's seed-1 draw and A and B are each half of the pool (the reference's "
        "time per set is still the seed-1 draw's, made on this machine); with `--pool-only` "
        "the pool is those files alone (where the seed-1 sets chose a card's settings; the "
        "time per set is then the pooled files' own where no seed-1 draw is cached). With "
        "`--stored-reference` (said in the model's section) the reference side of a row is "
        "the one kept from the model's earlier run, when the reference sets were not at hand "
        "for a re-measurement after a change of the model's card.",
        "",
        f"MAE = mean absolute difference of the mean radial power spectra over the seed's 79 "
        f"bins. Other columns: relative difference of the mean (generated / reference - 1) "
        f"± two standard errors (from the per-set values of both sides: about a 95 % "
        f"interval for the difference); a miss of the issue's tolerance (±{100 * TOL_MEAN:.0f} %, "
        f"min distance ±{100 * TOL_MIND:.0f} %) is marked ✗ where the interval lies wholly "
        f"beyond the tolerance and ✗? where it reaches into it (the miss may be noise: more "
        f"sets would tell). Gaussian / Heaviside MSE: equal-weight integration of "
        f"{INTEGRANDS} fixed random integrands each with exact integrals. Non-uniform models: "
        "all figures after the exact unwarping map to the uniform square; their density check "
        "gives the mean over sets of each set's chi-square on 8 x 8 cells (63 for sets that "
        "follow the density), and the mean density: the mean count in each cell over the "
        "expected count, its rms difference between the generated sets and reference batch A "
        "(floor: batch B against A) and between each side and the density itself (a bias "
        "every set shares, which a sum over many sets keeps).",
        "",
        "## Summary at n = 1024",
        "",
        "| model | sets | spectrum MAE | floor | target | met | vs seed curve (gen / ref) | "
        "seed's net's MAE | "
        "OT energy | L2* | Gauss MSE | Heaviside MSE | min dist |",
        "|---|---|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for r in results:
        row = r["rows"].get(1024)
        if row is None:
            continue
        tgt = target_mae(r["name"])
        met = "" if tgt is None else ("yes" if row["mae"] <= tgt else "**no**")
        seed = (f"{row['mae_seed_gen']:.4f} / {row['mae_seed_ref']:.4f}"
                if "mae_seed_gen" in row else "")
        # the targets are half the seed paper's own net's MAE: say where ours is worse (the
        # students and sot_32 too, against the seed's net of their sampler)
        theirs = 2 * TARGET_MAE[r["sampler"]] if r["sampler"] in SEED_COLUMNS else None
        seed_net = "" if theirs is None else f"{theirs:.3f}"
        if theirs is not None and row["mae"] > theirs:
            seed_net += " (**ours worse**)"
        sets = (f"{row['count']}" if row["spectrum_count"] == row["count"]
                else f"{row['count']} ({row['spectrum_count']} spectrum)") + _gen(row)
        lines.append(f"| {r['name']} | {sets} | {row['mae']:.4f} | {row['floor']:.4f} | "
                     f"{tgt if tgt is not None else ''} | {met} | {seed} | {seed_net} | "
                     + " | ".join(_fmt_rel(row[k], tolerance(k)) for k in STATS) + " |")
    lines += [""] + _tally_lines(results)
    if missing:
        lines += ["", "**Not measured yet** (in models/, but no result for the current model file): "
                  + ", ".join(missing) + "."]
    for r in results:
        c = r["card"]
        lines += ["", f"## {r['name']}", "", model_card_text(c), "",
                  "| n | sets | spectrum MAE (floor) | OT energy | L2* | Gauss MSE | "
                  "Heaviside MSE | min dist | extra | gen ms/set | ref ms/set |",
                  "|---|---|---|---|---|---|---|---|---|---|---|"]
        for n, row in r["rows"].items():
            extra = ""
            if "empty" in row:
                extra = (f"empty el. intervals {100 * row['empty'][0]:.1f} % (ref "
                         f"{100 * row['empty'][1]:.1f} %, jittered {100 * row['empty'][2]:.1f} %)")
            if "strat" in row:
                extra = (f"1-d stratified {100 * row['strat'][0]:.0f} % of sets "
                         f"(ref {100 * row['strat'][1]:.0f} %)")
            if "lattice" in row:
                extra = (f"reference's lattice in {100 * row['lattice'][0]:.0f} % of sets "
                         f"(ref {100 * row['lattice'][1]:.0f} %)")
            if "chi2" in row:
                extra = f"density chi2 {row['chi2'][0]:.0f} (ref {row['chi2'][1]:.0f}, ideal 63)"
            if "mean_density" in row:
                d = {k: 100 * v for k, v in row["mean_density"].items() if k != "ref_cells"}
                extra += (f"; mean density vs ref {d['diff']:.1f} % rms ({d['floor']:.1f}), "
                          f"vs the density {d['gen']:.1f} % (ref {d['ref']:.1f})")
            sets = (f"{row['count']} ({row['spectrum_count']} for the spectrum)"
                    if row["spectrum_count"] != row["count"] else str(row["count"])) + _gen(row)
            lines.append(f"| {n} | {sets} | {row['mae']:.4f} ({row['floor']:.4f}) | "
                         + " | ".join(_fmt_rel(row[k], tolerance(k)) for k in STATS)
                         + f" | {extra} | {row['gen_ms']:.0f} | {row['ref_ms']:.0f} |")
        lines += _taken_over(r) + _stale_note(r) + _stored_note(r)
        lines += ["", f"![{r['name']}](fidelity/{r['name']}.png)"]
    lines.append("")
    (out / "fidelity.md").write_text("\n".join(lines))
    summary = {r["name"]: {str(n): {k: ({**{kk: vv for kk, vv in v.items()
                                           if not kk.endswith("_sets")}, "two_se": two_se(v)}
                                        if k in STATS else v)
                                    for k, v in row.items()
                                    if not k.startswith(("spec_", "example_"))}
                           for n, row in r["rows"].items()} for r in results}
    (out / "fidelity.json").write_text(json.dumps(_jsonable(summary), indent=1))


def plot(r: dict, path: Path) -> None:
    try:
        import matplotlib
        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
    except ImportError:
        print("matplotlib not installed: no plot", file=sys.stderr)
        return
    path.parent.mkdir(parents=True, exist_ok=True)
    sizes = [n for n in PLOT_SIZES if n in r["rows"]]
    fig, axes = plt.subplots(1, 2 + len(sizes), figsize=(4.2 * (2 + len(sizes)), 4))
    x = np.arange(1, 80) * 0.0625
    for ax, n in zip(axes, sizes):
        row = r["rows"][n]
        ax.plot(x, row["spec_ref"], lw=1.5, label="reference")
        ax.plot(x, row["spec_gen"], lw=1.2, ls="--", label="learned")
        curve = seed_curve(r["sampler"]) if n == 1024 else None
        if curve is not None:
            ax.plot(x, curve, lw=0.8, color="k", alpha=0.5, label="seed paper")
        ax.set(title=f"{r['name']}: radial spectrum, n = {n}", xlabel="|f| / sqrt(n)")
        ax.legend(fontsize=8)
    row = next((r["rows"][n] for n in (*sizes, *r["rows"]) if "example_gen" in r["rows"][n]))
    for ax, key, title in ((axes[-2], "example_ref", "reference"), (axes[-1], "example_gen", "learned")):
        p = row[key]
        ax.scatter(p[:, 0], p[:, 1], s=1.5, c="k")
        ax.set(title=f"{title}, n = {len(p)}", xlim=(0, 1), ylim=(0, 1), aspect="equal",
               xticks=[], yticks=[])
    fig.tight_layout()
    fig.savefig(path, dpi=80)
    plt.close(fig)


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--models", nargs="*", help="default: every network in models/")
    p.add_argument("--sizes", type=int, nargs="*", default=list(SIZES))
    p.add_argument("--sets", type=int, default=128, help="sets per side (fast samplers; all at 1024)")
    p.add_argument("--slow-sets", type=int, default=64,
                   help="sets per side for slow samplers at sizes other than 1024 and 4096")
    p.add_argument("--slow-4096", type=int, default=16, help="sets per side, slow samplers, n=4096")
    p.add_argument("--spectrum-sets", type=int, default=1024,
                   help="sets per side for the spectrum at n = 1024 (fast samplers)")
    p.add_argument("--gen-sets", type=int, default=0,
                   help="generate at least this many sets per size (default: as many as the "
                        "reference side)")
    add_pool_options(p)
    p.add_argument("--workers", type=int, default=2)
    p.add_argument("--seed", type=int, default=1, help="seed of the generated sets")
    p.add_argument("--out", type=Path, default=ROOT / "benchmarks" / "results")
    p.add_argument("--merge", action="store_true",
                   help="keep the model's earlier rows at the sizes not given, where the "
                        "current file reproduces their sets (e.g. after a re-export that "
                        "only changes big grids; with --sizes and no size, every row: after "
                        "a card change that no square size's sets show)")
    p.add_argument("--stored-reference", nargs="?", const=True, default=None, metavar="MODEL",
                   help="measure the generated sets against the reference figures kept "
                        "from the model's last run (its fidelity/<model>.json), or from "
                        "MODEL's (same sampler, e.g. a new student's teacher), when the "
                        "reference sets are not at hand (e.g. after a card change)")
    p.add_argument("--report-only", action="store_true",
                   help="only rebuild fidelity.md from the kept per-model results")
    p.add_argument("--check-kept", action="store_true",
                   help="only check whether the current runtime still makes the sets of "
                        "every kept row (of --models), note in fidelity.md the rows it does "
                        "not, and rebuild it")
    p.add_argument("--references-only", nargs="+", metavar="SAMPLER",
                   help="only make (and cache) these samplers' reference sets and statistics")
    a = p.parse_args()
    check_pool_options(p, a)
    if not a.sizes and not (a.merge or a.report_only):
        p.error("--sizes: no size given (with --merge: keep every row the file reproduces)")
    bundled = zoo.networks()
    if a.check_kept:
        for m in a.models or bundled:
            bad = check_kept(m, a.out)
            print(f"{m}: " + (f"kept rows not reproduced at n = {bad}" if bad
                              else "every kept row reproduced"), flush=True)
    models = [] if a.report_only or a.check_kept else (a.models or bundled)
    a.out.mkdir(parents=True, exist_ok=True)
    with ProcessPoolExecutor(a.workers) as pool:
        if a.references_only:
            for sampler in a.references_only:
                for n in a.sizes:
                    t = time.perf_counter()
                    count = reference(pool, sampler, n, a)[0]
                    print(f"{sampler} n={n}: 2 x {count} reference sets and statistics "
                          f"({time.perf_counter() - t:.0f} s)", flush=True)
            return
        if a.merge:  # every model's kept rows checked before the first is measured
            for m in models:
                stop_if_stale(m, a.sizes or [], a.out, a.seed)
        for m in models:
            r = evaluate(pool, m, a)
            save_result(merge_kept(r, a.out, a.seed) if a.merge else r, a.out)
    report(*kept_results(a.out, bundled), a.out)
    print(f"wrote {a.out / 'fidelity.md'}")


if __name__ == "__main__":
    main()
