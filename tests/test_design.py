"""The experiment that settles a tie (``granbayes.design``, ``granbayes design``).

The separation per jump is checked against numerical integration, the allocation against
cases whose answer is known by hand, and the whole path (predictive moments of two fitted
laws, the plan, the command line on a diagnosis folder) on tiny fits of SYNTHETIC data
from the oracle of the test kit. Whether designed jumps break real ties more often than
random ones is a study, not a unit test: ``benchmarks/design_ties.py``.
"""

from __future__ import annotations

import json
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
from granbayes._sampler import SamplerSettings
from granbayes._synthetic import write_experiment
from granbayes.design import (
    LawDraws,
    candidate_settings,
    design_jumps,
    normal_separation,
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
    the plan's jumps times each setting's separation; the record is JSON."""
    _, _, fits = tied
    d = design_jumps(fits, evidence={("drag", "viscous"): (1.5, 2.5)}, max_jumps=15, n_draws=60)
    assert d.laws == ("drag", "viscous") and 0 < d.n_jumps <= 15
    assert d.n_jumps == d.plan["trials"].sum()
    cand = d.candidates.set_index(["command", "phi", "freq_hz"])
    hyp = d.hypotheses.set_index(["truth", "rival"])
    for (t, r), now in ((("drag", "viscous"), 1.5), (("viscous", "drag"), -1.5)):
        assert hyp.loc[(t, r), "elpd_diff_now"] == now
        assert 0.0 < hyp.loc[(t, r), "ess_share"] <= 1.0
        # the planned jumps add what their settings separate, less what the rival catches up
        first = sum(
            row.trials * cand.loc[(row.command, row.phi, row.freq_hz), f"kl[{t} vs {r}]"]
            for row in d.plan.itertuples()
        )
        assert hyp.loc[(t, r), "elpd_diff_expected"] <= now + first + 1e-9
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
    assert main(["design", str(data), "--diagnosis", str(bad), "--out", str(out)]) == EXIT_INPUT
    assert "no indistinguishable laws" in capsys.readouterr().err
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
