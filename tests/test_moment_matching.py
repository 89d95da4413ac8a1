"""Batched moment matching against ArviZ's ``loo_moment_match`` on an analytic model.

The model is a normal likelihood with unknown mean and log-scale (flat priors), fitted to
20 points of which two are outliers: their Pareto k exceed ``good_k`` with 2,000 draws.
The draws are independent (exact posterior sampling: Student-t mean, scaled inverse
chi-square variance), so ``r_eff = 1`` is right for both implementations.
"""

from __future__ import annotations

import warnings

import numpy as np
import pytest
import xarray as xr
from arviz_stats import loo, loo_moment_match

from granbayes.stats import moment_match

Y = np.array([0.3, -0.8, 1.1, 0.2, -0.4, 0.9, -1.3, 0.5, 0.1, -0.2,
              0.7, -0.6, 0.4, -1.0, 0.0, 0.8, -0.3, 0.6, 12.0, -11.0])  # fmt: skip
N_CHAIN, N_DRAW = 4, 500


def log_lik(theta: np.ndarray) -> np.ndarray:
    """Pointwise log-likelihood (..., n_obs) of draws (..., 2) = (mu, log sigma)."""
    mu, log_s = theta[..., :1], theta[..., 1:]
    return -0.5 * ((Y - mu) / np.exp(log_s)) ** 2 - log_s - 0.5 * np.log(2 * np.pi)


def log_post(theta: np.ndarray) -> np.ndarray:
    """Unnormalised log posterior (flat priors on mu and log sigma)."""
    return log_lik(theta).sum(axis=-1)


@pytest.fixture(scope="module")
def posterior() -> np.ndarray:
    """Exact posterior draws (chain, draw, 2) of (mu, log sigma)."""
    rng = np.random.default_rng(7)
    n = len(Y)
    s2 = np.var(Y, ddof=1)
    sigma2 = (n - 1) * s2 / rng.chisquare(n - 1, size=(N_CHAIN, N_DRAW))
    mu = rng.normal(Y.mean(), np.sqrt(sigma2 / n))
    return np.stack([mu, 0.5 * np.log(sigma2)], axis=-1)


def test_same_elpd_and_k_as_arviz(posterior: np.ndarray) -> None:
    """Every flagged observation gets ArviZ's moment-matched ELPD and k (to 1e-8).

    ArviZ is given the same draws, densities and ``r_eff``; the batched version evaluates
    the moved draws of all flagged observations in one call per stage.
    """
    ll = log_lik(posterior)
    dt = xr.DataTree.from_dict(
        {
            "posterior": xr.Dataset(
                {
                    "mu": (("chain", "draw"), posterior[..., 0]),
                    "log_s": (("chain", "draw"), posterior[..., 1]),
                }
            ),
            "log_likelihood": xr.Dataset({"y": (("chain", "draw", "obs"), ll)}),
            "observed_data": xr.Dataset({"y": (("obs",), Y)}),
        }
    )
    with warnings.catch_warnings():  # ArviZ warns about the k values this test is about
        warnings.simplefilter("ignore", UserWarning)
        orig = loo(dt, pointwise=True, reff=1.0)
    k_orig = orig.pareto_k.values
    flagged = np.flatnonzero(k_orig > orig.good_k)
    assert len(flagged) >= 2, k_orig  # the outliers

    upars = xr.DataArray(posterior, dims=("chain", "draw", "par"))

    def lp_fn(u: xr.DataArray) -> xr.DataArray:
        return xr.DataArray(log_post(u.values), dims=("chain", "draw"))

    def ll_fn(u: xr.DataArray, i: int) -> xr.DataArray:
        return xr.DataArray(log_lik(u.values)[..., i], dims=("chain", "draw"))

    with warnings.catch_warnings():  # about what remains above good_k, if anything
        warnings.simplefilter("ignore", UserWarning)
        ref = loo_moment_match(
            dt, orig, lp_fn, ll_fn, upars=upars, reff=1.0, pointwise=True, var_name="y"
        )
    calls = []

    def evaluate(u: np.ndarray, obs: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        calls.append(len(obs))
        ll_b = log_lik(u)
        return log_post(u), ll_b[np.arange(len(obs)), :, obs]

    res = moment_match(posterior, log_post(posterior), ll, flagged, evaluate, r_eff=1.0)
    np.testing.assert_allclose(res.elpd_i, ref.elpd_i.values[flagged], rtol=0, atol=1e-8)
    np.testing.assert_allclose(res.pareto_k, ref.pareto_k.values[flagged], rtol=0, atol=1e-8)
    assert np.all(res.pareto_k <= res.original_k)
    assert np.any(res.pareto_k < res.original_k)  # it helped
    # batched: a call serves every flagged observation at its stage
    assert max(calls) == len(flagged) and res.n_evaluations == len(calls)


def test_moved_draws_outside_the_support_get_weight_zero(posterior: np.ndarray) -> None:
    """A bounded prior: draws moved out of it have density 0, silently (no NaN warning).

    With ``mu`` restricted to (-4, 4) (the draws all lie inside) the maps move some
    draws out; the result is still ArviZ's, and no warning is raised (the suite turns
    every warning into an error).
    """
    inside = np.abs(posterior[..., 0]) < 4.0
    assert inside.all()

    def bounded(theta: np.ndarray) -> np.ndarray:
        return np.where(np.abs(theta[..., 0]) < 4.0, log_post(theta), -np.inf)

    outside = []

    def evaluate(u: np.ndarray, obs: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        lp = bounded(u)
        outside.append(int(np.sum(~np.isfinite(lp))))
        ll = log_lik(u)[np.arange(len(obs)), :, obs]
        return lp, np.where(np.isfinite(lp), ll, -np.inf)

    ll = log_lik(posterior)
    flagged = [18, 19]
    res = moment_match(posterior, bounded(posterior), ll, flagged, evaluate, r_eff=1.0)
    assert sum(outside) > 0  # the case this test is about happened
    assert np.all(np.isfinite(res.elpd_i)) and np.all(res.pareto_k <= res.original_k)
