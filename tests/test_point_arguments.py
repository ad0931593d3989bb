"""Every runtime function that takes point sets refuses NaNs, points outside the unit square
and wrong shapes with an error naming them (they used to pass NaNs through as garbage)."""
import numpy as np
import pytest

from diffsampler_rt import (density, elimination, lattice, low_frequencies, projections,
                            sliced_ot, spacing, structure)
from diffsampler_rt._validate import unit_points

TABLE = {"x_cdf": [0.0, 0.25, 1.0], "y_cdf": [[0.0, 0.5, 1.0], [0.0, 0.5, 1.0]]}
K = 8  # 64 points: one per cell of an 8 x 8 grid, so impose_n_rooks takes the good set


def _good() -> np.ndarray:
    c = (np.arange(K) + 0.5) / K
    return np.stack(np.meshgrid(c, c), axis=-1).reshape(-1, 2)  # row-major cell order


FUNCTIONS = {
    "eliminate": lambda p: elimination.eliminate(p, 50),
    "thin": lambda p: elimination.thin(p, 50),
    "fit_rank1_lattice": lattice.fit_rank1_lattice,
    "nearest_rank1_lattice": lattice.nearest_rank1_lattice,
    "close_pairs": lambda p: spacing.close_pairs(p, 0.05),
    "enforce_min_spacing": lambda p: spacing.enforce_min_spacing(p, 0.05),
    "impose_n_rooks": lambda p: structure.impose_n_rooks(p, K),
    "impose_dyadic_net": lambda p: structure.impose_dyadic_net(p, K),
    "polish": lambda p: sliced_ot.polish(p[None], 2, 8, [np.random.default_rng(0)]),
    "even_out": lambda p: low_frequencies.even_out(p, 0.5, cut=0.5),
    "spread_projections": lambda p: projections.spread_projections(p, 1.1),
    "restore_low_frequencies": lambda p: low_frequencies.restore_low_frequencies(p[:50], p),
    "warp": lambda p: density.warp(p, TABLE),
    "unwarp": lambda p: density.unwarp(p, TABLE),
}


@pytest.mark.parametrize("name", FUNCTIONS)
def test_good_points_pass(name):
    out = FUNCTIONS[name](_good())
    out = out[0] if isinstance(out, tuple) else out
    assert np.all(np.isfinite(out))


@pytest.mark.parametrize("name", FUNCTIONS)
def test_nan_is_refused(name):
    p = _good()
    p[5, 1] = np.nan
    with pytest.raises(ValueError, match=r"has 1 non-finite coordinate \(NaN or inf\)"):
        FUNCTIONS[name](p)


@pytest.mark.parametrize("name", FUNCTIONS)
def test_points_outside_the_square_are_refused(name):
    p = _good()
    p[5, 0] = 1.5
    with pytest.raises(ValueError, match=r"must lie in the unit square \[0, 1\]\^2, got "
                                         r"coordinates from 0\.0625 to 1\.5"):
        FUNCTIONS[name](p)


@pytest.mark.parametrize("name", FUNCTIONS)
def test_wrong_shape_is_refused(name):
    # polish takes (sets, n, 2) and gets p[None]; restore_low_frequencies gets p[:50] first
    with pytest.raises(ValueError, match=r"must have shape \(.*, 2\).*, got \((1, 64|64|50), 3\)"):
        FUNCTIONS[name](np.full((K * K, 3), 0.5))


def test_unit_points_forms():
    pts = np.full((3, 4, 2), 0.5)
    assert unit_points(pts) is pts  # float64 input: no copy
    assert unit_points(pts, form="(..., n, 2)").shape == (3, 4, 2)
    with pytest.raises(ValueError, match=r"points must have shape \(n, 2\), got \(3, 4, 2\)"):
        unit_points(pts, form="(n, 2)")
    with pytest.raises(ValueError, match=r"sets must have shape \(sets, n, 2\) with n >= 5, "
                                         r"got \(3, 4, 2\)"):
        unit_points(pts, name="sets", form="(sets, n, 2)", min_n=5)
    with pytest.raises(TypeError, match="points must be an array of numbers, got str"):
        unit_points("abc")
    assert unit_points([[0, 1]]).dtype == np.float64  # the square's closed edge is taken
    assert unit_points([0.5, 0.5], form="(..., 2)").shape == (2,)  # a lone point
    with pytest.raises(ValueError, match=r"points must have shape \(\.\.\., n, 2\), got \(2,\)"):
        unit_points([0.5, 0.5], form="(..., n, 2)")
