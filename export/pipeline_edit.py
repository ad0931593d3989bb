"""Edit a model card's finishing pipeline in place: add, remove, replace, move an entry, or
change its parameters. Everything is checked by the runtime's own card checks before the
file is written, so a bad edit leaves the file as it was.

Entries are addressed by position (0-based) or by step name where that name is unique.
``python -m export pipeline`` is the command line; its flags come from the step registry
(:data:`diffsampler_rt.finish.STEPS`), one per parameter name.
"""
from __future__ import annotations

import json
from pathlib import Path
from typing import Any

from diffsampler_rt.finish import STEPS

from .defaults import edit_card, with_guide_digests


def _index(pipeline: list[dict], which: int | str) -> int:
    if isinstance(which, int) or (isinstance(which, str) and which.lstrip("-").isdigit()):
        i = int(which)
        if not -len(pipeline) <= i < len(pipeline):
            raise ValueError(f"no pipeline entry {i}: the pipeline has {len(pipeline)}")
        return i % len(pipeline)
    hits = [i for i, e in enumerate(pipeline) if e["step"] == which]
    if len(hits) != 1:
        raise ValueError(f"step {which!r} appears {len(hits)} times in the pipeline; give "
                         "its position instead")
    return hits[0]


def _entry(step: str, params: dict[str, Any], where: str | None) -> dict:
    if step not in STEPS:
        raise ValueError(f"unknown step {step!r}; the runtime knows {', '.join(STEPS)}")
    entry = {"step": step, **{k: v for k, v in params.items() if v is not None}}
    if where and where != "always":
        entry["where"] = where
    return entry


def edit_pipeline(path: str | Path, *, add: str | None = None, at: int | None = None,
                  remove: int | str | None = None, replace: int | str | None = None,
                  update: int | str | None = None, move: tuple[int | str, int] | None = None,
                  params: dict[str, Any] | None = None, where: str | None = None) -> dict:
    """Apply one edit to the pipeline of the model card in ``path``; returns the card.

    ``add`` a step (at position ``at``, default the end) with ``params``; ``remove`` an
    entry; ``replace`` an entry by a new ``add``-style one; ``update`` an entry's
    ``params`` (a value None removes that parameter); ``move`` an entry to a position.
    ``where`` ("structured", "unstructured" or "always") sets an entry's condition.
    """
    params = dict(params or {})
    chosen = [x for x in (add, remove, replace, update, move) if x is not None]
    if len(chosen) != 1 and not (add is not None and replace is not None and len(chosen) == 2):
        raise ValueError("give one edit: add, remove, replace (with add), update or move")

    def edit(card: dict) -> None:
        pipe = card.setdefault("pipeline", [])
        if replace is not None:
            pipe[_index(pipe, replace)] = _entry(add, params, where)
        elif add is not None:
            pipe.insert(len(pipe) if at is None else at, _entry(add, params, where))
        elif remove is not None:
            del pipe[_index(pipe, remove)]
        elif update is not None:
            entry = pipe[_index(pipe, update)]
            if "model" in params and not {"network_sha256", "sha256"} & set(params):
                # another guide: its digest is taken anew (with_guide_digests)
                entry.pop("network_sha256", None)
                entry.pop("sha256", None)
            entry.update(params)
            for key in [k for k, v in entry.items() if v is None]:
                del entry[key]
            if where == "always":
                entry.pop("where", None)
            elif where:
                entry["where"] = where
        else:
            i = _index(pipe, move[0])
            pipe.insert(int(move[1]), pipe.pop(i))
        with_guide_digests(pipe, Path(path))

    return edit_card(path, edit)


def parse_value(text: str) -> Any:
    """A command-line parameter value: "none" (remove), a number, true / false, N:V pairs
    ("64:0.7,1024:0.6", a per-size table), JSON (lists, objects) or plain text."""
    if text == "none":
        return None
    if ":" in text and not text.lstrip().startswith("{"):
        pairs = [item.split(":") for item in text.split(",")]
        if all(len(p) == 2 for p in pairs):
            try:
                return {"n": [int(n) for n, _ in pairs],
                        "values": [_number(v) for _, v in pairs]}
            except ValueError:
                pass
    try:
        return json.loads(text)
    except json.JSONDecodeError:
        return text


def _number(text: str) -> int | float:
    v = float(text)
    return int(v) if v.is_integer() and "." not in text else v


def parameter_help() -> dict[str, str]:
    """Every parameter name of the registry, with the steps that take it and what each
    accepts (the CLI's help text for ``--NAME``)."""
    out: dict[str, list[str]] = {}
    for step in STEPS.values():
        for p in step.params:
            out.setdefault(p.name, []).append(f"{step.name}: {p.help} ({p.accepts()})")
    return {name: "; ".join(texts) for name, texts in out.items()}
