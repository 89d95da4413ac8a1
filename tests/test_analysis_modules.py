"""The analysis modules of the package: granbayes.analysis (maps, optimal, mechanics), figures.

Fast, seeded unit tests of what the scripts of ``analyses/`` are built from (the scripts
themselves run end to end in tests/test_analyses.py). Posteriors here are small
hand-made DataTrees; measured heights are simulated from a known law (SYNTHETIC data,
labelled so in their ``source`` column).
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pandas as pd
import pytest
import xarray as xr
from matplotlib.figure import Figure

from granbayes import (
    COMMAND_NAMES,
    Experiment,
    InputError,
    figures,
    simulate,
    simulate_trajectory,
)
from granbayes import analysis as an
from granbayes import stats as gstats
from granbayes.analysis import maps, mechanics, optimal

PHI_C = 0.612
SYNTHETIC = "SYNTHETIC (tests/test_analysis_modules.py)"


def posterior_tree(
    rng: np.random.Generator, phis: tuple[float, ...] = (0.592, 0.632), n: int = 40
) -> xr.DataTree:
    """A posterior of depth + drag over (chain, draw, phi): k [N/m], c_d [kg/m], sigma_mm."""
    shape = (2, n, len(phis))
    k = np.linspace(3000.0, 6000.0, len(phis)) * (1 + 0.02 * rng.standard_normal(shape))
    ds = xr.Dataset(
        {
            "k": (("chain", "draw", "phi"), k),
            "c_d": (("chain", "draw", "phi"), 20.0 + 2.0 * rng.standard_normal(shape)),
            "sigma_mm": (("chain", "draw", "phi"), 3.0 + 0.1 * rng.random(shape)),
        },
        coords={"chain": [0, 1], "draw": np.arange(n), "phi": list(phis)},
    )
    return xr.DataTree.from_dict({"posterior": ds})


def synthetic_jumps(rng: np.random.Generator, law: dict[str, float], n: int = 4) -> pd.DataFrame:
    """SYNTHETIC preload and delayed-stutter-preload jumps at two phis and two frequencies.

    The trial scatter of each cell is centred, so every cell mean is the law's height.
    """
    rows = []
    exp = Experiment()
    for phi in (0.592, 0.632):
        for command in maps.COMMANDS:
            for freq in (8.0, 12.0):
                h = simulate(command, phi, law, experiment=exp.replace(freq_hz=freq)).height_mm[0]
                noise = rng.normal(0.0, 1.5, n)
                for trial, e in enumerate(noise - noise.mean(), start=1):  # mean: the law's
                    rows.append(
                        {"phi": phi, "command": command, "height_mm": h + e, "trial": trial}
                        | {"freq_hz": freq, "amplitude_mm": exp.command.amplitude_mm}
                        | {"delay_ms": exp.command.delay_ms, "source": SYNTHETIC}
                        | {"settle_periods": exp.command.settle_periods}
                    )
    return pd.DataFrame(rows)


# ---------------------------------------------------------------------------------------
# granbayes.analysis._summaries
# ---------------------------------------------------------------------------------------
def test_interval_is_the_median_and_equal_tailed_quantiles_ignoring_nan() -> None:
    values = np.r_[np.arange(101.0), np.nan]
    assert gstats.interval(values) == pytest.approx((50.0, 5.0, 95.0))
    assert gstats.interval(values, 0.5) == pytest.approx((50.0, 25.0, 75.0))
    assert all(math.isnan(v) for v in gstats.interval([np.nan, np.inf]))
    assert gstats.fmt_triple(1.234, 1.0, 2.0, ".2f") == "1.23 [1.00, 2.00]"
    assert gstats.fmt_interval(values, 2) == "50 [5, 95]"


def test_posterior_draws_are_joint(rng: np.random.Generator) -> None:
    """The same (chain, draw) pair for every name: sigma_mm follows k draw by draw."""
    dt = posterior_tree(rng)
    dt["posterior"]["sigma_mm"] = dt.posterior["k"] / 1000.0
    draws = gstats.posterior_draws(dt, 0.6321, ["k", "sigma_mm"], 50, np.random.default_rng(1))
    assert draws["k"].shape == (50,)
    np.testing.assert_allclose(draws["sigma_mm"], draws["k"] / 1000.0)
    again = gstats.posterior_draws(dt, 0.632, ["k"], 50, np.random.default_rng(1))
    np.testing.assert_array_equal(again["k"], draws["k"])  # nearest phi, seeded


def test_cell_experiment_applies_the_row_settings_and_skips_nan() -> None:
    exp = Experiment()
    out = an.cell_experiment(exp, {"freq_hz": 9.0, "delay_ms": np.nan, "phi": 0.6})
    assert out.command.freq_hz == 9.0
    assert out.command.delay_ms == exp.command.delay_ms
    assert out.command.amplitude_mm == exp.command.amplitude_mm


def test_paired_probability_and_correlations() -> None:
    a = np.array([1.0, 2.0, np.nan, 4.0])
    assert gstats.p_greater(a, np.array([0.0, 3.0, 1.0, 3.0])) == pytest.approx(2 / 3)
    assert math.isnan(gstats.p_greater([np.nan], [1.0]))
    x = np.array([0.1, 0.5, 0.9, 1.3])
    draws = np.vstack([x, x + 0.1, x[::-1]])
    r = gstats.correlation(x, 2 * x + 1, draws, np.vstack([2 * x, 3 * x, x]))
    assert r["point"] == pytest.approx(1.0)
    assert r["spearman"]["point"] == pytest.approx(1.0)
    assert r["p_positive"] == pytest.approx(2 / 3)  # the reversed draw correlates negatively
    assert r["n_draws"] == 3
    assert math.isnan(gstats.pearson_rows(np.ones((1, 4)), x[None])[0])  # no spread: undefined


def test_cell_statistics_match_a_groupby(rng: np.random.Generator) -> None:
    table = pd.DataFrame(
        {
            "freq_hz": np.repeat([8.0, 12.0], 6),
            "phi": np.tile(np.repeat([0.6, 0.62], 3), 2),
            "command": np.tile(["stutter", "single", "single"], 4),
            "height_mm": rng.normal(50.0, 5.0, 12),
        }
    )
    stats = gstats.cell_statistics(table)
    g = table.groupby(["freq_hz", "phi", "command"])["height_mm"]
    got = stats.set_index(["freq_hz", "phi", "command"])
    pd.testing.assert_series_equal(got["mean_mm"].sort_index(), g.mean(), check_names=False)
    assert (stats["command"].iloc[:2] == ["single", "stutter"]).all()  # COMMAND_NAMES order
    np.testing.assert_allclose(stats["se_mm"], stats["sd_mm"] / np.sqrt(stats["n"]))


def test_mean_discrepancy_and_posterior_intervals(rng: np.random.Generator) -> None:
    sim = np.full(4000, 50.0)
    med, lo, hi, z = gstats.mean_discrepancy(56.0, 4, sim, np.full(4000, 6.0), rng)
    assert med == pytest.approx(6.0, abs=0.15)  # predictive sd of the mean: 6 / 2 = 3
    assert (lo, hi) == pytest.approx((6.0 - 1.645 * 3, 6.0 + 1.645 * 3), abs=0.3)
    assert z == pytest.approx(2.0, abs=0.05)
    dt = posterior_tree(rng)
    table = gstats.posterior_intervals(dt, ["k", "c_d"], [0.592, 0.632])
    assert list(table.columns) == ["phi", "parameter", "median", "lo", "hi"]
    assert list(table["parameter"]) == ["k", "k", "c_d", "c_d"]
    assert (table["lo"] < table["median"]).all() and (table["median"] < table["hi"]).all()


# ---------------------------------------------------------------------------------------
# granbayes.analysis.maps
# ---------------------------------------------------------------------------------------
def test_refine_interpolates_in_log_k_and_spreads_failures() -> None:
    h = np.array([[0.0, 10.0], [4.0, np.nan], [8.0, 30.0]])
    fine = maps.refine_log_k(h, 4)
    assert fine.shape == (9, 2)
    np.testing.assert_allclose(fine[:, 0], np.arange(9.0))
    assert np.isnan(fine[:8, 1]).all() and fine[8, 1] == 30.0  # the failed point's intervals
    k = maps.refine_k(np.array([100.0, 1000.0]), 2)
    np.testing.assert_allclose(k, [100.0, math.sqrt(1e5), 1000.0])
    assert maps.refine_log_k(h, 1) is not h


def test_evaluate_finds_the_shared_point_of_two_valleys() -> None:
    """Heights linear in (log k, c_d): the valleys cross at the one point fitting both."""
    k = np.geomspace(1000.0, 10000.0, 401)
    cd = np.linspace(0.0, 40.0, 21)
    lk = np.log10(k)[:, None]
    first = 100.0 * (lk - 3.5) + 0.5 * (cd[None] - 21.0)  # zero on its own line
    second = 100.0 * (lk - 3.5) - 0.5 * (cd[None] - 21.0)
    heights = {"preload": (50.0 + first)[None], "delayed_stutter_preload": (60.0 + second)[None]}
    means = {"preload": np.array([50.0]), "delayed_stutter_preload": np.array([60.0])}
    ses = {c: np.array([1.0]) for c in maps.COMMANDS}
    ev = maps.evaluate(heights, means, ses, k, cd)
    assert ev.intersect
    assert ev.closest_se_at[1] in (20.0, 22.0)
    assert ev.closest_se_at[0] == pytest.approx(10**3.5, rel=0.03)
    assert ev.curve_gap_cd_kg_per_m in (20.0, 22.0)
    crossings = maps.curve_crossings(ev, cd, math.log(k[1] / k[0]))
    assert crossings == [pytest.approx(21.0, abs=0.2)]
    far = maps.evaluate(heights, {**means, "preload": np.array([150.0])}, ses, k, cd)
    assert not far.intersect and far.closest_se > maps.TOLERANCE_SE


def test_cells_at_drops_cells_without_a_standard_error() -> None:
    table = pd.DataFrame(
        {
            "phi": 0.6,
            "command": "preload",
            "freq_hz": [8.0, 8.0, 12.0],
            "amplitude_mm": 20.0,
            "height_mm": [40.0, 42.0, 50.0],
        }
    )
    cells, notes = maps.cells_at(table, 0.6, "preload")
    assert [c.label for c in cells] == ["8 Hz"]
    assert cells[0].mean_mm == 41.0 and cells[0].se_mm == pytest.approx(1.0)
    assert len(notes) == 1 and "12 Hz" in notes[0]


def test_misfit_map_accepts_the_generating_law(rng: np.random.Generator) -> None:
    """SYNTHETIC jumps of one depth + drag law: both valleys pass it, so they intersect."""
    law = {"k": 3000.0, "c_d": 20.0}
    table = synthetic_jumps(rng, law)
    grid = maps.GridSpec(9, 5, 4, 1000.0, 9000.0, 40.0)
    notes: list[str] = []
    m = maps.misfit_map(Experiment(), table, 0.592, grid, 20, np.random.default_rng(0), notes)
    assert m is not None and m.observed.intersect
    assert len(m.boot) == 20 and m.boot["intersect"].mean() > 0.5
    assert [b["cell"] for b in m.by_cell] == ["8 Hz", "12 Hz"]
    s = m.summary()
    assert s["intersect_observed"] and s["k_range_N_per_m"][0] <= 1000.0
    assert len(maps.grid_table(m)) == m.k_sim_n_per_m.size * m.cd_kg_per_m.size
    assert set(maps.valley_table([m])["command"]) == set(maps.COMMANDS)
    assert len(maps.cell_table([m])) == 4
    fig = figures.plot_misfit_maps(m, PHI_C, "misfit maps, SYNTHETIC")
    assert isinstance(fig, Figure) and len(fig.axes) == 4  # two maps, overlay, colour bar
    assert isinstance(figures.plot_valleys([m, m], PHI_C, "valleys, SYNTHETIC"), Figure)
    assert maps.misfit_map(Experiment(), table, 0.7, grid, 5, rng) is None  # no cells there


# ---------------------------------------------------------------------------------------
# granbayes.analysis.optimal
# ---------------------------------------------------------------------------------------
def measured() -> pd.DataFrame:
    return pd.DataFrame({"amplitude_mm": [20.0, 20.0], "freq_hz": [8.0, 12.0]})


def test_settings_grid_contains_the_measured_settings() -> None:
    grid = optimal.settings_grid(measured(), 18.0, coarse=True)
    assert 8.0 in grid.freqs_hz and 12.0 in grid.freqs_hz
    assert grid.amplitudes_mm.max() == 18.0  # 20 mm is beyond the limit
    assert optimal.PUBLISHED_DELAY_MS in grid.delays_ms
    table = optimal.setting_table(grid, measured())
    assert set(table["command"]) == set(COMMAND_NAMES)
    extra = table[~table["searched"]]
    assert set(extra["command"]) == {"single", "delayed_stutter"}
    assert (extra["amplitude_mm"] == 20.0).all()
    assert table[table["command"] == "single"]["delay_ms"].isna().all()
    rec = {"freq_hz": 12.5, "amplitude_mm": 20.0, "delay_ms": np.nan, "settle_periods": 1.0}
    assert optimal.describe_setting(rec) == "12.5 Hz, 20 mm, 1-period hold (= 80 ms)"


#: Columns that name a delayed-stutter curve (amplitude [mm], frequency [Hz]).
AF = ("amplitude_mm", "freq_hz")


def test_search_finds_the_best_setting_for_common_draws(rng: np.random.Generator) -> None:
    dt = posterior_tree(rng, n=10)
    grid = optimal.settings_grid(measured(), 20.0, coarse=True)
    settings = optimal.setting_table(grid, measured())
    res = optimal.search(
        Experiment(), dt, 0.592, settings, 12, np.random.default_rng(1), np.random.default_rng(2)
    )
    t = res.settings
    assert res.heights_mm.shape == (len(t), 12)
    assert res.optimum == int(np.nanargmax(np.where(t["eligible"], t["expected_mm"], -np.inf)))
    assert t["p_best_draw"].sum() == pytest.approx(1.0)
    assert (t.loc[t["eligible"], "q05_predictive_mm"] < t.loc[t["eligible"], "expected_mm"]).all()
    entry = res.to_json(measured(), PHI_C)
    assert entry["optimum"]["command"] == t.iloc[res.optimum]["command"]
    assert set(entry["per_command"]) == set(COMMAND_NAMES)
    assert len(entry["published_check"]["at_data_settings"]) == 2
    shapes = entry["delayed_stutter"]["delay_curves"]
    assert shapes and all(s["best_delay_ms"] in grid.delays_ms for s in shapes)
    assert 0.0 <= optimal.robustness(res)["p_optimum_best"] <= 1.0
    for fig in (
        figures.plot_optimum_vs_frequency([res], PHI_C, 12.0, "SYNTHETIC"),
        figures.plot_delay_curves([res, res], measured(), PHI_C, "SYNTHETIC"),
        figures.plot_optimum_vs_phi([res, res], PHI_C, "SYNTHETIC"),
    ):
        assert isinstance(fig, Figure)
    # the left panel of the delay curves shows negative heights (robot stays in the bed)
    t = res.settings
    sunk = dataclasses.replace(
        res, settings=t.assign(**{c: t[c] - 40.0 for c in ("expected_mm", "lo_mm", "hi_mm")})
    )
    ax_left = figures.plot_delay_curves([sunk], measured(), PHI_C, "SYNTHETIC").axes[0]
    curve = optimal.delay_curve(sunk, *[sunk.settings.iloc[sunk.optimum][c] for c in AF])
    assert curve["lo_mm"].min() < 0.0
    assert ax_left.get_ylim()[0] <= curve["lo_mm"].min()


def test_draws_at_refuses_a_posterior_without_sigma(rng: np.random.Generator) -> None:
    dt = posterior_tree(rng)
    dt["posterior"]["sigma_mm"] = dt.posterior["sigma_mm"] * np.nan
    with pytest.raises(InputError, match="sigma_mm"):
        optimal.draws_at(dt, 0.592, 20, rng)


# ---------------------------------------------------------------------------------------
# granbayes.analysis.mechanics
# ---------------------------------------------------------------------------------------
def test_advancing_episodes_and_the_stieltjes_sum() -> None:
    """Two episodes; the cone grows in the first only; shedding carries no impulse."""
    data = pd.DataFrame(
        {
            "t_s": [0.0, 0.01, 0.02, 0.03, 0.04, 0.05, 0.06],
            "mode": ["free", "advancing", "advancing", "contact", "advancing", "advancing", "free"],
            "v_foot_m_s": [0.0, -1.0, -1.0, 0.0, -0.5, -0.5, 0.0],
            "added_mass_kg": [0.0, 0.0, 0.002, 0.0, 0.0, 0.0, 0.0],
        }
    )
    label, first, stop = mechanics.advancing_episodes(data["mode"].to_numpy())
    assert list(label) == [0, 1, 1, 0, 2, 2, 0]
    assert list(first) == [1, 4] and list(stop) == [3, 6]
    imp = mechanics.added_mass_impulse(data)
    assert imp.total_mN_s == pytest.approx(2.0)  # 1 m/s x 2 g
    assert imp.peak_mN_s == pytest.approx(2.0)
    assert imp.duration_ms == pytest.approx(20.0) and imp.start_ms == pytest.approx(10.0)
    assert imp.n_intervals == 2


def test_impulse_of_a_simulated_jump_agrees_with_the_flux_quadrature() -> None:
    law = {"k": 3000.0, "c_d": 20.0, "kappa": 1.0}
    traj = simulate_trajectory("stutter", 0.602, law, max_step=mechanics.MAX_STEP_S)
    imp = mechanics.added_mass_impulse(traj.data)
    quad = mechanics.flux_quadrature_mN_s(traj.data, 1.0, 0.602, Experiment())
    assert imp.total_mN_s > 0 and imp.n_intervals >= 1
    assert quad == pytest.approx(imp.total_mN_s, rel=0.02)
    cell = {"command": "stutter", "phi": 0.602, "freq_hz": 12.0}
    table, check = mechanics.integral_check(Experiment(), [(cell, law)])
    assert len(table) == 1 and check["max_rel_diff_double_step"] < 0.02
    draws = {k: np.array([v, v]) for k, v in law.items()}
    imps = mechanics.simulate_impulses("stutter", 0.602, draws, Experiment())
    assert [i.total_mN_s for i in imps] == pytest.approx([imp.total_mN_s] * 2)
    fig = figures.plot_added_mass(traj.data, Experiment(), 1.0, 0.602, "SYNTHETIC law")
    assert len(fig.axes) == 3


def test_rigid_floor_sweep_power_and_refined_optimum() -> None:
    exp = Experiment()
    freqs = np.array([8.0, 10.0, 12.0])
    h = mechanics.rigid_heights_mm(exp, "single", freqs)
    assert np.isfinite(h).all() and (h > 0).all()
    f, best = mechanics.best_frequency(exp, "single", freqs, h)
    assert best >= np.nanmax(h) and freqs[0] <= f <= freqs[-1]
    p = mechanics.actuator_power(exp, "single", 10.0)
    assert p["peak_power_w"] > 0 and p["positive_work_j"] > 0


# ---------------------------------------------------------------------------------------
# granbayes.figures: the remaining analysis figures
# ---------------------------------------------------------------------------------------
def test_heights_kappa_and_coefficient_figures(rng: np.random.Generator) -> None:
    table = synthetic_jumps(rng, {"k": 3000.0, "c_d": 20.0}, n=3)
    stats = gstats.cell_statistics(table)
    fig = figures.plot_heights_vs_phi(table, stats, PHI_C, "heights, SYNTHETIC")
    assert len(fig.axes) == 2  # one panel per frequency
    cells = stats.assign(
        kappa_median=0.5, kappa_lo=0.2, kappa_hi=0.9, y_median=stats["mean_mm"]
    ).assign(y_lo=lambda d: d["y_median"] - 1, y_hi=lambda d: d["y_median"] + 1)
    fig = figures.plot_vs_kappa(cells, "y", "y [mm]", PHI_C, 2.0, "caption", "SYNTHETIC")
    assert len(fig.axes) == 2
    intervals = pd.DataFrame(
        {
            "phi": [0.592, 0.632, 0.592],
            "command": ["shared", "shared", "preload"],
            "parameter": "k",
            "median": [3000.0, 5000.0, 3100.0],
            "lo": [2900.0, 4800.0, 2800.0],
            "hi": [3100.0, 5200.0, 3300.0],
        }
    )
    laws = [{"terms": ("depth",), "parameters": ("k",), "intervals": intervals}]
    fig = figures.plot_coefficients_vs_phi(laws, [0.592, 0.632], PHI_C, "SYNTHETIC")
    assert fig.axes[0].get_yscale() == "log"
    offsets = figures.command_offsets([0.592, 0.632], 0.0006)
    assert offsets["single"] == pytest.approx(-0.0012) and offsets["stutter"] == 0.0
