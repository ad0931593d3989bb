"""8-bit quantised models vs the float models they were made from: same noise, side by side.

For each quantised model (card ``"weights": "int8"``, made by ``python -m export quantize``)
and its float model (``models/float/<name>.onnx``, whose network hash the card records):
per n, the sets of the float model from noise A and from noise B (the floor: what another
draw of the float model changes) and of the quantised model from noise A. Columns: the
radial-spectrum MAE to the float model's noise-A sets, the relative differences of the
means of the fidelity report's per-set statistics, and how far the quantised model moves
each point from where the float model put it (same noise; median over points, in units of
the mean spacing 1/sqrt(n)). Then one denoiser evaluation's time at k = 32 (n = 1024),
batch 32, float and quantised interleaved in one process. The reference sampler is not
run here: the fidelity report measures the bundled (quantised) file against it.
Writes benchmarks/results/quantized.md (each model's section kept in
benchmarks/results/quantized/).

    python benchmarks/quantized.py [--models gbn_fast] [--sets 128] [--sets-4096 32]
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

import diffsampler_rt  # noqa: E402
from benchmarks.fidelity import STATS, TOL_MEAN, TOL_MIND, set_stats  # noqa: E402
from benchmarks.ort_tuning import ms_per_set, plain, session  # noqa: E402
from trainer.distil import network_hash  # noqa: E402
from trainer.stats import radial_spectrum, spectrum_mae  # noqa: E402

FLOAT_DIR = ROOT / "models" / "float"
LABELS = {"ot_energy": "OT energy", "l2_star": "L2*", "gauss_mse": "Gauss MSE",
          "heaviside_mse": "Heaviside MSE", "min_distance": "min dist"}


def quantised() -> list[str]:
    """Bundled models whose card says their convolutions are 8-bit."""
    return [m for m in diffsampler_rt.list_models()
            if diffsampler_rt.load(m).card.get("weights") == "int8"]


def float_of(name: str, float_dir: Path) -> Path:
    """The float model a quantised one was made from, checked against the card's hash."""
    card = diffsampler_rt.load(name).card
    path = float_dir / f"{name}.onnx"
    if not path.exists():
        raise SystemExit(f"error: {name}'s float model {path} is missing")
    want = card["quantization"]["float_network_sha1"]
    if network_hash(path) != want:
        raise SystemExit(f"error: {path} is not the network {name} was quantised from "
                         f"(hash {network_hash(path)}, card says {want})")
    return path


def rel(value: float, base: float, tol: float) -> str:
    d = value / base - 1
    return f"{100 * d:+.1f} %" + (" ✗" if abs(d) > tol else "")


def rows_at(pool, fmodel, qmodel, n: int, sets: int) -> list[str]:
    a = fmodel.generate(n, sets, seed=1)
    b = fmodel.generate(n, sets, seed=2)
    q = qmodel.generate(n, sets, seed=1)
    spec = radial_spectrum(a)[1]
    base = {k: v.mean() for k, v in set_stats(pool, a).items()}
    lines = []
    for label, x in (("float, other noise (floor)", b), ("**8-bit, same noise**", q)):
        st = set_stats(pool, x)
        moved = np.median(np.linalg.norm(x - a, axis=-1)) * np.sqrt(n)
        cells = " | ".join(rel(st[k].mean(), base[k], TOL_MIND if k == "min_distance"
                               else TOL_MEAN) for k in STATS)
        lines.append(f"| {n} ({sets}) | {label} | {spectrum_mae(radial_spectrum(x)[1], spec):.4f} | "
                     f"{cells} | {moved:.3f} |")
        print(lines[-1], flush=True)
    return lines


def speed(float_path: Path, q_path: Path, rounds: int = 6) -> tuple[float, float]:
    """Median ms per set of one evaluation at k = 32, batch 32, the two interleaved."""
    sessions = [session(str(float_path)), session(str(q_path))]
    times: list[list[float]] = [[], []]
    for _ in range(rounds):
        for i, s in enumerate(sessions):
            times[i].append(ms_per_set(plain(s, 32), 32, 5))
    return float(np.median(times[0])), float(np.median(times[1]))


def main() -> None:
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
    a = p.parse_args()
    models = [] if a.report_only else (a.models or quantised())
    kept = a.out.parent / "quantized"
    kept.mkdir(parents=True, exist_ok=True)
    header = ["# 8-bit convolutions vs the float model, same noise", "",
              f"`python benchmarks/quantized.py` ({os.cpu_count()} cores). Per row: the "
              "model's sets vs the float model's sets from the same noise (A); the first row "
              "of each size is the float model from other noise (B), the floor. Relative "
              f"differences of the means; ✗: beyond ±{100 * TOL_MEAN:.0f} % (min distance "
              f"±{100 * TOL_MIND:.0f} %). *moved*: median distance of a point from the "
              "float model's point of the same cell, in mean spacings 1/sqrt(n) (an "
              "OT-embedded model may swap a whole neighbourhood, so its tail is long). "
              "Default solver, steps and repairs of each card. The evaluation times are "
              "taken in the same process, float and 8-bit interleaved, so their ratio holds "
              "while other jobs run but their values do not (benchmarks/results/speed.md has "
              "clean timings). Each model's section is kept in benchmarks/results/quantized/ "
              "and says when it was run.", ""]
    with ProcessPoolExecutor(a.workers) as pool:
        for name in models:
            fpath = float_of(name, a.float_dir)
            qpath = diffsampler_rt.model.resolve(name)
            fmodel, qmodel = diffsampler_rt.load(fpath), diffsampler_rt.load(name)
            card = qmodel.card
            fast, slow = speed(fpath, qpath)
            lines = [f"## {name}", "",
                     f"{card['default_solver']} {card['default_steps']} steps; "
                     f"{card['quantization']['method']}; calibrated on "
                     f"{card['quantization']['feeds']} solver inputs at grid sides "
                     f"{', '.join(map(str, card['quantization']['sides']))}. Measured "
                     f"{dt.date.today().isoformat()}. File: {qpath.stat().st_size / 2**20:.2f} "
                     f"MiB (float: {fpath.stat().st_size / 2**20:.2f} MiB). One evaluation at "
                     f"n = 1024, batch 32: {fast:.2f} ms per set float, {slow:.2f} ms 8-bit "
                     f"({100 * (slow / fast - 1):+.0f} %).", "",
                     "| n (sets) | model | spectrum MAE to float | "
                     + " | ".join(LABELS[k] for k in STATS) + " | moved |",
                     "|---|---|---|" + "---|" * len(STATS) + "---|"]
            for n in a.sizes:
                lines += rows_at(pool, fmodel, qmodel, n, a.sets_4096 if n >= 4096 else a.sets)
            (kept / f"{name}.md").write_text("\n".join(lines + [""]))
    sections = [p.read_text() for p in sorted(kept.glob("*.md"))]
    a.out.write_text("\n".join(header + sections))
    print(f"wrote {a.out}")


if __name__ == "__main__":
    main()
