"""The nearest rank-1 lattice to a point set: the structure of the lattice models.

A shifted rank-1 (Korobov) lattice of n points is L + u with L = {(i / n, i g / n) mod 1},
i = 0 .. n-1, and a generator g coprime to n (both projections are then permutations). A
small net learns the look of such sets but not their arithmetic: its points sit near lattice
positions with a jitter that halves the minimum distance.

The lattice is read off the set's power spectrum. A lattice's Fourier transform is a comb on
its dual lattice L* = {h in Z^2 : h_1 + g h_2 = 0 mod n}; the network's sets keep the comb's
short vectors (wavelengths of a few point spacings), not the long ones. So each coprime g is
scored by the power of the set at the vectors of its dual lattice with |h_1|, |h_2| <=
1.5 sqrt(n) (about the first two shells; the power is taken from one FFT of the points
deposited on a fine grid), the best g wins, and the shift u follows from the phases of the
set's Fourier transform at a reduced basis of L*. The set is then replaced by L + u.

Which lattice comes out is the network's choice: at its trained sizes it is the reference
sampler's; at other sizes the lattice whose short-range order the network's set has. The
runtime then shifts it uniformly at random, as the reference sampler does: the network's own
shifts are close to uniform but not exactly.
"""
from __future__ import annotations

import math

import numpy as np

from ._cic import deposit
from ._validate import unit_points

_BELOW_ONE = np.nextafter(1.0, 0.0)
#: half-width of the frequency box scored, in units of sqrt(n)
BOX = 1.5


def _power(points: np.ndarray, half: int) -> np.ndarray:
    """|sum_j exp(2 pi i h . x_j)|^2 / n^2 for h_1 in [-half, half], h_2 in [0, half],
    shape (2 half + 1, half + 1), from a cloud-in-cell deposit on an M x M torus grid
    (M >= 8 half: aliases come in at most ~2 % of a peak's amplitude), deconvolved."""
    n = len(points)
    m = 1 << max(4, math.ceil(math.log2(8 * half)))
    hist = deposit(points, m)[0]
    # numpy's FFT has exp(-2 pi i ...): conjugate; rows are h_1, columns h_2 >= 0
    spec = np.conj(np.fft.rfft2(hist))[:, :half + 1]
    spec = np.concatenate([spec[m - half:], spec[:half + 1]])
    h = np.arange(-half, half + 1) / m
    taper = np.sinc(h) ** 2  # cloud-in-cell transfer function per axis
    spec = spec / (taper[:, None] * taper[half:][None, :])
    return np.abs(spec) ** 2 / n ** 2


def _best_generator(points: np.ndarray) -> tuple[int, float]:
    """The coprime g whose dual vectors in the box carry the most power; its share of the
    power a lattice would have there (1 for an exact lattice)."""
    n = len(points)
    half = max(2, math.ceil(BOX * math.sqrt(n)))
    power = _power(points, half)
    h2 = np.arange(1, half + 1)  # h_2 = 0: only multiples of n, none in the box
    score, count = np.empty(n), np.empty(n, dtype=np.int64)
    step = max(1, (1 << 22) // half)  # bounded temporaries at large n
    for start in range(0, n, step):
        g = np.arange(start, min(n, start + step))[:, None]
        h1 = (-g * h2[None, :]) % n  # the dual vector of g with this h_2, nearest 0
        h1 = np.where(h1 > n // 2, h1 - n, h1)
        inside = np.abs(h1) <= half
        at = power[np.clip(h1 + half, 0, 2 * half), h2[None, :]]
        score[start:start + len(g)] = np.where(inside, at, 0.0).sum(axis=1)
        count[start:start + len(g)] = inside.sum(axis=1)
    score[np.gcd(np.arange(n), n) != 1] = -1.0
    best = int(np.argmax(score))
    return best, float(score[best] / max(count[best], 1))


def _reduced_dual_basis(n: int, g: int) -> np.ndarray:
    """A Lagrange-Gauss reduced basis (rows) of the dual lattice {h : h_1 + g h_2 = 0 mod n}."""
    a, b = np.array([n, 0], dtype=np.int64), np.array([-g, 1], dtype=np.int64)
    if a @ a < b @ b:
        a, b = b, a
    while True:  # a is the longer; subtract the nearest multiple of b
        a = a - int(round((a @ b) / (b @ b))) * b
        if a @ a >= b @ b:
            return np.stack([b, a])
        a, b = b, a


def fit_rank1_lattice(points: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The rank-1 lattice closest to each set, in the sense of its short-range order.

    Parameters
    ----------
    points : array_like, shape (n, 2) or (sets, n, 2)
        Point sets in [0, 1)^2, n >= 4.

    Returns
    -------
    generator : numpy.ndarray of int
        Per set, the generator g of the lattice {(i / n, i g / n) mod 1} (g coprime to n).
    shift : numpy.ndarray
        Per set, the shift (a, b) in units of 1/n: the lattice is {((i + a) / n, (i g + b) /
        n) mod 1}, as :func:`rank1_lattice` takes it.
    fit : numpy.ndarray
        Per set, the mean power of the set at the lattice's short dual vectors relative to
        the lattice's own: about 1 (within a few %: the power comes from a gridded FFT) for a
        set that is that lattice, about 1/n for random points.

    Examples
    --------
    >>> import numpy as np
    >>> from diffsampler_rt.lattice import fit_rank1_lattice, rank1_lattice
    >>> pts = rank1_lattice(1024, 271, (0.3, 5.2))
    >>> jittered = (pts + np.random.default_rng(0).normal(0, 0.1 / 32, pts.shape)) % 1
    >>> g, shift, fit = fit_rank1_lattice(jittered)
    >>> int(g), bool(fit > 0.5)
    (271, True)
    """
    pts = unit_points(points, min_n=4)
    single = pts.ndim == 2
    pts = pts[None] if single else pts
    n = pts.shape[1]
    gens, shifts, fits = [], [], []
    for p in pts:
        g, fit = _best_generator(p)
        basis = _reduced_dual_basis(n, g)
        # for L + u the transform at a dual vector h is n exp(2 pi i h . u)
        phase = np.angle(np.exp(2j * np.pi * (p @ basis.T)).sum(axis=0)) / (2 * np.pi)
        u = np.linalg.solve(basis.astype(np.float64), phase)
        gens.append(g)
        shifts.append(u * n)  # x = i / n + u_1 = (i + n u_1) / n, likewise y
        fits.append(fit)
    generator, shift, fit = np.array(gens), np.array(shifts), np.array(fits)
    if single:
        return generator[0], shift[0], fit[0]
    return generator, shift, fit


def rank1_lattice(n: int, generator: int, shift: tuple[float, float] = (0.0, 0.0)
                  ) -> np.ndarray:
    """The lattice {((i + a) / n, (i g + b) / n) mod 1}, i = 0 .. n-1, shape (n, 2), float64.

    ``shift`` = (a, b) in units of 1/n. Computed from the exact integers i * g mod n.

    Examples
    --------
    >>> from diffsampler_rt.lattice import rank1_lattice
    >>> rank1_lattice(5, 2)[:3].tolist()
    [[0.0, 0.0], [0.2, 0.4], [0.4, 0.8]]
    """
    if n < 1 or math.gcd(int(generator), n) != 1:
        raise ValueError(f"the generator must be coprime to n = {n}, got {generator}")
    i = np.arange(n, dtype=np.int64)
    a, b = (float(s) % n for s in shift)
    x = ((i + a) % n) / n
    y = (((i * int(generator)) % n + b) % n) / n
    return np.minimum(np.stack([x, y], axis=-1), _BELOW_ONE)


def nearest_rank1_lattice(points: np.ndarray,
                          rngs: list[np.random.Generator] | None = None) -> np.ndarray:
    """Replace each set (..., n, 2) by the rank-1 lattice it is closest to.

    The lattice keeps the set's own shift, or with ``rngs`` (one generator per set) gets a
    uniformly random one, as a randomly shifted lattice rule has it (its estimates are
    unbiased only then). Points come back in lattice order (i = 0 .. n-1 along x), not
    matched to the input's.

    Examples
    --------
    >>> import numpy as np
    >>> from diffsampler_rt.lattice import nearest_rank1_lattice, rank1_lattice
    >>> exact = rank1_lattice(64, 19, (0.25, 7.5))
    >>> noisy = (exact + np.random.default_rng(1).normal(0, 0.002, exact.shape)) % 1
    >>> snapped = nearest_rank1_lattice(noisy)
    >>> float(np.abs(np.sort(snapped, axis=0) - np.sort(exact, axis=0)).max()) < 1e-3
    True
    """
    pts = unit_points(points, form="(..., n, 2)", min_n=4)
    flat = pts.reshape((-1,) + pts.shape[-2:])
    g, shift, _ = fit_rank1_lattice(flat)
    n = pts.shape[-2]
    if rngs is not None:
        if len(rngs) != len(flat):
            raise ValueError(f"rngs must give one generator per set ({len(flat)}), got "
                             f"{len(rngs)}")
        shift = np.stack([r.random(2) * n for r in rngs])  # uniform on the torus
    out = np.stack([rank1_lattice(n, int(gi), si) for gi, si in zip(g, shift)])
    return out.reshape(pts.shape)
