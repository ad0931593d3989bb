"""8-bit quantised models vs the float models they were made from: same noise, side by side.

For each quantised model (card ``"weights": "int8"``, made by ``python -m export quantize``)
and its float model (``models/float/<name>.onnx``, whose network hash the card records):
per n, the sets of the float model from noise A and from noise B (the floor: what another
draw of the float model changes) and of the quantised model from noise A. Columns: the
radial-spectrum MAE to the float model's noise-A sets, the relative differences of the
means of the fidelity report's per-set statistics, and how far the quantised model moves
each point from where the float model put it (same noise; median over points, in units of
the mean spacing 1/sqrt(n)). Non-uniform models are measured in the uniform square (after
the exact unwarping), as in the fidelity report. With ``--timing-only`` (on an otherwise
idle machine): one denoiser evaluation at k = 32 (batch 32) and ``generate`` at n = 1024
(batched and alone), float and quantised alternated, each measured in a fresh process. The
reference sampler is not run here: the fidelity report measures the bundled (quantised)
file against it. Writes
benchmarks/results/quantized.md (each model's section, and the timing tables, one per day,
kept in benchmarks/results/quantized/).

    python benchmarks/quantized.py [--models gbn_fast] [--sets 128] [--sets-4096 32]
    python benchmarks/quantized.py --timing-only
"""
from __future__ import annotations

import argparse
import datetime as dt
import json
import os
import subprocess
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
from benchmarks.common import FLOAT_DIR, cpu_description, float_source  # noqa: E402
from benchmarks.fidelity import (STATS, TOL_MEAN, TOL_MIND, set_stats,  # noqa: E402
                                 tolerance)
from benchmarks.ort_tuning import ms_per_set, plain  # noqa: E402
from trainer.samplers.densities import UNWARP  # noqa: E402
from trainer.stats import radial_spectrum, spectrum_mae  # noqa: E402

LABELS = {"ot_energy": "OT energy", "l2_star": "L2*", "gauss_mse": "Gauss MSE",
          "heaviside_mse": "Heaviside MSE", "min_distance": "min dist"}


def quantised() -> list[str]:
    """Bundled models whose card says their convolutions are 8-bit."""
    return [m for m in zoo.networks()
            if diffsampler_rt.load(m).card.get("weights") == "int8"]


def rel(value: float, base: float, tol: float) -> str:
    d = value / base - 1
    return f"{100 * d:+.1f} %" + (" ✗" if abs(d) > tol else "")


def rows_at(pool, fmodel, qmodel, n: int, sets: int) -> list[str]:
    # non-uniform models: in the uniform square, as the fidelity report measures them (the
    # integration errors of the mapped sets are their density's, the same for every draw)
    unwarp = UNWARP.get(fmodel.card["sampler"], lambda p: p)
    a, b, q = (unwarp(m.generate(n, sets, seed=s))
               for m, s in ((fmodel, 1), (fmodel, 2), (qmodel, 1)))
    spec = radial_spectrum(a)[1]
    base = {k: v.mean() for k, v in set_stats(pool, a).items()}
    lines = []
    for label, x in (("float, other noise (floor)", b), ("**8-bit, same noise**", q)):
        st = set_stats(pool, x)
        moved = np.median(np.linalg.norm(x - a, axis=-1)) * np.sqrt(n)
        cells = " | ".join(rel(st[k].mean(), base[k], tolerance(k)) for k in STATS)
        lines.append(f"| {n} ({sets}) | {label} | {spectrum_mae(radial_spectrum(x)[1], spec):.4f} | "
                     f"{cells} | {moved:.3f} |")
        print(lines[-1], flush=True)
    return lines


def generate_ms(model, batch: int) -> float:
    t = time.perf_counter()
    model.generate(1024, batch, seed=0)
    return 1000 * (time.perf_counter() - t) / batch


def child_timing(path: str) -> dict:
    """In a fresh process (one onnxruntime session, nothing else running in it): one
    evaluation at k = 32 (batch 32), and generate at n = 1024 batched and alone (medians of
    3 after a warm-up), ms per set."""
    model = diffsampler_rt.model.Model(path)
    model.generate(1024, 2, seed=0)  # warm-up
    ev = ms_per_set(plain(model.session, 32), 32, 5)
    return {"eval": ev,
            "batched": float(np.median([generate_ms(model, 32) for _ in range(3)])),
            "alone": float(np.median([generate_ms(model, 1) for _ in range(3)]))}


def timing_row(name: str, float_path: Path, rounds: int) -> str:
    """Float and 8-bit alternated, each measurement in a fresh child process (sessions in
    one process disturb each other's thread pools), medians over ``rounds``."""
    paths = [str(float_path), str(diffsampler_rt.model.resolve(name))]
    runs: list[list[dict]] = [[], []]
    for _ in range(rounds):
        for i in (0, 1):
            out = subprocess.run([sys.executable, __file__, "--child", paths[i]],
                                 capture_output=True, text=True, check=True)
            runs[i].append(json.loads(out.stdout.strip().splitlines()[-1]))
    f, q = ([float(np.median([r[key] for r in runs[i]])) for key in ("eval", "batched", "alone")]
            for i in (0, 1))
    return (f"| {name} | {f[0]:.2f} / {q[0]:.2f} ({100 * (q[0] / f[0] - 1):+.0f} %) | "
            f"{f[1]:.1f} / {q[1]:.1f} ({100 * (q[1] / f[1] - 1):+.0f} %) | "
            f"{f[2]:.1f} / {q[2]:.1f} ({100 * (q[2] / f[2] - 1):+.0f} %) |")


def timing(models: list[str], float_dir: Path, rounds: int) -> list[str]:
    lines = [f"## Timing, {dt.date.today().isoformat()}", "",
             f"n = 1024, ms per set, float / 8-bit: medians of {rounds} rounds that alternate "
             "the two, each measurement in a fresh process (one evaluation: median of 5 calls "
             "after 2 warm-ups; generate: median of 3 calls after a warm-up; "
             f"{os.cpu_count()} cores of {cpu_description()}, onnxruntime's default "
             "threads). Run with nothing else on the machine (`--timing-only`).", "",
             "| model | one evaluation (batch 32) | generate, batch of 32 | generate, alone |",
             "|---|---|---|---|"]
    for name in models:
        lines.append(timing_row(name, float_source(name, float_dir), rounds))
        print(lines[-1], flush=True)
    return lines + [""]


def main() -> None:
    if sys.argv[1:2] == ["--child"]:
        print(json.dumps(child_timing(sys.argv[2])))
        return
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--models", nargs="*", help="default: every quantised bundled model")
    p.add_argument("--sizes", type=int, nargs="*", default=[256, 576, 1024, 4096])
    p.add_argument("--sets", type=int, default=128, help="sets per row")
    p.add_argument("--sets-4096", type=int, default=32, help="sets per row at n >= 4096")
    p.add_argument("--float-dir", type=Path, default=FLOAT_DIR)
    p.add_argument("--workers", type=int, default=2)
    p.add_argument("--out", type=Path, default=ROOT / "benchmarks" / "results" / "quantized.md")
    p.add_argument("--report-only", action="store_true",
                   help="only rebuild quantized.md from the kept sections")
    p.add_argument("--timing-only", action="store_true",
                   help="only time float vs 8-bit (kept as quantized/timing.md)")
    p.add_argument("--rounds", type=int, default=5, help="interleaved timing rounds")
    a = p.parse_args()
    kept = a.out.parent / "quantized"
    kept.mkdir(parents=True, exist_ok=True)
    # one timing table per day: the 8-bit files' gain depends on the host's CPU (VNNI or not)
    if a.timing_only:
        table = timing(a.models or quantised(), a.float_dir, a.rounds)
        (kept / f"timing-{dt.date.today().isoformat()}.md").write_text("\n".join(table))
    models = [] if a.report_only or a.timing_only else (a.models or quantised())
    header = ["# 8-bit convolutions vs the float model, same noise", "",
              f"`python benchmarks/quantized.py` ({os.cpu_count()} cores). Per row: the "
              "model's sets vs the float model's sets from the same noise (A); the first row "
              "of each size is the float model from other noise (B), the floor. Relative "
              f"differences of the means; ✗: beyond ±{100 * TOL_MEAN:.0f} % (min distance "
              f"±{100 * TOL_MIND:.0f} %). *moved*: median distance of a point from the "
              "float model's point of the same cell, in mean spacings 1/sqrt(n) (an "
              "OT-embedded model may swap a whole neighbourhood, so its tail is long). "
              "Default solver, steps and repairs of each card. Each model's section is kept "
              "in benchmarks/results/quantized/ and says when it was run; the timing "
              "tables come last, one per day they were measured.", ""]
    with ProcessPoolExecutor(a.workers) as pool:
        for name in models:
            fpath = float_source(name, a.float_dir)
            qpath = diffsampler_rt.model.resolve(name)
            fmodel, qmodel = diffsampler_rt.load(fpath), diffsampler_rt.load(name)
            card = qmodel.card
            lines = [f"## {name}", "",
                     f"{card['default_solver']} {card['default_steps']} steps; "
                     f"{card['quantization']['method']}; calibrated on "
                     f"{card['quantization']['feeds']} solver inputs at grid sides "
                     f"{', '.join(map(str, card['quantization']['sides']))}. Measured "
                     f"{dt.date.today().isoformat()}. File: {qpath.stat().st_size / 2**20:.2f} "
                     f"MiB (float: {fpath.stat().st_size / 2**20:.2f} MiB).", "",
                     "| n (sets) | model | spectrum MAE to float | "
                     + " | ".join(LABELS[k] for k in STATS) + " | moved |",
                     "|---|---|---|" + "---|" * len(STATS) + "---|"]
            for n in a.sizes:
                lines += rows_at(pool, fmodel, qmodel, n, a.sets_4096 if n >= 4096 else a.sets)
            (kept / f"{name}.md").write_text("\n".join(lines + [""]))
    timed = sorted(kept.glob("timing*.md"))
    sections = [p.read_text() for p in sorted(kept.glob("*.md")) if p not in timed]
    sections += [p.read_text() for p in timed]
    a.out.write_text("\n".join(header + sections))
    print(f"wrote {a.out}")


if __name__ == "__main__":
    main()
