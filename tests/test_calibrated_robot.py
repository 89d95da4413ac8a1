"""Robot parameters known only to a calibration: sampled with the calibration as prior.

Data here are SYNTHETIC (the test kit's oracle, :func:`granbayes.testing.synthetic_jumps`).
The identities: a sampled robot parameter at value ``v`` is the fixed-robot model of a
robot whose parameter is ``v``, bit for bit; a stroke factor ``s`` is the program of the
stroke ``s A``, bit for bit; a fit without uncertainties is the fit it was before they
existed, bit for bit.
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pandas as pd
import pytest

from granbayes import COMMAND_NAMES, Experiment, build_command
from granbayes._experiment import load_experiment
from granbayes._fitting import FitSettings, fit, part_models
from granbayes._likelihood import JumpModel, Observations
from granbayes._prediction import predict
from granbayes._priors import Prior, calibration_priors, default_priors
from granbayes._sampler import SamplerSettings
from granbayes._saved import load_fit
from granbayes._sbc import draw_replicate
from granbayes._simulator import build_rows, simulate_frames_rows, simulate_rows
from granbayes._synthetic import write_experiment
from granbayes.report import write_fit_report
from granbayes.testing import synthetic_jumps

TINY = SamplerSettings(n_walkers=8, n_ensembles=2, check_every=50, max_steps=100, n_draws=30)


def test_calibration_priors_are_normal_about_the_nominal_values() -> None:
    priors = calibration_priors(
        {"k_spring": 5760.0, "m_motor": 1.0, "amplitude_mm": 20.0},
        {"k_spring": 150.0, "m_motor": 0.0, "amplitude_mm": 0.5},
    )
    assert set(priors) == {"k_spring", "amplitude_mm"}  # sd 0: known exactly, not sampled
    k = priors["k_spring"]
    assert (k.dist, k.mu, k.sigma, k.unit) == ("normal", 5760.0, 150.0, "N/m")
    assert (k.lower, k.upper) == (5760.0 - 900.0, 5760.0 + 900.0)
    # a wide calibration stays positive
    wide = calibration_priors({"m_foot": 0.1}, {"m_foot": 0.05})["m_foot"]
    assert wide.lower > 0.0


@pytest.mark.parametrize(
    ("sd", "fragment"),
    [
        ({"k": 100.0}, "not a robot parameter"),
        ({"freq_hz": 0.1}, "not a robot parameter"),
        ({"k_spring": -1.0}, "finite and >= 0"),
        ({"k_spring": float("nan")}, "finite and >= 0"),
    ],
)
def test_bad_calibrations_are_refused(sd: dict, fragment: str) -> None:
    with pytest.raises(ValueError, match=fragment):
        calibration_priors({"k_spring": 5760.0, "k": 1.0, "freq_hz": 10.0}, sd)


@pytest.mark.parametrize("command", COMMAND_NAMES)
def test_a_stroke_factor_is_the_program_of_that_stroke(command: str) -> None:
    """Every waveform is proportional to the stroke: ``s`` times A's program is s A's."""
    exp = Experiment()
    true = dataclasses.replace(exp.command, amplitude_mm=exp.command.amplitude_mm * 0.97)
    rows = build_rows(exp.robot, [0.59, 0.612, 0.63], {"k": 3000.0, "c_d": 20.0})
    scale = np.full(3, 0.97)
    want = simulate_rows(rows, [build_command(command, true)])
    got = simulate_rows(rows, [build_command(command, exp.command)], amplitude_scale=scale)
    np.testing.assert_array_equal(got.height_mm, want.height_mm)
    times = np.linspace(-0.01, 0.4, 30)
    want_f = simulate_frames_rows(rows, [build_command(command, true)], None, times)
    got_f = simulate_frames_rows(
        rows, [build_command(command, exp.command)], None, times, amplitude_scale=scale
    )
    np.testing.assert_array_equal(got_f.frames_flat, want_f.frames_flat)
    with pytest.raises(ValueError, match="amplitude_scale"):
        simulate_rows(rows, [build_command(command)], amplitude_scale=np.ones(2))


@pytest.fixture(scope="module")
def table():
    return synthetic_jumps(
        {"k": 3000.0, "c_d": 20.0},
        2.0,
        seed=3,
        phis=(0.602, 0.622),
        trials=2,
        settings_columns=True,
    )


def test_a_sampled_robot_parameter_is_the_robot_it_names(table) -> None:
    """Walker value v of ``k_spring``/``m_motor``/``amplitude_mm`` = the robot with v."""
    exp = Experiment()
    calibrated = calibration_priors(
        {"k_spring": exp.robot.k_spring, "m_motor": exp.robot.m_motor, "amplitude_mm": 20.0},
        {"k_spring": 150.0, "m_motor": 0.02, "amplitude_mm": 0.5},
    )
    model = JumpModel(Observations.from_table(table), exp, ("depth", "drag"), calibrated=calibrated)
    names = model.coordinate_names
    assert names[: model.n_law] == ["k", "c_d"]
    assert names[model.n_law : model.n_law + 3] == ["k_spring", "m_motor", "amplitude_mm"]
    true = {"k_spring": 5900.0, "m_motor": 1.03, "amplitude_mm": 19.5}
    u = np.zeros((2, model.ndim))
    u[:, :2] = [[np.log(3000.0), np.sqrt(20.0)], [np.log(2500.0), np.sqrt(30.0)]]
    for name, value in true.items():
        u[:, names.index(name)] = value
    u[:, model.n_law + 3 :] = np.log(2.0)  # the scatter
    lp, ll = model(u)
    assert np.all(np.isfinite(lp))

    robot = dataclasses.replace(exp.robot, k_spring=5900.0, m_motor=1.03)
    fixed_exp = dataclasses.replace(exp, robot=robot)
    fixed_table = table.assign(amplitude_mm=19.5)
    fixed = JumpModel(Observations.from_table(fixed_table), fixed_exp, ("depth", "drag"))
    keep = [i for i, n in enumerate(names) if n not in true]
    lp_fixed, ll_fixed = fixed(u[:, keep])
    np.testing.assert_array_equal(ll, ll_fixed)
    # the calibration's prior is the only difference of the log-posteriors
    prior = sum(calibrated[n].logpdf_u(u[:, names.index(n)]) for n in true)
    np.testing.assert_allclose(lp - lp_fixed, prior, rtol=1e-12)
    values = model.parameter_values(u)
    np.testing.assert_array_equal(values["k_spring"], np.full((2, 2), 5900.0))


def test_unknown_calibrated_keys_are_refused(table) -> None:
    with pytest.raises(ValueError, match="calibrated parameters"):
        JumpModel(
            Observations.from_table(table),
            Experiment(),
            ("depth",),
            calibrated={"k": Prior("normal", 1.0, 3.0, mu=2.0, sigma=0.5)},
        )


def _folder(tmp_path, table, uncertainty: str):
    write_experiment(tmp_path, table, Experiment())
    toml = tmp_path / "experiment.toml"
    toml.write_text(toml.read_text() + uncertainty)
    return load_experiment(tmp_path)


def test_a_robot_known_exactly_gives_the_same_fit_bit_for_bit(tmp_path, table) -> None:
    """No uncertainty, sd 0 and ``calibration="nominal"`` are the fixed-robot fit."""
    config = FitSettings(terms=("depth",), sampler=TINY, n_threads=1, n_prior_draws=0)
    plain = fit(Experiment(), table, config, seed=4).datatree["posterior"]
    exact = _folder(tmp_path / "a", table, "\n[robot.uncertainty]\nk_spring = 0.0\n")
    for experiment, cfg in (
        (exact, config),
        (
            _folder(tmp_path / "b", table, "\n[robot.uncertainty]\nk_spring = 150.0\n"),
            dataclasses.replace(config, calibration="nominal"),
        ),
    ):
        other = fit(experiment, table, cfg, seed=4).datatree["posterior"]
        assert set(other.data_vars) == set(plain.data_vars)
        for name in plain.data_vars:
            np.testing.assert_array_equal(other[name].values, plain[name].values)


def test_a_calibrated_fit_reports_the_robot_parameters(tmp_path, table) -> None:
    exp = _folder(tmp_path, table, "\n[robot.uncertainty]\nk_spring = 150.0\namplitude_mm = 0.5\n")
    config = FitSettings(terms=("depth",), sampler=TINY, n_threads=1, n_prior_draws=20)
    res = fit(exp, table, config, seed=5)
    post = res.datatree["posterior"]
    assert post["k_spring"].dims == ("chain", "draw", "phi")
    assert post["k_spring"].attrs.get("units", "N/m") == "N/m"
    assert np.all(np.isfinite(post["amplitude_mm"].values))
    # the prior group draws them from their calibration
    prior = res.datatree["prior"]
    assert abs(float(prior["k_spring"].mean()) - exp.robot.k_spring) < 3 * 150.0
    ((_, model, _), *_) = part_models(exp, table, config, default_priors())
    assert "k_spring" in model.calibrated
    assert not any("k_spring" in w for w in res.warnings)  # sampled, not taken as exact
    # the report lists them, with what the jumps say about them against their calibration
    out = tmp_path / "report"
    out.mkdir()
    write_fit_report(res.datatree, out, diagnostics_plots=False)
    summary = (out / "summary.md").read_text()
    assert "k_spring" in summary and "amplitude_mm" in summary
    ident = pd.read_csv(out / "identifiability.csv")
    assert {"k_spring", "amplitude_mm"} <= set(ident["parameter"])
    # a saved fit keeps the calibration, so its models (and predictions) sample the robot
    saved = load_fit(out / "posterior.nc")
    assert saved.experiment.uncertainty == exp.uncertainty
    assert "k_spring" in saved.model(saved.labels[0]).coordinate_names
    pred = predict(saved, "single", 0.602, n_draws=20, rng=1)
    assert np.all(np.isfinite(pred.height_sim_mm))


def test_sbc_draws_the_robot_from_its_calibration_whatever_the_fit_does(table) -> None:
    """The replicate's robot is drawn; ``calibration`` says only how the fit treats it.

    One robot per volume fraction, as per-volume-fraction runs model it; one for all when
    the fit pools it.
    """
    exp = dataclasses.replace(Experiment(), calibration_sd=(("k_spring", 150.0),))
    design = table.drop(columns=["source"], errors="ignore")
    got = {}
    for mode in ("sample", "nominal", "pool"):
        config = FitSettings(terms=("depth",), calibration=mode)
        heights, truths = draw_replicate(
            exp, design, config, default_priors(), np.random.default_rng(7)
        )
        got[mode] = (heights["height_mm"].to_numpy(), truths)
    np.testing.assert_array_equal(got["sample"][0], got["nominal"][0])
    for truth in got["nominal"][1].values():
        assert truth["k_spring"] != exp.robot.k_spring
        assert abs(truth["k_spring"] - exp.robot.k_spring) < 6 * 150.0
    robots = {mode: {t["k_spring"] for t in truths.values()} for mode, (_, truths) in got.items()}
    assert len(robots["sample"]) == 2 and len(robots["pool"]) == 1


def test_what_is_not_sampled_is_said_to_be_taken_as_exact() -> None:
    from granbayes._fitting import _warnings

    exp = dataclasses.replace(
        Experiment(), calibration_sd=(("k_spring", 150.0), ("freq_hz", 0.1)), phi_sd=0.002
    )
    sampled = " ".join(_warnings([], FitSettings(), exp))
    assert "freq_hz" in sampled and "phi_sd = 0.002" in sampled and "k_spring" not in sampled
    nominal = " ".join(_warnings([], FitSettings(calibration="nominal"), exp))
    assert "k_spring, freq_hz" in nominal
    assert _warnings([], FitSettings(), Experiment()) == []


def test_one_set_of_calibrated_keys() -> None:
    """The model's sampled keys, the priors' units and the experiment's values agree."""
    from granbayes._likelihood import CALIBRATED_KEYS
    from granbayes._priors import CALIBRATION_UNITS

    assert set(CALIBRATION_UNITS) == set(CALIBRATED_KEYS) == set(Experiment().robot_values)


# ----------------------------------------------------------------------------------------
# A robot pooled across volume fractions (calibration="pool")
# ----------------------------------------------------------------------------------------
def _calibration() -> dict[str, Prior]:
    exp = Experiment()
    return calibration_priors(
        {"k_spring": exp.robot.k_spring, "amplitude_mm": 20.0},
        {"k_spring": 150.0, "amplitude_mm": 0.5},
    )


def test_a_pooled_robot_is_every_volume_fraction_s_model_with_one_robot(table) -> None:
    """log p_pool(theta_1, theta_2, r) = sum_p log p_p(theta_p, r) - (P - 1) log p(r).

    The pooled model's pointwise log-likelihood is each volume fraction's own model's at
    the same robot, bit for bit (the same rows reach the simulator).
    """
    exp, calibrated = Experiment(), _calibration()
    obs = Observations.from_table(table)
    pooled = JumpModel(obs, exp, ("depth", "drag"), phi_mode="per_phi_joint", calibrated=calibrated)
    names = pooled.coordinate_names
    assert names[: pooled.n_law] == ["k[0.602]", "k[0.622]", "c_d[0.602]", "c_d[0.622]"]
    rng = np.random.default_rng(11)
    u = pooled.sample_prior(rng, 6)
    lp, ll = pooled(u)
    assert np.all(np.isfinite(lp))
    robot = [names.index("k_spring"), names.index("amplitude_mm")]
    prior_r = sum(calibrated[n].logpdf_u(u[:, names.index(n)]) for n in calibrated)
    total = np.zeros(len(u))
    for phi in (0.602, 0.622):
        sub = table[table["phi"] == phi]
        own = JumpModel(Observations.from_table(sub), exp, ("depth", "drag"), calibrated=calibrated)
        cols = [names.index(f"k[{phi:g}]"), names.index(f"c_d[{phi:g}]"), *robot]
        cols.append(names.index(f"sigma_mm[{phi:g}]"))
        assert own.coordinate_names == [
            "k",
            "c_d",
            "k_spring",
            "amplitude_mm",
            "sigma_mm[" + f"{phi:g}]",
        ]
        lp_own, ll_own = own(u[:, cols])
        np.testing.assert_array_equal(ll[:, np.flatnonzero(table["phi"] == phi)], ll_own)
        total += lp_own
    np.testing.assert_allclose(lp, total - prior_r, rtol=1e-12)
    # its law exists at its volume fractions only
    values = pooled.law_values(u, np.array([0.602, 0.61, 0.622]))
    np.testing.assert_array_equal(values["k"][:, 0], np.exp(u[:, names.index("k[0.602]")]))
    assert np.all(np.isnan(values["k"][:, 1]))


def test_pooling_a_robot_known_exactly_is_the_per_phi_fit_bit_for_bit(tmp_path, table) -> None:
    config = FitSettings(terms=("depth",), sampler=TINY, n_threads=1, n_prior_draws=0)
    plain = fit(Experiment(), table, config, seed=4).datatree["posterior"]
    pooled = fit(
        Experiment(), table, dataclasses.replace(config, calibration="pool"), seed=4
    ).datatree["posterior"]
    for name in plain.data_vars:
        np.testing.assert_array_equal(pooled[name].values, plain[name].values)


def test_a_pooled_fit_has_one_robot_for_every_volume_fraction(tmp_path, table) -> None:
    import arviz_stats as azs

    from granbayes._criticism import DiagnoseSettings
    from granbayes._fitting import compare_commands, screen
    from granbayes.stats import by_ensemble, summary_table

    exp = _folder(tmp_path, table, "\n[robot.uncertainty]\nk_spring = 150.0\namplitude_mm = 0.5\n")
    config = FitSettings(terms=("depth",), sampler=TINY, n_threads=1, calibration="pool")
    res = fit(exp, table, config, seed=5)
    assert [p.label for p in res.parts] == ["all"]
    post = res.datatree["posterior"]
    k_spring = post["k_spring"].values
    np.testing.assert_array_equal(k_spring[..., 0], k_spring[..., 1])  # one robot
    assert not np.array_equal(post["k"].values[..., 0], post["k"].values[..., 1])
    # the summary's R-hat is across ensembles, not over walkers as chains
    rhat = summary_table(res.datatree)["r_hat"]
    across = azs.rhat(by_ensemble(res.datatree))
    assert rhat["k[0.622]"] == pytest.approx(float(across["k"].sel(phi=0.622)), abs=1e-12)
    assert rhat["k_spring[0.602]"] == pytest.approx(float(across["k_spring"][0]), abs=1e-12)
    walkers = summary_table(_without_runs(res.datatree))["r_hat"]  # ArviZ's, per walker
    assert walkers["k[0.622]"] != rhat["k[0.622]"]
    # saved and read back: predictions at either volume fraction use the one run
    out = tmp_path / "report"
    out.mkdir()
    write_fit_report(res.datatree, out, diagnostics_plots=False)
    saved = load_fit(out / "posterior.nc")
    assert saved.runs_of(np.array([0.602, 0.622])) == ["all", "all"]
    pred = predict(saved, "single", 0.622, n_draws=20, rng=1)
    assert np.all(np.isfinite(pred.height_sim_mm))
    # what works per volume fraction refuses it, naming why
    with pytest.raises(ValueError, match="one run per volume fraction"):
        compare_commands(exp, table, res)
    with pytest.raises(ValueError, match="pool"):
        screen(exp, table, dataclasses.replace(config, terms=("depth", "drag")), res.datatree)
    with pytest.raises(ValueError, match="own copy of the robot"):
        DiagnoseSettings(calibration="pool")


def _without_runs(dt):
    """The DataTree without its ``runs`` record (ArviZ's R-hat over walkers as chains)."""
    out = dt.copy()
    out.attrs = {k: v for k, v in dt.attrs.items() if k != "runs"}
    return out
