"""``coarse_noise``: a gain on the coarse Fourier modes of the solver's starting noise, and a
temperature on the others (:mod:`diffsampler_rt.coarse_noise` has the maths and why)."""
from __future__ import annotations

from ..coarse_noise import MAX_GAIN, TEMPERATURE_RANGE, shape_noise
from .base import Param, Step, describe_value, value


class CoarseNoise(Step):
    name = "coarse_noise"
    phase = "noise"
    summary = ("scale the starting noise's modes up to cut x Nyquist by gain (the sets' "
               "large-scale variation), every other mode by temperature")
    params = (
        Param("gain", "factor on the coarse modes (> 1: more large-scale variation)",
              low=0, high=MAX_GAIN, open_low=True, per_size=True, required=False),
        Param("cut", "the coarse modes: up to cut x the grid's Nyquist frequency",
              low=0, high=1, open_low=True, per_size=True, required=False, default=1.0),
        Param("temperature", "factor on every other mode, the mean included",
              low=TEMPERATURE_RANGE[0], high=TEMPERATURE_RANGE[1], open_low=True,
              required=False, default=1.0),
    )

    def describe(self, params):
        parts = []
        if "gain" in params:
            parts.append(f"gain {describe_value(params, 'gain')} up to "
                         f"{describe_value({'cut': params.get('cut', 1.0)}, 'cut')} x Nyquist")
        if params.get("temperature", 1.0) != 1:
            parts.append(f"other modes x {params['temperature']:g}")
        return "starting noise: " + ("; ".join(parts) or "unchanged")

    def shape(self, params, x, ctx):
        size = ctx.k * ctx.k  # the grid's noise, whatever n is kept
        hot = params.get("temperature", 1.0)
        if "gain" in params:
            return shape_noise(x, value(params, "gain", size),
                               value(params, "cut", size, 1.0), hot)
        return x if hot == 1 else shape_noise(x, hot, 1.0, hot)


STEP = CoarseNoise()
