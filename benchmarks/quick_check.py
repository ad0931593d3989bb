"""Quick look at a training checkpoint: a few statistics against its reference sampler.

Exports the checkpoint's EMA weights to a temporary ONNX file (no parity check), generates
--sets sets per size with the runtime and prints, per size, the radial-spectrum MAE (with
the floor between two reference batches), star L2 discrepancy, mean minimum distance and,
for 2^m-point sets of a net sampler, the fraction of empty elementary intervals. Meant for
deciding whether a run is worth continuing; benchmarks/fidelity.py is the full report.

    python benchmarks/quick_check.py runs/sobol_owen/checkpoint.pt [--sizes 256 1024] [--sets 64]
"""
from __future__ import annotations

import argparse
import sys
import tempfile
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
from trainer import zoo  # noqa: E402
zoo.use()  # model names are the repository's networks (models/), not the wheel's copies

import diffsampler_rt  # noqa: E402
from export.onnx_export import export_checkpoint  # noqa: E402
from trainer.samplers import sample  # noqa: E402
from trainer.stats import (empty_elementary_fraction, l2_star, min_distance,  # noqa: E402
                           radial_spectrum, spectrum_mae, stratified_projections)


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("checkpoint", type=Path)
    p.add_argument("--sizes", type=int, nargs="*", default=[256, 1024])
    p.add_argument("--sets", type=int, default=64)
    p.add_argument("--steps", type=int, help="sampling steps (default: the config's)")
    p.add_argument("--solver", default="ddim")
    a = p.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        path, _ = export_checkpoint(a.checkpoint, Path(tmp) / "m.onnx", parity_sides=None)
        model = diffsampler_rt.load(path)
        card = model.card
        sampler = card["sampler"]
        print(f"{card['name']}: {card['training_steps']} steps, sampler {sampler}")
        for n in a.sizes:
            gen = model.generate(n, a.sets, seed=0, steps=a.steps, solver=a.solver)
            ref = sample(sampler, n, count=2 * a.sets, seed=[12345, n])
            ra, rb = ref[: a.sets], ref[a.sets:]
            sg, sa, sb = (radial_spectrum(x)[1] for x in (gen, ra, rb))
            line = (f"n={n}: MAE {spectrum_mae(sg, sa):.4f} (floor {spectrum_mae(sb, sa):.4f})"
                    f" | L2* {l2_star(gen).mean():.3e} vs {l2_star(ra).mean():.3e}"
                    f" | min dist {min_distance(gen).mean() / min_distance(ra).mean():.2f}x")
            if n & (n - 1) == 0 and empty_elementary_fraction(ra).max() == 0:
                line += f" | empty intervals {100 * empty_elementary_fraction(gen).mean():.1f} %"
            if stratified_projections(ra).all():
                line += f" | 1-d stratified {100 * stratified_projections(gen).mean():.0f} % of sets"
            print(line, flush=True)


if __name__ == "__main__":
    main()
