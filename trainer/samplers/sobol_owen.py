"""Sobol' points in 2-d with Owen's nested uniform scrambling (hash-based, 32 levels)."""
from __future__ import annotations

import numpy as np

_BITS = 32
_M1 = np.uint64(0xBF58476D1CE4E5B9)
_M2 = np.uint64(0x94D049BB133111EB)


def _mix64(z: np.ndarray) -> np.ndarray:
    """splitmix64 finaliser: a bijective, well-mixing hash of uint64 (wraps on overflow)."""
    z = (z ^ (z >> np.uint64(30))) * _M1
    z = (z ^ (z >> np.uint64(27))) * _M2
    return z ^ (z >> np.uint64(31))


def _direction_numbers(dim: int) -> np.ndarray:
    """Direction numbers V_1..V_32 (as 32-bit integers) of Sobol' dimension 1 or 2."""
    v = np.zeros(_BITS, dtype=np.uint64)
    for b in range(_BITS):
        if dim == 0:  # van der Corput: identity generating matrix
            v[b] = 1 << (_BITS - 1 - b)
        else:  # x^2 + x + 1 primitive polynomial: V_{b+1} = V_b ^ (V_b >> 1)
            v[b] = (1 << (_BITS - 1)) if b == 0 else int(v[b - 1]) ^ (int(v[b - 1]) >> 1)
    return v


def sobol_digits(n: int) -> np.ndarray:
    """Unscrambled 2-d Sobol' points as 32-bit integers, shape (n, 2), dtype uint64."""
    if n > 2**_BITS:
        raise ValueError(f"n must be <= 2^{_BITS}, got {n}")
    i = np.arange(n, dtype=np.uint64)
    out = np.zeros((n, 2), dtype=np.uint64)
    for dim in range(2):
        v = _direction_numbers(dim)
        for b in range(max(1, int(n - 1).bit_length())):
            out[:, dim] ^= ((i >> np.uint64(b)) & np.uint64(1)) * v[b]
    return out


def owen_scramble(digits: np.ndarray, seeds: np.ndarray) -> np.ndarray:
    """Owen's nested uniform scramble of 32-bit digits, one random tree per seed and dim.

    Bit ``l`` (from the top) is flipped by a random bit that depends only on the seed, the
    dimension, ``l`` and the ``l`` higher bits of the *original* value, so points that
    share a prefix share the flips of that prefix: the defining property of a nested
    scramble.

    Parameters
    ----------
    digits : (n, 2) uint64 array of 32-bit values.
    seeds : (count,) uint64 array, one scramble per entry.

    Returns
    -------
    (count, n, 2) uint64 array of scrambled 32-bit values.
    """
    count = seeds.shape[0]
    out = np.zeros((count,) + digits.shape, dtype=np.uint64)
    for dim in range(2):
        d = digits[:, dim]
        tree = _mix64(seeds ^ _mix64(np.full(count, dim + 1, dtype=np.uint64)))[:, None]
        for level in range(_BITS):
            prefix = d >> np.uint64(_BITS - level)  # the `level` higher bits
            node = prefix + (np.uint64(level) << np.uint64(_BITS))
            flip = _mix64(tree ^ _mix64(node[None, :])) >> np.uint64(63)
            bit = (d[None, :] >> np.uint64(_BITS - 1 - level)) & np.uint64(1)
            out[:, :, dim] |= (bit ^ flip) << np.uint64(_BITS - 1 - level)
    return out


def sobol_owen(n: int, count: int, rng: np.random.Generator) -> np.ndarray:
    """The first ``n`` 2-d Sobol' points, Owen-scrambled independently ``count`` times.

    For n = 2^m every set is a (0, m, 2)-net: each elementary interval of area 2^-m holds
    exactly one point.
    """
    seeds = rng.integers(0, 2**63, size=count, dtype=np.uint64, endpoint=False)
    scrambled = owen_scramble(sobol_digits(n), seeds)
    return scrambled.astype(np.float64) / float(2**_BITS)
