"""``guide``: autoguidance, every solver step steered away from a weaker model of the same
sampler (:mod:`diffsampler_rt.guidance`)."""
from __future__ import annotations

from ..guidance import DIGESTS, MAX_WEIGHT, guided
from .base import Param, Step, describe_value, value


def _name_problem(name) -> str | None:
    if isinstance(name, str) and name and "/" not in name and "\\" not in name:
        return None
    return f"'model' must be a model name (no directories), got {name!r}"


def _digest_problem(digest) -> str | None:
    if isinstance(digest, str) and len(digest) == 64 and all(c in "0123456789abcdef"
                                                             for c in digest):
        return None
    return f"a guide digest must be 64 lower-case hex digits, got {digest!r}"


class Guide(Step):
    name = "guide"
    phase = "denoiser"
    summary = ("autoguidance: eps = (1 + weight) eps_model - weight eps_guide, the guide a "
               "weaker model of the same sampler (two network evaluations a step)")
    shares_cores = True
    params = (
        Param("model", "the guide: NAME.onnx next to the model, or a bundled model or guide",
              kind="custom", check=_name_problem, form="a model name"),
        Param("weight", "guidance weight", low=0, high=MAX_WEIGHT, per_size=True),
        *(Param(key, f"the guide's {key}, checked on loading", kind="custom",
                check=_digest_problem, required=False, form="64 hex digits")
          for key in DIGESTS),
    )

    def describe(self, params):
        return f"guided by {params['model']}, weight {describe_value(params, 'weight')}"

    def wrap(self, params, eps, ctx):
        weight = value(params, "weight", ctx.k * ctx.k)
        if not weight:
            return eps
        return guided(eps, ctx.model.guide(params).denoise, weight)


STEP = Guide()
