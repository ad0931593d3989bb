"""No atoms on the border: points that a step moves outside the square are folded back
(reflected, or wrapped on the torus), so no generated coordinate is exactly 0 or the
largest double below 1, as clamped ones were (uniform points hold ~0 such coordinates in
100 k; a clamping runtime gave poisson_disk_fast ~430 per 262 k at n = 1024)."""
from __future__ import annotations

import numpy as np
import pytest

import diffsampler_rt
from trainer import zoo

BELOW_ONE = np.nextafter(1.0, 0.0)


def border_coordinates(points: np.ndarray) -> int:
    return int(np.sum((points == 0.0) | (points >= BELOW_ONE)))


@pytest.mark.slow
@pytest.mark.parametrize("name", zoo.networks())
def test_no_generated_coordinate_sits_on_the_border(name):
    model = diffsampler_rt.load(name)
    # >= 100 k points: a square size and a thinned one (thinning and restoring move points
    # too); base models at 5 solver steps, whose rougher sets leave the square more often
    steps = None if model.card.get("distillation") else 5
    total = 0
    for n, count in ((1024, 80), (200, 100)):
        pts = model.generate(n, count, seed=11, steps=steps)
        assert pts.shape == (count, n, 2)
        total += border_coordinates(pts)
    assert total == 0


def test_reflection_folds_values_into_the_square():
    from diffsampler_rt.grid import decode, reflect
    v = np.array([-1e-17, -0.3, 0.0, 0.4, 1.0, 1.2, 2.7, -3.2])
    out = reflect(v)
    np.testing.assert_allclose(out, [1e-17, 0.3, 0.0, 0.4, BELOW_ONE, 0.8, 0.7, 0.8])
    # a decoded offset past the square's edge lands as far inside, not on it
    grid = np.zeros((2, 4, 4))
    grid[0, 0, 0] = -0.7  # the first cell's x 0.2 cells past the left edge
    pts = decode(grid)
    assert pts[0, 0] == pytest.approx(0.2 / 4)
    # a stratified offset past its cell's edge is reflected within the cell
    grid[0, 0, 1] = 0.6
    pts = decode(grid, stratified=True)
    assert pts[1, 0] == pytest.approx((1 + 0.9) / 4) and pts[0, 0] == pytest.approx(0.2 / 4)
