"""How few denoiser evaluations keep a model's fidelity: solvers x steps against the reference.

For each model and n in --sizes, sets generated with every (solver, steps) setting are
compared with the same cached reference batch as benchmarks/fidelity.py: radial-spectrum
MAE (floor: reference batch B vs A) and the relative difference of the mean OT energy, star
L2 discrepancy, Gaussian / Heaviside integration MSE and minimum distance. The generation
time per set (batched, this machine) is printed next to each setting. Writes
benchmarks/results/solver_sweep.md; the runtime's defaults (model card `default_solver` /
`default_steps`, set with `python -m export set-defaults`) are chosen from it.

    python benchmarks/solver_sweep.py --models gbn poisson_disk [--sets 64] [--sizes 1024]
"""
from __future__ import annotations

import argparse
import datetime as dt
import os
import sys
import time
import warnings
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
from trainer import zoo  # noqa: E402
zoo.use()  # model names are the repository's networks (models/), not the wheel's copies

import diffsampler_rt  # noqa: E402
from benchmarks.fidelity import (STATS, TOL_MEAN, TOL_MIND, reference,  # noqa: E402
                                 set_stats, tolerance)
from trainer.samplers.densities import UNWARP  # noqa: E402
from trainer.stats import radial_spectrum, spectrum_mae  # noqa: E402

SETTINGS = (("ddim", 50), ("ddim", 20), ("ddim", 10), ("dpmpp_2m", 20), ("dpmpp_2m", 12),
            ("dpmpp_2m", 10), ("dpmpp_2m", 8), ("dpmpp_2m", 6))


def parse_setting(text: str) -> tuple:
    """``solver:steps`` or ``solver:steps:gL`` (L: the card's structure_guidance overridden,
    the last L solver steps projected; ldbn-like models)."""
    solver, _, rest = text.partition(":")
    steps, _, guidance = rest.partition(":")
    if guidance and not (guidance.startswith("g") and guidance[1:].isdigit()):
        raise argparse.ArgumentTypeError(f"setting {text!r}: the third part must be gL, e.g. g3")
    return (solver, int(steps)) + ((int(guidance[1:]),) if guidance else ())


def load_with(name: str, guidance: int | None) -> "diffsampler_rt.Model":
    """The model, its pipeline's structure_guidance steps replaced when ``guidance`` is given."""
    if guidance is None:
        return diffsampler_rt.load(name)
    model = diffsampler_rt.Model(diffsampler_rt.load(name).path)  # a private copy
    pipeline = [{**e, "steps": guidance} if e["step"] == "structure_guidance" else e
                for e in model.card["pipeline"]]
    model.card = {**model.card, "pipeline": pipeline}
    return model


def compare(pool, sampler: str, n: int, runs, a, refs=None) -> list[dict]:
    """Rows for ``runs`` = [(label, model, solver, steps[, guidance])], all of reference
    ``sampler``.

    ``refs``: the reference batch sizes (fidelity.py's options; default its defaults, so
    its cached sets are reused); ``a.sets`` caps the sets compared.
    """
    unwarp = UNWARP.get(sampler) or (lambda p: p)
    # the fidelity references: per-set statistics of batch A (and B for the floor)
    count, _, ref_a, ref_b, _, stats_a, stats_b = reference(pool, sampler, n,
                                                            refs or FIDELITY_REFS)
    count = min(count, a.sets)
    ra, rb = unwarp(ref_a[:count]), unwarp(ref_b[:count])
    sa, sb = radial_spectrum(ra)[1], radial_spectrum(rb)[1]
    rows = [{"setting": "reference B (floor)", "mae": spectrum_mae(sb, sa), "ms": float("nan"),
             "count": count,
             **{k: float(stats_b[k][:count].mean() / stats_a[k][:count].mean() - 1) for k in STATS}}]
    for label, name, solver, steps, *guidance in runs:
        model = load_with(name, guidance[0] if guidance else None)
        with warnings.catch_warnings():  # a distilled model off its setting is the point here
            warnings.simplefilter("ignore")
            model.generate(n, 2, seed=0, steps=steps, solver=solver)  # warm-up
            t = time.perf_counter()
            gen = unwarp(model.generate(n, count, seed=a.seed, steps=steps, solver=solver))
        ms = 1000 * (time.perf_counter() - t) / count
        st = set_stats(pool, gen)
        row = {"setting": label, "mae": spectrum_mae(radial_spectrum(gen)[1], sa), "ms": ms,
               **{k: float(st[k].mean() / stats_a[k][:count].mean() - 1) for k in STATS}}
        rows.append(row)
        print(f"{sampler} n={n} {label}: MAE {row['mae']:.4f}, "
              + ", ".join(f"{k} {100 * row[k]:+.1f}%" for k in STATS) + f", {ms:.0f} ms/set",
              flush=True)
    return rows


def sweep(pool, name: str, n: int, settings, a) -> list[dict]:
    """One model under every (solver, steps) setting."""
    sampler = diffsampler_rt.load(name).card["sampler"]
    return compare(pool, sampler, n,
                   [(f"{solver} {steps}" + (f", guidance {more[0]}" if more else ""), name,
                     solver, steps, *more) for solver, steps, *more in settings], a)


def table(rows: list[dict]) -> list[str]:
    """Markdown table of :func:`compare` rows; ✗ marks a miss of the issue's tolerances."""
    lines = ["| setting | spectrum MAE | " + " | ".join(STATS) + " | ms/set |",
             "|---|---|" + "---|" * len(STATS) + "---|"]
    for r in rows:
        cells = [f"{100 * r[k]:+.1f} %" + (" ✗" if abs(r[k]) > tolerance(k) else "")
                 for k in STATS]
        lines.append(f"| {r['setting']} | {r['mae']:.4f} | " + " | ".join(cells)
                     + f" | {r['ms']:.0f} |")
    return lines


#: fidelity.py's default batch sizes: the sweep reuses its cached reference sets and stats
FIDELITY_REFS = argparse.Namespace(sets=128, slow_sets=64, slow_4096=16, spectrum_sets=1024)


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--models", nargs="*", help="default: every bundled model")
    p.add_argument("--sizes", type=int, nargs="*", default=[1024])
    p.add_argument("--settings", nargs="*", type=parse_setting,
                   default=list(SETTINGS),
                   help="solver:steps[:gL], e.g. dpmpp_2m:10 or ddim:8:g3")
    p.add_argument("--sets", type=int, default=64, help="sets per setting (and reference)")
    p.add_argument("--workers", type=int, default=1)
    p.add_argument("--seed", type=int, default=1)
    p.add_argument("--out", type=Path, default=ROOT / "benchmarks" / "results" / "solver_sweep.md")
    p.add_argument("--append", action="store_true",
                   help="add this run's sections to --out instead of replacing it")
    a = p.parse_args()
    models = a.models or zoo.networks()
    command = ("`python benchmarks/solver_sweep.py " + " ".join(sys.argv[1:]) + "` on "
               f"{dt.date.today().isoformat()} ({os.cpu_count()} cores)")
    if a.append and a.out.exists():
        lines = a.out.read_text().rstrip("\n").split("\n") + [
            "", f"Sections below: {command}.", ""]
    else:
        lines = ["# Few-step sampling: solvers x steps vs the reference sampler", "",
                 f"{command}; other jobs may have shared the machine, so times are indicative: "
                 "benchmarks/results/speed.md has the timings. Each figure: generated vs "
                 "reference batch A; the first row is an independent reference batch B (the "
                 "noise floor). Relative differences of the means; ✗: beyond "
                 f"±{100 * TOL_MEAN:.0f} % (min distance ±{100 * TOL_MIND:.0f} %).", ""]
    with ProcessPoolExecutor(a.workers) as pool:
        for name in models:
            for n in a.sizes:
                rows = sweep(pool, name, n, a.settings, a)
                lines += [f"## {name}, n = {n}", ""] + table(rows) + [""]
    a.out.parent.mkdir(parents=True, exist_ok=True)
    a.out.write_text("\n".join(lines))
    print(f"wrote {a.out}")


if __name__ == "__main__":
    main()
