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
from granbayes import datatree as gdt
from granbayes.cli import EXIT_INPUT, EXIT_OK, main
from granbayes.design import (
    allocate_jumps,
    candidate_settings,
    design_jumps,
    normal_separation,
    save_tie_laws,
    ties_of,
)
from granbayes.fitting import FitSettings, fit
from granbayes.sampler import SamplerSettings
from granbayes.synthetic import write_experiment
from granbayes.testing import synthetic_jumps

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


def test_jumps_go_where_the_laws_differ_most_and_stop_when_settled() -> None:
    """One hypothesis, settings separating by 0.2, 1 and 0.5 nats per jump (variance =
    KL): the rule needs n KL > 4 and n KL > 2 sqrt(n KL), i.e. 5 jumps of the best."""
    kl = np.array([[0.2, 1.0, 0.5]])
    counts, diff, se, settled = allocate_jumps(kl, kl, np.zeros(1), np.zeros(1), max_jumps=50)
    assert counts.tolist() == [0, 5, 0]
    assert settled and diff[0] == pytest.approx(5.0) and se[0] == pytest.approx(np.sqrt(5.0))


def test_every_hypothesis_is_served() -> None:
    """Two hypotheses (either law true), each separated by a different setting: the plan
    uses both, and each hypothesis passes the rule in expectation."""
    kl = np.array([[1.0, 0.0, 0.3], [0.0, 1.0, 0.3]])
    counts, diff, se, settled = allocate_jumps(
        kl, kl, np.array([2.0, -2.0]), np.array([1.0, 1.0]), max_jumps=100
    )
    assert settled
    assert counts[0] > 0 and counts[1] > 0
    assert np.all(diff > 4.0) and np.all(diff > 2.0 * se)
    assert diff.tolist() == pytest.approx((np.array([2.0, -2.0]) + kl @ counts).tolist())


def test_an_impossible_tie_spends_the_budget_and_says_so() -> None:
    kl = np.zeros((2, 3))
    counts, diff, _, settled = allocate_jumps(kl, kl + 0.1, np.zeros(2), np.ones(2), max_jumps=12)
    assert counts.sum() == 12 and not settled
    assert diff.tolist() == [0.0, 0.0]


def test_separated_data_need_no_jump() -> None:
    counts, _, _, settled = allocate_jumps(
        np.ones((2, 2)), np.ones((2, 2)), np.array([9.0, 9.0]), np.ones(2), max_jumps=5
    )
    assert settled and counts.sum() == 0


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
    for (t, r), now in (((("drag", "viscous")), 1.5), ((("viscous", "drag")), -1.5)):
        expected = now + sum(
            row.trials * cand.loc[(row.command, row.phi, row.freq_hz), f"kl[{t} vs {r}]"]
            for row in d.plan.itertuples()
        )
        assert hyp.loc[(t, r), "elpd_diff_now"] == now
        assert hyp.loc[(t, r), "elpd_diff_expected"] == pytest.approx(expected)
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
    assert not out.exists()
