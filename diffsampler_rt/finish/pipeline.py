"""A card's pipeline: checked once when the model loads, then planned for each size and run.

The runtime's generation path is: starting noise -> noise steps -> solver (the denoiser
wrapped by the denoiser steps) -> decode -> point steps -> the model's density map. Steps
run in the order the card lists them; nothing here reorders them. Two things depend on the
size: which grid side the network runs at (a structure step may pick a larger one) and
whether the structure holds there (for entries that say ``"where"``).
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Callable, Mapping, Sequence

import numpy as np

from . import STEPS
from .base import PHASES, WHERE, Context, Step

Entry = Mapping[str, Any]


def entry_problem(entry: Any) -> str | None:
    """Why one pipeline entry is invalid (naming the step and field), or None."""
    if not isinstance(entry, dict) or not isinstance(entry.get("step"), str):
        return f"each pipeline entry must be {{\"step\": NAME, ...}}, got {entry!r}"
    name = entry["step"]
    step = STEPS.get(name)
    if step is None:
        return f"unknown step {name!r}; this runtime knows {', '.join(STEPS)}"
    where = entry.get("where")
    if where is not None and where not in WHERE:
        return f"step {name!r}: 'where' must be one of {list(WHERE)}, got {where!r}"
    declared = {p.name: p for p in step.params}
    extra = set(entry) - set(declared) - {"step", "where"}
    if extra:
        return (f"step {name!r} has no parameter {sorted(extra)[0]!r}; it takes "
                f"{', '.join(declared) or 'none'}")
    for p in step.params:
        if p.name not in entry:
            if p.required:
                return f"step {name!r} needs {p.name!r} ({p.accepts()})"
            continue
        if problem := p.problem(entry[p.name]):
            return f"step {name!r}: {problem}"
    problem = step.problem(params_of(entry))
    return f"step {name!r}: {problem}" if problem else None


def pipeline_problem(pipeline: Any) -> str | None:
    """Why a card's ``"pipeline"`` is invalid, or None: every entry valid, at most one
    structure step, and the steps that need one ("where", structure guidance) have it."""
    if not isinstance(pipeline, list):
        return f"'pipeline' must be a list of steps, got {pipeline!r}"
    for i, entry in enumerate(pipeline):
        if problem := entry_problem(entry):
            return f"pipeline entry {i}: {problem}"
    if not any(STEPS[e["step"]].essential for e in pipeline):
        return ("a pipeline needs a 'thin' step: an n that is not a square makes the next "
                "square's set, thinned to n points")
    structures = [e["step"] for e in pipeline if STEPS[e["step"]].structure]
    if len(structures) > 1:
        return f"a pipeline holds at most one structure step, got {structures}"
    for i, e in enumerate(pipeline):
        steers = STEPS[e["step"]].needs_structure
        if ("where" in e or steers) and not structures:
            return f"pipeline entry {i} ({e['step']!r}) needs a structure step in the pipeline"
        if steers:
            step = STEPS[structures[0]]
            if type(step).project is Step.project:
                return (f"pipeline entry {i} ({e['step']!r}) cannot steer towards "
                        f"{structures[0]!r}")
    return None


def params_of(entry: Entry) -> dict[str, Any]:
    """An entry's parameters (without ``step`` and ``where``)."""
    return {k: v for k, v in entry.items() if k not in ("step", "where")}


def describe(pipeline: Sequence[Entry]) -> list[str]:
    """One line per entry: "name: what it does [where ...]"."""
    lines = []
    for e in pipeline:
        where = f" (only where the structure {'holds' if e['where'] == 'structured' else 'does not hold'})" \
            if "where" in e else ""
        lines.append(f"{e['step']}: {STEPS[e['step']].describe(params_of(e))}{where}")
    return lines


def shares_cores(pipeline: Sequence[Entry]) -> bool:
    """Whether any step runs work of its own between the network's runs on the same cores
    (a sliced-OT polish, a guide's network): the model's session must not spin then."""
    return any(STEPS[e["step"]].shares_cores for e in pipeline)


@dataclass(frozen=True)
class Plan:
    """The pipeline resolved for one size: the grid side, whether the structure holds, and
    the entries that run there, in the card's order, grouped by phase."""
    k: int
    structured: bool
    steps: dict[str, list[tuple[Step, dict]]]
    project: Callable[[np.ndarray], np.ndarray] | None

    def context(self, n: int, **kwargs: Any) -> Context:
        return Context(n=n, k=self.k, structured=self.structured, project=self.project,
                       **kwargs)

    def shape_noise(self, x: np.ndarray, ctx: Context) -> np.ndarray:
        for step, params in self.steps["noise"]:
            x = step.shape(params, x, ctx)
        return x

    def denoiser(self, eps: Callable, ctx: Context) -> Callable:
        for step, params in self.steps["denoiser"]:
            eps = step.wrap(params, eps, ctx)
        return eps

    def finish(self, pts: np.ndarray, ctx: Context) -> np.ndarray:
        for step, params in self.steps["points"]:
            pts = step.apply(params, pts, ctx)
        return pts


def plan(pipeline: Sequence[Entry], n: int, *, structure: bool = True) -> Plan:
    """The pipeline at n points. ``structure=False`` keeps only the essential steps
    (thinning, with its plain parameters), so the network's own sets come out."""
    k = int(np.ceil(np.sqrt(n)))
    if not structure:
        kept = [(STEPS[e["step"]], STEPS[e["step"]].plain(params_of(e))) for e in pipeline
                if STEPS[e["step"]].essential]
        return Plan(k, False, _by_phase([(s, p) for s, p in kept if p is not None]), None)
    main = [(STEPS[e["step"]], params_of(e)) for e in pipeline if STEPS[e["step"]].structure]
    for step, params in main:
        k = step.side(params, n, k)
    structured = any(step.holds(params, n, k) for step, params in main)
    project = None
    if main and structured and type(main[0][0]).project is not Step.project:
        step, params = main[0]
        project = lambda pts, step=step, params=params, k=k: step.project(params, pts, k)  # noqa: E731
    wanted = "structured" if structured else "unstructured"
    active = [(STEPS[e["step"]], params_of(e)) for e in pipeline
              if e.get("where", wanted) == wanted]
    return Plan(k, structured, _by_phase(active), project)


def _by_phase(active: list[tuple[Step, dict]]) -> dict[str, list[tuple[Step, dict]]]:
    return {phase: [(s, p) for s, p in active if s.phase == phase] for phase in PHASES}


def find(pipeline: Sequence[Entry], name: str) -> dict[str, Any] | None:
    """The parameters of the first entry of step ``name``, or None (readers such as the
    distiller and the reports; the runtime itself never looks a step up by name)."""
    return next((params_of(e) for e in pipeline if e["step"] == name), None)


def markdown_table() -> str:
    """The step registry as a Markdown table (docs/runtime.md carries it; a test checks it
    against the registry)."""
    rows = ["| step | phase | what it does | parameters |", "|---|---|---|---|"]
    for step in STEPS.values():
        params = "<br>".join(f"`{p.name}`{'' if p.required else ' (optional)'}: {p.help}; "
                             f"{p.accepts()}" for p in step.params) or "none"
        kind = ", structure" if step.structure else ""
        rows.append(f"| `{step.name}` | {step.phase}{kind} | {step.summary} | "
                    f"{params.replace('|', '/')} |")
    return "\n".join(rows)
