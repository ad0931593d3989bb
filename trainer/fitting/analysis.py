"""What a fit learns from the examples before training: their embedding, whether their
points are uniform, which structure every set has, and whether the invariances a user
asserts (symmetries of the square, the torus) agree with them.

Each test reads the sets once, a chunk at a time. The decisions and the statistics behind
them go into the model card (``"fit"``) and the report.
"""
from __future__ import annotations

import math
from dataclasses import asdict, dataclass, field

import numpy as np
from scipy import stats as sps

from .examples import Examples

#: bins per axis of the intensity test; the share of relative deviation that counts
INTENSITY_BINS, INTENSITY_EFFECT = 4, 0.10
#: p-value below which a test's finding counts (uniformity, assertions)
ALPHA = 1e-3
#: a set is that structure when all its sets have it (structures are exact by construction)
STRUCTURES = ("dyadic_net", "n_rooks", "rank1_lattice")


@dataclass
class Analysis:
    """The findings, by example size where they differ."""
    embedding: str
    uniform: bool
    intensity_p: float
    intensity_deviation: float
    structure: str | None
    structure_sizes: list[int] = field(default_factory=list)
    symmetries: list[int] = field(default_factory=lambda: [0])
    toroidal: bool = False
    warnings: list[str] = field(default_factory=list)

    def to_dict(self) -> dict:
        return asdict(self)


def _stratified(sets: np.ndarray) -> np.ndarray:
    """Per set: one point in every cell of its k x k grid."""
    n = sets.shape[1]
    k = math.isqrt(n)
    cell = np.minimum((sets * k).astype(np.int64), k - 1)
    flat = cell[..., 1] * k + cell[..., 0]
    return np.array([np.bincount(f, minlength=n).max() == 1 for f in flat])


def _counts(sets: np.ndarray, bins: int) -> np.ndarray:
    """Points per bin of a bins x bins grid, per set: (S, bins * bins)."""
    cell = np.minimum((sets * bins).astype(np.int64), bins - 1)
    flat = cell[..., 1] * bins + cell[..., 0]
    return np.stack([np.bincount(f, minlength=bins * bins) for f in flat])


def intensity_test(ex: Examples) -> tuple[float, float]:
    """(p-value, largest relative deviation) of the hypothesis that every example size's
    points have a uniform intensity: each bin's mean count over sets against n / bins^2,
    with the standard error from the sets' own spread (so clustered and blue-noise sets,
    whose counts vary more or less than Poisson ones, are judged fairly)."""
    chi2, dof, worst = 0.0, 0, 0.0
    b = INTENSITY_BINS
    for n in ex.sizes:
        counts = np.concatenate([_counts(s, b) for s in ex.iter_sets(n)]).astype(np.float64)
        expect = n / (b * b)
        mean = counts.mean(axis=0)
        se = counts.std(axis=0, ddof=1) / math.sqrt(len(counts)) if len(counts) > 1 else \
            np.full(b * b, np.inf)
        se = np.maximum(se, 1e-3 * expect)  # a bin every set fills alike: count exactly
        chi2 += float(np.sum(((mean - expect) / se) ** 2))
        dof += b * b - 1
        worst = max(worst, float(np.max(np.abs(mean / expect - 1))))
    return float(sps.chi2.sf(chi2, dof)), worst


def _structure_holds(name: str, sets: np.ndarray) -> bool:
    from trainer.stats.structure import stratified_projections, t_value
    n = sets.shape[1]
    if name == "dyadic_net":
        return n & (n - 1) == 0 and bool(np.all(t_value(sets) == 0))
    if name == "n_rooks":
        return bool(np.all(stratified_projections(sets)))
    from diffsampler_rt.lattice import fit_rank1_lattice
    return bool(np.all(fit_rank1_lattice(sets[:16])[2] > 0.9))


def common_structure(ex: Examples, stratified: bool) -> tuple[str | None, list[int]]:
    """The strongest structure every example set has (a (0, m, 2)-net, stratified
    projections, a rank-1 lattice) at every example size from some size up, and those
    sizes; None if none. A sampler whose structure starts at some grid size (LDBN's
    stratified projections) gets it from there: the step's smallest side."""
    for name in STRUCTURES:
        if name != "rank1_lattice" and not stratified:
            continue
        # nets and stratified projections are imposed at power-of-two sides only
        sizes = [n for n in ex.sizes if name == "rank1_lattice" or n & (n - 1) == 0]
        holds = [n for n in sizes
                 if all(_structure_holds(name, s) for s in ex.iter_sets(n))]
        if holds and holds == sizes[len(sizes) - len(holds):]:  # every size from one up
            return name, holds
    return None, []


def _transformed(sets: np.ndarray, g: int) -> np.ndarray:
    """The symmetry g of the square (0..7, as trainer.embedding.symmetries numbers them:
    bit 0 mirror x, bit 1 mirror y, bit 2 swap x and y) applied to points."""
    p = sets.copy()
    if g & 4:
        p = p[..., ::-1]
    if g & 1:
        p[..., 0] = 1 - p[..., 0]
    if g & 2:
        p[..., 1] = 1 - p[..., 1]
    return np.clip(p, 0, np.nextafter(1.0, 0.0))


def _features(sets: np.ndarray) -> np.ndarray:
    """Per set: the intensity map (4 x 4 bins) and the power at the low integer
    frequencies |fx|, |fy| <= 3 (the arrangement's orientation), as one vector."""
    f = np.arange(-3, 4)
    ex = np.exp(-2j * np.pi * f[None, :, None] * sets[:, None, :, 0])
    ey = np.exp(-2j * np.pi * f[None, :, None] * sets[:, None, :, 1])
    power = np.abs(np.einsum("syn,sxn->syx", ey, ex)) ** 2 / sets.shape[1]
    return np.concatenate([_counts(sets, 4), power.reshape(len(sets), -1)], axis=1)


def symmetry_p(ex: Examples, g: int) -> float:
    """p-value of 'the sets' distribution is invariant under symmetry g': the per-set
    features of the sets and of their images, compared set by set (paired)."""
    diffs = []
    for n in ex.sizes:
        for s in ex.iter_sets(n, chunk=128):
            diffs.append(_features(s) - _features(_transformed(s, g)))
    d = np.concatenate(diffs)
    if len(d) < 4:
        return 1.0
    se = d.std(axis=0, ddof=1) / math.sqrt(len(d))
    keep = se > 1e-9 * (np.abs(d).mean(axis=0) + 1e-12)
    z2 = np.sum((d.mean(axis=0)[keep] / se[keep]) ** 2)
    return float(sps.chi2.sf(z2, int(keep.sum())))


def toroidal_p(ex: Examples) -> float:
    """p-value of 'the sets look the same across the square's edges as inside': per set,
    the mean nearest-neighbour distance (on the torus) of its tenth of points closest to an
    edge minus that of the others, tested for a zero mean over sets. On the torus the edge
    is not special and the difference averages out; sets made in the square are spaced
    differently across the seam (too close, or too far where they avoid the edges)."""
    from scipy.spatial import cKDTree
    diffs = []
    for n in ex.sizes:
        for chunk in ex.iter_sets(n, chunk=128):
            for p in chunk:
                d = cKDTree(p, boxsize=1.0).query(p, k=2)[0][:, 1]
                to_edge = np.minimum(p, 1 - p).min(axis=1)
                edge = to_edge <= np.quantile(to_edge, 0.1)
                diffs.append((d[edge].mean() - d[~edge].mean()) * math.sqrt(n))
    if len(diffs) < 4:
        return 1.0
    return float(sps.ttest_1samp(diffs, 0.0).pvalue)


def analyse(ex: Examples, *, symmetries: list[int] | None = None,
            toroidal: bool = False) -> Analysis:
    """Every finding the fit acts on (see the module docstring)."""
    stratified = all(bool(np.all(_stratified(s))) for n in ex.sizes for s in ex.iter_sets(n))
    p, deviation = intensity_test(ex)
    uniform = not (p < ALPHA and deviation > INTENSITY_EFFECT)
    structure, sizes = common_structure(ex, stratified) if uniform else (None, [])
    out = Analysis("stratified" if stratified else "ot", uniform, p, deviation, structure,
                   sizes, sorted(set(symmetries or [0]) | {0}), toroidal)
    for g in out.symmetries:
        if g and (q := symmetry_p(ex, g)) < ALPHA:
            out.warnings.append(f"the examples contradict symmetry {g} (p = {q:.1e}): "
                                "training with it teaches the net a pattern they do not have")
    if toroidal and (q := toroidal_p(ex)) < ALPHA:
        out.warnings.append(f"the examples look different near the square's edges than "
                            f"inside (p = {q:.1e}): they may not be toroidal")
    return out


def describe(a: Analysis) -> list[str]:
    """The findings in words, one a line (printed by ``fit``, kept in the report)."""
    lines = [f"embedding: {a.embedding} ("
             + ("every set has one point per cell of its k x k grid" if a.embedding ==
                "stratified" else "not every set is stratified: optimal-transport assignment")
             + ")",
             f"intensity: {'uniform' if a.uniform else 'NOT uniform'} (largest deviation of a "
             f"4 x 4 bin's mean count {100 * a.intensity_deviation:.1f} %, p = "
             f"{a.intensity_p:.2g})" + ("" if a.uniform else
                                        ": the net learns the sets mapped to the square"),
             "structure every set has: " + (f"{a.structure} (every set at n = "
                                            f"{', '.join(map(str, a.structure_sizes))})"
                                            if a.structure else "none"),
             f"augmentations: symmetries {a.symmetries}"
             + (", toroidal shifts" if a.toroidal else "")
             + (" (asserted)" if a.toroidal or a.symmetries != [0] else " (none asserted)")]
    return lines + [f"warning: {w}" for w in a.warnings]
