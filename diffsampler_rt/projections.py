"""How evenly a set's points spread along each axis: its x and y projections.

A sampler's 1-d projections are part of what the star discrepancy (L2*) measures. The grid
embedding leaves a net's rows and columns in its sets' projections: at small grids they come
out more even than the sampler's, which lowers their star discrepancy below the sampler's.
:func:`spread_projections` scales, for each
axis, the deviations of the set's sorted coordinates from the evenly spread positions
(i + 1/2) / n by a gain: above 1 the projections get as uneven as the sampler's, below 1
more even. Each point moves along the axes only, by (gain - 1) times its own deviation
(a small fraction of a point spacing for gains near 1), so the 2-d pattern and its spectrum
change little. Coordinates are taken in the unit square (a toroidal model's set as
returned).

A model card's pipeline asks for it with the step ``{"step": "projection_gain", "gain": G}``
(:mod:`diffsampler_rt.finish.projection_gain`; G a number or a per-size table, linear in
log n between the sizes, the end values beyond), where the card lists it: sot_32_fast's
after the evening-out and before the minimum spacing. A structure fixes the projections
itself, so a card with one marks this step ``"where": "unstructured"``.
"""
from __future__ import annotations

from typing import Any

import numpy as np

from . import per_size
from ._validate import unit_points
from .grid import reflect

#: gains a card may ask for: beyond these the move is no longer small against the spacing
MIN_GAIN, MAX_GAIN = 0.5, 1.5
_BELOW_ONE = np.nextafter(1.0, 0.0)


def spread_projections(points: np.ndarray, gain: float) -> np.ndarray:
    """Scale each axis's deviations from evenly spread positions by ``gain``.

    For every set and axis, with x_(0) <= ... <= x_(n-1) its sorted coordinates, x_(i)
    becomes (i + 1/2) / n + gain (x_(i) - (i + 1/2) / n), reflected into [0, 1) at the edges. ``gain`` = 1
    returns the points unchanged.

    Parameters
    ----------
    points : numpy.ndarray
        (n, 2) or (sets, n, 2) points in [0, 1]^2.
    gain : float
        Factor on the deviations, in [0.5, 1.5]: > 1 spreads the projections less evenly.

    Returns
    -------
    numpy.ndarray
        float64 array of the input's shape, in [0, 1)^2.

    Examples
    --------
    >>> import numpy as np
    >>> from diffsampler_rt.projections import spread_projections
    >>> pts = np.array([[0.1, 0.7], [0.6, 0.2]])
    >>> spread_projections(pts, 1.2)  # sorted x 0.1, 0.6: 0.25 / 0.75 - 1.2 * 0.15
    array([[0.07, 0.69],
           [0.57, 0.19]])
    """
    pts = unit_points(points)
    if isinstance(gain, bool) or not per_size.finite_number(gain) or not (
            MIN_GAIN <= gain <= MAX_GAIN):
        raise ValueError(f"gain must be a number in [{MIN_GAIN}, {MAX_GAIN}], got {gain!r}")
    if gain == 1:
        return pts.copy()
    n = pts.shape[-2]
    even = ((np.arange(n) + 0.5) / n)[:, None]
    order = np.argsort(pts, axis=-2, kind="stable")
    sorted_pts = np.take_along_axis(pts, order, axis=-2)
    moved = reflect(even + gain * (sorted_pts - even))
    out = np.empty_like(pts)
    np.put_along_axis(out, order, moved, axis=-2)
    return out


def gain_at(spec: float | dict, n: int) -> float:
    """The gain at n points of a card's ``"projection_gain"`` (a number or a table)."""
    return per_size.value_at(spec, "gain", n)


def describe(spec: float | dict | None) -> str:
    """The card value in words: "none", "gain 1.1" or "gain 1 / 1.1 / 1 at n = 64 / 256 /
    576 (log-linear)"."""
    if spec is None:
        return "none"
    if isinstance(spec, dict):
        return per_size.describe_gain(spec)
    return f"gain {spec:g}"


def _gain_ok(g: Any) -> bool:
    return per_size.finite_number(g) and MIN_GAIN <= g <= MAX_GAIN


def settings_problem(spec: Any) -> str | None:
    """Why a card's ``"projection_gain"`` is invalid, or None."""
    form = (f"'projection_gain' must be a number in [{MIN_GAIN}, {MAX_GAIN}] or "
            "{\"n\": [sizes], \"gain\": [G per size]}")
    if isinstance(spec, dict):
        if set(spec) != {"n", "gain"}:
            return f"{form}, got {spec!r}"
        sizes, gains = spec["n"], spec["gain"]
        if not (per_size.sizes_ok(sizes) and isinstance(gains, list)
                and len(gains) == len(sizes)):
            return ("'projection_gain' n and gain must be lists of the same length, n "
                    f"strictly increasing sizes >= 1; got {sizes!r}, {gains!r}")
        if not all(_gain_ok(g) for g in gains):
            return f"'projection_gain' gains must be in [{MIN_GAIN}, {MAX_GAIN}], got {gains!r}"
        return None
    return None if _gain_ok(spec) else f"{form}, got {spec!r}"
