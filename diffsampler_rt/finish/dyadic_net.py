"""``dyadic_net``: every set of 2^m points made a (0, m, 2)-net without moving a point out of
its grid cell (:mod:`diffsampler_rt.structure`); with ``prefix``, a set of n points, n not
a power of four, is the first n points in Sobol' order of a net of the next power-of-four
size (:mod:`diffsampler_rt.sobol_orbit`). A structure step: holds at power-of-two sides."""
from __future__ import annotations

from ..sobol_orbit import first_points, orbit
from ..structure import impose
from .base import SIDE_PARAMS, Param, Step, describe_sides, power_of_two, side_listed


class DyadicNet(Step):
    name = "dyadic_net"
    summary = "each set made a (0, m, 2)-net (Sobol'-like), points kept in their cells"
    structure = True
    params = (*SIDE_PARAMS,
              Param("prefix", "n not a power of four: the first n points, in Sobol' order, "
                    "of a net of the next power-of-four size", kind="bool", required=False,
                    default=False))

    def describe(self, params):
        prefix = "; other n: the first n points of the next net" if params.get("prefix") else ""
        return f"(0, m, 2)-net imposed{describe_sides(params)}{prefix}"

    def _holds_at(self, params, k):
        return power_of_two(k) and side_listed(params, k)

    def side(self, params, n, k):
        if not params.get("prefix"):
            return k
        side = 1 << (k - 1).bit_length()
        return side if side * side != n and self._holds_at(params, side) else k

    def holds(self, params, n, k):
        return self._holds_at(params, k)

    def project(self, params, pts, k):
        return impose(pts, k, "dyadic_net")

    def apply(self, params, pts, ctx):
        if not self._holds_at(params, ctx.k):
            return pts
        if params.get("prefix") and ctx.n < pts.shape[-2]:
            return first_points(*orbit(pts, ctx.k, ctx.rngs), ctx.n)
        return impose(pts, ctx.k, "dyadic_net")


STEP = DyadicNet()
