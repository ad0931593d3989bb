"""Rank-1 (Korobov) lattices (i/n, i*g/n mod 1) with a random toroidal shift."""
from __future__ import annotations

import math
from functools import lru_cache

import numpy as np

from diffsampler_rt.lattice import rank1_lattice


def korobov(n: int, g: int) -> np.ndarray:
    """The unshifted lattice {(i/n, (i*g mod n)/n)}, shape (n, 2), computed exactly (the
    runtime's construction, which the lattice models' structure also uses)."""
    return rank1_lattice(n, g)


def _coprime_generators(n: int) -> np.ndarray:
    """Candidate generators 1 <= g <= n/2 with gcd(g, n) = 1 (g and n - g are mirror images)."""
    return np.array([g for g in range(1, n // 2 + 1) if math.gcd(g, n) == 1], dtype=np.int64)


def _score_generators(n: int, i: np.ndarray, score) -> tuple[np.ndarray, np.ndarray]:
    """score((g*i) mod n as a (G, len(i)) array) for every candidate g, in chunks."""
    cand = _coprime_generators(n)
    out = np.empty(cand.size)
    chunk = max(1, 4_000_000 // n)
    for s in range(0, cand.size, chunk):
        out[s:s + chunk] = score((cand[s:s + chunk, None] * i[None, :]) % n)
    return cand, out


@lru_cache(maxsize=64)
def maxmin_generator(n: int) -> int:
    """The generator g (coprime to n) that maximises the lattice's toroidal min distance.

    Ties go to the smallest g. Coprimality keeps the y-projection a permutation (a g
    sharing a factor with n stacks points on fewer rows). Cost O(n^2), cached.

    Examples
    --------
    >>> maxmin_generator(1024)
    271
    """
    if n < 3:
        return 1
    i = np.arange(1, n, dtype=np.int64)
    dx = np.minimum(i, n - i).astype(np.float64) ** 2
    cand, best = _score_generators(
        n, i, lambda y: (dx[None, :] + np.minimum(y, n - y).astype(np.float64) ** 2).min(axis=1))
    return int(cand[int(np.argmax(best))])  # argmax returns the first (smallest g) tie


def shifted(base: np.ndarray, count: int, rng: np.random.Generator) -> np.ndarray:
    """``count`` copies of ``base`` (n, 2), each under its own uniform toroidal shift."""
    shifts = rng.random((count, 1, 2))
    return (base[None, :, :] + shifts) % 1.0


def rank1(n: int, count: int, rng: np.random.Generator) -> np.ndarray:
    """Rank-1 Korobov lattice with the max-min-distance generator, randomly shifted."""
    return shifted(korobov(n, maxmin_generator(n)), count, rng)


@lru_cache(maxsize=64)
def p2_generator(n: int) -> int:
    """The generator g (coprime to n) minimising the lattice's P_2 figure of merit.

    P_alpha (alpha = 2) is the worst-case error of the lattice rule on the Korobov space:
    P_2 = -1 + (1/n) sum_i prod_d (1 + 2 pi^2 B_2({x_id})), B_2(x) = x^2 - x + 1/6. This is
    the criterion a tool such as LatNetBuilder optimises; ties go to the smallest g.

    Examples
    --------
    >>> p2_generator(1024)
    275
    """
    if n < 3:
        return 1
    i = np.arange(n, dtype=np.int64)

    def factor(x: np.ndarray) -> np.ndarray:
        return 1.0 + 2.0 * math.pi**2 * (x * x - x + 1.0 / 6.0)

    fx = factor(i / n)
    cand, merit = _score_generators(n, i, lambda y: (fx[None, :] * factor(y / n)).mean(axis=1) - 1.0)
    return int(cand[int(np.argmin(merit))])


def p2_lattice(n: int, count: int, rng: np.random.Generator) -> np.ndarray:
    """Rank-1 Korobov lattice with the P_2-optimal generator, randomly shifted."""
    return shifted(korobov(n, p2_generator(n)), count, rng)
