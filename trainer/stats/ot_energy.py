"""Semi-discrete optimal transport energy W2^2(uniform square, point set with weights 1/n).

Exact up to the Newton tolerance: the Laguerre (power) cells of the points with weights w
are computed from the regular triangulation (the lower convex hull of the lifted points
(x, |x|^2 - w)), clipped to the square; damped Newton on the dual (Kitagawa, Merigot and
Thibert 2019) finds the weights that give every cell area 1/n; the energy is the sum of
each cell's second moment about its point.

Points closer than ``MERGE`` mean spacings are one point of their summed weight: the lifted
hull cannot separate them (a pair 1e-8 apart in a corner, as the unwarping of a density
near zero can make, lost one point and left it the whole square); merging a pair moves the
energy (about 1/(6n)) by at most its mass 2/n times the move 1e-6/sqrt(n) times the
transport distance ~1/sqrt(n): about 1e-5 / n of itself.
"""
from __future__ import annotations

import warnings

import numpy as np
from scipy.sparse import coo_matrix
from scipy.sparse.linalg import spsolve
from scipy.spatial import ConvexHull, cKDTree

_SQUARE = [(0.0, 0.0), (1.0, 0.0), (1.0, 1.0), (0.0, 1.0)]
#: pairs closer than this many mean spacings 1 / sqrt(n) are merged (see the module doc)
MERGE = 1e-6


def _neighbours(x: np.ndarray, w: np.ndarray) -> np.ndarray:
    """Pairs (i, j), i < j, adjacent in the regular triangulation of (x, w)."""
    lifted = np.column_stack([x, (x * x).sum(1) - w])
    # a far point above closes the hull; lower facets have outward normals pointing down
    hull = ConvexHull(np.vstack([lifted, [0.5, 0.5, lifted[:, 2].max() + 1e3]]))
    lower = hull.simplices[hull.equations[:, 2] < 0]
    e = np.concatenate([lower[:, [0, 1]], lower[:, [1, 2]], lower[:, [0, 2]]])
    e = np.sort(e, axis=1)
    return np.unique(e, axis=0)


def _clip(poly: list, labels: list, ax: float, ay: float, c: float, label: int):
    """Clip polygon (vertex tuples, edge labels) by the half-plane ax y0 + ay y1 <= c.

    Plain Python floats: for these 4-8 vertex polygons numpy's per-call overhead would
    dominate (this loop is most of the time of an OT energy)."""
    out, out_l = [], []
    m = len(poly)
    for k in range(m):
        p, q, lab = poly[k], poly[(k + 1) % m], labels[k]
        sp, sq = ax * p[0] + ay * p[1] - c, ax * q[0] + ay * q[1] - c
        if sp <= 0:
            out.append(p)
            out_l.append(lab)
            if sq > 0:
                t = sp / (sp - sq)
                out.append((p[0] + (q[0] - p[0]) * t, p[1] + (q[1] - p[1]) * t))
                out_l.append(label)
        elif sq <= 0:
            t = sp / (sp - sq)
            out.append((p[0] + (q[0] - p[0]) * t, p[1] + (q[1] - p[1]) * t))
            out_l.append(lab)
    return out, out_l


def _cells(x: np.ndarray, w: np.ndarray):
    """Per point: area, second moment about the point, and {neighbour: shared edge length}.

    A point the triangulation leaves out (hidden by its neighbours' weights) has an empty
    cell, not the whole square."""
    n = len(x)
    pairs = _neighbours(x, w) if n > 1 else np.empty((0, 2), int)
    nbrs: list[list[int]] = [[] for _ in range(n)]
    for i, j in pairs:
        nbrs[i].append(j)
        nbrs[j].append(i)
    xs = x.tolist()
    sqw = ((x * x).sum(1) - w).tolist()
    # every cell's polygon edges (p -> q), its owner and the neighbour across it, flattened
    ps: list = []
    qs: list = []
    owner: list[int] = []
    across: list[int] = []
    for i in range(n):
        poly, labels = list(_SQUARE), [-1, -1, -1, -1]
        xi0, xi1, ci = xs[i][0], xs[i][1], sqw[i]
        if n > 1 and not nbrs[i]:
            continue
        for j in nbrs[i]:
            # |y - x_i|^2 - w_i <= |y - x_j|^2 - w_j  <=>  2 (x_j - x_i) . y <= sq_j - sq_i - w_j + w_i
            poly, labels = _clip(poly, labels, 2 * (xs[j][0] - xi0), 2 * (xs[j][1] - xi1),
                                 sqw[j] - ci, j)
            if len(poly) < 3:
                break
        if len(poly) < 3:
            continue
        ps += poly
        qs += poly[1:] + poly[:1]
        owner += [i] * len(poly)
        across += labels
    own = np.array(owner)
    P = np.array(ps) - x[own]
    Q = np.array(qs) - x[own]
    cross = P[:, 0] * Q[:, 1] - P[:, 1] * Q[:, 0]
    area = np.bincount(own, cross, minlength=n) / 2
    # second moment of a polygon about the origin: sum cross (|p|^2 + p.q + |q|^2) / 12
    moment = np.bincount(own, cross * ((P * P).sum(1) + (P * Q).sum(1) + (Q * Q).sum(1)),
                         minlength=n) / 12
    L = np.linalg.norm(Q - P, axis=1)
    lab = np.array(across)
    keep = (lab >= 0) & (own < lab)
    edges = dict(zip(zip(own[keep].tolist(), lab[keep].tolist()), L[keep].tolist()))
    return area, moment, edges


def ot_energy(points: np.ndarray, tol: float = 1e-9, max_iter: int = 100) -> np.ndarray:
    """W2^2 between the uniform measure on [0, 1]^2 and each set (weights 1/n).

    A k x k cell-centred grid gives exactly 1 / (6 k^2).
    """
    pts = np.asarray(points, dtype=np.float64)
    flat = pts.reshape((-1,) + pts.shape[-2:])
    return np.array([_ot_energy_one(p, tol, max_iter) for p in flat]).reshape(pts.shape[:-2])


def _close_groups(x: np.ndarray) -> np.ndarray:
    """Per point, the smallest index of its group of points chained by pairs closer than
    MERGE mean spacings (its own index when it has no such neighbour)."""
    root = np.arange(len(x))

    def find(i: int) -> int:
        while root[i] != i:
            i = root[i]
        return i

    for i, j in cKDTree(x).query_pairs(MERGE / np.sqrt(len(x))):
        a, b = sorted((find(i), find(j)))
        root[b] = a
    return np.array([find(i) for i in range(len(x))])


def _ot_energy_one(x: np.ndarray, tol: float, max_iter: int) -> float:
    n = len(x)
    group = _close_groups(x)
    while True:  # a point the unweighted triangulation still leaves out (a Voronoi cell is
        # never empty: only rounding drops one) joins its nearest neighbour's group
        reps, mass = np.unique(group, return_counts=True)
        w = np.zeros(len(reps))
        area, moment, edges = _cells(x[reps], w)
        if len(reps) == 1 or area.min() > 0:
            break
        lost = reps[np.argmin(area)]
        others = reps[reps != lost]
        group[group == lost] = others[np.argmin(np.linalg.norm(x[others] - x[lost], axis=1))]
    x, m = x[reps], len(reps)
    target = mass / n  # 1/n per point, k/n for k merged points
    err = np.abs(area - target).max()
    for _ in range(max_iter):
        if err <= tol / n:
            break
        (i, j), L = np.array(list(edges.keys())).T, np.array(list(edges.values()))
        c = L / (2 * np.linalg.norm(x[i] - x[j], axis=1))
        H = coo_matrix((np.concatenate([-c, -c, c, c]),
                        (np.concatenate([i, j, i, j]), np.concatenate([j, i, i, j]))),
                       shape=(m, m)).tocsr()
        H = H + coo_matrix((np.full(m, 1e-12 * c.mean()), (np.arange(m), np.arange(m))),
                           shape=(m, m)).tocsr()  # pins the additive constant of w
        step = spsolve(H.tocsc(), target - area)
        # damping keeps every cell at least half its target area along the way
        floor = min(area.min(), 1.0 / n) / 2
        alpha = 1.0
        while alpha > 1e-6:
            w_new = w + alpha * step
            a2, m2, e2 = _cells(x, w_new)
            e_new = np.abs(a2 - target).max()
            if a2.min() >= floor and e_new < (1 - alpha / 2) * err:
                break
            alpha /= 2
        w, area, moment, edges, err = w_new, a2, m2, e2, e_new
    if err > tol / n:
        # relative to the cell area 1/n, so that a near miss (1e-8: rounding, the energy
        # still exact to many digits) reads apart from a failed solve (order 1 or more)
        warnings.warn(f"semi-discrete OT stopped after {max_iter} Newton steps: max cell-area "
                      f"error {err * n:.2g} of the cell area 1/n (tolerance {tol:.2g})",
                      RuntimeWarning, stacklevel=3)
    return float(moment.sum())
