"""The experiment that settles it (``granbayes.design``, ``granbayes design``): the jumps
that separate tied laws, and those that identify a parameter.

The separation per jump is checked against numerical integration, the allocation against
cases whose answer is known by hand, and the whole path (predictive moments of two fitted
laws, the plan, the command line on a diagnosis folder) on tiny fits of SYNTHETIC data
from the oracle of the test kit. Whether designed jumps break real ties more often than
random ones is a study, not a unit test: ``benchmarks/design_ties.py``.
"""

from __future__ import annotations

import json
import math
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pandas as pd
import pytest
from scipy import integrate, stats

from granbayes import Experiment
from granbayes import _datatree as gdt
from granbayes._cli import EXIT_INPUT, EXIT_OK, main
from granbayes._fitting import FitSettings, fit
from granbayes._identify import allocate_jumps
from granbayes._sampler import SamplerSettings
from granbayes._synthetic import write_experiment
from granbayes.design import (
    LawDraws,
    candidate_settings,
    design_jumps,
    design_parameters,
    normal_separation,
    parameter_contraction,
    plan_jumps,
    save_tie_laws,
    ties_of,
)
from granbayes.testing import synthetic_jumps

#: One worker for the module: its tiny fits (a module fixture) are made once.
pytestmark = pytest.mark.xdist_group("design")

TINY = SamplerSettings(n_walkers=8, n_ensembles=2, check_every=50, max_steps=100, n_draws=30)


@pytest.mark.parametrize(
    ("mt", "st", "mr", "sr"), [(0.0, 1.0, 0.0, 1.0), (0.0, 1.0, 2.0, 1.0), (10.0, 2.0, 9.0, 3.5)]
)
def test_separation_per_jump_is_the_integrated_log_ratio(mt, st, mr, sr) -> None:
    """KL(p_T || p_R) and the variance of the log ratio, by quadrature (to 1e-8)."""
    p_t, p_r = stats.norm(mt, st), stats.norm(mr, sr)

    def log_ratio(y: float) -> float:
        return p_t.logpdf(y) - p_r.logpdf(y)

    lo, hi = mt - 12 * st, mt + 12 * st
    mean = integrate.quad(lambda y: p_t.pdf(y) * log_ratio(y), lo, hi)[0]
    second = integrate.quad(lambda y: p_t.pdf(y) * log_ratio(y) ** 2, lo, hi)[0]
    kl, var = normal_separation(mt, st, mr, sr)
    assert float(kl) == pytest.approx(mean, abs=1e-8)
    assert float(var) == pytest.approx(second - mean**2, abs=1e-8)
    if (mt, st) == (mr, sr):
        assert float(kl) == 0.0 and float(var) == 0.0


def _fixed(means: list[float], sd: float = 1.0, n_draws: int = 4) -> LawDraws:
    """A law without parameter uncertainty: every draw predicts ``means`` [mm]."""
    m = np.tile(np.asarray(means, dtype=float), (n_draws, 1))
    return LawDraws(
        mean_mm=m,
        var_mm2=np.full_like(m, sd**2),
        log_lik=np.zeros((n_draws, 1)),
        setting_run=np.zeros(m.shape[1], dtype=int),
        jump_run=np.zeros(1, dtype=int),
    )


def _evidence(diff: float, se: float) -> dict:
    return {("T", "R"): (diff, se), ("R", "T"): (-diff, se)}


def test_without_parameter_uncertainty_jumps_add_their_separation() -> None:
    """Laws known exactly (every draw alike: nothing moves when jumps are added), unit
    scatter, means 0 and 1, 2 and 0.5 mm apart at three settings: the best setting
    separates by 2 nats per jump with variance 4 under either hypothesis, so the rule
    (> 4 nats and > 2 SE from a tie at 0 +- 0) needs 5 jumps there; the first hypothesis
    then expects 10 +- sqrt(20) nats."""
    draws = {"T": _fixed([0.0, 0.0, 0.0]), "R": _fixed([1.0, 2.0, 0.5])}
    counts, hyp, settled, first = plan_jumps(draws, _evidence(0.0, 0.0), max_jumps=50)
    assert counts.tolist() == [0, 5, 0] and settled and first == 0.0
    row = hyp.set_index(["truth", "rival"]).loc[("T", "R")]
    assert row["elpd_diff_expected"] == pytest.approx(10.0)
    assert row["se_expected"] == pytest.approx(np.sqrt(20.0))
    assert row["ess_share"] == pytest.approx(1.0)


def test_a_rival_that_can_move_is_not_credited_with_the_separation_it_promises() -> None:
    """The rival's draws disagree at setting 0 (half predict 0 mm, as the truth; half
    10 mm) but all predict 1.5 mm at setting 1. Judged before the posteriors move, setting
    0 looks best (1.63 against 1.13 nats per jump: its predictive spread); but one jump
    there gives the weight to the rival's draws that agree with the truth, and the
    separation at setting 0 vanishes. The plan goes to setting 1, where the rival cannot
    follow: 8 jumps (8 x 1.125 > 4 nats and > 2 SE, SE = 1.5 sqrt(8))."""
    n = 400
    rival_m = np.column_stack([np.repeat([0.0, 10.0], n // 2), np.full(n, 1.5)])
    rival = LawDraws(
        mean_mm=rival_m,
        var_mm2=np.ones_like(rival_m),
        log_lik=np.zeros((n, 1)),
        setting_run=np.zeros(2, dtype=int),
        jump_run=np.zeros(1, dtype=int),
    )
    draws = {"T": _fixed([0.0, 0.0], n_draws=n), "R": rival}
    kl_first = [float(normal_separation(0.0, 1.0, m.mean(), np.sqrt(1 + m.var()))[0])
                for m in rival_m.T]  # fmt: skip
    assert kl_first[0] > kl_first[1]  # the naive criterion prefers setting 0
    evidence = {("T", "R"): (0.0, 0.0)}
    counts, hyp, settled, _ = plan_jumps(draws, evidence, max_jumps=40)
    assert settled and counts.tolist() == [0, 8]
    assert hyp.loc[0, "elpd_diff_expected"] == pytest.approx(8 * 1.125)


def test_every_hypothesis_is_served() -> None:
    """Either law may be the truth; a setting where only the truth's scatter is wide
    separates one way only: the plan must pass the rule under both hypotheses."""
    draws = {"T": _fixed([0.0, 0.0], sd=1.0), "R": _fixed([3.0, 0.0], sd=0.5)}
    _, hyp, settled, _ = plan_jumps(draws, _evidence(2.0, 1.0), max_jumps=100)
    assert settled and hyp["settled"].all()
    assert (hyp["elpd_diff_expected"] > 4.0).all()
    assert (hyp["elpd_diff_expected"] > 2.0 * hyp["se_expected"]).all()


def test_an_impossible_tie_spends_the_budget_and_says_so() -> None:
    draws = {"T": _fixed([1.0, 2.0]), "R": _fixed([1.0, 2.0])}
    counts, hyp, settled, _ = plan_jumps(draws, _evidence(0.0, 1.0), max_jumps=12)
    assert counts.sum() == 12 and not settled
    assert hyp["elpd_diff_expected"].tolist() == [0.0, 0.0]


def test_separated_data_need_no_jump() -> None:
    draws = {"T": _fixed([0.0]), "R": _fixed([1.0])}
    counts, _, settled, first = plan_jumps(draws, _evidence(9.0, 1.0), max_jumps=5)
    assert settled and counts.sum() == 0 and first > 1.0


def test_candidates_stay_within_what_was_measured() -> None:
    measured = pd.DataFrame(
        {"phi": [0.6, 0.62], "command": ["single", "stutter"], "freq_hz": [8.0, 12.0]}
    )
    c = candidate_settings(measured, commands=["single", "delayed_stutter"], n_freqs=3)
    assert set(c["phi"]) == {0.6, 0.62}
    assert sorted(set(c["freq_hz"])) == [8.0, 10.0, 12.0]
    assert len(c) == 2 * 2 * 3 and c["delay_ms"].isna().all()
    c = candidate_settings(measured, commands=["delayed_stutter", "single"], delays_ms=[50, 90])
    assert len(c[c["command"] == "delayed_stutter"]) == 2 * 5 * 2
    assert c.loc[c["command"] == "single", "delay_ms"].isna().all()
    # the preload's hold is settle_periods (the command registry): delay_ms does not apply
    c = candidate_settings(measured, commands=["delayed_stutter_preload"], delays_ms=[50, 90])
    assert len(c) == 2 * 5 and c["delay_ms"].isna().all()
    with pytest.raises(ValueError, match="unknown command"):
        candidate_settings(measured, commands=["hop"])


def test_the_laws_of_a_tie_are_read_from_the_record() -> None:
    record = {
        "baseline": {"terms": ["depth"]},
        "selected": {
            "added": ["compaction", "drag"],
            "indistinguishable": [
                {"round": 2, "selected": "drag", "term": "viscous", "elpd_diff": 1.0,
                 "elpd_diff_se": 2.0, "converged": True},
            ],
        },
    }  # fmt: skip
    (tie,) = ties_of(record)
    assert tie["laws"] == (("depth", "drag", "compaction"), ("depth", "viscous", "compaction"))


# ----------------------------------------------------------------------------------------
# the whole path on tiny fits
# ----------------------------------------------------------------------------------------
def _truth(phi: float) -> dict[str, float]:
    return {"k": 3500.0 + 1.2e5 * (phi - 0.612), "c_d": 60.0}


@pytest.fixture(scope="module")
def tied(tmp_path_factory: pytest.TempPathFactory):
    """(data folder, diagnosis folder, {law: fit}) with a tie of drag and viscous."""
    exp = Experiment()
    table = synthetic_jumps(
        _truth,
        2.0,
        seed=3,
        experiment=exp,
        phis=(0.602, 0.622),
        freqs_hz=(8.0, 12.0),
        commands=("single", "stutter"),
        trials=2,
        label="tests/test_design.py",
        settings_columns=True,
    )
    root = tmp_path_factory.mktemp("design")
    data = write_experiment(root / "data", table, exp)
    fits = {
        name: fit(
            exp,
            table,
            FitSettings(terms=("depth", name), sampler=TINY, n_threads=1, n_prior_draws=0),
            seed=1,
            data_source=str(data),
        )
        for name in ("drag", "viscous")
    }
    out = root / "diagnosis"
    out.mkdir()
    record = {
        "data_source": str(data),
        "baseline": {"terms": ["depth"]},
        "selected": {
            "added": ["drag"],
            "indistinguishable": [
                {"round": 1, "selected": "drag", "term": "viscous", "elpd_diff": 1.5,
                 "elpd_diff_se": 2.5, "converged": True},
            ],
        },
        "rule": {"min_gain": 4.0, "se_factor": 2.0},
    }  # fmt: skip
    (out / "diagnosis.json").write_text(json.dumps(record))
    gdt.write_datatree(fits["drag"].datatree, out / "posterior_selected.nc")
    by_terms = {("depth", n): f for n, f in fits.items()}
    diagnosis = SimpleNamespace(record=SimpleNamespace(to_json=lambda: record), fits=by_terms)
    written = save_tie_laws(diagnosis, out)
    assert sorted(p.name for p in written) == ["depth+drag.nc", "depth+viscous.nc"]
    return data, out, fits


def test_a_design_of_two_fitted_laws(tied) -> None:
    """The plan's settings are candidates; the expected difference is the one so far plus
    the planned jumps' separation (at most their settings') and the laws' changed fit of
    the measured jumps; the record is JSON."""
    _, _, fits = tied
    d = design_jumps(fits, evidence={("drag", "viscous"): (1.5, 2.5)}, max_jumps=15, n_draws=60)
    assert d.laws == ("drag", "viscous") and 0 < d.n_jumps <= 15
    assert d.n_jumps == d.plan["trials"].sum()
    cand = d.candidates.set_index(["command", "phi", "freq_hz"])
    hyp = d.hypotheses.set_index(["truth", "rival"])
    for (t, r), now in ((("drag", "viscous"), 1.5), (("viscous", "drag"), -1.5)):
        assert hyp.loc[(t, r), "elpd_diff_now"] == now
        assert 0.0 < hyp.loc[(t, r), "ess_share"] <= 1.0
        # the planned jumps add at most what their settings separate (the truth's predictive
        # density of its own jumps is highest at its own moments; the rival catches up); the
        # rest of the expected difference is each law's changed fit of the measured jumps,
        # which can be large: the rival, pulled towards the truth at the new settings, loses
        # fit of the old ones
        first = sum(
            row.trials * cand.loc[(row.command, row.phi, row.freq_hz), f"kl[{t} vs {r}]"]
            for row in d.plan.itertuples()
        )
        h = hyp.loc[(t, r)]
        new = h["elpd_diff_expected"] - now - (h["fit_change_truth"] - h["fit_change_rival"])
        assert 0.0 < new <= first + 1e-9
    assert (d.candidates["worst_kl"] >= 0).all()
    assert json.loads(json.dumps(d.to_json()))["laws"] == ["drag", "viscous"]
    again = design_jumps(fits, evidence={("drag", "viscous"): (1.5, 2.5)}, max_jumps=15, n_draws=60)
    pd.testing.assert_frame_equal(again.plan, d.plan)  # seeded: the same plan


def test_fits_of_different_data_are_refused(tied) -> None:
    _, _, fits = tied
    other = fits["viscous"].datatree.copy()
    other.attrs["data_sha256"] = "0" * 64
    with pytest.raises(ValueError, match="different data"):
        design_jumps({"drag": fits["drag"].datatree, "viscous": other}, max_jumps=2)


def test_cli_design_writes_the_plan(tied, tmp_path: Path, capsys) -> None:
    data, diagnosis, _ = tied
    out = tmp_path / "design"
    args = ["design", str(data), "--diagnosis", str(diagnosis), "--out", str(out)]
    code = main([*args, "--max-jumps", "10", "--draws", "50", "--freq-hz", "8,10,12"])
    assert code == EXIT_OK
    rec = json.loads((out / "design.json").read_text())
    assert rec["laws"] == ["depth+drag", "depth+viscous"]
    assert rec["tie"]["laws"] == [["depth", "drag"], ["depth", "viscous"]]
    plan = pd.read_csv(out / "plan.csv")
    assert plan["trials"].sum() == rec["n_jumps"] <= 10
    assert set(plan["freq_hz"]) <= {8.0, 10.0, 12.0}
    assert "The jumps that would settle depth+drag against depth+viscous" in capsys.readouterr().out
    assert (out / "candidates.csv").exists() and (out / "design.md").exists()


def test_cli_design_refuses_with_one_message(tied, tmp_path: Path, capsys) -> None:
    data, diagnosis, _ = tied
    bad = tmp_path / "no-tie"
    bad.mkdir()
    record = json.loads((diagnosis / "diagnosis.json").read_text())
    record["selected"]["indistinguishable"] = []
    (bad / "diagnosis.json").write_text(json.dumps(record))
    out = tmp_path / "design"
    # without a tie, the parameters of the selected law: its posterior is needed
    assert main(["design", str(data), "--diagnosis", str(bad), "--out", str(out)]) == EXIT_INPUT
    assert "no tie to settle, and no posterior of the selected law" in capsys.readouterr().err
    assert main(["design", str(data), "--diagnosis", str(tmp_path), "--out", str(out)]) == (
        EXIT_INPUT
    )
    assert "no diagnosis.json" in capsys.readouterr().err
    other = tmp_path / "other"  # the diagnosed folder with one height changed
    other.mkdir()
    (other / "experiment.toml").write_text((data / "experiment.toml").read_text())
    jumps = pd.read_csv(data / "jumps.csv")
    jumps.loc[0, "height_mm"] += 1.0
    jumps.to_csv(other / "jumps.csv", index=False)
    args = ["design", str(other), "--diagnosis", str(diagnosis), "--out", str(out)]
    assert main(args) == EXIT_INPUT
    assert "diagnosed other data" in capsys.readouterr().err
    assert not out.exists()


def test_the_study_s_extra_jumps_come_from_the_oracle() -> None:
    """``granbayes.calibration.extra_jumps``: a plan's jumps of a study case, simulated
    by the oracle at the plan's settings (the case's truth), with the case's scatter."""
    from granbayes.calibration import extra_jumps, make_case
    from granbayes.testing import simulate_height_scipy

    case = make_case("drag", 3)
    plan = pd.DataFrame(
        {"command": ["stutter", "single"], "phi": [case.truth["phis"][0]] * 2,
         "freq_hz": [7.0, 12.0], "delay_ms": [np.nan, np.nan], "trials": [2, 1]}
    )  # fmt: skip
    new = extra_jumps(case, plan, np.random.default_rng(0))
    assert len(new) == 3 and set(new.columns) == set(case.table.columns)
    assert new["trial"].tolist() == [case.truth["trials"] + i for i in (1, 2, 1)]
    assert new["source"].str.startswith("synthetic").all()
    k0, k1, k2 = case.truth["k_law"]
    x = plan["phi"][0] - 0.612
    law = {"k": k0 + k1 * x + k2 * x * x, **case.truth["effect"]}
    exp = case.experiment.replace(freq_hz=12.0)
    true = simulate_height_scipy("single", plan["phi"][0], law, exp)
    noise = np.random.default_rng(0).normal(0.0, case.truth["sigma_mm"], 3)
    assert new["height_mm"].iloc[2] == pytest.approx(true + noise[2], abs=1e-9)
    with pytest.raises(ValueError, match="only library truths"):
        extra_jumps(make_case("janssen_saturation", 3), plan, np.random.default_rng(0))


# ----------------------------------------------------------------------------------------
# the jumps that identify a parameter
# ----------------------------------------------------------------------------------------
def _exact_normal(n: int, sd: float, seed: int) -> np.ndarray:
    """``n`` draws with mean 0 and sample SD exactly ``sd``."""
    z = np.random.default_rng(seed).normal(size=n)
    return sd * (z - z.mean()) / z.std(ddof=1)


def test_a_linear_law_gets_the_jumps_the_conjugate_update_needs() -> None:
    """Height = a theta + b, scatter sigma: n jumps leave var = 1 / (1/v + n a^2/sigma^2)
    (the conjugate normal update, exact for a linear law); the plan is the smallest n that
    halves the SD, all at the informative setting, none at the flat one."""
    v, a, sigma = 4.0, 3.0, 7.0
    theta = _exact_normal(2000, math.sqrt(v), 0)[:, None]
    mean = np.column_stack([a * theta[:, 0] + 5.0, np.full(2000, 80.0)])
    goal = 0.25 * v  # SD halved
    n_needed = math.ceil((v / goal - 1.0) * sigma**2 / (a**2 * v))
    counts, var_after, info, first = allocate_jumps(
        theta, np.array([0]), mean, np.full(2, sigma**2), np.array([0, 0]), np.array([goal]), 60
    )
    assert counts.tolist() == [n_needed, 0]
    exact = 1.0 / (1.0 / v + n_needed * a**2 / sigma**2)
    assert var_after[0] == pytest.approx(exact, rel=1e-10)
    assert info == pytest.approx(0.5 * math.log(v / exact), rel=1e-10)
    assert first[0] == pytest.approx(0.5 * math.log(1.0 + a**2 * v / sigma**2), rel=1e-10)
    assert first[1] == 0.0
    few = allocate_jumps(
        theta, np.array([0]), mean, np.full(2, sigma**2), np.array([0, 0]), np.array([goal]), 2
    )
    assert few[0].tolist() == [2, 0] and few[1][0] > goal  # budget spent, goal not reached


def test_a_jump_informs_the_parameters_of_its_own_run_only() -> None:
    """Two runs (a per-phi fit's volume fractions): the target whose run has no usable
    setting keeps its variance; the other is served until it reaches its goal."""
    t0, t1 = _exact_normal(1000, 1.0, 1), _exact_normal(1000, 1.0, 2)
    theta = np.column_stack([t0, t1])
    mean = np.column_stack([10.0 * t0, 10.0 * t1])
    runs = np.array([0, -1])  # the setting of run 1 is not usable
    counts, var_after, _, first = allocate_jumps(
        theta, np.array([0, 1]), mean, np.full(2, 1.0), runs, np.array([0.01, 0.01]), 50
    )
    assert counts[1] == 0 and first[1] == 0.0
    assert var_after[1] == pytest.approx(1.0)
    # 1 / (1 + 100 n) <= 0.01 from n = 1; then no setting serves the other target: stop
    assert counts.tolist() == [1, 0] and var_after[0] == pytest.approx(1 / 101, rel=1e-10)


def test_prior_spread_and_contraction_of_a_fit(tied) -> None:
    """Prior SDs from 20,000 prior draws match the analytic ones (uniform c_d on [0, 300]:
    300/sqrt(12); log-uniform k on [200, 50000]: ln(250)/sqrt(12) in log k) within 1.5%
    (about 5 SE of a sample SD from 20,000 draws); the posterior SD is that of every draw."""
    _, _, fits = tied
    table = parameter_contraction(fits["drag"]).set_index(["parameter", "phi"])
    assert set(table.index.get_level_values("phi")) == {0.602, 0.622}
    assert table.loc["c_d", "prior_sd"].iloc[0] == pytest.approx(300 / math.sqrt(12), rel=0.015)
    assert table.loc["k", "prior_sd"].iloc[0] == pytest.approx(
        math.log(250) / math.sqrt(12), rel=0.015
    )
    post = fits["drag"].datatree["posterior"]["c_d"].sel(phi=0.602).values.ravel()
    row = table.loc[("c_d", 0.602)]
    assert row["posterior_sd"] == pytest.approx(np.std(post, ddof=1), rel=1e-12)
    assert row["contraction"] == pytest.approx(1 - row["posterior_sd"] ** 2 / row["prior_sd"] ** 2)
    assert row["unidentified"] == (row["contraction"] < 0.5)
    with pytest.raises(ValueError, match="has k, c_d"):
        parameter_contraction(fits["drag"], ["b"])


def test_a_design_for_a_fitted_parameter(tied) -> None:
    """The plan's settings are candidates of the targets' volume fractions; the expected
    SD is below the present one and reaches the goal where the plan says so; seeded."""
    _, _, fits = tied
    d = design_parameters(fits["drag"], parameters=["c_d"], sd_ratio=0.8, max_jumps=20, n_draws=60)
    assert d.n_jumps == d.plan["trials"].sum() <= 20
    assert set(d.plan["phi"]) <= {0.602, 0.622}
    t = d.targets.set_index("phi")
    assert (t["posterior_sd_expected"] < t["posterior_sd"]).all()
    assert (t["information_nats"] > 0).all()
    assert d.reached == bool(t["reached"].all())
    if d.reached:
        assert (t["posterior_sd_expected"] <= 0.8 * t["posterior_sd"] * 1.0001).all()
    else:
        assert d.n_jumps == 20
    doc = json.loads(json.dumps(d.to_json()))
    assert doc["target"] == "parameters" and doc["goal_sd_ratio"] == 0.8
    again = design_parameters(
        fits["drag"], parameters=["c_d"], sd_ratio=0.8, max_jumps=20, n_draws=60
    )
    pd.testing.assert_frame_equal(again.plan, d.plan)
    # by default the unidentified parameters, and nothing to do if there are none
    table = parameter_contraction(fits["drag"])
    if table["unidentified"].any():
        auto = design_parameters(fits["drag"], max_jumps=5, n_draws=60)
        pairs = set(zip(auto.targets["parameter"], auto.targets["phi"], strict=True))
        weak = table[table["unidentified"]]
        assert pairs == set(zip(weak["parameter"], weak["phi"], strict=True))
    else:
        with pytest.raises(ValueError, match="nothing to design"):
            design_parameters(fits["drag"], max_jumps=5, n_draws=60)
    for bad in ({"goal": 1.0}, {"sd_ratio": 0.0}, {"max_jumps": 0}):
        with pytest.raises(ValueError):
            design_parameters(fits["drag"], parameters=["c_d"], **bad)


def test_cli_design_for_parameters(tied, tmp_path: Path, capsys) -> None:
    """``--fit`` (and ``--diagnosis`` without a tie) designs for parameters."""
    data, diagnosis, fits = tied
    fit_dir = tmp_path / "fit"
    fit_dir.mkdir()
    gdt.write_datatree(fits["drag"].datatree, fit_dir / "posterior.nc")
    out = tmp_path / "design"
    args = ["design", str(data), "--fit", str(fit_dir), "--out", str(out), "--draws", "50"]
    assert main([*args, "--parameter", "c_d", "--sd-ratio", "0.8", "--max-jumps", "12"]) == EXIT_OK
    rec = json.loads((out / "design.json").read_text())
    assert rec["target"] == "parameters" and rec["fit"] == str(fit_dir)
    assert pd.read_csv(out / "plan.csv")["trials"].sum() == rec["n_jumps"] <= 12
    assert "The jumps that would identify the parameters of depth+drag" in capsys.readouterr().out
    no_tie = tmp_path / "no-tie"
    no_tie.mkdir()
    record = json.loads((diagnosis / "diagnosis.json").read_text())
    record["selected"]["indistinguishable"] = []
    (no_tie / "diagnosis.json").write_text(json.dumps(record))
    gdt.write_datatree(fits["drag"].datatree, no_tie / "posterior_selected.nc")
    args = ["design", str(data), "--diagnosis", str(no_tie), "--out", str(tmp_path / "d2")]
    assert main([*args, "--parameter", "c_d", "--max-jumps", "3"]) == EXIT_OK
    assert json.loads((tmp_path / "d2" / "design.json").read_text())["diagnosis"] == str(no_tie)
    capsys.readouterr()
    bad = ["design", str(data), "--fit", str(fit_dir), "--out", str(tmp_path / "d3")]
    assert main([*bad, "--parameter", "b"]) == EXIT_INPUT
    assert "has k, c_d" in capsys.readouterr().err
    assert main([*bad, "--sd-ratio", "1.5"]) == EXIT_INPUT
    assert "--sd-ratio 1.5" in capsys.readouterr().err
    assert not (tmp_path / "d3").exists()
