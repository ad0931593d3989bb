"""Figures of point sets: the points, the 2-d power spectrum and the radial spectrum.

Needs matplotlib (``pip install "diffsampler_rt[plot]"``); everything else is numpy.
"""
from __future__ import annotations

import os
from typing import Any

import numpy as np

from ._validate import unit_points
from .spectrum import BIN_WIDTH, periodogram, radial_spectrum


def _pyplot():
    try:
        import matplotlib
    except ImportError as exc:  # a clear message instead of a bare ModuleNotFoundError
        raise ImportError('plotting needs matplotlib: pip install "diffsampler_rt[plot]"') from exc
    if os.environ.get("MPLBACKEND") is None:
        matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    return plt


def _as_sets(name: str, points: Any) -> np.ndarray:
    """(count, n, 2) float64 sets in the unit square, or a ValueError naming what is wrong
    (the spectra are those of the unit square: NaNs or points outside it make no plot)."""
    pts = unit_points(points, name=name, form="(n, 2) or (count, n, 2)")
    return pts[None] if pts.ndim == 2 else pts


def plot_sets(points: np.ndarray, *, title: str = "", reference: np.ndarray | None = None,
              reference_label: str = "reference", path: str | os.PathLike | None = None) -> Any:
    """Three panels for sets (count, n, 2) or one set (n, 2): the first set's points, the
    mean 2-d periodogram (log scale, |f| up to 2.5 sqrt(n)) and the mean radial spectrum.

    Parameters
    ----------
    points : numpy.ndarray
        One set (n, 2) or several (count, n, 2) in [0, 1)^2; spectra average over sets.
    title : str, optional
        Prefix of the panel titles.
    reference : numpy.ndarray, optional
        Sets of the same n whose radial spectrum is drawn for comparison.
    path : path-like, optional
        Save the figure there (format from the suffix: .png, .pdf, .svg).

    Returns
    -------
    matplotlib.figure.Figure

    Examples
    --------
    >>> import diffsampler_rt
    >>> from diffsampler_rt.plot import plot_sets
    >>> fig = plot_sets(diffsampler_rt.generate("rank1", 256, count=2, seed=0))
    >>> len(fig.axes)
    4
    """
    pts = _as_sets("points", points)
    if reference is not None:
        reference = _as_sets("reference", reference)
    plt = _pyplot()
    n = pts.shape[1]
    fig, ax = plt.subplots(1, 3, figsize=(13, 4.2))
    ax[0].scatter(pts[0, :, 0], pts[0, :, 1], s=max(0.3, min(8.0, 3000 / n)), c="k", lw=0)
    ax[0].set(xlim=(0, 1), ylim=(0, 1), aspect="equal", xticks=[], yticks=[],
              title=f"{title} points (n = {n})".strip())
    fmax = max(4, int(2.5 * np.sqrt(n)))
    P = periodogram(pts, fmax)
    P[fmax, fmax] = np.nan  # the DC term (= n) would swamp the scale
    im = ax[1].imshow(np.log10(np.maximum(P, 1e-3)), origin="lower", cmap="magma",
                      extent=[-fmax - 0.5, fmax + 0.5, -fmax - 0.5, fmax + 0.5], vmin=-2, vmax=1)
    fig.colorbar(im, ax=ax[1], fraction=0.046, label="log10 power")
    ax[1].set(title=f"{title} power spectrum ({len(pts)} sets)".strip(), xticks=[], yticks=[])
    x, s = radial_spectrum(pts)
    if reference is not None:
        ax[2].plot(x, radial_spectrum(reference)[1], lw=1.5, color="0.5", label=reference_label)
    ax[2].plot(x, s, lw=1.2, color="C1", label=title or "points")
    ax[2].axhline(1.0, color="k", lw=0.5, ls=":")
    ax[2].set(title="radial spectrum", xlabel="|f| / sqrt(n)", ylabel="power",
              xlim=(0, x[-1] + BIN_WIDTH))
    ax[2].legend(fontsize=8)
    fig.tight_layout()
    if path is not None:
        fig.savefig(path, dpi=100)
    return fig
