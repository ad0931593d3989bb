"""L2 discrepancies."""
from __future__ import annotations

import numpy as np


def l2_star(points: np.ndarray, chunk: int = 2048) -> np.ndarray:
    """Star L2 discrepancy (Warnock's formula), per set: the square root, as scipy returns.

    D^2 = 3^-d - 2^(1-d)/n sum_i prod_k (1 - x_ik^2) + 1/n^2 sum_ij prod_k (1 - max(x_ik, x_jk)).
    O(n^2) in chunks of rows. ``points`` (..., n, d) -> (...).
    """
    pts = np.asarray(points, dtype=np.float64)
    flat = pts.reshape((-1,) + pts.shape[-2:])
    n, d = flat.shape[1:]
    out = np.empty(len(flat))
    for s, p in enumerate(flat):
        term1 = np.prod(1.0 - p**2, axis=1).sum() * 2.0 ** (1 - d) / n
        term2 = 0.0
        for i in range(0, n, chunk):
            term2 += np.prod(1.0 - np.maximum(p[i:i + chunk, None, :], p[None, :, :]),
                             axis=2).sum()
        out[s] = 3.0 ** (-d) - term1 + term2 / n**2
    return np.sqrt(np.maximum(out, 0.0)).reshape(pts.shape[:-2])


def gl2(points: np.ndarray, chunk: int = 2048) -> np.ndarray:
    """Hickernell's generalised L2 discrepancy, per set (square root).

    The discrepancy of the kernel K(x, y) = prod_k (2 - max(x_k, y_k)):
    D^2 = (4/3)^d - 2/n sum_i prod_k (3 - x_ik^2) / 2 + 1/n^2 sum_ij prod_k (2 - max(x_ik, x_jk)).
    """
    pts = np.asarray(points, dtype=np.float64)
    flat = pts.reshape((-1,) + pts.shape[-2:])
    n, d = flat.shape[1:]
    out = np.empty(len(flat))
    for s, p in enumerate(flat):
        term1 = np.prod((3.0 - p**2) / 2.0, axis=1).sum() * 2.0 / n
        term2 = 0.0
        for i in range(0, n, chunk):
            term2 += np.prod(2.0 - np.maximum(p[i:i + chunk, None, :], p[None, :, :]),
                             axis=2).sum()
        out[s] = (4.0 / 3.0) ** d - term1 + term2 / n**2
    return np.sqrt(np.maximum(out, 0.0)).reshape(pts.shape[:-2])
