"""``projection_gain``: each axis's sorted coordinates spread from evenly spread positions by
a gain (:mod:`diffsampler_rt.projections`); n is the size of the set returned."""
from __future__ import annotations

from ..projections import MAX_GAIN, MIN_GAIN, spread_projections
from .base import Param, Step, describe_value, value


class ProjectionGain(Step):
    name = "projection_gain"
    summary = "the x and y projections made less (gain > 1) or more (< 1) even"
    params = (Param("gain", "factor on each sorted coordinate's deviation from (i + 1/2) / n",
                    low=MIN_GAIN, high=MAX_GAIN, per_size=True),)

    def describe(self, params):
        return f"projections spread, gain {describe_value(params, 'gain')}"

    def apply(self, params, pts, ctx):
        gain = value(params, "gain", ctx.n)
        return pts if gain == 1 else spread_projections(pts, gain)


STEP = ProjectionGain()
