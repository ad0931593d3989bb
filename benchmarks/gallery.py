"""The gallery: for every bundled model, reference sampler vs learned model side by side.

Per row (one model): reference points, learned points, the reference's and the model's
mean 2-d power spectrum, and both radial spectra (n = 1024 by default, spectra over
--sets sets). Reference sets come from the fidelity benchmark's cache when present
(~/.cache/diffsampler/reference), else they are drawn here. Non-uniform models are shown
as generated (warped); their spectra are taken after the exact unwarping map.
Writes benchmarks/results/gallery.png, then redraws benchmarks/results/violins.png from the
per-set statistics kept by benchmarks/fidelity.py (benchmarks/violins.py alone does only
that), so one command makes both figures the README shows.

    python benchmarks/gallery.py [--n 1024] [--sets 32] [--models gbn sot]
"""
from __future__ import annotations

import argparse
import functools
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
from trainer import zoo  # noqa: E402
zoo.use()  # model names are the repository's networks (models/), not the wheel's copies

import diffsampler_rt  # noqa: E402
from benchmarks.common import cache_dir, save_png  # noqa: E402
from diffsampler_rt.spectrum import periodogram, radial_spectrum  # noqa: E402
from trainer.samplers import sample  # noqa: E402
from trainer.samplers.densities import UNWARP  # noqa: E402


@functools.lru_cache(maxsize=None)  # models of one sampler (a student, its teacher) share them
def reference_sets(sampler: str, n: int, count: int) -> np.ndarray:
    """Up to ``count`` reference sets: the smallest cached batch (seed 1) holding ``count``,
    else the largest cached one (slow samplers: fewer sets, the figure says how many), else
    ``count`` fresh ones."""
    cached = sorted((int(path.name.split("_c")[-1].split("_")[0]), path)
                    for path in (cache_dir() / "reference").glob(f"{sampler}_n{n}_c*_s1.npz"))
    if not cached:
        return sample(sampler, n, count=count, seed=[1, n])
    enough = [path for c, path in cached if c >= count]
    return np.load(enough[0] if enough else cached[-1][1])["pts"][:count]


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--models", nargs="*", help="default: every bundled model")
    p.add_argument("--n", type=int, default=1024)
    p.add_argument("--sets", type=int, default=32)
    p.add_argument("--out", type=Path, default=ROOT / "benchmarks" / "results" / "gallery.png")
    a = p.parse_args()
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    models = a.models or zoo.networks()
    fig, axes = plt.subplots(len(models), 5, figsize=(17, 3.5 * len(models)), squeeze=False)
    fmax = int(2.5 * np.sqrt(a.n))
    for row, name in zip(axes, models):
        model = diffsampler_rt.load(name)
        sampler = model.card["sampler"]
        gen = model.generate(a.n, a.sets, seed=0)
        ref = reference_sets(sampler, a.n, a.sets)
        unwarp = UNWARP.get(sampler, lambda q: q)
        for ax, pts, label in ((row[0], ref, f"{sampler} (reference)"), (row[1], gen, f"{name} (learned)")):
            ax.scatter(pts[0, :, 0], pts[0, :, 1], s=0.8, c="k", lw=0)
            ax.set(xlim=(0, 1), ylim=(0, 1), aspect="equal", xticks=[], yticks=[], title=label)
        for ax, pts, label in ((row[2], ref, "reference"), (row[3], gen, "learned")):
            P = periodogram(unwarp(pts), fmax)
            P[fmax, fmax] = np.nan
            ax.imshow(np.log10(np.maximum(P, 1e-3)), origin="lower", cmap="magma", vmin=-2, vmax=1)
            ax.set(xticks=[], yticks=[], title=f"{label}: power spectrum")
        x, sr = radial_spectrum(unwarp(ref))
        row[4].plot(x, sr, lw=1.5, color="0.5", label="reference")
        row[4].plot(x, radial_spectrum(unwarp(gen))[1], lw=1.1, color="C1", label="learned")
        row[4].axhline(1.0, color="k", lw=0.5, ls=":")
        sets = (f"{len(ref)} ref / {len(gen)} learned sets" if len(ref) != len(gen)
                else f"{len(gen)} sets")
        row[4].set(title=f"radial spectrum, n = {a.n}, {sets}", xlabel="|f| / sqrt(n)")
        row[4].legend(fontsize=8)
        print(f"{name}: done", flush=True)
    fig.tight_layout()
    a.out.parent.mkdir(parents=True, exist_ok=True)
    save_png(fig, a.out)
    print(f"wrote {a.out}")
    from benchmarks import violins
    kept = violins.load(a.models, violins.RESULTS)
    if kept:
        violins.draw(kept, a.out.parent / "violins.png")


if __name__ == "__main__":
    main()
