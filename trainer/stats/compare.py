"""Compare two collections of point sets statistic by statistic."""
from __future__ import annotations

from typing import Callable, Mapping

import numpy as np
from scipy import stats as sps

from .discrepancy import l2_star
from .distance import min_distance
from .spectrum import radial_spectrum, spectrum_mae

Statistic = Callable[[np.ndarray], np.ndarray]

#: per-set statistics compared by default (cheap at n <= 4096)
DEFAULT_STATISTICS: dict[str, Statistic] = {
    "l2_star": l2_star,
    "min_distance": min_distance,
}


def compare(a: np.ndarray, b: np.ndarray,
            statistics: Mapping[str, Statistic] | None = None) -> dict[str, dict[str, float]]:
    """Statistic-by-statistic comparison of collections ``a`` (candidate) and ``b`` (reference).

    Returns ``{name: {"mean_a", "mean_b", "rel_diff", "p_value"}}`` where rel_diff is
    (mean_a - mean_b) / |mean_b| and p_value that of Welch's two-sample t-test of equal means
    (NaN when either side has fewer than two sets); plus ``"radial_spectrum"`` with the mean
    absolute difference of the two mean radial spectra over the 79 bins.
    """
    a = np.asarray(a, dtype=np.float64).reshape((-1,) + np.shape(a)[-2:])
    b = np.asarray(b, dtype=np.float64).reshape((-1,) + np.shape(b)[-2:])
    out: dict[str, dict[str, float]] = {}
    for name, fn in (DEFAULT_STATISTICS if statistics is None else statistics).items():
        va, vb = np.asarray(fn(a), dtype=np.float64), np.asarray(fn(b), dtype=np.float64)
        mb = float(vb.mean())
        p = (float(sps.ttest_ind(va, vb, equal_var=False).pvalue)
             if len(va) > 1 and len(vb) > 1 else float("nan"))
        out[name] = {"mean_a": float(va.mean()), "mean_b": mb,
                     "rel_diff": float((va.mean() - mb) / abs(mb)) if mb else float("nan"),
                     "p_value": p}
    if a.shape[1] == b.shape[1]:
        out["radial_spectrum"] = {"mae": spectrum_mae(radial_spectrum(a)[1],
                                                      radial_spectrum(b)[1])}
    return out


def format_table(result: Mapping[str, Mapping[str, float]]) -> str:
    """A markdown table of :func:`compare`'s result."""
    rows = ["| statistic | mean A | mean B | rel. diff | p-value |", "|---|---|---|---|---|"]
    for name, r in result.items():
        if "mae" in r:
            rows.append(f"| {name} (MAE) | | | {r['mae']:.4f} | |")
        else:
            rows.append(f"| {name} | {r['mean_a']:.4g} | {r['mean_b']:.4g} | "
                        f"{100 * r['rel_diff']:+.1f} % | {r['p_value']:.3g} |")
    return "\n".join(rows)
