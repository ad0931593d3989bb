"""Fit the density of a non-uniform sampler from its example sets (see diffsampler_rt.density).

Three fits, all ending in the table that :func:`diffsampler_rt.density.unwarp` uses to take
the sets to the uniform square before the grid embedding, and that the runtime inverts:

- ``"histogram"``: the pooled points on a bins x bins histogram. Simple, but its density is
  constant per bin and noisy where it is low: on the SOT ramp (p = 2x, 12 bins) the map
  moves points by up to 0.04 (2.5 point spacings at n = 4096), which the net then learns
  as part of the pattern.
- ``"log_legendre"``: the log density as a Legendre series (an exponential family fitted
  by maximum likelihood), degree by held-out likelihood across grid sizes. It stays
  positive and its error is relative, so it follows a density that nearly vanishes (the
  GBN blob's edges) where the linear series dips below zero and the map stretches.
- ``"legendre"``: a smooth fit, the tensor-product Legendre series of the density (the
  projection estimator: each coefficient is the mean of its basis function over the
  points), its degree chosen by cross-validation (across grid sizes where there are
  several, else over folds of the sets), then integrated exactly over the cells of a
  fine table. Blue-noise and low-discrepancy sets
  integrate polynomials far better than random points, so the coefficients are precise
  and the fit converges like the density's series, not like a histogram's bins.
"""
from __future__ import annotations

from functools import lru_cache
from typing import Sequence

import numpy as np
from numpy.polynomial import legendre

from diffsampler_rt.density import MAX_BINS

#: density fits the trainer knows (DataConfig.density_fit)
FITS = ("histogram", "legendre", "log_legendre")

#: mass added to every cell, as a fraction of the mean cell mass: enough for strictly
#: increasing CDFs, small enough not to bias the density. It mixes that fraction of the
#: uniform density in: the floor of 1e-3 used before moved the SOT ramp's x-CDF by up to
#: 2.4e-4, which at n = 4096 made the Gaussian integration error of the model's sets ~20x
#: the sampler's (SOT integrates smooth functions to ~1e-5 there).
FLOOR = 1e-6
#: the floor of every table made before the floor was a setting (cards without a
#: ``density_floor``, configs without one)
OLD_FLOOR = 1e-3


def check_floor(name: str, floor) -> None:
    """ValueError naming ``name`` unless ``floor`` is a number in (0, 1)."""
    if isinstance(floor, bool) or not isinstance(floor, (int, float)) or not 0 < floor < 1:
        raise ValueError(f"{name} must be a number in (0, 1), got {floor!r}")


def _check(points: np.ndarray, bins: int, floor: float) -> np.ndarray:
    if not isinstance(bins, int) or not 1 <= bins <= MAX_BINS:
        raise ValueError(f"bins must be an integer in [1, {MAX_BINS}], got {bins!r}")
    if not floor > 0:
        raise ValueError(f"floor must be > 0, got {floor!r}")
    p = np.asarray(points, dtype=np.float64).reshape(-1, 2)
    if len(p) == 0 or not np.all((p >= 0) & (p <= 1)):
        raise ValueError("fitting a density needs a non-empty set of points in [0, 1]^2")
    return p


def _table(mass: np.ndarray, floor: float) -> dict[str, list]:
    """The card's table from the mass of each of the bins x bins cells (x index first).

    ``floor`` (a fraction of the mean cell mass) is added to every cell, so that both CDFs
    increase strictly and the maps invert even where the density vanishes (:data:`FLOOR`).
    """
    bins = mass.shape[0]
    mass = np.maximum(mass, 0.0) + floor * mass.sum() / bins**2
    x_cdf = np.concatenate([[0.0], np.cumsum(mass.sum(axis=1))]) / mass.sum()
    y_cdf = np.concatenate([np.zeros((bins, 1)), np.cumsum(mass, axis=1)], axis=1)
    y_cdf /= y_cdf[:, -1:]
    x_cdf[-1] = 1.0  # exact ends despite rounding in the sums
    y_cdf[:, -1] = 1.0
    return {"x_cdf": x_cdf.tolist(), "y_cdf": y_cdf.tolist()}


def cell_masses(table: dict[str, list], floor: float) -> np.ndarray:
    """(bins, bins) masses (x index first, summing to 1) of the fit behind a card's table
    made with ``floor``: the table's own cell masses less the floor's share.

    Exact where the fit had no negative cells (those were clipped to zero before the floor
    was added; they come back as zero).
    """
    xc = np.asarray(table["x_cdf"], dtype=np.float64)
    yc = np.asarray(table["y_cdf"], dtype=np.float64)
    bins = xc.size - 1
    mass = np.diff(xc)[:, None] * np.diff(yc, axis=1)  # sums to 1, the floor included
    return np.maximum(mass * (1 + floor) - floor / bins**2, 0.0)


def refloor(table: dict[str, list], old: float, new: float) -> dict[str, list]:
    """The same fitted density tabulated with floor ``new`` instead of ``old`` (both
    fractions of the mean cell mass; see :data:`FLOOR`).

    Examples
    --------
    >>> import numpy as np
    >>> u = np.random.default_rng(0).random((16, 256, 2))
    >>> ramp = np.stack([np.sqrt(u[..., 0]), u[..., 1]], -1)  # density 2x
    >>> a = fit_density(ramp, 16, floor=1e-3)
    >>> b = refloor(a, 1e-3, 1e-6)
    >>> bool(np.allclose(b["x_cdf"], fit_density(ramp, 16, floor=1e-6)["x_cdf"]))
    True
    """
    check_floor("old floor", old)
    check_floor("new floor", new)
    return _table(cell_masses(table, old), new)


def fit_density(points: np.ndarray, bins: int, *, floor: float = FLOOR) -> dict[str, list]:
    """Density table of the points (..., 2) on a ``bins`` x ``bins`` histogram.

    ``floor`` (a fraction of the mean count per bin) is added to every bin, so that both
    CDFs increase strictly and the maps invert even where the examples left a bin empty.
    """
    p = _check(points, bins, floor)
    edges = np.linspace(0.0, 1.0, bins + 1)
    hist, _, _ = np.histogram2d(p[:, 0], p[:, 1], bins=[edges, edges])
    return _table(hist, floor)


def _basis(t: np.ndarray, degree: int) -> np.ndarray:
    """(..., degree + 1): the Legendre polynomials orthonormal on [0, 1] at t."""
    return legendre.legvander(2.0 * t - 1.0, degree) * np.sqrt(2.0 * np.arange(degree + 1) + 1)


def _cell_integrals(bins: int, degree: int) -> np.ndarray:
    """(bins, degree + 1): the integral of each orthonormal polynomial over each 1/bins cell."""
    edges = np.linspace(-1.0, 1.0, bins + 1)
    out = np.empty((bins, degree + 1))
    for i in range(degree + 1):
        c = np.zeros(degree + 1)
        c[i] = np.sqrt(2.0 * i + 1)
        prim = legendre.legval(edges, legendre.legint(c, lbnd=-1.0)) / 2  # dx = d(2x-1) / 2
        out[:, i] = np.diff(prim)
    return out


def legendre_coefficients(sets: Sequence[np.ndarray], degree: int) -> np.ndarray:
    """(degree + 1, degree + 1): the mean over the points of phi_i(x) phi_j(y)."""
    p = np.concatenate([np.asarray(s, dtype=np.float64).reshape(-1, 2) for s in sets])
    return np.einsum("pi,pj->ij", _basis(p[:, 0], degree), _basis(p[:, 1], degree)) / len(p)


def choose_degree(sets: Sequence[np.ndarray], max_degree: int,
                  folds: int = 8) -> tuple[int, np.ndarray, np.ndarray]:
    """The degree D <= ``max_degree`` of the series, by cross-validation over the sets.

    The sets are dealt into ``folds`` folds; with coefficients a from one fold and b from the
    others, the sum over i, j <= D of a^2 - 2 a b estimates |f_a - f|^2 - |f|^2 (b is
    unbiased and independent of a). Of the degrees whose mean estimate over the folds is
    within one standard error of the best, the lowest is taken (the one-standard-error rule).

    Returns D, and the mean estimate and its standard error for every degree 0 .. max_degree.
    """
    folds = min(folds, len(sets))
    if folds < 2:
        raise ValueError(f"cross-validation needs at least 2 example sets, got {len(sets)}")
    return _pick([list(sets[f::folds]) for f in range(folds)], max_degree)


def choose_degree_across_sizes(groups: Sequence[Sequence[np.ndarray]],
                               max_degree: int) -> tuple[int, np.ndarray, np.ndarray]:
    """Like :func:`choose_degree`, but a from the sets of one grid size and b from those of
    another, over every ordered pair of the ``groups`` (one per size).

    A sampler's own edge effects (e.g. SOT's first row of points, whose place depends on n)
    are systematic within a size, so cross-validation inside one size keeps taking more
    terms to follow them, and a high-degree series rings across the whole square (on the
    SOT ramp's 1024-point sets: degree 16, points moved by up to 0.31). The density is what
    every size shares: across sizes the estimate rises as soon as the terms stop doing so.
    """
    if len(groups) < 2:
        raise ValueError(f"cross-validation across sizes needs 2 or more sizes, got {len(groups)}")
    return _pick([list(g) for g in groups], max_degree, leave_one_out=False)


def _pick(parts: list, max_degree: int,
          leave_one_out: bool = True) -> tuple[int, np.ndarray, np.ndarray]:
    """The one-standard-error degree over estimates with a from one part and b from the
    others pooled (``leave_one_out``) or from each other part in turn. Each part's
    coefficients are computed once; pooled ones are their point-weighted mean."""
    coef = [legendre_coefficients(p, max_degree) for p in parts]
    count = [sum(np.size(s) // 2 for s in p) for p in parts]
    risks = []
    for i, a in enumerate(coef):
        others = [j for j in range(len(parts)) if j != i]
        held = ([sum(coef[j] * count[j] for j in others) / sum(count[j] for j in others)]
                if leave_one_out else [coef[j] for j in others])
        for b in held:
            term = a * a - 2 * a * b
            risks.append([term[:d + 1, :d + 1].sum() for d in range(max_degree + 1)])
    risks = np.asarray(risks)
    mean, se = risks.mean(axis=0), risks.std(axis=0, ddof=1) / np.sqrt(len(risks))
    best = int(np.argmin(mean))
    return int(np.flatnonzero(mean <= mean[best] + se[best])[0]), mean, se


def _each_set(sets: Sequence[np.ndarray], bins: int, floor: float, max_degree: int,
              cap: int) -> list[np.ndarray]:
    """The smooth fits' input as a list of (n, 2) float64 sets (``sets``: sets, or
    (count, n, 2) arrays of them), checked with the fit's arguments."""
    groups = [sets] if isinstance(sets, np.ndarray) else sets
    each = [s for g in groups
            for s in np.asarray(g, dtype=np.float64).reshape(-1, np.shape(g)[-2], 2)]
    _check(np.concatenate([s.reshape(-1, 2) for s in each]), bins, floor)
    if not isinstance(max_degree, int) or not 0 <= max_degree <= cap:
        raise ValueError(f"max_degree must be an integer in [0, {cap}], got {max_degree!r}")
    return each


def fit_density_legendre(sets: Sequence[np.ndarray], bins: int, *, max_degree: int = 24,
                         floor: float = FLOOR,
                         sizes: Sequence[np.ndarray] | None = None) -> tuple[dict[str, list], int]:
    """Smooth density table (``bins`` x ``bins``) of example sets: the Legendre series of the
    density, degree by cross-validation, integrated over the cells.

    ``sets``: a sequence of (n, 2) sets, or (count, n, 2) arrays of them (sets of different
    sizes may be mixed). Where the series dips below zero the cell gets the floor.
    ``sizes``: (count, n, 2) arrays of sets, one per size (two or more): the degree is then
    cross-validated across them (:func:`choose_degree_across_sizes`), else over ``sets``
    (:func:`choose_degree`).

    Returns the table and the chosen degree.

    Examples
    --------
    >>> import numpy as np
    >>> u = np.random.default_rng(0).random((64, 256, 2))
    >>> ramp = np.stack([np.sqrt(u[..., 0]), u[..., 1]], -1)  # density 2x
    >>> table, degree = fit_density_legendre(ramp, 32, max_degree=6)
    >>> round(table["x_cdf"][16], 2)  # F_X(1/2) = 1/4
    0.25
    """
    each = _each_set(sets, bins, floor, max_degree, 64)
    degree = (choose_degree_across_sizes(sizes, max_degree) if sizes is not None
              else choose_degree(each, max_degree))[0]
    c = legendre_coefficients(each, degree)
    cells = _cell_integrals(bins, degree)
    return _table(cells @ c @ cells.T, floor), degree


def _quadrature(nodes: int) -> tuple[np.ndarray, np.ndarray]:
    """(nodes^2, 2) tensor Gauss-Legendre nodes on the unit square and their weights."""
    t, w = legendre.leggauss(nodes)
    t, w = (t + 1) / 2, w / 2
    return np.stack(np.meshgrid(t, t, indexing="ij"), -1).reshape(-1, 2), np.outer(w, w).ravel()


def _log_partition(s: np.ndarray, w2: np.ndarray) -> tuple[float, np.ndarray]:
    """log sum_q w2_q exp(s_q), computed stably, and the normalised weights."""
    top = s.max()
    e = w2 * np.exp(s - top)
    return float(np.log(e.sum()) + top), e / e.sum()


def _loglik_fit(stats: np.ndarray, phi: np.ndarray, w2: np.ndarray,
                ridge: float = 1e-8, iterations: int = 100) -> np.ndarray:
    """theta maximising theta . stats - log Z(theta), Z = sum_q w2_q exp(theta . phi_q).

    Newton's method with backtracking on the concave log-likelihood; ``phi`` (Q, m) holds
    the basis at the quadrature nodes, ``w2`` (Q,) their weights.
    """
    theta = np.zeros(len(stats))

    def value(th: np.ndarray) -> tuple[float, np.ndarray]:
        log_z, q = _log_partition(phi @ th, w2)
        return float(th @ stats - log_z - ridge * th @ th), q

    f, q = value(theta)
    for _ in range(iterations):
        mean = q @ phi
        grad = stats - mean - 2 * ridge * theta
        cov = (phi * q[:, None]).T @ phi - np.outer(mean, mean)
        step = np.linalg.solve(cov + 2 * ridge * np.eye(len(theta)), grad)
        if grad @ step < 1e-12:
            break
        t = 1.0
        while True:
            f_new, q_new = value(theta + t * step)
            if f_new >= f or t < 1e-6:
                break
            t /= 2
        theta, f, q = theta + t * step, f_new, q_new
    return theta


def _features(p: np.ndarray, degree: int) -> np.ndarray:
    """(points, (degree + 1)^2): phi_i(x) phi_j(y), the constant term included."""
    bx, by = _basis(p[:, 0], degree), _basis(p[:, 1], degree)
    return (bx[:, :, None] * by[:, None, :]).reshape(len(p), -1)


@lru_cache(maxsize=2)
def _node_features(degree: int, nodes: int) -> tuple[np.ndarray, np.ndarray]:
    """The basis at the quadrature nodes and their weights (cached: a degree search fits and
    normalises every size at one degree before it moves to the next)."""
    q, w2 = _quadrature(nodes)
    feats = _features(q, degree)
    feats.flags.writeable = w2.flags.writeable = False  # shared by every caller
    return feats, w2


def fit_log_density(groups: Sequence[np.ndarray], degree: int, *,
                    nodes: int = 96) -> np.ndarray:
    """theta ((degree + 1)^2,), x index first, zero constant term: the log-density series of
    the pooled ``groups`` fitted by maximum likelihood (up to its normalising constant)."""
    p = np.concatenate([np.asarray(g, dtype=np.float64).reshape(-1, 2) for g in groups])
    feats, w2 = _node_features(degree, nodes)
    # the constant is log Z's job
    theta = _loglik_fit(_features(p, degree)[:, 1:].mean(axis=0), feats[:, 1:], w2)
    return np.concatenate([[0.0], theta])


def _log_norm(theta: np.ndarray, degree: int, nodes: int = 96) -> float:
    feats, w2 = _node_features(degree, nodes)
    return _log_partition(feats @ theta, w2)[0]


def choose_log_degree(groups: Sequence[np.ndarray], max_degree: int
                      ) -> tuple[int, np.ndarray, np.ndarray]:
    """Degree of the log-density series by held-out log-likelihood across the ``groups``
    (one per grid size, two or more): fit to one size, score the mean log density of every
    other size's points; the lowest degree within one standard error of the best (the
    one-standard-error rule, on the negative log-likelihood). Returns the degree, and the
    mean negative held-out log-likelihood and its standard error for each degree."""
    if len(groups) < 2:
        raise ValueError(f"cross-validation across sizes needs 2 or more sizes, got {len(groups)}")
    pts = [np.asarray(g, dtype=np.float64).reshape(-1, 2) for g in groups]
    losses = np.empty((max_degree + 1, len(pts) * (len(pts) - 1)))
    for d in range(max_degree + 1):
        col = 0
        for i in range(len(pts)):
            theta = fit_log_density([pts[i]], d)
            log_z = _log_norm(theta, d)
            for j in range(len(pts)):
                if j != i:
                    losses[d, col] = -(np.mean(_features(pts[j], d) @ theta) - log_z)
                    col += 1
    mean = losses.mean(axis=1)
    se = losses.std(axis=1, ddof=1) / np.sqrt(losses.shape[1])
    best = int(np.argmin(mean))
    return int(np.flatnonzero(mean <= mean[best] + se[best])[0]), mean, se


def fit_density_log_legendre(sets: Sequence[np.ndarray], bins: int, *, max_degree: int = 12,
                             floor: float = FLOOR,
                             sizes: Sequence[np.ndarray] | None = None,
                             sub: int = 4) -> tuple[dict[str, list], int]:
    """Smooth positive density table (``bins`` x ``bins``): exp of a Legendre series fitted
    by maximum likelihood, degree by held-out likelihood across ``sizes`` (one array of sets
    per grid size; else ``max_degree`` is used as the degree), each cell's mass by a
    ``sub`` x ``sub`` midpoint rule.

    Returns the table and the degree.

    Examples
    --------
    >>> import numpy as np
    >>> u = np.random.default_rng(0).random((64, 256, 2))
    >>> ramp = np.stack([np.sqrt(u[..., 0]), u[..., 1]], -1)  # density 2x
    >>> table, degree = fit_density_log_legendre(ramp, 32, max_degree=6)
    >>> round(table["x_cdf"][16], 2)  # F_X(1/2) = 1/4
    0.25
    """
    each = _each_set(sets, bins, floor, max_degree, 32)
    degree = choose_log_degree(sizes, max_degree)[0] if sizes is not None else max_degree
    theta = fit_log_density(each, degree)
    m = bins * sub
    t = (np.arange(m) + 0.5) / m
    bx = _basis(t, degree)
    s = bx @ theta.reshape(degree + 1, degree + 1) @ bx.T  # (m, m), x index first
    dens = np.exp(s - s.max())
    mass = dens.reshape(bins, sub, bins, sub).sum(axis=(1, 3))
    return _table(mass, floor), degree
