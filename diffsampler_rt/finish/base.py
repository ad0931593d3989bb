"""The finishing-step contract: what every step module declares and how its parameters are
checked, described and read.

A model card's ``"pipeline"`` is an ordered list of entries ``{"step": NAME, PARAM: VALUE,
...}``; :mod:`diffsampler_rt.finish.pipeline` runs them in that order. Each step acts in
one phase:

``"noise"``
    on the solver's starting noise, (sets, 2, k, k);
``"denoiser"``
    on the denoiser the solver calls, ``eps(x, t)`` (guidance);
``"points"``
    on the decoded points, (sets, m, 2) in [0, 1)^2, before the model's density map.

A step is a :class:`Step` subclass instance in its own module, registered in
:data:`diffsampler_rt.finish.STEPS`. Its parameters are declared as :class:`Param` so that
validation, descriptions and the ``python -m export pipeline`` flags come from one place.
A parameter declared ``per_size`` may be a number or a per-size table ``{"n": [sizes],
"values": [...]}`` (:func:`diffsampler_rt.per_size.value`).

Any entry may also say ``"where": "structured"`` or ``"unstructured"``: it then runs only at
the sizes where the pipeline's structure step holds (or does not), e.g. a spacing that must
come before an imposed structure there and after thinning elsewhere.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Callable, Mapping

import numpy as np

from .. import per_size

PHASES = ("noise", "denoiser", "points")
WHERE = ("structured", "unstructured")


@dataclass(frozen=True)
class Param:
    """A step parameter: its name, a one-line help text, and what it accepts.

    ``kind`` is "number", "integer", "bool", "choice", "text" or "custom" (``check`` returns
    why a value is wrong, or None); numbers and integers lie in [``low``, ``high``], an end
    excluded where ``open_low`` / ``open_high``; ``per_size`` numbers may be per-size tables.
    """
    name: str
    help: str
    kind: str = "number"
    low: float | None = None
    high: float | None = None
    open_low: bool = False
    open_high: bool = False
    per_size: bool = False
    required: bool = True
    default: Any = None
    choices: tuple = ()
    check: Callable[[Any], str | None] | None = None
    form: str = ""

    def accepts(self) -> str:
        """What the parameter accepts, in words (for messages and help)."""
        if self.kind in ("number", "integer"):
            lo = "(" if self.open_low else "["
            hi = ")" if self.open_high else "]"
            what = "a number" if self.kind == "number" else "an integer"
            text = (f"{what} in {lo}{_num(self.low, '-inf')}, {_num(self.high, 'inf')}{hi}"
                    if self.low is not None or self.high is not None else what)
            return text + (" or a per-size table {\"n\": [sizes], \"values\": [...]}"
                           if self.per_size else "")
        if self.kind == "bool":
            return "true or false"
        if self.kind == "choice":
            return "one of " + ", ".join(map(repr, self.choices))
        if self.kind == "text":
            return self.form or "a text"
        return self.form

    def problem(self, value: Any) -> str | None:
        """Why ``value`` is not acceptable, or None."""
        if self.kind in ("number", "integer") and self.per_size and isinstance(value, dict):
            if (set(value) != {"n", "values"} or not per_size.sizes_ok(value["n"])
                    or not isinstance(value["values"], list)
                    or len(value["values"]) != len(value["n"])):
                return (f"{self.name!r} table must be {{\"n\": [increasing sizes], "
                        f"\"values\": [one per size]}}, got {value!r}")
            bad = [v for v in value["values"] if not self._scalar_ok(v)]
            return f"{self.name!r} values must each be {self._scalar()}, got {bad[0]!r}" \
                if bad else None
        if self.kind in ("number", "integer"):
            return None if self._scalar_ok(value) else \
                f"{self.name!r} must be {self.accepts()}, got {value!r}"
        if self.kind == "bool":
            return None if isinstance(value, bool) else \
                f"{self.name!r} must be true or false, got {value!r}"
        if self.kind == "choice":
            return None if value in self.choices else \
                f"{self.name!r} must be {self.accepts()}, got {value!r}"
        if self.kind == "text" and not isinstance(value, str):
            return f"{self.name!r} must be {self.accepts()}, got {value!r}"
        return self.check(value) if self.check else None

    def _scalar(self) -> str:
        return self.accepts().split(" or a per-size")[0]

    def _scalar_ok(self, v: Any) -> bool:
        if not per_size.finite_number(v):
            return False
        if self.kind == "integer" and not isinstance(v, int):
            return False
        if self.low is not None and (v < self.low or (self.open_low and v == self.low)):
            return False
        return not (self.high is not None
                    and (v > self.high or (self.open_high and v == self.high)))


def _num(v: float | None, missing: str) -> str:
    return missing if v is None else f"{v:g}"


@dataclass(frozen=True)
class Context:
    """What a step may read besides its parameters and its input.

    n: points the caller asked for; k: side of the grid the network ran at (k*k >= n);
    torus: whether the model makes sets on the torus; structured: whether the pipeline's
    structure step holds at this size; rngs: one generator per set (point steps draw their
    randomness from these only, so a set does not depend on its batch); model: the
    :class:`diffsampler_rt.Model` (denoiser steps: its guide, schedule and offset scale);
    project: the structure's deterministic imposition on k*k stratified points (None
    without a structure step), for steps that steer the solver towards it.
    """
    n: int
    k: int
    torus: bool = False
    structured: bool = False
    rngs: list = field(default_factory=list)
    model: Any = None
    timesteps: np.ndarray | None = None
    project: Callable[[np.ndarray], np.ndarray] | None = None


class Step:
    """One finishing step. Subclasses set the class attributes and override the hook of
    their phase (and :meth:`problem` for checks that span parameters)."""
    #: registry name, the entry's ``"step"``
    name: str = ""
    #: "noise", "denoiser" or "points"
    phase: str = "points"
    #: one line: what the step does (``diffsampler info``, docs, CLI help)
    summary: str = ""
    params: tuple[Param, ...] = ()
    #: a structure step: declares where it holds (:meth:`holds`) and may pick the grid side
    structure: bool = False
    #: still run (as :meth:`plain` says) when the caller asks for the network's own sets
    #: (``structure=False``): only thinning, which every non-square n needs
    essential: bool = False
    #: acts only through the pipeline's structure step (which must exist and project)
    needs_structure: bool = False
    #: runs work of its own between the network's runs on the same cores (a polish, a
    #: guide's network): the model's onnxruntime session must not spin then
    shares_cores: bool = False

    # --- parameters
    def problem(self, params: Mapping[str, Any]) -> str | None:
        """Checks that span several parameters (each one is checked by its Param)."""
        return None

    def describe(self, params: Mapping[str, Any]) -> str:
        """The entry in one line of words."""
        return self.summary

    def plain(self, params: Mapping[str, Any]) -> dict | None:
        """The parameters an essential step runs with under ``structure=False``."""
        return None

    # --- structure steps
    def side(self, params: Mapping[str, Any], n: int, k: int) -> int:
        """The grid side to run the network at for n points (default k, ceil sqrt n)."""
        return k

    def holds(self, params: Mapping[str, Any], n: int, k: int) -> bool:
        """Whether this structure acts on sets of n points made at side k."""
        return False

    def project(self, params: Mapping[str, Any], pts: np.ndarray, k: int) -> np.ndarray:
        """The structure imposed on k*k stratified points, without random parts."""
        raise NotImplementedError(f"{self.name} has no projection")

    # --- the three phases
    def shape(self, params: Mapping[str, Any], x: np.ndarray, ctx: Context) -> np.ndarray:
        """Noise phase: the solver's starting noise (sets, 2, k, k) -> the same shape."""
        raise NotImplementedError

    def wrap(self, params: Mapping[str, Any], eps: Callable, ctx: Context) -> Callable:
        """Denoiser phase: a denoiser ``eps(x, t)`` -> another."""
        raise NotImplementedError

    def apply(self, params: Mapping[str, Any], pts: np.ndarray, ctx: Context) -> np.ndarray:
        """Points phase: (sets, m, 2) in [0, 1)^2 -> (sets, m', 2) in [0, 1)^2, m' >= n."""
        raise NotImplementedError


def value(params: Mapping[str, Any], name: str, n: int, default: float | None = None) -> float:
    """A numeric parameter at n points (a number, or a per-size table read log-linearly)."""
    spec = params.get(name, default)
    return per_size.value(spec, n)


def describe_value(params: Mapping[str, Any], name: str, fmt: str = "{:g}") -> str:
    """A numeric parameter in words: "0.6" or "0.5 / 0.6 at n = 64 / 1024 (log-linear)"."""
    spec = params[name]
    if isinstance(spec, dict):
        return per_size.describe(spec["n"], [fmt.format(v) for v in spec["values"]]) + \
            " (log-linear)"
    return fmt.format(spec)


def _sides_problem(sides: Any) -> str | None:
    if per_size.sizes_ok(sides):
        return None
    return f"'sides' must be a list of increasing grid sides >= 1, got {sides!r}"


#: the parameters every structure step shares: where on the grid sides it is imposed
SIDE_PARAMS = (
    Param("min_side", "imposed from this grid side up", kind="integer", low=1,
          required=False, default=1),
    Param("sides", "imposed only at these grid sides", kind="custom", check=_sides_problem,
          required=False, form="a list of grid sides"),
)


def side_listed(params: Mapping[str, Any], k: int) -> bool:
    """Whether grid side k passes a structure's ``min_side`` and ``sides``."""
    return k >= params.get("min_side", 1) and k in params.get("sides", [k])


def describe_sides(params: Mapping[str, Any]) -> str:
    """" at k >= 16", " at k in [8, 16, 32]" or ""."""
    text = f" at k >= {params['min_side']}" if params.get("min_side", 1) > 1 else ""
    return text + (f" at k in {params['sides']}" if "sides" in params else "")


def power_of_two(k: int) -> bool:
    return k & (k - 1) == 0
