"""Optimal jumping under a posterior: which command and settings jump highest, and reliably.

At one volume fraction, :func:`search` simulates every command on a grid of actuator
settings (frequency, amplitude, delay of the delayed stutter, settle periods of the
delayed stutter preload) for the same joint posterior draws of the force law at every
setting (common random numbers, so differences between settings are paired). It reports
per setting the expected (posterior mean) height, its equal-tailed interval and the 5th
percentile of the posterior predictive height (model height plus the trial scatter
``Normal(0, sigma_mm)``), and finds two optima: the largest expected height and the most
reliable jump (the highest predictive 5th percentile). Per posterior draw the best setting
is found too (:func:`robustness`: how sure the posterior is about the optimum).
:func:`published_check` and :func:`delay_shape` hold the model against the published
finding (physics-model.md section 7.1): a delayed stutter with a ~50 ms delay beats the
single jump on loose beds, and a delay near 0 gives the lowest jumps.

Heights in mm, frequencies in Hz, amplitudes in mm, delays in ms, holds in periods.

:func:`granbayes.predict` answers the same question for a few settings from a saved fit
(draws without replacement, its own noise model); this module searches thousands of
settings with one batched simulator call per chunk and keeps every per-draw height.

Length: about 700 lines: the grid search over every command's settings, its posterior
summaries and the robust choice.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np
import pandas as pd
import xarray as xr

from .._errors import InputError
from .._experiment import Experiment
from .._simulator import build_rows, simulate_rows
from ..commands import COMMAND_NAMES, COMMANDS, CommandProgram, CommandSettings, build_command
from ..commands import SETTINGS as SETTING_COLUMNS
from ..forces import PARAMETER_NAMES
from ..stats import CI_PROB, eti_probs, interval, p_greater, posterior_draws

__all__ = [
    "MAX_FAIL_FRACTION",
    "N_NOISE",
    "NEAR_ZERO_MS",
    "PUBLISHED_DELAY_MS",
    "delay_curve",
    "delay_settings",
    "delay_shape",
    "describe_setting",
    "draws_at",
    "force_names",
    "measured_settings",
    "OptimumSearch",
    "published_check",
    "robustness",
    "search",
    "setting_table",
    "settings_grid",
    "SettingsGrid",
]

#: Settings whose posterior draws fail more often than this are left out of the search.
MAX_FAIL_FRACTION = 0.05
#: Quantile of the posterior predictive height that defines the "reliable" optimum.
RELIABLE_QUANTILE = 0.05
#: Published delay of the delayed stutter (Aguilar & Goldman 2015) [ms].
PUBLISHED_DELAY_MS = 50.0
#: Delays up to this count as "near 0" in the check of the published finding [ms].
NEAR_ZERO_MS = 20.0
#: The two commands with a hold between countermovement and push-off.
DELAYED = ("delayed_stutter", "delayed_stutter_preload")
#: Noise replicates per posterior draw for the predictive quantile (no extra simulation).
N_NOISE = 20


# ----------------------------------------------------------------------------------------
@dataclass(frozen=True)
class SettingsGrid:
    """The actuator settings searched.

    Attributes
    ----------
    freqs_hz : ndarray
        Actuator frequencies [Hz].
    amplitudes_mm : ndarray
        Actuator amplitudes [mm], all at most the actuator limit.
    delays_ms : ndarray
        Holds of the delayed stutter [ms].
    settle_periods : ndarray
        Holds of the delayed stutter preload [periods].
    """

    freqs_hz: np.ndarray
    amplitudes_mm: np.ndarray
    delays_ms: np.ndarray
    settle_periods: np.ndarray


def measured_settings(table: pd.DataFrame) -> pd.DataFrame:
    """Distinct (``amplitude_mm``, ``freq_hz``) of the measured single jumps (all if none).

    Parameters
    ----------
    table : pandas.DataFrame
        The jumps.
    """
    rows = table[table["command"] == "single"]
    rows = rows if not rows.empty else table
    pairs = rows[["amplitude_mm", "freq_hz"]].astype(float).drop_duplicates()
    return pairs.sort_values(["freq_hz", "amplitude_mm"]).reset_index(drop=True)


def settings_grid(
    measured: pd.DataFrame, max_amplitude_mm: float, *, coarse: bool = False
) -> SettingsGrid:
    """The search grid: 5-20 Hz, half to full amplitude, delays 0-150 ms, holds 1-4 periods.

    The measured frequencies and amplitudes (when within the limit) and the published
    50 ms delay are always included, so the data's own settings are grid points.

    Parameters
    ----------
    measured : pandas.DataFrame
        ``amplitude_mm`` [mm] and ``freq_hz`` [Hz] of the data (:func:`measured_settings`).
    max_amplitude_mm : float
        The actuator limit [mm].
    coarse : bool
        A very coarse grid (tests and quick looks).

    Returns
    -------
    SettingsGrid
    """
    if coarse:
        freqs = np.linspace(5.0, 20.0, 3)
        amps = np.array([0.5, 1.0]) * max_amplitude_mm
        delays = np.array([0.0, 50.0, 100.0, 150.0])
        settles = np.array([1.0, 3.0])
    else:
        freqs = np.linspace(5.0, 20.0, 11)
        amps = np.linspace(0.5, 1.0, 4) * max_amplitude_mm
        delays = np.arange(0.0, 151.0, 10.0)
        settles = np.array([1.0, 2.0, 3.0, 4.0])
    freqs = np.union1d(np.round(freqs, 6), measured["freq_hz"].to_numpy())
    amp = measured["amplitude_mm"].to_numpy()
    amps = np.union1d(np.round(amps, 6), amp[amp <= max_amplitude_mm + 1e-9])
    delays = np.union1d(delays, [PUBLISHED_DELAY_MS])
    return SettingsGrid(freqs, amps, delays, settles)


def setting_table(grid: SettingsGrid, measured: pd.DataFrame) -> pd.DataFrame:
    """One row per (command, setting); ``searched`` marks the grid, not the extra data rows.

    The extra rows are the single jump and the 50 ms delayed stutter at every measured
    (amplitude, frequency), for the comparison with the published finding. Settings that
    do not apply to a command (the delay of a single jump, say) are NaN.

    Parameters
    ----------
    grid : SettingsGrid
    measured : pandas.DataFrame
        :func:`measured_settings`.

    Returns
    -------
    pandas.DataFrame
        ``command``, the setting columns and ``searched``; no duplicate settings.
    """
    recs: list[dict] = []
    for command in COMMAND_NAMES:
        for freq in grid.freqs_hz:
            for amp in grid.amplitudes_mm:
                base = {"command": command, "amplitude_mm": amp, "freq_hz": freq}
                uses = COMMANDS[command].uses  # its own setting, searched over its grid
                if "delay_ms" in uses:
                    recs += [{**base, "delay_ms": d} for d in grid.delays_ms]
                elif "settle_periods" in uses:
                    recs += [{**base, "settle_periods": s} for s in grid.settle_periods]
                else:
                    recs.append(base)
    table = pd.DataFrame(recs, columns=["command", *SETTING_COLUMNS])
    table["searched"] = True
    extra = []
    for amp, freq in measured[["amplitude_mm", "freq_hz"]].itertuples(index=False):
        base = {"amplitude_mm": amp, "freq_hz": freq}
        extra.append({"command": "single", **base})
        extra.append({"command": "delayed_stutter", **base, "delay_ms": PUBLISHED_DELAY_MS})
    extra_df = pd.DataFrame(extra, columns=["command", *SETTING_COLUMNS])
    extra_df["searched"] = False
    table = pd.concat([table, extra_df], ignore_index=True)
    key = pd.Series(
        [
            (rec["command"], *(round(float(rec[s]), 9) for s in SETTING_COLUMNS))
            for rec in table.to_dict("records")
        ]
    ).astype(str)
    return table[~key.duplicated().to_numpy()].reset_index(drop=True)


def programs_of(settings: pd.DataFrame, defaults: CommandSettings) -> list[CommandProgram]:
    """One command program per row of ``settings`` (NaN settings take ``defaults``)."""
    out = []
    for rec in settings.to_dict("records"):
        values = {
            s: float(getattr(defaults, s)) if pd.isna(rec[s]) else float(rec[s])
            for s in SETTING_COLUMNS
        }
        out.append(build_command(rec["command"], CommandSettings(**values)))
    return out


def describe_setting(rec: Mapping) -> str:
    """A setting in words, e.g. ``"12.5 Hz, 20 mm, 50 ms delay"``.

    Parameters
    ----------
    rec : mapping
        A row of a search result.
    """
    text = f"{rec['freq_hz']:.3g} Hz, {rec['amplitude_mm']:.3g} mm"
    if pd.notna(rec.get("delay_ms", np.nan)):
        text += f", {rec['delay_ms']:.0f} ms delay"
    if pd.notna(rec.get("settle_periods", np.nan)):
        n = float(rec["settle_periods"])
        hold_ms = 1e3 * n / float(rec["freq_hz"])
        text += f", {n:g}-period hold (= {hold_ms:.0f} ms)"
    return text


# ----------------------------------------------------------------------------------------
def force_names(dt: xr.DataTree) -> list[str]:
    """Force parameters in a posterior (everything with a ``phi`` axis but ``sigma_mm``).

    Parameters
    ----------
    dt : xarray.DataTree
        A fit.
    """
    post = dt.posterior
    return [
        str(v)
        for v in post.data_vars
        if v in PARAMETER_NAMES and "phi" in post[v].dims and v != "sigma_mm"
    ]


def draws_at(
    dt: xr.DataTree, phi: float, n: int, rng: np.random.Generator
) -> dict[str, np.ndarray]:
    """``n`` joint draws of the force parameters present at ``phi`` and of ``sigma_mm``.

    Parameters that are NaN for every draw at ``phi`` are absent terms and are dropped;
    draws with any remaining NaN are dropped.

    Raises
    ------
    InputError
        If ``k`` or ``sigma_mm`` is missing, or fewer than ``max(10, n // 2)`` draws are
        finite.

    Parameters
    ----------
    dt : xarray.DataTree
        A fit.
    phi : float
        Volume fraction [-].
    n : int
        Number of draws.
    rng : numpy.random.Generator
        Source of randomness.
    """
    draws = posterior_draws(dt, phi, [*force_names(dt), "sigma_mm"], n, rng)
    draws = {k: v for k, v in draws.items() if np.isfinite(v).any()}
    if "sigma_mm" not in draws or "k" not in draws:
        raise InputError(f"posterior has no finite k or sigma_mm at phi = {phi:g}")
    keep = np.logical_and.reduce([np.isfinite(v) for v in draws.values()])
    if keep.sum() < max(10, n // 2):
        raise InputError(f"posterior has too few finite draws at phi = {phi:g}")
    return {k: v[keep] for k, v in draws.items()}


# ----------------------------------------------------------------------------------------
@dataclass
class OptimumSearch:
    """Everything :func:`search` computed at one volume fraction.

    Attributes
    ----------
    phi : float
        Volume fraction [-].
    settings : pandas.DataFrame
        The settings with per-setting summaries: ``phi``, ``command``, the settings,
        ``searched``, ``expected_mm``, ``median_mm``, ``lo_mm``, ``hi_mm`` (posterior of the
        simulated height), ``q05_predictive_mm``, ``fail_fraction``, ``eligible`` and
        ``p_best_draw`` (share of draws for which the setting is the best).
    heights_mm : ndarray, shape (n_settings, n_draws)
        Simulated (noise-free) heights per setting and posterior draw; NaN if failed.
    best_per_draw : ndarray of int, shape (n_draws,)
        Row of ``settings`` that is best for each draw (-1 if none).
    optimum : int
        Row of the expected-height optimum.
    reliable : int
        Row of the 5th-percentile optimum.
    family_optimum : dict of str to int
        Expected-height optimum per command (-1 if none).
    family_reliable : dict of str to int
        5th-percentile optimum per command (-1 if none).
    n_failed : int
        Failed simulations.
    """

    phi: float
    settings: pd.DataFrame
    heights_mm: np.ndarray
    best_per_draw: np.ndarray
    optimum: int
    reliable: int
    family_optimum: dict[str, int]
    family_reliable: dict[str, int]
    n_failed: int

    def to_json(self, measured: pd.DataFrame, phi_c: float) -> dict:
        """The optima, their robustness and the published check, JSON-ready.

        Parameters
        ----------
        measured : pandas.DataFrame
            :func:`measured_settings` (for :func:`published_check` and the delay curves).
        phi_c : float
            Critical packing [-].

        Returns
        -------
        dict
            ``phi``, ``phi_minus_phi_c``, ``optimum`` (command, settings, expected height,
            its (median, lo, hi) [mm], the predictive 5th percentile and the robustness of
            :func:`robustness`), ``reliable_optimum``, ``per_command`` (best and most
            reliable setting of each command), ``delayed_stutter`` (per-draw optimal delay
            and :func:`delay_shape` of each examined delay curve), ``published_check`` and
            ``failed_jumps``.
        """
        t, h = self.settings, self.heights_mm
        opt, rel = t.iloc[self.optimum], t.iloc[self.reliable]
        rob = robustness(self)
        shapes = [
            {"role": c["role"], **delay_shape(self, c["amplitude_mm"], c["freq_hz"])}
            for c in delay_settings(self, measured)
        ]
        entry = {
            "phi": self.phi,
            "phi_minus_phi_c": self.phi - phi_c,
            "optimum": {
                "command": opt["command"],
                "settings": _settings_of(opt),
                "expected_mm": opt["expected_mm"],
                "height_mm": interval(h[self.optimum]),
                "q05_predictive_mm": opt["q05_predictive_mm"],
                "p_optimal": rob["p_optimum_best"],
                "p_command_optimal": rob["p_command_best"],
                "p_delayed_command_optimal": rob["p_delayed_best"],
                "optimal_freq_hz": rob["optimal_freq_hz"],
                "optimal_amplitude_mm": rob["optimal_amplitude_mm"],
                "regret_mm": rob["regret_mm"],
                "regret_mm_p95": rob["regret_mm_p95"],
            },
            "reliable_optimum": {
                "command": rel["command"],
                "settings": _settings_of(rel),
                "q05_predictive_mm": rel["q05_predictive_mm"],
                "expected_mm": rel["expected_mm"],
                "height_mm": interval(h[self.reliable]),
            },
            "per_command": {},
            "delayed_stutter": {
                "per_draw_optimal_delay_ms": rob["ds_optimal_delay_ms"],
                "delay_curves": shapes,
            },
            "published_check": published_check(self, measured),
            "failed_jumps": self.n_failed,
        }
        for command in COMMAND_NAMES:
            i_e, i_q = self.family_optimum[command], self.family_reliable[command]
            if i_e >= 0:
                e, q = t.iloc[i_e], t.iloc[i_q]
                entry["per_command"][command] = {
                    "settings": _settings_of(e),
                    "expected_mm": e["expected_mm"],
                    "height_mm": interval(h[i_e]),
                    "reliable_settings": _settings_of(q),
                    "reliable_q05_mm": q["q05_predictive_mm"],
                }
        return entry


def _settings_of(rec: pd.Series) -> dict[str, float]:
    """The settings of a row that apply to its command (the non-NaN ones)."""
    return {s: rec[s] for s in SETTING_COLUMNS if pd.notna(rec[s])}


def simulate_settings(
    experiment: Experiment, phi: float, params: Mapping[str, np.ndarray], settings: pd.DataFrame
) -> tuple[np.ndarray, int]:
    """Heights [mm] of every setting for every draw, shape (n_settings, n_draws).

    The same parameter rows are used for every setting (common random numbers). Returns
    the heights (NaN where failed) and the number of failed simulations.
    """
    rows = build_rows(experiment.robot, phi, params)
    programs = programs_of(settings, experiment.command)
    n_draw, n_set = rows.shape[0], len(programs)
    heights = np.full((n_set, n_draw), np.nan)
    n_failed = 0
    chunk = max(1, 40_000 // n_draw)  # settings per call: bounded memory
    for start in range(0, n_set, chunk):
        stop = min(n_set, start + chunk)
        index = np.repeat(np.arange(stop - start), n_draw)
        res = simulate_rows(np.tile(rows, (stop - start, 1)), programs[start:stop], index)
        n_failed += int((~res.ok).sum())
        heights[start:stop] = np.where(res.ok, res.height_mm, np.nan).reshape(-1, n_draw)
    return heights, n_failed


def summarise_settings(
    settings: pd.DataFrame, heights_mm: np.ndarray, predictive_mm: np.ndarray
) -> pd.DataFrame:
    """Per setting: expected height, its interval, the predictive 5th percentile, failures."""
    out = settings.copy()
    finite = np.isfinite(heights_mm)
    n_ok = finite.sum(axis=1)
    with np.errstate(invalid="ignore", divide="ignore"):
        out["expected_mm"] = np.where(n_ok > 0, np.nansum(heights_mm, axis=1) / n_ok, np.nan)
    q = np.full((len(out), 3), np.nan)
    q05 = np.full(len(out), np.nan)
    lo_p, _, hi_p = eti_probs(CI_PROB)
    for i in np.flatnonzero(n_ok > 0):
        q[i] = np.quantile(heights_mm[i, finite[i]], [0.5, lo_p, hi_p])
        pred = predictive_mm[i][np.isfinite(predictive_mm[i])]
        q05[i] = np.quantile(pred, RELIABLE_QUANTILE)
    out["median_mm"], out["lo_mm"], out["hi_mm"] = q.T
    out["q05_predictive_mm"] = q05
    out["fail_fraction"] = 1.0 - n_ok / heights_mm.shape[1]
    out["eligible"] = out["searched"] & (out["fail_fraction"] <= MAX_FAIL_FRACTION)
    return out


def argmax_where(values: pd.Series, mask: pd.Series) -> int:
    """Row position of the largest finite ``values`` where ``mask`` (-1 if none)."""
    v = np.where(mask.to_numpy() & np.isfinite(values.to_numpy()), values.to_numpy(), -np.inf)
    return int(np.argmax(v)) if np.isfinite(v).any() else -1


def search(
    experiment: Experiment,
    dt: xr.DataTree,
    phi: float,
    settings: pd.DataFrame,
    n_draws: int,
    rng_draws: np.random.Generator,
    rng_noise: np.random.Generator,
) -> OptimumSearch:
    """Simulate every setting at ``phi`` for the same posterior draws and find the optima.

    Parameters
    ----------
    experiment : Experiment
        The robot (and default settings for what a setting row leaves NaN).
    dt : xarray.DataTree
        A fit's DataTree (force parameters and ``sigma_mm`` [mm] over ``phi``).
    phi : float
        Volume fraction [-] (the nearest one of the posterior is used).
    settings : pandas.DataFrame
        :func:`setting_table`.
    n_draws : int
        Joint posterior draws (with replacement).
    rng_draws, rng_noise : numpy.random.Generator
        Pick the draws; draw the trial scatter (:data:`N_NOISE` replicates per draw).

    Returns
    -------
    OptimumSearch

    Raises
    ------
    InputError
        If the posterior is unusable at ``phi`` or every simulated jump failed.
    """
    draws = draws_at(dt, phi, n_draws, rng_draws)
    sigma_mm = draws.pop("sigma_mm")
    heights, n_failed = simulate_settings(experiment, phi, draws, settings)
    eps = rng_noise.standard_normal((heights.shape[1], N_NOISE))
    predictive = (heights[:, :, None] + sigma_mm[None, :, None] * eps[None]).reshape(
        heights.shape[0], -1
    )
    table = summarise_settings(settings, heights, predictive)
    table.insert(0, "phi", phi)
    eligible = table["eligible"]
    optimum = argmax_where(table["expected_mm"], eligible)
    reliable = argmax_where(table["q05_predictive_mm"], eligible)
    if optimum < 0:
        raise InputError(f"every simulated jump failed at phi = {phi:g}")
    family_optimum, family_reliable = {}, {}
    for command in COMMAND_NAMES:
        mask = eligible & (table["command"] == command)
        family_optimum[command] = argmax_where(table["expected_mm"], mask)
        family_reliable[command] = argmax_where(table["q05_predictive_mm"], mask)
    masked = np.where(eligible.to_numpy()[:, None] & np.isfinite(heights), heights, -np.inf)
    best = np.argmax(masked, axis=0)
    best[~np.isfinite(masked.max(axis=0))] = -1
    wins = np.bincount(best[best >= 0], minlength=len(table))
    table["p_best_draw"] = wins / max(1, int((best >= 0).sum()))
    return OptimumSearch(
        phi, table, heights, best, optimum, reliable, family_optimum, family_reliable, n_failed
    )


# ----------------------------------------------------------------------------------------
def find_row(table: pd.DataFrame, command: str, **values: float) -> int:
    """Row position of ``command`` with the given settings (-1 if absent)."""
    mask = table["command"] == command
    for k, v in values.items():
        mask &= np.isclose(table[k].to_numpy(float), v)
    hits = np.flatnonzero(mask.to_numpy())
    return int(hits[0]) if hits.size else -1


def delay_curve(res: OptimumSearch, amplitude_mm: float, freq_hz: float) -> pd.DataFrame:
    """Delayed-stutter rows at one (amplitude, frequency), by delay (searched grid only).

    Parameters
    ----------
    res : OptimumSearch
        A search result.
    amplitude_mm : float
        Amplitude [mm].
    freq_hz : float
        Frequency [Hz].
    """
    t = res.settings
    mask = (
        (t["command"] == "delayed_stutter")
        & t["searched"]
        & np.isclose(t["amplitude_mm"], amplitude_mm)
        & np.isclose(t["freq_hz"], freq_hz)
    )
    return t[mask].sort_values("delay_ms")


def robustness(res: OptimumSearch) -> dict:
    """How sure the posterior is about the optimum, from the per-draw best settings.

    Parameters
    ----------
    res : OptimumSearch
        A search result.

    Returns
    -------
    dict
        ``p_optimum_best`` (share of draws whose best setting is the reported optimum),
        ``p_command_best`` (per command, share of draws whose best setting is of it),
        ``p_delayed_best``, the per-draw optimal frequency and amplitude, the regret [mm]
        (how much higher the draw's own best setting jumps than the reported one; median
        triple and 95th percentile) and the delayed stutter's per-draw optimal delay [ms].
    """
    t = res.settings
    best = res.best_per_draw
    valid = best >= 0
    h_opt = res.heights_mm[res.optimum]
    regret = res.heights_mm[best[valid], np.flatnonzero(valid)] - h_opt[valid]
    regret = regret[np.isfinite(regret)]
    best_rows = t.iloc[best[valid]]
    commands = best_rows["command"].value_counts(normalize=True)
    ds = t["eligible"] & (t["command"] == "delayed_stutter")
    masked = np.where(ds.to_numpy()[:, None], res.heights_mm, np.nan)
    ok_cols = np.isfinite(masked).any(axis=0)
    ds_best = np.nanargmax(np.where(np.isfinite(masked), masked, -np.inf)[:, ok_cols], axis=0)
    delays = t["delay_ms"].to_numpy()[ds_best]
    return {
        "p_optimum_best": float(np.mean(best[valid] == res.optimum)) if valid.any() else math.nan,
        "p_command_best": {str(k): float(v) for k, v in commands.items()},
        "p_delayed_best": float(best_rows["command"].isin(DELAYED).mean()),
        "optimal_freq_hz": interval(best_rows["freq_hz"].to_numpy(float)),
        "optimal_amplitude_mm": interval(best_rows["amplitude_mm"].to_numpy(float)),
        "regret_mm": interval(regret),
        "regret_mm_p95": float(np.quantile(regret, 0.95)) if regret.size else math.nan,
        "ds_optimal_delay_ms": interval(delays),
        "ds_optimal_delay_p_interior": float(np.mean((delays > 0) & (delays < delays.max())))
        if delays.size
        else math.nan,
        "ds_optimal_delay_ms_all": delays,
        "optimal_freq_hz_all": best_rows["freq_hz"].to_numpy(float),
    }


def published_check(res: OptimumSearch, measured: pd.DataFrame) -> dict:
    """Physics-model.md section 7.1 at one volume fraction.

    Parameters
    ----------
    res : OptimumSearch
        A search result.
    measured : pandas.DataFrame
        Measured settings (:func:`measured_settings`).

    Returns
    -------
    dict
        ``p_best_ds_beats_best_single`` and ``best_ds_minus_best_single_mm`` (paired over
        the draws), and per measured (amplitude, frequency) ``at_data_settings``: the
        50 ms delayed stutter against the single jump.
    """
    t, h = res.settings, res.heights_mm
    ds, single = res.family_optimum["delayed_stutter"], res.family_optimum["single"]
    both = min(ds, single) >= 0
    out: dict = {
        "p_best_ds_beats_best_single": p_greater(h[ds], h[single]) if both else math.nan,
        "best_ds_minus_best_single_mm": interval(h[ds] - h[single]) if both else (math.nan,) * 3,
        "at_data_settings": [],
    }
    for amp, freq in measured[["amplitude_mm", "freq_hz"]].itertuples(index=False):
        i_ds = find_row(t, "delayed_stutter", amplitude_mm=amp, freq_hz=freq, delay_ms=50.0)
        i_single = find_row(t, "single", amplitude_mm=amp, freq_hz=freq)
        if min(i_ds, i_single) < 0:
            continue
        out["at_data_settings"].append(
            {
                "amplitude_mm": amp,
                "freq_hz": freq,
                "p_ds50_beats_single": p_greater(h[i_ds], h[i_single]),
                "ds50_mm": interval(h[i_ds]),
                "single_mm": interval(h[i_single]),
                "difference_mm": interval(h[i_ds] - h[i_single]),
            }
        )
    return out


def delay_settings(res: OptimumSearch, measured: pd.DataFrame) -> list[dict]:
    """(amplitude, frequency) pairs whose delay curves are examined: data's, then optimum.

    Parameters
    ----------
    res : OptimumSearch
        A search result.
    measured : pandas.DataFrame
        Measured settings (:func:`measured_settings`).
    """
    out = [
        {"amplitude_mm": float(a), "freq_hz": float(f), "role": "data"}
        for a, f in measured[["amplitude_mm", "freq_hz"]].itertuples(index=False)
    ]
    i = res.family_optimum["delayed_stutter"]
    if i >= 0:
        opt = res.settings.iloc[i]
        a, f = float(opt["amplitude_mm"]), float(opt["freq_hz"])
        same = [c for c in out if np.isclose(c["amplitude_mm"], a) and np.isclose(c["freq_hz"], f)]
        if same:
            same[0]["role"] = "data, optimum"
        else:
            out.append({"amplitude_mm": a, "freq_hz": f, "role": "optimum"})
    return [c for c in out if not delay_curve(res, c["amplitude_mm"], c["freq_hz"]).empty]


def delay_shape(res: OptimumSearch, amplitude_mm: float, freq_hz: float) -> dict:
    """Whether there is an interior optimum delay, and whether delays near 0 are the lowest.

    Parameters
    ----------
    res : OptimumSearch
        A search result.
    amplitude_mm : float
        Amplitude [mm].
    freq_hz : float
        Frequency [Hz].

    Returns
    -------
    dict
        Empty if there is no delay curve at this (amplitude [mm], frequency [Hz]); else the
        best and lowest delay [ms] of the expected height, the per-draw best delay, the
        probabilities of an interior optimum, of the lowest delay being near 0 and of 50 ms
        beating 0 ms, and the expected heights [mm] at 0 ms, 50 ms and the best delay.
    """
    curve = delay_curve(res, amplitude_mm, freq_hz)
    if curve.empty:
        return {}
    h = res.heights_mm[curve.index.to_numpy()]
    delays = curve["delay_ms"].to_numpy(float)
    mean = curve["expected_mm"].to_numpy(float)
    finite = np.isfinite(h)
    per_draw = delays[np.argmax(np.where(finite, h, -np.inf), axis=0)]
    i0 = int(np.argmin(np.abs(delays)))
    i50 = int(np.argmin(np.abs(delays - PUBLISHED_DELAY_MS)))
    lowest = delays[np.argmin(np.where(finite, h, np.inf), axis=0)]
    return {
        "amplitude_mm": amplitude_mm,
        "freq_hz": freq_hz,
        "best_delay_ms": float(delays[int(np.nanargmax(mean))]),
        "lowest_delay_ms": float(delays[int(np.nanargmin(mean))]),
        "per_draw_best_delay_ms": interval(per_draw),
        "p_interior_optimum": float(np.mean((per_draw > delays.min()) & (per_draw < delays.max()))),
        "p_lowest_near_zero": float(np.mean(lowest <= NEAR_ZERO_MS)),
        "p_50ms_beats_0ms": p_greater(h[i50], h[i0]),
        "expected_0ms_mm": float(mean[i0]),
        "expected_50ms_mm": float(mean[i50]),
        "expected_best_mm": float(np.nanmax(mean)),
    }
