import math

import numpy as np
import pytest

torch = pytest.importorskip("torch")

from trainer.optimise import (_uniform_projection_quantiles, decode_torch,  # noqa: E402
                              l2_star_torch, optimise_noise, sliced_ot_uniform)
from trainer.stats import l2_star  # noqa: E402
from trainer.unet import UNet  # noqa: E402

from .conftest import tiny_config  # noqa: E402

# minutes in all: run by the full suite, not by `pytest -m "not slow"`
pytestmark = pytest.mark.slow


def test_l2_star_torch_is_warnock_squared():
    pts = np.random.default_rng(0).random((3, 50, 2))
    np.testing.assert_allclose(l2_star_torch(torch.tensor(pts)).numpy(), l2_star(pts) ** 2,
                               rtol=1e-10)


def test_projection_quantiles_match_a_dense_uniform_grid():
    g = (np.stack(np.meshgrid(np.arange(400), np.arange(400)), -1).reshape(-1, 2) + 0.5) / 400
    theta = torch.tensor([0.0, 0.3, math.pi / 4, 1.2, math.pi / 2, 2.0, 3.0], dtype=torch.float64)
    q = _uniform_projection_quantiles(theta, 10).numpy()
    for th, row in zip(theta.numpy(), q):
        proj = np.sort(g @ np.array([np.cos(th), np.sin(th)]))
        emp = proj[((np.arange(10) + 0.5) / 10 * len(proj)).astype(int)]
        np.testing.assert_allclose(row, emp, atol=3e-3)
    # a k x k grid of cell centres is close to uniform; a clump is far
    k = 16
    grid = torch.tensor((np.stack(np.meshgrid(np.arange(k), np.arange(k)), -1).reshape(1, -1, 2)
                         + 0.5) / k)
    assert sliced_ot_uniform(grid)[0] < 1e-4 < sliced_ot_uniform(grid * 0.5)[0]


def test_decode_torch_matches_the_runtime():
    from diffsampler_rt.grid import decode
    g = np.random.default_rng(1).normal(size=(2, 2, 8, 8))
    for strat in (False, True):
        np.testing.assert_allclose(decode_torch(torch.tensor(g), 2.0, strat).numpy(),
                                   decode(g / 2.0, stratified=strat), atol=1e-12)


class GaussianDenoiser(torch.nn.Module):
    """The exact eps-predictor for offsets ~ N(0, s^2): a smooth stand-in for a trained net
    (an untrained U-Net's predictions throw most points onto the clamped border)."""

    def __init__(self, schedule, s=0.4):
        super().__init__()
        from diffsampler_rt.schedule import alphas_cumprod
        self.register_buffer("ab", torch.tensor(alphas_cumprod(schedule), dtype=torch.float32))
        self.s = s

    def forward(self, x, t):
        ab = self.ab[t.long()].view(-1, 1, 1, 1)
        return (1 - ab).sqrt() * x / (ab * self.s**2 + 1 - ab)


@pytest.fixture(scope="module")
def net():
    cfg = tiny_config()
    return GaussianDenoiser(cfg.schedule), cfg


def test_runs_with_a_unet():
    torch.manual_seed(0)
    cfg = tiny_config()
    res = optimise_noise(UNet(cfg.unet), schedule=cfg.schedule, offset_scale=2.0,
                         embedding="stratified", n=64, count=1, steps=3, iterations=2)
    assert res.points.shape == (1, 64, 2) and len(res.trajectory) == 3


def _run(net, **kw):
    unet, cfg = net
    args = dict(schedule=cfg.schedule, offset_scale=cfg.data.offset_scale,
                embedding="ot", n=64, count=2, steps=4, iterations=15, lr=0.1, seed=3)
    args.update(kw)
    return optimise_noise(unet, **args)


def test_optimisation_lowers_the_objective_and_is_reproducible(net):
    res = _run(net)
    first, last = res.trajectory[0]["mean"], res.trajectory[-1]["mean"]
    assert last < 0.7 * first
    assert res.points.shape == res.initial_points.shape == (2, 64, 2)
    assert np.isfinite(res.points).all() and (res.points >= 0).all() and (res.points < 1).all()
    np.testing.assert_allclose(l2_star(res.points) ** 2,
                               res.trajectory[-1]["per_set"], rtol=1e-9)
    again = _run(net)
    np.testing.assert_array_equal(res.points, again.points)
    # checkpointing changes memory, not the result
    np.testing.assert_allclose(_run(net, use_checkpoint=False).points, res.points, atol=1e-10)


def test_step_noise_ot_proxy_and_callables(net):
    res = _run(net, objective="ot_proxy", step_noise=True, iterations=5)
    assert len(res.trajectory) == 6 and res.trajectory[0]["objective"] == "ot_proxy"

    def spread(p):  # a user objective: pull points toward the centre
        return ((p - 0.5) ** 2).sum((-1, -2))

    res = _run(net, objective=spread, iterations=10)
    assert res.trajectory[-1]["mean"] < res.trajectory[0]["mean"]


@pytest.mark.parametrize("kw, match", [
    (dict(objective="energy"), "unknown objective 'energy'"),
    (dict(n=65), "n must be a perfect square"),
    (dict(count=0), "count must be a positive integer, got 0"),
    (dict(steps=0), r"steps must be an integer in \[1, "),
    (dict(lr=-1.0), "lr must be positive, got -1.0"),
])
def test_bad_arguments(net, kw, match):
    with pytest.raises(ValueError, match=match):
        _run(net, **kw)
