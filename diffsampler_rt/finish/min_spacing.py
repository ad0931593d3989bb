"""``min_spacing``: pairs closer than c / sqrt(n) pushed apart, every other point kept
(:mod:`diffsampler_rt.spacing`); n is the size of the set returned, on the torus where the
model is toroidal."""
from __future__ import annotations

import numpy as np

from ..spacing import MAX_SPACING, enforce_min_spacing
from .base import Param, Step, describe_value, value


class MinSpacing(Step):
    name = "min_spacing"
    summary = "pairs closer than c / sqrt(n) pushed apart (blue noise's exclusion radius)"
    params = (Param("c", "the radius in units of 1 / sqrt(n), n the points returned",
                    low=0, high=MAX_SPACING, open_low=True, open_high=True, per_size=True),)

    def describe(self, params):
        return f"pairs pushed to at least c / sqrt(n), c = {describe_value(params, 'c')}"

    def apply(self, params, pts, ctx):
        r = value(params, "c", ctx.n) / np.sqrt(ctx.n)
        return enforce_min_spacing(pts, r, torus=ctx.torus)


STEP = MinSpacing()
