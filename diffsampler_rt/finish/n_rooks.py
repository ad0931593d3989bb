"""``n_rooks``: both 1-d projections of each set stratified (one point per row and column of
the k^2 sub-strips) without moving a point out of its cell, as LDBN's sets are
(:mod:`diffsampler_rt.structure`). A structure step: holds at power-of-two sides, and with
``runs`` at other sides that hold a full run."""
from __future__ import annotations

from ..structure import block_problem, describe_block, impose
from .base import SIDE_PARAMS, Param, Step, describe_sides, power_of_two, side_listed


def _block_problem(block) -> str | None:
    problem = block_problem(block)
    return problem.replace("'structure_block'", "'block'") if problem else None


class NRooks(Step):
    name = "n_rooks"
    summary = "both projections of each set stratified, points kept in their cells"
    structure = True
    params = (*SIDE_PARAMS,
              Param("block", "aligned halves of every column and row, down to this many "
                    "cells, stratified at their own widths too (one B, or per side)",
                    kind="custom", check=_block_problem, required=False,
                    form="a power of two, or {\"sides\": [K, ...], \"block\": [B, ...]}"),
              Param("runs", "at sides that are not powers of two: every run of this many "
                    "cells of a column and row stratified", kind="integer", low=2,
                    required=False))

    def describe(self, params):
        extra = f", {describe_block(params['block'])}" if "block" in params else ""
        runs = f", runs of {params['runs']} at other sides" if "runs" in params else ""
        return f"n-rooks projections imposed{describe_sides(params)}{extra}{runs}"

    def _runs(self, params, k):
        run = params.get("runs")
        return run if run and not power_of_two(k) and k >= run else None

    def _block(self, params, k):
        if (run := self._runs(params, k)) is not None:
            return run
        block = params.get("block")
        return dict(zip(block["sides"], block["block"])).get(k) if isinstance(block, dict) \
            else block

    def holds(self, params, n, k):
        exists = power_of_two(k) or self._runs(params, k) is not None
        return exists and side_listed(params, k)

    def project(self, params, pts, k):
        return impose(pts, k, "n_rooks", block=self._block(params, k))

    def apply(self, params, pts, ctx):
        if not self.holds(params, ctx.n, ctx.k):
            return pts
        return impose(pts, ctx.k, "n_rooks", ctx.rngs, self._block(params, ctx.k))


STEP = NRooks()
