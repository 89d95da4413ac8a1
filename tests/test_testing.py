"""The test kit: the fake fit has a real fit's structure, and reports and statistics run
on it without a sampler."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from granbayes import Experiment, stats
from granbayes._fitting import FitSettings, fit
from granbayes._synthetic import make_jumps
from granbayes.commands import COMMAND_NAMES
from granbayes.report import write_fit_report
from granbayes.testing import QUICK_SAMPLER, fake_fit, simulate_height_scipy, synthetic_jumps

COMMANDS = ("single", "preload", "stutter")


@pytest.fixture(scope="module")
def real():
    """A real (capped) fit of the fake fit's design."""
    table = synthetic_jumps(
        lambda phi: {"k": 4000.0 + 1.5e5 * (phi - 0.612), "c_d": 20.0},
        3.0,
        seed=2,
        phis=(0.602, 0.622),
        freqs_hz=(8.0, 12.0),
        commands=COMMANDS,
        trials=3,
        settings_columns=True,
    )
    config = FitSettings(terms=("depth", "drag"), sampler=QUICK_SAMPLER, n_prior_draws=40)
    return fit(Experiment(), table, config, seed=1).datatree


def test_fake_fit_has_the_structure_of_a_real_fit(real) -> None:
    """Same groups, variables, dimensions, units and attributes (values aside)."""
    fake = fake_fit(3, commands=COMMANDS)
    assert set(fake.children) == set(real.children)
    for group in real.children:
        a, b = fake[group].to_dataset(), real[group].to_dataset()
        assert set(a.data_vars) == set(b.data_vars), group
        for name in b.data_vars:
            assert a[name].dims == b[name].dims, (group, name)
            assert a[name].attrs.get("units") == b[name].attrs.get("units"), (group, name)
        assert set(a.coords) >= {c for c in b.coords if c not in ("chain", "draw")}, group
    assert set(fake.attrs) == set(real.attrs)
    for key in ("config", "priors", "experiment"):
        assert json.loads(fake.attrs[key]).keys() == json.loads(real.attrs[key]).keys(), key
    assert json.loads(fake.attrs["parameters"]) == json.loads(real.attrs["parameters"])
    fake_run, real_run = json.loads(fake.attrs["runs"])[0], json.loads(real.attrs["runs"])[0]
    assert set(fake_run) == set(real_run)
    assert fake_run["coordinates"] == real_run["coordinates"]


def test_fake_fit_is_seeded() -> None:
    """The same seed gives the same tree; another seed other draws."""
    a, b, c = fake_fit(5), fake_fit(5), fake_fit(6)
    np.testing.assert_array_equal(a.posterior["k"].values, b.posterior["k"].values)
    assert not np.array_equal(a.posterior["k"].values, c.posterior["k"].values)


@pytest.mark.long
def test_statistics_and_the_report_run_on_a_fake_fit(tmp_path: Path) -> None:
    """No sampler: the report's tables and figures, labelled SYNTHETIC, from a fake fit."""
    dt = fake_fit(7, terms=("depth", "drag", "compaction"))
    loo = stats.loo(dt)
    assert np.isfinite(loo["elpd"]) and loo["elpd_i"].shape == (dt.observed_data.sizes["jump"],)
    cells = stats.residual_table(dt)
    assert len(cells) == 2 * 2 * 3  # phi x frequency x command
    ident = stats.identifiability_table(dt)
    assert set(ident["parameter"]) == {"k", "c_d", "c_comp", "sigma_mm"}
    written = write_fit_report(dt, tmp_path)
    names = {p.name for p in written}
    assert {"posterior.nc", "summary.md", "predictive.png", "rank.png", "trace.png"} <= names
    assert {"prior_posterior.png", "loo_pit.png", "corner_phi0.602.png"} <= names
    assert "SYNTHETIC" in (tmp_path / "summary.md").read_text()


def test_synthetic_jumps_come_from_the_oracle_with_the_draws_of_make_jumps() -> None:
    """Heights are the oracle's, not the kernel's; the scatter is make_jumps's, draw for draw.

    The kernel at converged settings agrees with the oracle within 1e-4 mm here (the
    reference tolerance is 0.05 mm), so the kit's table and the kernel's differ only by that.
    """
    law = {"k": 3500.0, "c_d": 25.0}
    kw = {"phis": (0.602, 0.622), "freqs_hz": (8.0,), "trials": 2, "seed": 3}
    kit = synthetic_jumps(law, 2.0, decimals=None, true_heights=True, **kw)
    ref = make_jumps(lambda _phi: law, 2.0, decimals=None, **kw)
    cell_exp = Experiment().replace(freq_hz=8.0)
    oracle = np.repeat(
        [simulate_height_scipy(c, p, law, cell_exp) for p in kw["phis"] for c in COMMAND_NAMES],
        2,
    )
    scatter = np.random.default_rng(3).normal(0.0, 2.0, size=len(oracle))  # make_jumps's draws
    np.testing.assert_array_equal(kit["height_mm"].to_numpy(), oracle + scatter)
    np.testing.assert_allclose(kit["height_mm"], ref["height_mm"], rtol=0, atol=1e-4)
    assert (kit["source"] == "synthetic: granbayes.testing.synthetic_jumps seed=3").all()
