"""``structure_guidance``: the pipeline's structure imposed on the clean-set prediction of
the solver's last steps, so that the network arranges its sets around it
(:func:`diffsampler_rt.solvers.project_x0`). Acts only where the structure holds."""
from __future__ import annotations

from ..grid import decode, encode_stratified
from ..solvers import project_x0
from .base import Param, Step


class StructureGuidance(Step):
    name = "structure_guidance"
    phase = "denoiser"
    summary = "the structure imposed on the predicted clean set of the last steps solver steps"
    params = (Param("steps", "how many of the last solver steps", kind="integer", low=1),)
    needs_structure = True

    def describe(self, params):
        return (f"the structure imposed on the predicted clean set of the last "
                f"{params['steps']} solver steps")

    def wrap(self, params, eps, ctx):
        if not ctx.structured or ctx.project is None:  # a lattice has no projection to guide by
            return eps
        k, scale = ctx.k, float(ctx.model.card["offset_scale"])

        def project(x0):
            return encode_stratified(ctx.project(decode(x0 / scale, stratified=True)), k) * scale

        ts = ctx.timesteps
        return project_x0(eps, ctx.model.alpha_bar, project,
                          ts[max(0, len(ts) - params["steps"]):])


STEP = StructureGuidance()
