"""Card settings given per trained size (``"n": [...]`` beside the values): linear in log n
between the listed sizes, the end values beyond. Used by ``min_spacing``, ``sliced_ot`` and
``coarse_noise``."""
from __future__ import annotations

from typing import Any, Sequence

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
