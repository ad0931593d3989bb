"""Reference samplers against the seed paper's curves: radial spectrum at n = 1024 and speed.

For every sampler with a curve in the seed's figure data: the mean absolute difference
(79 bins) between its mean radial spectrum over --sets sets (1 for the deterministic
rank1 lattice) and the seed's curve, next to the noise floor of that many sets; time per
set at n = 64, 256, 1024, 4096; a figure of each sampler's points and spectrum over the
seed's curve. Sets are generated on --workers processes, set by set, with seeds fixed here.
Writes benchmarks/results/reference_samplers.md and reference_samplers.png.

    python benchmarks/reference_samplers.py [--sets 256] [--workers 2]
"""
from __future__ import annotations

import argparse
import datetime as dt
import os
import sys
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
from trainer import zoo  # noqa: E402
zoo.use()  # model names are the repository's networks (models/), not the wheel's copies

from benchmarks.common import SEED_COLUMNS as COLUMNS, SEED_CSV, cached_sets, generate  # noqa: E402
from trainer.stats import radial_spectrum, spectrum_mae, stratified_projections  # noqa: E402

TARGETS = {"rank1": 0.005, "sobol_owen": 0.01, "sot": 0.03, "gbn": 0.03,
           "poisson_disk": 0.03, "ldbn": 0.05}
SIZES = (64, 256, 1024, 4096)


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--sets", type=int, default=256)
    p.add_argument("--workers", type=int, default=2)
    p.add_argument("--samplers", nargs="*", default=COLUMNS)
    p.add_argument("--out", type=Path, default=ROOT / "benchmarks" / "results")
    p.add_argument("--no-timing", action="store_true",
                   help="only generate (and cache) the n = 1024 sets; no report")
    a = p.parse_args()
    curves = np.loadtxt(SEED_CSV, delimiter=",", skiprows=1)
    rows, figs = [], []
    with ProcessPoolExecutor(a.workers) as pool:
        for name in a.samplers:
            sets = 1 if name == "rank1" else a.sets
            pts, per_set, _ = cached_sets(pool, name, 1024, sets, 1)
            wall = per_set * sets / a.workers  # wall time of generating them on the workers
            if a.no_timing:
                print(f"{name}: {sets} sets cached ({per_set:.2f} s per set)", flush=True)
                continue
            _, spec = radial_spectrum(pts)
            curve = curves[:, 1 + COLUMNS.index(name)]
            mae = spectrum_mae(spec, curve)
            floor = float("nan")
            if sets > 1:  # noise floor: two independent halves against each other, scaled
                _, s1 = radial_spectrum(pts[: sets // 2])
                _, s2 = radial_spectrum(pts[sets // 2:])
                floor = spectrum_mae(s1, s2) / 2  # MAE of a mean of `sets` vs the truth ~ half
            times = {}
            for n in SIZES:
                reps = 1 if (n == 4096 and name in ("sot", "gbn")) else (2 if n >= 1024 else 4)
                _, times[n] = generate(pool, name, n, reps, 7, chunk=1)
            strat = bool(np.all(stratified_projections(pts)))
            rows.append((name, sets, mae, floor, TARGETS.get(name), times, wall, strat))
            figs.append((name, pts[0], spec, curve))
            print(f"{name}: MAE {mae:.4f} (floor ~{floor:.4f}), {sets} sets ~{wall:.0f} s; "
                  + ", ".join(f"n={n}: {1000 * t:.1f} ms" for n, t in times.items()), flush=True)
    if not a.no_timing:
        write(a, rows, figs)


def write(a, rows, figs) -> None:
    lines = ["# Reference samplers vs the seed paper's curves", "",
             f"`python benchmarks/reference_samplers.py --sets {a.sets} --workers {a.workers}` on "
             f"{dt.date.today().isoformat()}, {os.cpu_count()} cores. MAE = mean absolute "
             "difference between the mean radial power spectrum at n = 1024 and the seed's "
             "curve over its 79 bins; floor = the expected MAE from sampling noise alone with "
             "that many sets (half the MAE between the two halves of the sets). Times are per "
             "set, one set at a time on one core; the wall time is that of generating the "
             f"n = 1024 sets on {a.workers} worker processes.", "",
             "| sampler | sets | MAE vs seed | noise floor | target | met | 1-d stratified | "
             + " | ".join(f"ms/set n={n}" for n in SIZES) + " | wall time for the sets |",
             "|---|---|---|---|---|---|---|" + "---|" * len(SIZES) + "---|"]
    for name, sets, mae, floor, target, times, wall, strat in rows:
        met = "" if target is None else ("yes" if mae <= target else "**no**")
        lines.append(f"| {name} | {sets} | {mae:.4f} | {floor:.4f} | {target} | {met} | "
                     f"{'yes' if strat else 'no'} | "
                     + " | ".join(f"{1000 * times[n]:.1f}" for n in SIZES)
                     + f" | {wall:.0f} s |")
    lines += ["", "![points and spectra](reference_samplers.png)", ""]
    a.out.mkdir(parents=True, exist_ok=True)
    (a.out / "reference_samplers.md").write_text("\n".join(lines))
    try:
        import matplotlib
        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
    except ImportError:
        return
    fig, axes = plt.subplots(len(figs), 2, figsize=(9, 3.6 * len(figs)), squeeze=False,
                             gridspec_kw={"width_ratios": [1, 1.6]})
    x = np.arange(1, 80) * 0.0625
    for (name, pts, spec, curve), (a0, a1) in zip(figs, axes):
        a0.scatter(pts[:, 0], pts[:, 1], s=1.5, c="k")
        a0.set(title=f"{name}, n = 1024", xlim=(0, 1), ylim=(0, 1), aspect="equal",
               xticks=[], yticks=[])
        a1.plot(x, curve, color="k", lw=2, alpha=0.4, label="seed paper")
        a1.plot(x, spec, color="C1", lw=1, label="ours")
        a1.set(title=f"{name}: radial spectrum", xlabel="|f| / sqrt(n)")
        a1.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(a.out / "reference_samplers.png", dpi=80)


if __name__ == "__main__":
    main()
