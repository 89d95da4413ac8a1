"""The paired ELPD difference and its SE, pooled over units or stratified by kind.

``diagnose`` adds a term when its ELPD gain exceeds the rule's margin and 2 SE. With jump
heights alone the SE is the usual ``sqrt(n var(d))``. With tracked jumps (hundreds of
frames each) or intrusion tests beside the heights, the units' differences come from
populations of very different means, and the pooled SE counts that difference in kind as
sampling error: measured in the power study of tracked designs, ``diagnose`` gained 4,268 +-
2,431 nats from the true drag and did not add it (4,268 +- 2,162 stratified: that case's
evidence sits in one or two tracked jumps, README). The stratified SE is the standard error of
a stratified sum (the design fixes how many units of each kind it has).
"""

from __future__ import annotations

import numpy as np
import pytest

from granbayes.stats import elpd_difference, unit_kinds

#: A design like the tracked power study's: 40 jumps and 8 tracked jumps; per-unit
#: differences [nats] with these means and sds (a strong effect).
N_HEIGHTS, N_TRACKED = 40, 8
MEANS = np.r_[np.full(N_HEIGHTS, 1.0), np.full(N_TRACKED, 500.0)]
SDS = np.r_[np.full(N_HEIGHTS, 2.0), np.full(N_TRACKED, 150.0)]
STRATA = np.array(["height_mm"] * N_HEIGHTS + ["tracked_jump"] * N_TRACKED)


def test_one_kind_gives_the_pooled_se_bit_for_bit(rng: np.random.Generator) -> None:
    a, b = rng.normal(size=50), rng.normal(size=50)
    d = a - b
    pooled = (float(np.sum(d)), float(np.sqrt(d.size * np.var(d))))
    assert elpd_difference(a, b) == pooled
    assert elpd_difference(a, b, np.full(50, "height_mm")) == pooled


def test_the_stratified_se_by_hand() -> None:
    d = np.array([1.0, 3.0, 2.0, 100.0, 140.0])
    strata = np.array(["h", "h", "h", "t", "t"])
    # h: sample variance 1 (3 units); t: 800 (2 units)
    diff, se = elpd_difference(d, np.zeros(5), strata)
    assert diff == 246.0
    assert se == pytest.approx(np.sqrt(3 * 1.0 + 2 * 800.0), rel=1e-15)
    _, pooled = elpd_difference(d, np.zeros(5))
    assert pooled > 2 * se  # the kinds' different means, counted as error
    # a stratum of one unit adds no variance
    _, alone = elpd_difference(np.r_[d, 7.0], np.zeros(6), np.append(strata, "i"))
    assert alone == se
    with pytest.raises(ValueError, match="labels"):
        elpd_difference(d, np.zeros(5), strata[:4])


def test_stratified_se_covers_as_a_standard_error_and_pooled_does_not() -> None:
    """4,000 seeded replicates of the design: the stratified SE is close to the sum's true
    sd (sqrt(40 x 2^2 + 8 x 150^2) = 424.5 nats), and the sum lies within 2 SE of its mean
    in about 91% of them (the t distribution of 8 tracked units: P(|t_7| < 2) = 0.914;
    Monte Carlo SE 0.0045, tolerance 0.02), where the pooled SE is over three times the
    true sd and covers every replicate."""
    rng = np.random.default_rng(20261128)
    true_mean, true_sd = MEANS.sum(), float(np.sqrt(np.sum(SDS**2)))
    n = 4000
    d = MEANS + SDS * rng.standard_normal((n, MEANS.size))
    zeros = np.zeros(MEANS.size)
    stratified = np.array([elpd_difference(row, zeros, STRATA) for row in d])
    pooled = np.array([elpd_difference(row, zeros) for row in d])
    np.testing.assert_array_equal(stratified[:, 0], pooled[:, 0])
    assert stratified[:, 1].mean() == pytest.approx(true_sd, rel=0.05)
    assert pooled[:, 1].mean() > 3.0 * true_sd
    covered = np.abs(stratified[:, 0] - true_mean) < 2.0 * stratified[:, 1]
    assert covered.mean() == pytest.approx(0.914, abs=0.02)
    assert np.all(np.abs(pooled[:, 0] - true_mean) < 2.0 * pooled[:, 1])


def test_unit_kinds_follow_the_log_likelihood_groups_order() -> None:
    import xarray as xr

    ll = xr.Dataset(
        {
            "height_mm": (("chain", "draw", "jump"), np.zeros((1, 2, 3))),
            "tracked_jump": (("chain", "draw", "trajectory"), np.zeros((1, 2, 2))),
        }
    )
    dt = xr.DataTree.from_dict({"log_likelihood": ll})
    assert unit_kinds(dt).tolist() == ["height_mm"] * 3 + ["tracked_jump"] * 2
