"""The fit's report: the model's sets beside HELD-OUT example sets (never trained or
calibrated on), at every example size and at one larger size no example has.

Per size: radial spectrum (mean absolute difference, next to its noise floor), pair
correlation function (likewise), nearest-neighbour distance (mean, and its distribution in
the plot), smallest distance, star L2 discrepancy, and for non-uniform examples the
intensity on a 4 x 4 grid. Each figure ends in a verdict: *within noise* when the
difference is at most twice its noise (the floor, or two standard errors), else *off by X*.

Noise floors: the curves' floor is half the mean absolute difference between the two
halves of the held-out sets (the difference the held-out sets' own noise makes against a
mean of many generated sets); the means' noise is the standard error of the difference.
At the larger size there are no examples: its row compares the generated sets with the
largest example size's held-out sets in units that do not depend on n (frequency and
distances in units of 1 / sqrt(n)), which holds for samplers whose pattern does not change
with n; read it as a check of the extrapolation, not a measurement against the sampler.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from diffsampler_rt.spectrum import radial_spectrum
from trainer.stats.distance import nearest_neighbour_distances

from .analysis import _counts


@dataclass
class Figure:
    name: str
    generated: float
    reference: float
    noise: float
    kind: str  # "curve": MAE against a floor; "mean": relative difference against its SE

    def verdict(self) -> str:
        if self.kind == "curve":
            if self.generated <= 2 * self.noise:
                return "within noise"
            if self.noise < 1e-9:  # identical held-out sets (a lattice): no floor to scale by
                return f"off by {self.generated:.4f} (floor 0)"
            return f"off by {self.generated / self.noise:.1f}x the floor"
        diff = self.generated - self.reference
        if abs(diff) <= 2 * self.noise:
            return "within noise"
        return f"off by {100 * diff / abs(self.reference):+.1f} %"

    def row(self) -> str:
        if self.kind == "curve":
            return (f"| {self.name} | {self.generated:.4f} | floor {self.noise:.4f} | "
                    f"{self.verdict()} |")
        rel = 100 * (self.generated / self.reference - 1) if self.reference else float("nan")
        return (f"| {self.name} | {self.generated:.4g} vs {self.reference:.4g} ({rel:+.1f} %) | "
                f"+-{100 * self.noise / abs(self.reference):.1f} % | {self.verdict()} |")


def _curve_mae(a: np.ndarray, b: np.ndarray) -> float:
    return float(np.mean(np.abs(a - b)))


def _mean_figure(name: str, gen: np.ndarray, ref: np.ndarray) -> Figure:
    se = math.sqrt(gen.var(ddof=1) / len(gen) + ref.var(ddof=1) / len(ref))
    return Figure(name, float(gen.mean()), float(ref.mean()), se, "mean")


def compare(gen: np.ndarray, ref: np.ndarray, *, uniform: bool = True,
            same_size: bool = True) -> tuple[list[Figure], dict]:
    """The figures of generated sets against reference sets (and the curves to plot)."""
    from trainer.stats.discrepancy import l2_star
    from trainer.stats.distance import pair_correlation
    half = len(ref) // 2
    f, s_gen = radial_spectrum(gen)
    _, s_ref = radial_spectrum(ref)
    floor = _curve_mae(radial_spectrum(ref[:half])[1], radial_spectrum(ref[half:])[1]) / 2
    r, g_gen = pair_correlation(gen)
    _, g_ref = pair_correlation(ref)
    g_floor = _curve_mae(pair_correlation(ref[:half])[1], pair_correlation(ref[half:])[1]) / 2
    nn_gen, nn_ref = nearest_neighbour_distances(gen), nearest_neighbour_distances(ref)
    figures = [Figure("radial spectrum, mean abs. difference", _curve_mae(s_gen, s_ref),
                      0.0, floor, "curve"),
               Figure("pair correlation, mean abs. difference", _curve_mae(g_gen, g_ref),
                      0.0, g_floor, "curve"),
               _mean_figure("mean nearest-neighbour distance x sqrt(n)", nn_gen.mean(axis=1),
                            nn_ref.mean(axis=1))]
    if same_size:  # the smallest of more distances is smaller: compared at one n only
        figures += [_mean_figure("smallest distance x sqrt(n)", nn_gen.min(axis=1),
                                 nn_ref.min(axis=1)),
                    _mean_figure("star L2 discrepancy", l2_star(gen), l2_star(ref))]
    if not uniform and same_size:
        b = 4
        dev = np.abs(_counts(gen, b).mean(axis=0) - _counts(ref, b).mean(axis=0))
        noise = _counts(ref, b).std(axis=0, ddof=1) / math.sqrt(len(ref))
        worst = int(np.argmax(dev / np.maximum(noise, 1e-9)))
        figures.append(Figure(f"intensity, worst of {b}x{b} cells (points)",
                              float(_counts(gen, b).mean(axis=0)[worst]),
                              float(_counts(ref, b).mean(axis=0)[worst]), float(noise[worst] *
                                                                                 math.sqrt(2)),
                              "mean"))
    curves = {"f": f, "s_gen": s_gen, "s_ref": s_ref, "r": r, "g_gen": g_gen, "g_ref": g_ref,
              "nn_gen": nn_gen.ravel(), "nn_ref": nn_ref.ravel()}
    return figures, curves


def write_report(path_md: Path, path_png: Path, title: str, header: list[str],
                 rows: list[tuple[int, int | None, list[Figure], dict, np.ndarray,
                                  np.ndarray | None]]) -> None:
    """The Markdown report and its figure: one section and one plot row per size
    (n, the example size compared with, the figures, the curves, a generated set, an
    example set)."""
    lines = [f"# {title}", ""] + header + [""]
    for n, ref_n, figures, _, _, _ in rows:
        where = (f"held-out example sets of n = {n}" if ref_n == n else
                 f"no examples of this size: compared with the held-out sets of n = {ref_n} "
                 "in units of sqrt(n)")
        lines += [f"## n = {n}", "", f"Against {where}.", "",
                  "| figure | generated vs held-out | noise | verdict |", "|---|---|---|---|"]
        lines += [fig.row() for fig in figures] + [""]
    lines.append(f"![sets and spectra]({path_png.name})")
    path_md.write_text("\n".join(lines) + "\n")
    _plot(path_png, rows)


def _plot(path: Path, rows) -> None:
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    fig, axes = plt.subplots(len(rows), 4, figsize=(16, 3.8 * len(rows)), squeeze=False)
    for (n, ref_n, _, c, gen_set, ref_set), ax in zip(rows, axes):
        ax[0].scatter(*gen_set.T, s=max(0.5, 300 / n), c="k")
        ax[0].set_title(f"generated, n = {n}")
        if ref_set is not None:
            ax[1].scatter(*ref_set.T, s=max(0.5, 300 / len(ref_set)), c="tab:blue")
        ax[1].set_title(f"example (held out), n = {ref_n}")
        for a in ax[:2]:
            a.set_aspect("equal"), a.set_xlim(0, 1), a.set_ylim(0, 1)
            a.set_xticks([]), a.set_yticks([])
        ax[2].plot(c["f"], c["s_ref"], label=f"held-out (n = {ref_n})")
        ax[2].plot(c["f"], c["s_gen"], label="generated", ls="--")
        ax[2].set_xlabel("frequency / sqrt(n)"), ax[2].set_title("radial spectrum")
        ax[2].legend()
        bins = np.linspace(0, max(c["nn_ref"].max(), c["nn_gen"].max()), 40)
        ax[3].hist(c["nn_ref"], bins, density=True, alpha=0.5, label="held-out")
        ax[3].hist(c["nn_gen"], bins, density=True, histtype="step", color="k",
                   label="generated")
        ax[3].set_xlabel("nearest-neighbour distance x sqrt(n)")
        ax[3].legend()
    fig.tight_layout()
    fig.savefig(path, dpi=60)
    plt.close(fig)
