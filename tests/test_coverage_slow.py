"""Frequentist calibration of the fit's credible intervals on SYNTHETIC replicates (slow)."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest

from granbayes import Experiment
from granbayes._fitting import FitSettings, fit
from granbayes._sampler import SamplerSettings
from granbayes.testing import synthetic_jumps

TRUE_K = 4000.0  # N/m, depth-only law
TRUE_SIGMA_MM = 3.0
PHI = 0.612
TRIALS = 2
N_REPLICATES = 20
MIN_COVERAGE = 0.7


def replicate_table(seed: int) -> pd.DataFrame:
    """One SYNTHETIC replicate (the test kit): the true heights (the independent oracle)
    plus seeded Gaussian noise of 3 mm, not rounded, with the command-setting columns."""
    return synthetic_jumps(
        {"k": TRUE_K},
        TRUE_SIGMA_MM,
        seed=seed,
        phis=(PHI,),
        trials=TRIALS,
        label="tests/test_coverage_slow.py",
        decimals=None,
        settings_columns=True,
    )


@pytest.mark.slow
def test_ninety_percent_intervals_cover_k() -> None:
    """Over 20 replicate data sets the 90 % interval of k covers the truth >= 70 % of the time.

    Each replicate: the depth-only law k = 4000 N/m at phi = 0.612, five commands x two
    trials, Gaussian noise with sigma = 3 mm (a new seed per replicate), fitted with k and
    sigma_mm free (four independent ensembles of 10 walkers, the default stopping rule:
    autocorrelation, R-hat across ensembles <= 1.01, bulk and tail ESS >= 400; at most 1500
    steps). If the intervals are calibrated, the
    number of hits is Binomial(20, 0.9), and P(hits < 14) = 0.0024, so the threshold
    14/20 = 0.7 fails a calibrated fit about 0.2 % of the time (the check is seeded, so
    the outcome is reproducible); it does catch intervals whose true coverage is much
    lower (P(fail) = 9 % at true coverage 0.8, > 50 % below 0.7). The sigma_mm coverage
    and convergence are reported in the failure message.
    """
    experiment = Experiment()
    config = FitSettings(
        terms=("depth",),
        sampler=SamplerSettings(
            n_walkers=10, n_ensembles=4, check_every=100, max_steps=1500, n_draws=100
        ),
        n_threads=1,
        n_prior_draws=0,  # only the posterior intervals are needed
    )
    hits_k, hits_sigma, converged = [], [], []
    for rep in range(N_REPLICATES):
        table = replicate_table(seed=1000 + rep)
        result = fit(experiment, table, config, seed=rep)
        post = result.datatree.posterior
        k_lo, k_hi = np.quantile(post["k"].values.ravel(), [0.05, 0.95])
        s_lo, s_hi = np.quantile(post["sigma_mm"].values.ravel(), [0.05, 0.95])
        hits_k.append(bool(k_lo <= TRUE_K <= k_hi))
        hits_sigma.append(bool(s_lo <= TRUE_SIGMA_MM <= s_hi))
        converged.append(result.converged)
    coverage = float(np.mean(hits_k))
    report = (
        f"k coverage {coverage:.2f}, sigma_mm coverage {np.mean(hits_sigma):.2f}, "
        f"converged {sum(converged)}/{N_REPLICATES}"
    )
    assert coverage >= MIN_COVERAGE, report
