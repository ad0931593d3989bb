"""``rank1_lattice``: each set replaced by the rank-1 lattice it is closest to, under a
uniformly random shift (:mod:`diffsampler_rt.lattice`); at an n that is not a square, the
set is first thinned to n points by elimination. A structure step: holds at the listed
sides, and wherever n is not a square."""
from __future__ import annotations

from ..elimination import eliminate
from ..lattice import nearest_rank1_lattice
from .base import SIDE_PARAMS, Step, describe_sides, side_listed


class Rank1Lattice(Step):
    name = "rank1_lattice"
    summary = "each set replaced by its nearest rank-1 lattice, randomly shifted"
    structure = True
    params = SIDE_PARAMS

    def describe(self, params):
        return (f"nearest rank-1 lattice{describe_sides(params)}, and of n points where n is "
                "not a square")

    def holds(self, params, n, k):
        return n < k * k or side_listed(params, k)

    def apply(self, params, pts, ctx):
        if ctx.n < pts.shape[-2]:
            return nearest_rank1_lattice(eliminate(pts, ctx.n, torus=ctx.torus), ctx.rngs)
        if side_listed(params, ctx.k):
            return nearest_rank1_lattice(pts, ctx.rngs)
        return pts


STEP = Rank1Lattice()
