"""A bed's volume fraction known only to its measurement (``[bed] phi_sd``), integrated out.

Data here are SYNTHETIC: the test kit's oracle lab (:func:`granbayes.testing.
synthetic_lab_data`, seed 20261127), each jump and each intrusion test on its own bed whose
true phi is drawn about the written one. The identities: without ``phi_sd`` (or with
``bed_phi="measured"``, or in ``per_phi`` mode) the model is the one before beds were
latent, bit for bit. The accuracy: every unit's integrated log-likelihood against brute-
force integration over phi (thousands of simulations or closed-form forces), with the
tolerances measured here stated beside each assertion.
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from scipy.integrate import trapezoid
from scipy.special import logsumexp

from granbayes import Experiment
from granbayes import _datatree as gdt
from granbayes._experiment import load_experiment
from granbayes._fitting import FitSettings, _make_model, _warnings, fit
from granbayes._likelihood import BedPhi, HeightBlock, IntrusionBlock, JumpModel, Observations
from granbayes._prediction import predict
from granbayes._priors import default_priors
from granbayes._sampler import SamplerSettings
from granbayes._saved import load_fit
from granbayes._simulator import intrusion_force
from granbayes.kinds import load_measurements
from granbayes.testing import LabDesign, synthetic_lab_data, write_lab_experiment

#: One module fixture (a small fit) for two of its tests, ~35 s in all: run first
#: (tests/conftest.py).
pytestmark = pytest.mark.long

PHI_SD = 0.002
TINY = SamplerSettings(
    n_walkers=8, n_ensembles=2, check_every=50, max_steps=100, n_draws=30, start="search"
)
#: The fits of the wiring tests: quadratic laws, one scatter and one force noise, tiny runs.
QUADRATIC = FitSettings(
    terms=("depth", "drag"),
    phi_mode="quadratic",
    sigma_mode="global",
    sampler=TINY,
    n_threads=1,
    n_prior_draws=0,
)
LOG_K = (np.log(4000.0), 38.0, 300.0)  # log k = c0 + c1 x + c2 x^2, x = phi - phi_c


def _truth(phi: float) -> dict[str, float]:
    x = phi - 0.612
    return {"k": float(np.exp(LOG_K[0] + LOG_K[1] * x + LOG_K[2] * x * x)), "c_d": 10.0}


@pytest.fixture(scope="module")
def lab():
    design = LabDesign(
        phis=(0.602, 0.622),
        commands=("single", "stutter", "delayed_stutter_preload"),
        trials=2,
        tracked_trials=0,
        intrusion_speeds_mm_s=(1.0, 200.0),
        depth_max_mm=20.0,
        depth_step_mm=1.0,
        phi_sd=PHI_SD,
        phi_jitter="jump",
    )
    return synthetic_lab_data(_truth, seed=20261127, design=design)


@pytest.fixture(scope="module")
def loaded(lab, tmp_path_factory):
    """The lab's folder as the fit reads it: (folder, experiment, measurements)."""
    folder = write_lab_experiment(tmp_path_factory.mktemp("lab") / "lab", lab)
    experiment = load_experiment(folder / "experiment.toml")
    return folder, experiment, load_measurements(folder, experiment)


def _u(model: JumpModel, sigma_mm: float = 1.0, force_sd_n: float = 0.3) -> np.ndarray:
    """The truth's position in a quadratic model's coordinates."""
    priors = default_priors()
    values = {
        "k:c0": LOG_K[0],
        "k:c1": LOG_K[1],
        "k:c2": LOG_K[2],
        "c_d:c0": float(priors["c_d"].to_u(np.array(10.0))),
    }
    u = np.zeros((1, model.ndim))
    for j, c in enumerate(model.coordinates):
        if c.name in values:
            u[0, j] = values[c.name]
        elif c.parameter == "sigma_mm":
            u[0, j] = c.prior.to_u(np.array(sigma_mm))
        elif c.parameter == "force_sd_N":
            u[0, j] = c.prior.to_u(np.array(force_sd_n))
    assert np.isfinite(model.log_prior(u)).all()
    return u


def test_the_integration_weights_are_a_normal_distribution() -> None:
    bed = BedPhi(PHI_SD, 9)
    x, log_w = bed.grid(8)
    w = np.exp(log_w)
    assert w.sum() == pytest.approx(1.0, abs=1e-12)
    assert (w * x).sum() == pytest.approx(0.0, abs=1e-12)
    assert (w * x * x).sum() == pytest.approx(1.0, abs=2e-3)  # the 4-sd truncation
    assert bed.nodes(np.array([0.6]))[[0, 4, 8]] == pytest.approx([0.592, 0.6, 0.608])
    # a Gaussian integrand is integrated exactly by the adaptive rule, however narrow:
    # integral exp(-(x - a)^2 / (2 s^2)) N(x) dx = s / sqrt(1 + s^2) exp(-a^2 / (2 (1 + s^2)))
    for a, s in ((0.3, 0.005), (-2.0, 0.5), (1.0, 3.0)):
        q = np.array([a * a / s**2, -2 * a / s**2, 1 / s**2])
        exact = np.log(s / np.sqrt(1 + s * s)) - a * a / (2 * (1 + s * s))
        assert bed.integrate_polynomial(q) == pytest.approx(exact, abs=1e-10)


def test_bad_beds_are_refused() -> None:
    for kwargs, fragment in (
        ({"phi_sd": -0.001}, "phi_sd"),
        ({"phi_sd": 0.002, "n_nodes": 2}, "n_nodes"),
        ({"phi_sd": 0.002, "reach_sd": 0.0}, "reach_sd"),
    ):
        with pytest.raises(ValueError, match=fragment):
            BedPhi(**kwargs)
    with pytest.raises(ValueError, match="bed_phi"):
        FitSettings(bed_phi="sampled")


def test_jump_heights_integrated_over_phi_match_brute_force(loaded) -> None:
    """Each jump's marginal log-likelihood against 281-point brute force over +/- 7 sd.

    A hard case: this law's heights move up to 5.4 mm per sd of phi against a 1 mm
    scatter, so each jump's density pins its bed's phi to a fifth of an sd, and a
    simulated height is not smooth in phi at that scale (regime switches). Tolerance 0.03
    nats per jump with the default 9 nodes (measured 0.0225 with the cubic spline; 0.077
    with piecewise-linear interpolation, 0.0252 Akima, 0.0282 PCHIP; 25 nodes 0.004;
    median 0.008). 5 nodes miss by more.
    """
    _, exp, data = loaded
    jumps = data.tables["heights"]
    obs = Observations.from_table(jumps)
    latent = JumpModel([HeightBlock(obs, bed=BedPhi(PHI_SD, 9))], exp, ["depth", "drag"],
                       phi_mode="quadratic")  # fmt: skip
    u = _u(latent)
    got = latent(u)[1][0]
    grid = np.linspace(-7.0, 7.0, 281)
    per_phi = []
    for x in grid:
        table = jumps.assign(phi=jumps["phi"] + PHI_SD * x)
        model = JumpModel(Observations.from_table(table), exp, ["depth", "drag"],
                          phi_mode="quadratic")  # fmt: skip
        per_phi.append(model(_u(model))[1][0])
    ll = np.array(per_phi)
    weight = np.exp(-0.5 * grid**2) / np.sqrt(2 * np.pi)
    brute = np.log(trapezoid(weight[:, None] * np.exp(ll), grid, axis=0))
    assert np.all(np.isfinite(got))
    assert np.max(np.abs(got - brute)) < 0.03
    # and integrating matters here: the measured-phi likelihood is off by much more
    assert np.max(np.abs(ll[len(grid) // 2] - brute)) > 0.1
    coarse = JumpModel([HeightBlock(obs, bed=BedPhi(PHI_SD, 5))], exp, ["depth", "drag"],
                       phi_mode="quadratic")  # fmt: skip
    assert np.max(np.abs(coarse(u)[1][0] - brute)) > np.max(np.abs(got - brute))


def test_intrusion_tests_integrated_over_phi_match_brute_force(loaded) -> None:
    """Each test's marginal log-likelihood against brute force on a 0.001-sd grid.

    A test's force curve pins its bed's phi to ~0.01 sd: the brute force integrates the
    closed-form force over +/- 6 sd in 12,000 steps. Tolerance 1e-3 nats per test
    (measured: 3e-4 with 9 nodes, 2e-4 with 5; the force is a least-squares quartic in phi
    through the nodes, integrated by adaptive Gauss-Hermite quadrature).
    """
    _, exp, data = loaded
    table = data.tables["intrusions"]
    block = IntrusionBlock(table, bed=BedPhi(PHI_SD, 9))
    model = JumpModel([block], exp, ["depth", "drag"], phi_mode="quadratic")
    u = _u(model)
    got = model(u)[1][0]
    grid = np.linspace(-6.0, 6.0, 12_001)
    brute = []
    for _, test in table.groupby("test", sort=False):
        phi = test["phi"].to_numpy()[0] + PHI_SD * grid[:, None]
        law = _truth(0.612)
        x = phi - 0.612
        k = np.exp(LOG_K[0] + LOG_K[1] * x + LOG_K[2] * x * x)
        force = intrusion_force(phi, {"k": k, "c_d": np.full_like(k, law["c_d"])},
                                test["depth_mm"].to_numpy()[None, :],
                                test["speed_mm_s"].to_numpy()[None, :], experiment=exp)  # fmt: skip
        r = (test["force_N"].to_numpy()[None, :] - force) / 0.3
        ll = np.sum(-0.5 * r * r - np.log(0.3) - 0.5 * np.log(2 * np.pi), axis=1)
        log_w = -0.5 * grid**2 - 0.5 * np.log(2 * np.pi) + np.log(grid[1] - grid[0])
        brute.append(logsumexp(ll + log_w))
    assert len(got) == len(brute)
    assert np.max(np.abs(got - np.array(brute))) < 1e-3
    # a test's bed is off its written phi by up to ~2 sd: ignoring that costs many nats
    measured = JumpModel([IntrusionBlock(table)], exp, ["depth", "drag"], phi_mode="quadratic")
    assert np.min(measured(u)[1][0] - got) < -10.0


def test_without_a_latent_phi_the_model_is_unchanged_bit_for_bit(loaded) -> None:
    """phi_sd 0, ``bed_phi="measured"`` and per_phi mode: the blocks of a measured phi."""
    _, uncertain, data = loaded
    assert uncertain.phi_sd == PHI_SD
    exact = uncertain.replace(phi_sd=0.0)
    rng = np.random.default_rng(3)
    for mode, law in (("quadratic", "quadratic"), ("per_phi", "per_phi")):
        ref = _make_model(data, exact, FitSettings(phi_mode=mode), default_priors(), law)
        u = ref.sample_prior(rng, 6)
        for config in (FitSettings(phi_mode=mode, bed_phi="measured"), FitSettings(phi_mode=mode)):
            if mode == "quadratic" and config.bed_phi == "integrate":
                continue  # the one case that integrates
            model = _make_model(data, uncertain, config, default_priors(), law)
            a, b = model(u), ref(u)
            np.testing.assert_array_equal(a[0], b[0])
            np.testing.assert_array_equal(a[1], b[1])
    latent = _make_model(data, uncertain, FitSettings(phi_mode="quadratic"), default_priors(),
                         "quadratic")  # fmt: skip
    assert [b.bed for b in latent.blocks] == [BedPhi(PHI_SD, 9)] * 2


def test_the_fit_says_what_it_does_with_phi_sd() -> None:
    def said(config: FitSettings) -> str:
        return " ".join(_warnings([], config, Experiment().replace(phi_sd=PHI_SD)))

    assert "as exact" in said(FitSettings(phi_mode="quadratic", bed_phi="measured"))
    assert "absorbed" in said(FitSettings(phi_mode="per_phi"))
    assert said(FitSettings(phi_mode="quadratic")) == ""
    # a fit saved before beds were latent is read back as it was made
    assert FitSettings.from_dict({"terms": ["depth"]}).bed_phi == "measured"
    assert FitSettings.from_dict(FitSettings().to_dict()).bed_phi == "integrate"


@pytest.fixture(scope="module")
def latent_fit(loaded, tmp_path_factory):
    """A tiny fit that integrates the beds, and its saved DataTree read back."""
    _, exp, data = loaded
    res = fit(exp, data, dataclasses.replace(QUADRATIC, n_prior_draws=10), seed=2)
    path = tmp_path_factory.mktemp("fit") / "posterior.nc"
    gdt.write_datatree(res.datatree, path)
    return res, load_fit(path)


def test_a_fit_integrates_the_beds_and_a_saved_fit_rebuilds_them(latent_fit) -> None:
    """Tiny sampler: the wiring, not the answer (benchmarks/latent_phi_fit.py measures it)."""
    res, saved = latent_fit
    assert not any("phi_sd" in w for w in res.warnings)  # integrated, nothing to say
    tree = res.datatree
    assert np.all(np.isfinite(tree["posterior_predictive"]["force_N"].values))
    assert np.isfinite(tree["posterior_predictive"]["height_mm"].values).mean() > 0.99
    model = saved.model(saved.labels[0])
    assert [b.bed for b in model.blocks] == [BedPhi(PHI_SD, 9)] * 2
    u = saved.draws(saved.labels[0])[:5]
    stored = np.concatenate(
        [
            tree["log_likelihood"][v].stack(s=("chain", "draw")).transpose("s", ...).values[:5]
            for v in ("height_mm", "intrusion")
        ],
        axis=1,
    )
    np.testing.assert_allclose(model(u)[1], stored, rtol=0, atol=1e-9)


def test_a_new_jump_is_predicted_on_a_new_bed(latent_fit) -> None:
    """``predict`` of a fit that integrated the beds: replicates carry the beds' scatter.

    Tiny sampler (the scatter is far from converged, ~9 mm): what is tested is that a new
    jump's spread about the law's height exceeds the fitted scatter, by the beds' share
    (heights of the delayed stutter preload move several mm per sd of phi). 5 settings x
    every kept draw (~300 replicates): the sd's standard error is ~4%; the excess measured
    86%. The same saved fit read as if its beds had been measured predicts without them.
    """
    _, saved = latent_fit
    freqs = [8.0, 9.0, 10.0, 11.0, 12.0]
    wide = predict(saved, "delayed_stutter_preload", 0.622, freq_hz=freqs, n_draws=None, rng=1)
    assert any("new bed" in note for note in wide.notes)
    spread = np.nanstd(wide.height_mm - wide.height_sim_mm)
    sigma = float(np.median(wide.table["sigma_mm_median"]))
    assert spread > 1.1 * sigma
    config = dataclasses.replace(saved.settings, bed_phi="measured")
    as_measured = dataclasses.replace(saved, settings=config, _models={})
    narrow = predict(
        as_measured, "delayed_stutter_preload", 0.622, freq_hz=freqs, n_draws=None, rng=1
    )
    assert not any("new bed" in note for note in narrow.notes)
    np.testing.assert_array_equal(narrow.height_sim_mm, wide.height_sim_mm)
    assert np.nanstd(narrow.height_mm - narrow.height_sim_mm) < spread
