"""``sliced_ot``: a few of the SOT sampler's own sliced optimal-transport iterations from the
network's set (:mod:`diffsampler_rt.sliced_ot`)."""
from __future__ import annotations

from ..sliced_ot import MAX_DIRECTIONS, MAX_STEP, polish, thinned_iterations
from .base import Param, Step, describe_value, value


class SlicedOT(Step):
    name = "sliced_ot"
    summary = "sliced optimal-transport iterations towards the uniform square"
    shares_cores = True
    params = (
        Param("directions", "projection directions an iteration", kind="integer", low=1,
              high=MAX_DIRECTIONS),
        Param("iterations", "iterations (per-size values are rounded); a thinned set gets "
              "three times as many", kind="integer", low=0, per_size=True),
        Param("step_size", "each move scaled by this (1: the sampler's update)", low=0,
              high=MAX_STEP, open_low=True, required=False, default=1.0),
    )

    def describe(self, params):
        step = f", each move x {params['step_size']:g}" if params.get("step_size", 1) != 1 else ""
        return (f"{describe_value(params, 'iterations')} sliced-OT iterations of "
                f"{params['directions']} directions{step}")

    def apply(self, params, pts, ctx):
        base = int(round(value(params, "iterations", ctx.n)))
        its = thinned_iterations(base) if ctx.n < ctx.k * ctx.k else base
        if not its:
            return pts
        return polish(pts, its, params["directions"], ctx.rngs,
                      step=params.get("step_size", 1.0))


STEP = SlicedOT()
