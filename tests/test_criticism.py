"""Fast tests of the model-criticism loop: residual statistics, diagnosis.json, the CLI.

The hidden-effect tests (slow) are in ``tests/test_hidden_effects.py``. Data here are
SYNTHETIC (granbayes.synthetic.make_jumps, fixed seeds).
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from granbayes import Experiment
from granbayes.cli import main
from granbayes.criticism import DiagnoseConfig, describe_cell, diagnose, residual_table
from granbayes.fitting import FitConfig, fit
from granbayes.sampler import SamplerSettings
from granbayes.synthetic import make_jumps, write_experiment

SMALL = SamplerSettings(n_walkers=8, check_every=100, tau_factor=10, n_draws=40, max_steps=400)


def _table(effect: dict[str, float], seed: int = 3) -> pd.DataFrame:
    jumps = make_jumps(
        lambda phi: {"k": 4000.0 + 1.5e5 * (phi - 0.612), **effect},
        2.0,
        phis=(0.602, 0.622),
        freqs_hz=(10.0,),
        commands=("single", "preload", "delayed_stutter"),
        trials=3,
        seed=seed,
        label="tests/test_criticism.py",
    )
    return jumps.drop(columns="true_height_mm").assign(
        amplitude_mm=20.0, delay_ms=50.0, settle_periods=3.0
    )


@pytest.fixture(scope="module")
def depth_fit_on_drag_data():
    table = _table({"c_d": 150.0})
    return table, fit(Experiment(), table, FitConfig(terms=("depth",), sampler=SMALL), seed=1)


def test_residual_table_cells_and_statistics(depth_fit_on_drag_data) -> None:
    """One row per command x phi x frequency; residual = observed - simulated mean."""
    table, result = depth_fit_on_drag_data
    res = residual_table(result)
    assert len(res) == table.groupby(["command", "phi", "freq_hz"]).ngroups
    assert np.allclose(res["mean_residual_mm"], res["observed_mm"] - res["simulated_mm"])
    assert (res["p_value"].between(0, 1)).all() and (res["p_predictive"].between(0, 1)).all()
    assert res["z"].abs().is_monotonic_decreasing  # worst first
    # a strong hidden drag makes the depth-only law clearly wrong somewhere
    assert res["z"].abs().max() > 3.5


def test_lack_of_fit_z_uses_the_measured_scatter(depth_fit_on_drag_data) -> None:
    """z = residual / sqrt(s^2/n + var_post), s^2 pooled within cells at the same phi."""
    table, result = depth_fit_on_drag_data
    res = residual_table(result)
    row = res.iloc[0]
    at_phi = table[table["phi"] == row["phi"]]
    groups = at_phi.groupby(["command", "freq_hz"])["height_mm"]
    s2 = float(groups.apply(lambda g: ((g - g.mean()) ** 2).sum()).sum()) / float(
        (groups.size() - 1).sum()
    )
    se_min = np.sqrt(s2 / row["n"])  # posterior variance only adds to it
    assert abs(row["z"]) <= abs(row["mean_residual_mm"]) / se_min + 1e-9


def test_describe_cell_in_words() -> None:
    text = describe_cell(
        {
            "command": "delayed_stutter_preload",
            "phi": 0.592,
            "freq_hz": 12.0,
            "mean_residual_mm": 18.04,
            "z": 5.31,
        }
    )
    assert text == (
        "delayed stutter preload at phi = 0.592 (12 Hz) is under-predicted by 18.0 mm (z = +5.3)"
    )


def test_diagnosis_json_contract(tmp_path: Path) -> None:
    """granbayes diagnose writes diagnosis.json with every key of shared/data-format.md."""
    table = _table({"c_d": 150.0})
    folder = write_experiment(tmp_path / "exp", table, Experiment())
    out = tmp_path / "out"
    code = main(
        [
            "diagnose",
            str(folder),
            "--out",
            str(out),
            "--candidates",
            "drag,viscous",
            "--walkers",
            "8",
            "--max-steps",
            "400",
            "--seed",
            "2",
            "--quiet",
        ]
    )
    assert code == 0
    rec = json.loads((out / "diagnosis.json").read_text())
    assert set(rec["baseline"]) >= {"terms", "elpd", "rmse_mm"}
    assert rec["baseline"]["terms"] == ["depth"]
    assert {"command", "phi", "mean_residual_mm"} <= set(rec["misfit"][0])
    for cand in rec["candidates"]:
        assert {"added", "elpd_diff", "elpd_diff_se", "rmse_mm"} <= set(cand)
    assert rec["verdict"] in ("baseline_adequate", "extended")
    sel = rec["selected"]
    assert {
        "terms",
        "added",
        "elpd_gain",
        "elpd_gain_se",
        "rmse_before_mm",
        "rmse_after_mm",
    } <= set(sel)
    assert (sel["added"] == []) == (rec["verdict"] == "baseline_adequate")
    for name in ("report.md", "residuals_baseline.png", "residuals_selected.png"):
        assert (out / name).exists()
    assert "SYNTHETIC" in (out / "report.md").read_text()


def test_diagnose_bad_input_is_refused_before_any_fit(tmp_path: Path, capsys, monkeypatch):
    """Unknown term and bad data: exit 2, one line, nothing written, no sampling."""
    import granbayes.criticism as gc

    monkeypatch.setattr(gc, "fit", lambda *a, **k: pytest.fail("sampled despite bad input"))
    table = _table({})
    folder = write_experiment(tmp_path / "exp", table, Experiment())
    code = main(["diagnose", str(folder), "--out", str(tmp_path / "o"), "--baseline", "dept"])
    assert code == 2
    assert "dept" in capsys.readouterr().err
    bad = table.copy()
    bad.loc[2, "command"] = "hop"
    bad.to_csv(folder / "jumps.csv", index=False)
    code = main(["diagnose", str(folder), "--out", str(tmp_path / "o")])
    err = capsys.readouterr().err.strip()
    assert code == 2 and "jumps.csv" in err and "row 3" in err and "command" in err
    assert len(err.splitlines()) == 1
    assert not (tmp_path / "o").exists()


def test_rule_keeps_the_baseline_without_clear_evidence() -> None:
    """A candidate whose gain is below the threshold is not added."""
    table = _table({})
    cfg = DiagnoseConfig(candidates=("viscous",), sampler=SMALL, min_gain=1e6)
    d = diagnose(Experiment(), table, cfg, seed=4, log=lambda *a, **k: None)
    assert d.verdict == "baseline_adequate"
    assert d.to_json()["selected"]["added"] == []
