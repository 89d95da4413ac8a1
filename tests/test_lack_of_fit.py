"""The omnibus lack-of-fit test of a law's jump heights (``granbayes.stats.lack_of_fit``).

Its reference distribution is checked where it is exact: heights linear in the fitted
coordinates, fitted by least squares, normal scatter. The DataTrees are
``granbayes.testing.fake_fit``'s (SYNTHETIC), with their heights and simulated heights
replaced by such a regression.
"""

from __future__ import annotations

import json

import numpy as np
import pytest
from scipy import stats

from granbayes.stats import lack_of_fit
from granbayes.testing import fake_fit

#: The fake fit's design: 2 volume fractions x 3 commands x 2 frequencies, 3 trials.
TRIALS = 3


def _regression(dt, rng: np.random.Generator, p: int, shift_mm=None, sigma_mm: float = 2.0):
    """Heights y = X beta + noise per volume fraction (an intercept and ``p - 1``
    covariates per cell), and as simulated heights the least-squares fit of each volume
    fraction's jumps; ``shift_mm(cell index)`` added to the heights: a misfit."""
    obs = dt["observed_data"].to_dataset()
    phi = obs["phi"].values
    cell = [f"{c}|{f}" for c, f in zip(obs["command"].values, obs["freq_hz"].values, strict=True)]
    y = np.empty(phi.size)
    fit = np.empty(phi.size)
    for value in np.unique(phi):
        rows = np.flatnonzero(phi == value)
        names = sorted(set(np.array(cell)[rows]))
        x_cell = np.column_stack([np.ones(len(names)), rng.normal(size=(len(names), p - 1))])
        idx = np.array([names.index(cell[i]) for i in rows])
        design = x_cell[idx]
        truth = design @ np.array([50.0, *rng.normal(0.0, 5.0, p - 1)])
        y[rows] = truth + rng.normal(0.0, sigma_mm, rows.size)
        if shift_mm is not None:
            y[rows] += shift_mm(idx)
        beta, *_ = np.linalg.lstsq(design, y[rows], rcond=None)
        fit[rows] = design @ beta
    out = dt.copy(deep=True)
    out["observed_data"]["height_mm"].values[:] = y
    out["posterior_predictive"]["height_sim_mm"].values[:] = fit
    return out


def _with_intercept_coordinates(dt, p: int):
    """The runs' coordinates: ``p`` law coordinates per volume fraction and the scatter."""
    out = dt.copy()
    runs = json.loads(out.attrs["runs"])
    for run in runs:
        phi = run["label"].split("=")[1]
        run["coordinates"] = [*("k", "c_d", "kappa")[:p], f"sigma_mm[{phi}]"]
    out.attrs["runs"] = json.dumps(runs)
    out.attrs["parameters"] = json.dumps(["k", "c_d", "kappa"][:p])
    return out


@pytest.mark.long
def test_the_reference_distribution_is_exact_for_a_linear_law() -> None:
    """A least-squares fit of a linear law with 2 coordinates per volume fraction: the
    p-values over 400 data sets are uniform (KS p-value above 0.01) and the share below
    0.05 is 0.05 within 3 SE (0.011 each)."""
    base = _with_intercept_coordinates(fake_fit(0), 2)
    rng = np.random.default_rng(20261127)
    p_values = []
    for _ in range(400):
        res = lack_of_fit(_regression(base, rng, 2), n_null=20_000)
        p_values.append(res["p_value"])
    assert res["dof_lack"] == 2 * (6 - 2) and res["dof_pure"] == 2 * 6 * (TRIALS - 1)
    p_values = np.array(p_values)
    assert stats.kstest(p_values, "uniform").pvalue > 0.01
    assert abs(np.mean(p_values < 0.05) - 0.05) < 3 * np.sqrt(0.05 * 0.95 / 400)


def test_many_small_misfits_are_seen_together() -> None:
    """Every cell of one volume fraction off by 1.2 scatter SDs / sqrt(trials) in a
    pattern the law cannot absorb (alternating signs): no cell alone is far off, all of
    them together are (p < 0.001 in each of 20 data sets)."""
    base = _with_intercept_coordinates(fake_fit(0), 2)
    rng = np.random.default_rng(1)
    sigma = 2.0
    step = 1.2 * sigma * np.sqrt(TRIALS)

    def pattern(idx):
        return np.where(idx % 2 == 0, step, -step) * np.where(idx < 3, 1.0, -1.0)

    for _ in range(20):
        res = lack_of_fit(_regression(base, rng, 2, pattern, sigma), n_null=20_000)
        assert res["p_value"] < 1e-3


def test_shared_coordinates_are_spread_over_the_cells() -> None:
    """A quadratic law's one run: its law coordinates are counted once, shared by the
    volume fractions in proportion to their cells; the scatter's are not counted."""
    dt = fake_fit(0).copy()
    dt.attrs["runs"] = json.dumps(
        [
            {
                "label": "all",
                "coordinates": ["k:c0", "k:c1", "k:c2", "c_d:c0", "c_d:c1", "c_d:c2", "sigma_mm"],
            }
        ]
    )
    table = lack_of_fit(dt, n_null=1000)["by_phi"]
    assert table["coordinates"].tolist() == [3.0, 3.0]
    assert table["dof_lack"].tolist() == [3.0, 3.0]


def test_without_repeats_there_is_no_pure_error() -> None:
    dt = fake_fit(0, trials=1)
    res = lack_of_fit(dt, n_null=1000)
    assert np.isnan(res["p_value"]) and res["dof_pure"] == 0.0


@pytest.mark.parametrize("seed", [0, 1])
def test_the_monte_carlo_tail_is_seeded(seed: int) -> None:
    dt = fake_fit(seed)
    assert lack_of_fit(dt, n_null=5000)["p_value"] == lack_of_fit(dt, n_null=5000)["p_value"]
