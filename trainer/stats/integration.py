"""Integration error on random integrands with exact integrals over [0, 1]^2."""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.special import erf


@dataclass(frozen=True)
class Gaussians:
    """Anisotropic Gaussians f(x) = exp(-1/2 (x - mu)^T A (x - mu)), one per row."""

    mu: np.ndarray  # (J, 2)
    A: np.ndarray  # (J, 2, 2) symmetric positive definite

    @classmethod
    def random(cls, count: int, seed: int = 0) -> "Gaussians":
        """Random centre in the square, angle, axis ratio 1:1..1:9, largest axis 0.1..1/3."""
        rng = np.random.default_rng(seed)
        mu = rng.random((count, 2))
        big = rng.uniform(0.1, 1 / 3, count)
        small = big / rng.uniform(1.0, 9.0, count)
        th = rng.uniform(0, np.pi, count)
        R = np.stack([np.stack([np.cos(th), -np.sin(th)], -1),
                      np.stack([np.sin(th), np.cos(th)], -1)], -2)
        D = np.zeros((count, 2, 2))
        D[:, 0, 0], D[:, 1, 1] = big ** -2.0, small ** -2.0
        return cls(mu, R @ D @ np.swapaxes(R, 1, 2))

    def __call__(self, x: np.ndarray) -> np.ndarray:
        """Values at points x (n, 2) -> (J, n)."""
        d = x[None, :, :] - self.mu[:, None, :]
        q = np.einsum("jni,jik,jnk->jn", d, self.A, d)
        return np.exp(-0.5 * q)

    def integrals(self, nodes: int = 64, panels: int = 32) -> np.ndarray:
        """Exact integrals: y in closed form (erf), x by composite Gauss-Legendre."""
        g, w = np.polynomial.legendre.leggauss(nodes)
        edges = np.linspace(0, 1, panels + 1)
        x = ((edges[:-1, None] + edges[1:, None]) / 2 + (g[None, :] / 2) / panels).ravel()
        wx = np.tile(w / 2 / panels, panels)
        a11, a12, a22 = self.A[:, 0, 0, None], self.A[:, 0, 1, None], self.A[:, 1, 1, None]
        dx = x[None, :] - self.mu[:, 0, None]
        c = a12 * dx / a22  # complete the square in y: a22 (dy + c)^2 + (a11 - a12^2/a22) dx^2
        h = np.sqrt(a22 / 2)
        inner = np.sqrt(np.pi / (2 * a22)) * (erf(h * (1 - self.mu[:, 1, None] + c))
                                              - erf(h * (-self.mu[:, 1, None] + c)))
        outer = np.exp(-0.5 * (a11 - a12**2 / a22) * dx**2)
        return (inner * outer) @ wx


@dataclass(frozen=True)
class Heavisides:
    """Half-plane indicators f(x) = 1[(x - p) . normal > 0] for random lines through the square."""

    p: np.ndarray  # (J, 2) a point on the line, inside the square
    normal: np.ndarray  # (J, 2)

    @classmethod
    def random(cls, count: int, seed: int = 0) -> "Heavisides":
        rng = np.random.default_rng(seed)
        th = rng.uniform(0, 2 * np.pi, count)
        return cls(rng.random((count, 2)), np.stack([np.cos(th), np.sin(th)], -1))

    def __call__(self, x: np.ndarray) -> np.ndarray:
        return (((x[None, :, :] - self.p[:, None, :]) * self.normal[:, None, :]).sum(-1)
                > 0).astype(np.float64)

    def integrals(self) -> np.ndarray:
        """Area of the unit square clipped by each half-plane (polygon clip + shoelace)."""
        square = np.array([[0.0, 0.0], [1.0, 0.0], [1.0, 1.0], [0.0, 1.0]])
        out = np.empty(len(self.p))
        for j, (p, nrm) in enumerate(zip(self.p, self.normal)):
            s = (square - p) @ nrm
            poly = []
            for i in range(4):  # Sutherland-Hodgman against one plane
                a, b, sa, sb = square[i], square[(i + 1) % 4], s[i], s[(i + 1) % 4]
                if sa > 0:
                    poly.append(a)
                if (sa > 0) != (sb > 0):
                    poly.append(a + (b - a) * sa / (sa - sb))
            if len(poly) < 3:
                out[j] = 0.0
                continue
            q = np.array(poly)
            out[j] = 0.5 * abs(np.dot(q[:, 0], np.roll(q[:, 1], -1))
                               - np.dot(q[:, 1], np.roll(q[:, 0], -1)))
        return out


def integration_mse(points: np.ndarray, integrands, exact: np.ndarray | None = None) -> np.ndarray:
    """Mean squared error of the equal-weight rule over the integrands, per set."""
    exact = integrands.integrals() if exact is None else exact
    pts = np.asarray(points, dtype=np.float64)
    flat = pts.reshape((-1,) + pts.shape[-2:])
    out = np.array([np.mean((integrands(p).mean(axis=1) - exact) ** 2) for p in flat])
    return out.reshape(pts.shape[:-2])
