"""``thin``: at an n that is not a square, the k*k set thinned to n points (the most crowded
first, or at random), its large scales then restored from the full set's
(:mod:`diffsampler_rt.elimination`). Sets that already have n points pass unchanged."""
from __future__ import annotations

from ..elimination import thin
from ..low_frequencies import MAX_CUT, RESTORE_CUT
from .base import Param, Step


class Thin(Step):
    name = "thin"
    summary = "k*k points thinned to n, large scales restored from the full set"
    essential = True
    params = (
        Param("drop", "which points go: the most crowded (blue noise) or random ones",
              kind="choice", choices=("crowded", "random"), required=False,
              default="random"),
        Param("restore_cut", "large scales restored below restore_cut sqrt(n)", low=0,
              high=MAX_CUT, open_low=True, required=False, default=RESTORE_CUT),
    )

    def describe(self, params):
        return (f"thinned to n ({params.get('drop', 'random')} points first), large scales "
                f"restored below {params.get('restore_cut', RESTORE_CUT):g} sqrt(n)")

    def plain(self, params):
        return {"drop": params.get("drop", "random")}

    def apply(self, params, pts, ctx):
        if pts.shape[-2] <= ctx.n:
            return pts
        crowded = params.get("drop", "random") == "crowded"
        return thin(pts, ctx.n, torus=ctx.torus, rngs=None if crowded else ctx.rngs,
                    cut=params.get("restore_cut", RESTORE_CUT))


STEP = Thin()
