import numpy as np
import pytest

from diffsampler_rt.grid import cell_centres, decode
from trainer.embedding import embed, symmetries
from trainer.samplers import sample


def canon(p):
    return p[np.lexsort((p[:, 1], p[:, 0]))]


@pytest.mark.parametrize("kind,sampler,n", [("stratified", "sobol_owen", 256),
                                            ("stratified", "sobol_owen", 1024),
                                            ("ot", "rank1", 576), ("ot", "rank1", 625)])
def test_embed_decode_round_trip(kind, sampler, n):
    pts = sample(sampler, n, count=3, seed=1)
    grid = embed(pts, kind)
    k = int(np.sqrt(n))
    assert grid.shape == (3, 2, k, k)
    back = decode(grid, stratified=kind == "stratified")
    for a, b in zip(pts, back):
        np.testing.assert_allclose(canon(a), canon(b), atol=1e-12)


def test_offsets_are_in_cell_units():
    # the same relative position in a cell gives the same offset whatever k is
    for k in (4, 9):
        pts = cell_centres(k) + 0.25 / k
        np.testing.assert_allclose(embed(pts, "stratified"), 0.25)


def test_stratified_embedding_rejects_unstratified_sets():
    pts = np.random.default_rng(0).random((64, 2))
    with pytest.raises(ValueError, match="not stratified"):
        embed(pts, "stratified")


def test_non_square_n_rejected():
    with pytest.raises(ValueError, match="square number"):
        embed(np.random.default_rng(0).random((10, 2)), "ot")


def test_ot_assignment_is_optimal():
    ot = pytest.importorskip("ot")
    pts = np.random.default_rng(2).random((64, 2))
    grid = embed(pts, "ot")
    cost = float(np.sum((grid / 8) ** 2)) / 64
    M = ot.dist(cell_centres(8), pts)
    best = ot.emd2(np.full(64, 1 / 64), np.full(64, 1 / 64), M)
    assert cost == pytest.approx(best, rel=1e-9)


@pytest.mark.parametrize("w", range(8))
def test_symmetries_transform_the_decoded_set(w):
    pts = sample("sobol_owen", 64, count=1, seed=4)
    grid = embed(pts, "stratified")
    got = decode(symmetries(grid, np.array([w])), stratified=True)[0]
    p = pts[0].copy()
    if w & 1:
        p[:, 0] = 1 - p[:, 0]
    if w & 2:
        p[:, 1] = 1 - p[:, 1]
    if w & 4:
        p = p[:, ::-1]
    np.testing.assert_allclose(canon(got), canon(np.clip(p, 0, np.nextafter(1, 0))), atol=1e-12)


def test_decode_stratified_keeps_one_point_per_cell():
    grid = np.random.default_rng(0).normal(scale=2, size=(2, 16, 16))
    pts = decode(grid, stratified=True)
    cells = np.floor(pts * 16).astype(int)
    assert np.unique(cells[:, 1] * 16 + cells[:, 0]).size == 256
    assert np.all(pts >= 0) and np.all(pts < 1)


def test_strip_bounds_respect_floor_convention():
    from diffsampler_rt.grid import strip_bounds
    for k in range(4, 700):
        lo, hi = strip_bounds(k)
        np.testing.assert_array_equal(np.floor(lo * k), np.arange(k))
        np.testing.assert_array_equal(np.floor(hi * k), np.arange(k))


def test_decode_toroidal_wraps_instead_of_reflecting():
    grid = np.zeros((2, 4, 4))
    grid[0, 0, 3] = 0.75  # cell (row 0, col 3): x = (3.5 + 0.75) / 4 = 1.0625
    grid[1, 0, 0] = -1.0  # cell (row 0, col 0): y = (0.5 - 1) / 4 = -0.125
    reflected, wrapped = decode(grid), decode(grid, toroidal=True)
    # in the square a point past an edge is folded back as far inside, never onto the edge
    np.testing.assert_allclose([reflected[3, 0], reflected[0, 1]], [0.9375, 0.125])
    np.testing.assert_allclose([wrapped[3, 0], wrapped[0, 1]], [0.0625, 0.875])
    np.testing.assert_array_equal(np.delete(wrapped, [0, 3], axis=0),
                                  np.delete(reflected, [0, 3], axis=0))
    from diffsampler_rt.grid import wrap
    assert np.array_equal(wrap(np.array([[-1e-17, 1.0]])),  # -1e-17 + 1 rounds to 1.0
                          [[np.nextafter(1.0, 0.0), 0.0]])
