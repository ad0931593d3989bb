"""Solvers against the exact probability-flow ODE of Gaussian data (closed form)."""
import numpy as np
import pytest

from diffsampler_rt.schedule import alphas_cumprod, timesteps
from diffsampler_rt.solvers import SOLVERS, ddim, dpmpp_2m, project_x0, solve

AB = alphas_cumprod({"kind": "linear", "beta_start": 1e-4, "beta_end": 0.02, "num_steps": 1000})
S2 = 0.3**2  # data ~ N(0, S2): the optimal eps predictor is linear in x


def eps(x, t):
    return np.sqrt(1 - AB[t]) * x / (AB[t] * S2 + 1 - AB[t])


def exact(x, ts):
    """PF-ODE from ts[0] to ts[-1] (x_t / std_t is constant), then the final x0 prediction."""
    tl = ts[-1]
    xl = x * np.sqrt(AB[tl] * S2 + 1 - AB[tl]) / np.sqrt(AB[ts[0]] * S2 + 1 - AB[ts[0]])
    return (xl - np.sqrt(1 - AB[tl]) * eps(xl, tl)) / np.sqrt(AB[tl])


X = np.random.default_rng(0).standard_normal((3, 2, 6, 6))


@pytest.mark.parametrize("fn", [ddim, dpmpp_2m])
def test_solvers_converge_to_the_ode_solution(fn):
    err = [np.abs(fn(eps, X, AB, timesteps(1000, n)) - exact(X, timesteps(1000, n))).max()
           for n in (100, 200, 500)]
    assert err[0] > err[1] > err[2]
    assert err[2] < (2e-3 if fn is dpmpp_2m else 1.5e-2)


def test_second_order_beats_ddim_at_few_steps():
    for n in (10, 20, 100):
        ts = timesteps(1000, n)
        e_ddim = np.abs(ddim(eps, X, AB, ts) - exact(X, ts)).max()
        e_dpm = np.abs(dpmpp_2m(eps, X, AB, ts) - exact(X, ts)).max()
        assert e_dpm < 0.5 * e_ddim


def test_solve_dispatch():
    ts = timesteps(1000, 8)
    np.testing.assert_array_equal(solve("dpmpp_2m", eps, X, AB, ts), dpmpp_2m(eps, X, AB, ts))
    np.testing.assert_array_equal(solve("ddim", eps, X, AB, ts), ddim(eps, X, AB, ts))
    assert set(SOLVERS) == {"ddim", "ddpm", "dpmpp_2m"}
    with pytest.raises(ValueError, match="unknown solver 'euler'"):
        solve("euler", eps, X, AB, ts)
    with pytest.raises(ValueError, match="noise source"):
        solve("ddpm", eps, X, AB, ts)


def test_projection_guidance_replaces_the_clean_prediction():
    ts = timesteps(1000, 10)
    same = project_x0(eps, AB, lambda x0: x0, ts)
    np.testing.assert_allclose(same(X, int(ts[3])), eps(X, int(ts[3])), rtol=1e-10, atol=1e-12)
    target = np.full_like(X, 0.25)
    late = project_x0(eps, AB, lambda x0: target, ts[-3:])
    np.testing.assert_array_equal(late(X, int(ts[0])), eps(X, int(ts[0])))  # not guided
    for fn in (ddim, dpmpp_2m):  # guided through the last step: the output is the projection
        np.testing.assert_allclose(fn(late, X, AB, ts), target, atol=1e-9)
