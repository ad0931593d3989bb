"""Finishing steps: what runs around and after the network, declared in the model card's
``"pipeline"`` and run in the listed order (:mod:`.pipeline`).

Each step is one module exposing ``STEP``, an instance of :class:`.base.Step`; the registry
:data:`STEPS` maps names to them. To add a step, write its module and list it here.
"""
from __future__ import annotations

from . import (coarse_noise, dyadic_net, even_out, guide, min_spacing, n_rooks,
               projection_gain, rank1_lattice, sliced_ot, structure_guidance, thin)
from .base import PHASES, Context, Param, Step

#: every step the runtime knows, by the name a card's entry gives in ``"step"``
STEPS: dict[str, Step] = {m.STEP.name: m.STEP for m in (
    coarse_noise, guide, structure_guidance, dyadic_net, n_rooks, rank1_lattice, thin,
    sliced_ot, even_out, projection_gain, min_spacing)}

__all__ = ["STEPS", "PHASES", "Context", "Param", "Step"]
