"""``structure_guidance``: the pipeline's structure imposed on the clean-set prediction of
the solver's last steps, so that the network arranges its sets around it
(:func:`diffsampler_rt.solvers.project_x0`). Acts only where the structure holds."""
from __future__ import annotations

from ..grid import decode, encode_stratified
from ..solvers import project_x0
from .base import Param, Step, describe_value, value


class StructureGuidance(Step):
    name = "structure_guidance"
    phase = "denoiser"
    summary = "the structure imposed on the predicted clean set of the last steps solver steps"
    params = (Param("steps", "how many of the last solver steps (per-size values are "
                    "rounded; 0: none at that size)", kind="integer", low=0, per_size=True),)
    needs_structure = True

    def describe(self, params):
        return (f"the structure imposed on the predicted clean set of the last "
                f"{describe_value(params, 'steps')} solver steps")

    @staticmethod
    def steps_at(params, k: int) -> int:
        """The guided steps on a k x k grid."""
        return int(round(value(params, "steps", k * k)))

    def wrap(self, params, eps, ctx):
        steps = self.steps_at(params, ctx.k)
        # a lattice has no projection to guide by
        if not steps or not ctx.structured or ctx.project is None:
            return eps
        k, scale = ctx.k, float(ctx.model.card["offset_scale"])

        def project(x0):
            return encode_stratified(ctx.project(decode(x0 / scale, stratified=True)), k) * scale

        ts = ctx.timesteps
        return project_x0(eps, ctx.model.alpha_bar, project,
                          ts[max(0, len(ts) - steps):])


STEP = StructureGuidance()
