"""Unit tests of the likelihood (``granbayes._likelihood``) and the priors (``granbayes._priors``).

Everything here is cheap: the log-likelihood is checked against scipy given fixed simulated
heights (no integration), and the few tests that simulate use one walker per config.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
import scipy.stats

from granbayes import Experiment, InputError, SolverSettings
from granbayes._likelihood import JumpModel, Observations
from granbayes._priors import Prior, default_priors, load_priors
from granbayes.commands import SETTINGS as SETTING_COLUMNS

EXPERIMENT = Experiment()
CONFIG_COLUMNS = ["phi", "command", *SETTING_COLUMNS]


def jumps_table(rows: list[tuple]) -> pd.DataFrame:
    """A validated-looking jumps table from ``(phi, command, height_mm, freq_hz)`` tuples."""
    table = pd.DataFrame(rows, columns=["phi", "command", "height_mm", "freq_hz"])
    table["amplitude_mm"] = 20.0
    table["delay_ms"] = 50.0
    table["settle_periods"] = 3.0
    return table


def small_table() -> pd.DataFrame:
    """Two volume fractions, two commands, two frequencies, repeated trials, shuffled.

    The heights are arbitrary: only the grouping and the noise model are exercised.
    """
    rows = [
        (0.602, "single", 40.0, 10.0),
        (0.622, "stutter", 55.0, 10.0),
        (0.602, "single", 43.5, 10.0),
        (0.602, "preload", 61.0, 12.0),
        (0.622, "stutter", 52.5, 10.0),
        (0.602, "single", 38.0, 12.0),
        (0.622, "single", 47.0, 10.0),
        (0.602, "preload", 58.0, 12.0),
    ]
    return jumps_table(rows)


@pytest.fixture(scope="module")
def obs() -> Observations:
    """Observations of :func:`small_table`."""
    return Observations.from_table(small_table())


# ----------------------------------------------------------------------------------------
# Observations
# ----------------------------------------------------------------------------------------


def test_observations_group_unique_configs(obs: Observations) -> None:
    """One config per distinct (phi, command, settings); every jump maps back to its own.

    Exact comparison: grouping is pure bookkeeping, no arithmetic.
    """
    table = small_table()
    expected = table[CONFIG_COLUMNS].drop_duplicates()
    assert len(obs.configs) == len(expected) == 5
    assert not obs.configs.duplicated().any()
    assert list(obs.configs.columns) == CONFIG_COLUMNS
    assert obs.config_of_obs.shape == (len(table),)
    assert obs.config_of_obs.dtype == np.int64
    mapped = obs.configs.iloc[obs.config_of_obs].reset_index(drop=True)
    pd.testing.assert_frame_equal(mapped, table[CONFIG_COLUMNS].reset_index(drop=True))
    assert len(obs.programs) == len(obs.configs)
    for program, command in zip(obs.programs, obs.configs["command"], strict=True):
        assert program.name == command
    # frequency is part of the config: the two 'single' frequencies at 0.602 are separate
    single = obs.configs[(obs.configs["phi"] == 0.602) & (obs.configs["command"] == "single")]
    assert sorted(single["freq_hz"]) == [10.0, 12.0]
    np.testing.assert_array_equal(obs.phis, [0.602, 0.622])
    np.testing.assert_array_equal(obs.height_mm, table["height_mm"].to_numpy())
    assert obs.n_obs == len(table)


def test_observations_settings_distinguish_configs() -> None:
    """A row differing only in ``delay_ms`` is its own config, with its own program."""
    table = jumps_table([(0.612, "delayed_stutter", 90.0, 10.0)] * 3)
    table.loc[2, "delay_ms"] = 80.0
    o = Observations.from_table(table)
    assert len(o.configs) == 2
    assert o.config_of_obs[0] == o.config_of_obs[1] != o.config_of_obs[2]
    assert o.programs[0] != o.programs[1]


def test_observations_subset(obs: Observations) -> None:
    """``subset`` regroups only the selected jumps (configs of other phis disappear)."""
    sub = obs.subset(obs.table["phi"] == 0.622)
    assert sub.n_obs == 3
    np.testing.assert_array_equal(sub.phis, [0.622])
    assert len(sub.configs) == 2


# ----------------------------------------------------------------------------------------
# Noise model against scipy
# ----------------------------------------------------------------------------------------


def _heights_and_u(model: JumpModel, rng: np.random.Generator, n: int = 4):
    """Random simulated heights per config and walker positions inside the prior."""
    heights = rng.uniform(30.0, 70.0, size=(n, len(model.obs.configs)))
    u = model.sample_prior(rng, n)
    return heights, u


@pytest.mark.parametrize("noise", ["normal", "student_t"])
def test_log_likelihood_matches_scipy(
    obs: Observations, noise: str, rng: np.random.Generator
) -> None:
    """Pointwise log-likelihood equals scipy's logpdf with the per-phi sigma (rtol 1e-12).

    Both compute the same closed form in double precision, so only rounding differs.
    Student-t: ``nu`` degrees of freedom, location the simulated height, scale sigma.
    """
    nu = 3.5
    model = JumpModel(obs, EXPERIMENT, ["depth"], noise=noise, nu=nu)
    heights, u = _heights_and_u(model, rng)
    ll = model.log_likelihood(u, heights)
    assert ll.shape == (len(u), obs.n_obs)
    sig_cols = [model.coordinate_names.index(f"sigma_mm[{phi:g}]") for phi in obs.table["phi"]]
    sigma = np.exp(u[:, sig_cols])  # sigma_mm is log-uniform: sampled in log space
    mean = heights[:, obs.config_of_obs]
    y = obs.height_mm[None, :]
    if noise == "normal":
        expected = scipy.stats.norm.logpdf(y, loc=mean, scale=sigma)
    else:
        expected = scipy.stats.t.logpdf(y, df=nu, loc=mean, scale=sigma)
    np.testing.assert_allclose(ll, expected, rtol=1e-12, atol=0)


def test_log_likelihood_global_sigma(obs: Observations, rng: np.random.Generator) -> None:
    """With ``sigma_mode="global"`` one scatter applies to every jump (rtol 1e-12)."""
    model = JumpModel(obs, EXPERIMENT, ["depth"], phi_mode="quadratic", sigma_mode="global")
    assert model.coordinate_names[-1] == "sigma_mm"
    heights, u = _heights_and_u(model, rng)
    sigma = np.exp(u[:, -1:])
    expected = scipy.stats.norm.logpdf(
        obs.height_mm[None, :], loc=heights[:, obs.config_of_obs], scale=sigma
    )
    np.testing.assert_allclose(model.log_likelihood(u, heights), expected, rtol=1e-12, atol=0)


def test_call_is_prior_plus_summed_likelihood(obs: Observations, rng: np.random.Generator) -> None:
    """``model(u)`` returns log prior + the sum of the pointwise terms of ``predict``.

    Same arithmetic on the same simulated heights, so rtol 1e-12.
    """
    model = JumpModel(obs, EXPERIMENT, ["depth", "drag"])
    u = model.sample_prior(rng, 3)
    lp, ll = model(u)
    heights, ok = model.predict(u)
    assert ok.all()
    expected_ll = model.log_likelihood(u, heights)
    np.testing.assert_allclose(ll, expected_ll, rtol=1e-12)
    np.testing.assert_allclose(lp, model.log_prior(u) + expected_ll.sum(axis=1), rtol=1e-12)


# ----------------------------------------------------------------------------------------
# Walkers that must get -inf (and never raise)
# ----------------------------------------------------------------------------------------


def test_outside_prior_gives_minus_inf_row(obs: Observations, rng: np.random.Generator) -> None:
    """Walkers outside the prior bounds (or NaN) get ``-inf`` and a full ``-inf`` row.

    The walker inside the prior in the same batch is unaffected (finite everywhere).
    """
    model = JumpModel(obs, EXPERIMENT, ["depth", "drag"])
    good = model.sample_prior(rng, 1)[0]
    names = model.coordinate_names
    walkers = np.tile(good, (5, 1))
    walkers[1, names.index("k")] = math.log(1e6)  # above k's upper bound 5e4 N/m
    walkers[2, names.index("c_d")] = -1.0  # drag coefficient below 0
    walkers[3, names.index("sigma_mm[0.622]")] = math.log(100.0)  # above 30 mm
    walkers[4, names.index("k")] = np.nan
    lp, ll = model(walkers)
    assert lp.shape == (5,)
    assert ll.shape == (5, obs.n_obs)
    assert np.isfinite(lp[0])
    assert np.all(np.isfinite(ll[0]))
    assert np.all(lp[1:] == -np.inf)
    assert np.all(ll[1:] == -np.inf)


def test_simulation_failure_gives_minus_inf(obs: Observations, rng: np.random.Generator) -> None:
    """A step budget of 20 makes every jump fail: ``-inf`` log-prob and rows, no exception."""
    model = JumpModel(obs, EXPERIMENT, ["depth"], settings=SolverSettings(max_steps=20))
    u = model.sample_prior(rng, 3)
    assert np.all(np.isfinite(model.log_prior(u)))
    _, ok = model.predict(u)
    assert not ok.any()
    lp, ll = model(u)
    assert np.all(lp == -np.inf)
    assert np.all(ll == -np.inf)


# ----------------------------------------------------------------------------------------
# Priors in sampling coordinates
# ----------------------------------------------------------------------------------------


def test_log_prior_includes_log_transform() -> None:
    """The prior density is expressed in sampling coordinates (``log`` for log-uniform,
    ``sqrt`` for a uniform prior from zero).

    A log-uniform prior on ``[a, b]`` is uniform in ``u = log(value)``: density
    ``1 / (log b - log a)`` everywhere inside, bounds included, ``-inf`` just outside;
    the uniform ``c_d`` on ``[0, 300]`` sampled in ``u = sqrt(c_d)`` has density
    ``2 u / 300``. Closed forms, so rtol 1e-12.
    """
    obs = Observations.from_table(jumps_table([(0.612, "single", 50.0, 10.0)]))
    model = JumpModel(obs, EXPERIMENT, ["depth", "drag"])
    assert model.coordinate_names == ["k", "c_d", "sigma_mm[0.612]"]
    lk = -math.log(math.log(5e4) - math.log(200.0))
    lsig = -math.log(math.log(30.0) - math.log(0.3))
    lcd = math.log(2.0 * 3.0 / 300.0)  # at u = sqrt(c_d) = 3
    log_k = np.array([math.log(200.0), math.log(1000.0), math.log(2e4), math.log(5e4)])
    u = np.column_stack([log_k, np.full(4, 3.0), np.full(4, math.log(3.0))])
    np.testing.assert_allclose(model.log_prior(u), lk + lcd + lsig, rtol=1e-12)
    # just outside each bound, in sampling coordinates
    eps = 1e-9
    outside = np.array(
        [
            [math.log(200.0) - eps, 3.0, 0.0],
            [math.log(5e4) + eps, 3.0, 0.0],
            [math.log(1000.0), -eps, 0.0],
            [math.log(1000.0), math.sqrt(300.0) + eps, 0.0],
            [math.log(1000.0), 3.0, math.log(0.3) - eps],
            [math.log(1000.0), 3.0, math.log(30.0) + eps],
        ]
    )
    assert np.all(model.log_prior(outside) == -np.inf)
    # both densities integrate to one over their sampling coordinate
    for name in ("k", "c_d"):
        prior = model.priors[name]
        grid = np.linspace(*prior.bounds_u, 2001)
        assert np.trapezoid(np.exp(prior.logpdf_u(grid)), grid) == pytest.approx(1.0, rel=1e-6)
    # the value of u = sqrt(c_d) is its square
    np.testing.assert_allclose(model.priors["c_d"].to_value(np.array([3.0])), [9.0])


def test_prior_sampling_stays_inside(rng: np.random.Generator) -> None:
    """Draws of every default prior lie inside its bounds (in sampling coordinates)."""
    for name, prior in default_priors().items():
        u = prior.sample_u(rng, 200)
        lo, hi = prior.bounds_u
        assert np.all((u >= lo) & (u <= hi)), name
        assert np.all(np.isfinite(prior.logpdf_u(u))), name
    truncated = Prior("lognormal", 100.0, 1e4, mu=math.log(3000.0), sigma=2.0)
    u = truncated.sample_u(rng, 500)
    assert np.all((u >= math.log(100.0)) & (u <= math.log(1e4)))


# ----------------------------------------------------------------------------------------
# Quadratic phi mode
# ----------------------------------------------------------------------------------------


@pytest.fixture(scope="module")
def quadratic_model(obs: Observations) -> JumpModel:
    """Depth + drag as quadratics in ``phi - phi_c`` over phis 0.602 and 0.622."""
    return JumpModel(obs, EXPERIMENT, ["depth", "drag"], phi_mode="quadratic")


def test_quadratic_value_at_phi_c(quadratic_model: JumpModel, rng: np.random.Generator) -> None:
    """At ``phi_c`` only the ``c0`` coefficient counts: ``k = exp(c0)``, ``c_d = c0^2``.

    ``x = 0`` makes the c1 and c2 terms exactly zero, so rtol 1e-12.
    """
    m = quadratic_model
    assert m.coordinate_names == [
        "k:c0",
        "k:c1",
        "k:c2",
        "c_d:c0",
        "c_d:c1",
        "c_d:c2",
        "sigma_mm[0.602]",
        "sigma_mm[0.622]",
    ]
    u = m.sample_prior(rng, 5)
    vals = m.parameter_values(u, np.array([EXPERIMENT.phi_c]))
    np.testing.assert_allclose(vals["k"][:, 0], np.exp(u[:, 0]), rtol=1e-12)
    np.testing.assert_allclose(vals["c_d"][:, 0], u[:, 3] ** 2, rtol=1e-12)
    # sigma is only defined at the fitted volume fractions
    assert np.all(np.isnan(vals["sigma_mm"]))
    at_data = m.parameter_values(u)
    np.testing.assert_allclose(at_data["sigma_mm"], np.exp(u[:, 6:8]), rtol=1e-12)
    x = m.phis - EXPERIMENT.phi_c
    log_k = u[:, 0:1] + u[:, 1:2] * x + u[:, 2:3] * x**2
    np.testing.assert_allclose(at_data["k"], np.exp(log_k), rtol=1e-12)


def test_quadratic_implied_out_of_bounds(
    quadratic_model: JumpModel, rng: np.random.Generator
) -> None:
    """Coefficients inside their own priors whose implied law leaves the bounds get -inf.

    ``k:c1 = 400`` is inside its prior (bound ``log(250) / 0.01 ~ 552``) but makes
    ``k(0.622) = 4000 e^4 ~ 2.2e5 N/m > 5e4``; a negative ``sqrt(c_d)`` at 0.602 likewise.
    """
    m = quadratic_model
    base = np.array([math.log(4000.0), 0.0, 0.0, 3.0, 0.0, 0.0, math.log(3.0), math.log(3.0)])
    assert np.isfinite(m.log_prior(base[None, :])[0])
    bad_k = base.copy()
    bad_k[1] = 400.0
    bad_cd = base.copy()
    bad_cd[4] = 500.0  # sqrt(c_d)(0.602) = 3 - 500 * 0.01 = -2: outside [0, sqrt(300)]
    walkers = np.stack([bad_k, bad_cd])
    for j in range(m.ndim):  # each coefficient alone is inside its own prior
        lo, hi = m._coords[j].prior.bounds_u
        assert np.all((walkers[:, j] >= lo) & (walkers[:, j] <= hi))
    assert np.all(m.log_prior(walkers) == -np.inf)
    lp, ll = m(walkers)
    assert np.all(lp == -np.inf)
    assert np.all(ll == -np.inf)
    starts = m.sample_prior(rng, 20)
    assert np.all(np.isfinite(m.log_prior(starts)))


# ----------------------------------------------------------------------------------------
# Prior overrides from TOML
# ----------------------------------------------------------------------------------------


def _toml(tmp_path: Path, text: str) -> Path:
    path = tmp_path / "priors.toml"
    path.write_text(text, encoding="utf-8")
    return path


def test_load_priors_overrides(tmp_path: Path) -> None:
    """Given keys replace the default; the rest of the prior and other priors are kept."""
    path = _toml(
        tmp_path,
        '[k]\ndist = "uniform"\nlower = 100\nupper = 1e4\n\n[sigma_mm]\nlower = 1.0\n'
        '\n[c_d]\ndist = "normal"\nmu = 10\nsigma = 5.0\n',
    )
    priors = load_priors(path)
    defaults = default_priors()
    assert priors["k"].dist == "uniform"
    assert (priors["k"].lower, priors["k"].upper) == (100.0, 1e4)
    assert isinstance(priors["k"].lower, float)
    assert priors["k"].unit == defaults["k"].unit
    assert priors["sigma_mm"].dist == "loguniform"
    assert (priors["sigma_mm"].lower, priors["sigma_mm"].upper) == (1.0, 30.0)
    assert (priors["c_d"].mu, priors["c_d"].sigma) == (10.0, 5.0)
    assert (priors["c_d"].lower, priors["c_d"].upper) == (0.0, 300.0)
    for name in set(defaults) - {"k", "sigma_mm", "c_d"}:
        assert priors[name] == defaults[name]
    assert default_priors()["k"] == defaults["k"]  # the defaults are not mutated
    # uniform k is sampled in value space now
    obs = Observations.from_table(jumps_table([(0.612, "single", 50.0, 10.0)]))
    model = JumpModel(obs, EXPERIMENT, ["depth"], priors=priors)
    vals = model.parameter_values(np.array([[2500.0, 0.0]]))
    assert vals["k"][0, 0] == 2500.0


@pytest.mark.parametrize(
    ("text", "column", "fragment"),
    [
        ("[kk]\nlower = 1.0\n", "kk", "unknown parameter"),
        ("[k]\nlowr = 1.0\n", "k.lowr", "unknown key"),
        ("[k]\nlower = true\n", "k.lower", "expected a number"),
        ('[k]\nupper = "big"\n', "k.upper", "expected a number"),
        ("[k]\ndist = 3\n", "k.dist", "expected a string"),
        ("[k]\nlower = 5000.0\nupper = 5000.0\n", "k", "lower < upper"),
        ("[k]\nlower = 6e4\n", "k", "lower < upper"),
        ("[k]\nlower = 0.0\n", "k", "lower > 0"),
        ('[c_d]\ndist = "loguniform"\n', "c_d", "lower > 0"),
        ('[k]\ndist = "gamma"\n', "k", "dist must be one of"),
        ('[c_d]\ndist = "normal"\n', "c_d", "mu and sigma"),
        ("k = 3\n", "k", "expected a table"),
    ],
)
def test_load_priors_errors(tmp_path: Path, text: str, column: str, fragment: str) -> None:
    """Every bad override is one InputError naming the file and the parameter or key."""
    path = _toml(tmp_path, text)
    with pytest.raises(InputError) as info:
        load_priors(path)
    err = info.value
    assert err.file == str(path)
    assert err.column == column
    assert fragment in err.message
    assert str(path) in str(err)
    assert f"'{column}'" in str(err)


@pytest.mark.parametrize(
    "values",
    ["mu = nan\nsigma = 1.0", "mu = 10.0\nsigma = -1.0", "mu = 10.0\nsigma = inf"],
    ids=["mu-nan", "sigma-negative", "sigma-inf"],
)
def test_load_priors_rejects_bad_normal_parameters(tmp_path: Path, values: str) -> None:
    """A normal prior needs finite mu and finite sigma > 0.

    Accepted today: with ``mu = nan`` (or ``sigma = inf``) ``Prior.sample_u`` never
    collects a draw inside the bounds and loops forever when the fit draws its start;
    ``sigma < 0`` fails later inside numpy with a message that names no file.
    """
    path = _toml(tmp_path, f'[c_d]\ndist = "normal"\n{values}\n')
    with pytest.raises(InputError) as info:
        load_priors(path)
    assert info.value.column == "c_d"


def test_load_priors_malformed_and_missing(tmp_path: Path) -> None:
    """Malformed TOML and a missing file are InputErrors naming the file."""
    path = _toml(tmp_path, "[k\nlower = 1\n")
    with pytest.raises(InputError, match="malformed TOML") as info:
        load_priors(path)
    assert info.value.file == str(path)
    assert str(path) in str(info.value)
    missing = tmp_path / "nope.toml"
    with pytest.raises(InputError, match="no such file") as info:
        load_priors(missing)
    assert info.value.file == str(missing)


def test_prior_rejects_bad_construction() -> None:
    """Direct construction validates the same rules (non-finite bounds included)."""
    with pytest.raises(ValueError, match="finite"):
        Prior("uniform", 0.0, math.inf)
    with pytest.raises(ValueError, match="lower < upper"):
        Prior("uniform", 1.0, 0.0)
    with pytest.raises(ValueError, match="lower > 0"):
        Prior("loguniform", -1.0, 1.0)
