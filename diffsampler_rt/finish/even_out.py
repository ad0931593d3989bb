"""``even_out``: each set's density deviations below cut sqrt(m) shrunk by 1 - gain (gain < 0
amplifies them) by a smooth move, m the size of the set it gets
(:mod:`diffsampler_rt.low_frequencies`)."""
from __future__ import annotations

from ..low_frequencies import MAX_CUT, MAX_GAIN, even_out
from .base import Param, Step, describe_value, value


class EvenOut(Step):
    name = "even_out"
    summary = "large-scale density deviations shrunk (gain > 0) or amplified (gain < 0)"
    params = (
        Param("gain", "deviations below the cut shrink by 1 - gain", low=-MAX_GAIN,
              high=MAX_GAIN, per_size=True),
        Param("cut", "the large scales: frequencies below cut sqrt(m)", low=0, high=MAX_CUT,
              open_low=True, per_size=True),
    )

    def describe(self, params):
        return (f"large scales evened, gain {describe_value(params, 'gain')} below "
                f"{describe_value(params, 'cut')} sqrt(n)")

    def apply(self, params, pts, ctx):
        m = pts.shape[-2]
        return even_out(pts, value(params, "gain", m), cut=value(params, "cut", m),
                        torus=ctx.torus)


STEP = EvenOut()
