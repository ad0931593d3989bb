"""Violin plots of the per-set statistics across sizes: reference sampler vs learned model.

Reads the per-model results kept by benchmarks/fidelity.py
(benchmarks/results/fidelity/<model>.json: per-set OT energy, star L2 discrepancy, Gaussian
and Heaviside integration MSE and minimum distance of every generated and reference set) and
draws, per model, one panel per statistic with a pair of violins (reference, learned) at
every n. Values are scaled by the reference mean at each n so that sizes share an axis
(1 = the reference's mean). Writes benchmarks/results/violins.png.

    python benchmarks/violins.py [--models gbn sot]
"""
from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
RESULTS = ROOT / "benchmarks" / "results"
STATS = {"ot_energy": "OT energy", "l2_star": "star L2", "gauss_mse": "Gaussian MSE",
         "heaviside_mse": "Heaviside MSE", "min_distance": "min distance"}


def load(models: list[str] | None, results: Path = RESULTS) -> dict[str, dict]:
    out = {}
    for path in sorted((results / "fidelity").glob("*.json")):
        if models and path.stem not in models:
            continue
        r = json.loads(path.read_text())
        if any("gen_sets" in row.get("l2_star", {}) for row in r["rows"].values()):
            out[path.stem] = r
    return out


def draw(results: dict[str, dict], out: Path) -> None:
    """One row of violin panels per model (see the module docstring) -> ``out``."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    fig, axes = plt.subplots(len(results), len(STATS), squeeze=False,
                             figsize=(3.3 * len(STATS), 2.3 * len(results)))
    for i, (name, r) in enumerate(results.items()):
        sizes = sorted(int(n) for n in r["rows"])
        for j, (key, label) in enumerate(STATS.items()):
            ax = axes[i, j]
            lo, hi = np.inf, 0.0
            for s_i, n in enumerate(sizes):
                st = r["rows"][str(n)][key]
                ref, gen = np.asarray(st["ref_sets"]), np.asarray(st["gen_sets"])
                scale = ref.mean()
                for side, (vals, colour) in enumerate(((ref, "C0"), (gen, "C1"))):
                    at = s_i + (side - 0.5) * 0.38
                    v = vals / scale
                    lo, hi = min(lo, v.min()), max(hi, v.max())
                    if len(v) < 2 or np.ptp(v) == 0:  # no density to draw: a mark
                        ax.plot([at] * len(v), v, "_", color=colour, ms=10, mew=2)
                        continue
                    parts = ax.violinplot(v, positions=[at], widths=0.36, showmeans=True,
                                          showextrema=False)
                    for b in parts["bodies"]:
                        b.set_facecolor(colour)
                        b.set_alpha(0.6)
                    parts["cmeans"].set_color(colour)
            if lo > 0 and hi / lo > 30:  # a model far off at some n: a log axis keeps the rest legible
                ax.set_yscale("log")
            ax.axhline(1.0, lw=0.6, c="k", alpha=0.4)
            ax.set_xticks(range(len(sizes)), [str(n) for n in sizes], fontsize=7)
            ax.tick_params(axis="y", labelsize=7)
            if i == 0:
                ax.set_title(f"{label} / reference mean", fontsize=9)
            if j == 0:
                ax.set_ylabel(name, fontsize=10)
            if i == len(results) - 1:
                ax.set_xlabel("n", fontsize=8)
    axes[0, 0].legend(handles=[plt.Rectangle((0, 0), 1, 1, color="C0", alpha=0.6),
                               plt.Rectangle((0, 0), 1, 1, color="C1", alpha=0.6)],
                      labels=["reference", "learned"], fontsize=7, loc="upper right")
    fig.tight_layout()
    sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
    from benchmarks.common import save_png
    save_png(fig, out)
    plt.close(fig)
    print(f"wrote {out}")


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--models", nargs="*")
    p.add_argument("--results", type=Path, default=RESULTS, help="fidelity.py's --out")
    p.add_argument("--out", type=Path, default=None, help="default: RESULTS/violins.png")
    a = p.parse_args()
    results = load(a.models, a.results)
    if not results:
        raise SystemExit("no kept fidelity results with per-set statistics; run "
                         "benchmarks/fidelity.py first")
    draw(results, a.out or a.results / "violins.png")


if __name__ == "__main__":
    main()
