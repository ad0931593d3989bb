"""Windowed vs global self-attention on a grid larger than any trained one.

A bundled model's weights (read back from its ONNX file) run in torch with global attention
and with windows of 8 and 16 cells (trainer.unet.UNetConfig.attention_window), from the same
noise, at the card's default solver and steps; each is compared with the model's reference
sampler at n = --n (default 4096: the attention level is 16 x 16 cells, twice the widest
trained one). Windows of w cells change nothing where the level is at most w wide, so only
unseen large grids can differ. Writes benchmarks/results/attention_window.md.

    python benchmarks/attention_window.py [--models sobol_owen ldbn rank1] [--n 4096] [--sets 16]
"""
from __future__ import annotations

import argparse
import dataclasses
import datetime as dt
import sys
import time
from pathlib import Path

import numpy as np
import torch

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
from trainer import zoo  # noqa: E402
zoo.use()  # model names are the repository's networks (models/), not the wheel's copies

from diffsampler_rt.grid import decode  # noqa: E402
from diffsampler_rt.model import resolve  # noqa: E402
from diffsampler_rt.schedule import alphas_cumprod, timesteps  # noqa: E402
from diffsampler_rt.solvers import solve  # noqa: E402
from trainer.samplers import sample  # noqa: E402
from trainer.stats import (empty_elementary_fraction, l2_star, min_distance,  # noqa: E402
                           radial_spectrum, spectrum_mae, stratified_projections)
from trainer.unet import UNet  # noqa: E402
from trainer.warm_start import net_from_onnx  # noqa: E402

WINDOWS = (None, 8, 16)


def statistics(pts: np.ndarray, ref_spectrum: np.ndarray, sampler: str) -> dict[str, float]:
    out = {"spectrum MAE": spectrum_mae(radial_spectrum(pts)[1], ref_spectrum),
           "L2*": float(l2_star(pts).mean()), "min distance": float(min_distance(pts).mean())}
    if sampler == "sobol_owen":
        out["empty intervals %"] = 100 * float(empty_elementary_fraction(pts).mean())
    if sampler == "ldbn":
        out["1-d stratified %"] = 100 * float(stratified_projections(pts).mean())
    return out


def run(name: str, n: int, count: int) -> list[tuple[str, dict[str, float], float]]:
    net, cfg, card = net_from_onnx(resolve(name))
    k = int(round(n ** 0.5))
    ab = alphas_cumprod(card["schedule"])
    ts = timesteps(len(ab), card["default_steps"])
    ref = sample(card["sampler"], n, count=2 * count, seed=[999, n])
    spec = radial_spectrum(ref[:count])[1]
    rows = [("reference B (floor)", statistics(ref[count:], spec, card["sampler"]), float("nan")),
            ("reference A", statistics(ref[:count], spec, card["sampler"]), float("nan"))]
    for window in WINDOWS:
        m = UNet(dataclasses.replace(cfg.unet, attention_window=window))
        m.load_state_dict(net.state_dict())
        m.eval()

        def eps(x: np.ndarray, t: int) -> np.ndarray:
            with torch.no_grad():
                xt = torch.tensor(x, dtype=torch.float32)
                return m(xt, torch.full((x.shape[0],), float(t))).double().numpy()

        x = np.random.default_rng(5).standard_normal((count, 2, k, k))
        t0 = time.perf_counter()
        x = solve(card["default_solver"], eps, x, ab, ts)
        seconds = (time.perf_counter() - t0) / count
        pts = decode(x / card["offset_scale"], stratified=card["embedding"] == "stratified")
        label = "global attention" if window is None else f"windows of {window} cells"
        rows.append((label, statistics(pts, spec, card["sampler"]), seconds))
        print(name, label, rows[-1][1], flush=True)
    return rows


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--models", nargs="*", default=["sobol_owen", "ldbn", "rank1"])
    p.add_argument("--n", type=int, default=4096)
    p.add_argument("--sets", type=int, default=16)
    p.add_argument("--threads", type=int, default=1)
    p.add_argument("--out", type=Path,
                   default=ROOT / "benchmarks" / "results" / "attention_window.md")
    a = p.parse_args()
    torch.set_num_threads(a.threads)
    lines = ["# Windowed vs global attention at an unseen size", "",
             f"`python benchmarks/attention_window.py --n {a.n} --sets {a.sets}` on "
             f"{dt.date.today().isoformat()}: the bundled weights in torch, same noise, the "
             "card's default solver and steps; reference sets from the model's sampler "
             "(batch A compared, batch B the floor). L2* and minimum distance: mean over the "
             "sets, relative to reference A. Seconds: torch on "
             f"{a.threads} thread(s), per set, indicative only.", ""]
    for name in a.models:
        rows = run(name, a.n, a.sets)
        keys = list(rows[0][1])
        base = rows[1][1]
        lines += [f"## {name}, n = {a.n}", "", "| attention | " + " | ".join(keys) + " | s/set |",
                  "|---|" + "---|" * (len(keys) + 1)]
        for label, st, sec in rows:
            cells = []
            for key in keys:
                if key in ("L2*", "min distance"):
                    cells.append(f"{100 * (st[key] / base[key] - 1):+.1f} %")
                else:
                    cells.append(f"{st[key]:.4g}")
            lines.append(f"| {label} | " + " | ".join(cells) + f" | {sec:.1f} |")
        lines.append("")
    a.out.parent.mkdir(parents=True, exist_ok=True)
    a.out.write_text("\n".join(lines))
    print(f"wrote {a.out}")


if __name__ == "__main__":
    main()
