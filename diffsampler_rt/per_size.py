"""Card settings given per trained size (``"n": [...]`` beside the values): linear in log n
between the listed sizes, the end values beyond. Used by ``min_spacing``, ``projection_gain``,
``sliced_ot``, ``coarse_noise`` and ``even_out`` (the last two share the form of a gain table:
``{"cut": C, "gain": G}`` or ``{"cut": C, "n": [sizes], "gain": [G per size]}``, where the
cut may be a list per size too: ``"cut": [C per size]``)."""
from __future__ import annotations

from typing import Any, Callable, Sequence

import numpy as np


def at(sizes: Sequence[int], values: Sequence[float], n: int) -> float:
    """The value at n points of a per-size table."""
    return float(np.interp(np.log(n), np.log(sizes), values))


def sizes_ok(sizes: Any) -> bool:
    """Whether ``sizes`` is a non-empty list of strictly increasing positive integers."""
    return (isinstance(sizes, list) and len(sizes) > 0
            and all(isinstance(v, int) and not isinstance(v, bool) and v > 0 for v in sizes)
            and all(a < b for a, b in zip(sizes, sizes[1:])))


def describe(sizes: Sequence[int], values: Sequence[str], what: str = "") -> str:
    """A per-size table in words, the values already formatted: "1 / 1.5 at n = 64 / 256"
    (``what`` goes between: "0 / 8 iterations at n = 256 / 1024")."""
    return (" / ".join(values) + (f" {what}" if what else "") + " at n = "
            + " / ".join(map(str, sizes)))


def finite_number(v: Any) -> bool:
    """A real number (not a bool), finite."""
    return not isinstance(v, bool) and isinstance(v, (int, float)) and bool(np.isfinite(v))


def value(spec: float | dict, n: int) -> float:
    """The value at n points of a step parameter that is a number or a per-size table
    ``{"n": [sizes], "values": [...]}`` (the one form of the card's pipeline)."""
    if isinstance(spec, dict):
        return at(spec["n"], spec["values"], n)
    return float(spec)


def value_at(spec: float | dict, key: str, n: int) -> float:
    """The value at n points of a card setting that is a number or a per-size table
    ``{"n": [sizes], key: [values]}`` (``min_spacing``'s "c", ``projection_gain``'s "gain")."""
    return _table_value(spec, key, n) if isinstance(spec, dict) else float(spec)


def gain_at(spec: dict, n: int) -> float:
    """The gain at n points of a gain table."""
    return _table_value(spec, "gain", n)


def cut_at(spec: dict, n: int) -> float:
    """The cut at n points of a gain table (one cut, or a list per size)."""
    return _table_value(spec, "cut", n)


def _table_value(spec: dict, key: str, n: int) -> float:
    if isinstance(spec[key], list):
        return at(spec["n"], spec[key], n)
    return float(spec[key])


def describe_cut(spec: dict, unit: str) -> str:
    """A gain table's cut in words: "1 sqrt(n)", or "1 / 0.5 sqrt(n) at those sizes" for a
    list (after :func:`describe_gain`, which names the sizes)."""
    if isinstance(spec["cut"], list):
        return " / ".join(f"{c:g}" for c in spec["cut"]) + f" {unit} at those sizes"
    return f"{spec['cut']:g} {unit}"


def describe_gain(spec: dict) -> str:
    """A gain table's gains in words: "gain 1.4" or "gain 1.3 / 1.5 at n = 64 / 1024
    (log-linear)"."""
    if "n" in spec:
        return "gain " + describe(spec["n"], [f"{g:g}" for g in spec["gain"]]) + " (log-linear)"
    return f"gain {spec['gain']:g}"


def gain_table_problem(spec: Any, field: str, cut_ok: Callable[[Any], bool], cut_text: str,
                       gain_ok: Callable[[Any], bool], gain_text: str) -> str | None:
    """Why the card's gain table ``field`` is invalid, or None; ``cut_ok`` / ``gain_ok``
    accept a cut / a gain, described by ``cut_text`` / ``gain_text``."""
    form = (f"'{field}' must be {{\"cut\": C, \"gain\": G}} or {{\"cut\": C or [C per "
            "size], \"n\": [sizes], \"gain\": [G per size]}")
    if not isinstance(spec, dict) or set(spec) - {"n"} != {"cut", "gain"}:
        return f"{form}, got {spec!r}"
    gains, cuts = spec["gain"], spec["cut"]
    if "n" in spec:
        if not (sizes_ok(spec["n"]) and isinstance(gains, list)
                and len(gains) == len(spec["n"])):
            return (f"'{field}' n and gain must be lists of the same length, n strictly "
                    f"increasing sizes >= 1; got {spec['n']!r}, {gains!r}")
        if isinstance(cuts, list) and len(cuts) != len(spec["n"]):
            return (f"'{field}' cut, given per size, must have one value per size in n; "
                    f"got {cuts!r} for n = {spec['n']!r}")
    else:
        gains = [gains]
    if not all(cut_ok(c) for c in (cuts if isinstance(cuts, list) and "n" in spec else [cuts])):
        return f"'{field}' cut must be {cut_text}, got {spec['cut']!r}"
    if not all(gain_ok(g) for g in gains):
        return f"'{field}' gain must be {gain_text}, got {spec['gain']!r}"
    return None
