"""Optimal jumping under the posterior: which command and settings jump highest, and reliably.

The force law is fitted per volume fraction (``--terms``; or read from ``--posterior``).
At every volume fraction the five commands are simulated on a grid of actuator settings
(frequency, amplitude up to ``--max-amplitude-mm``, delay of the delayed stutter, settle
periods of the delayed stutter preload) for the same posterior draws at every setting
(common random numbers, so differences between settings are paired). Two optima are
reported: (a) the largest expected jump height and (b) the most reliable jump, the highest
5th percentile of the posterior predictive height (model height plus the trial scatter
``Normal(0, sigma_mm)``). Per posterior draw the best setting is found too, which gives the
probability that the reported optimum is the best and the spread of the optimal frequency
and delay. Finally the model is held against the published finding (physics-model.md
section 7.1): a delayed stutter with a ~50 ms delay beats the single jump on loose beds,
and a delay near 0 gives the lowest jumps.
"""

from __future__ import annotations

import argparse
import math
import sys
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pandas as pd
import xarray as xr
from matplotlib import colormaps
from matplotlib.axes import Axes
from matplotlib.figure import Figure
from matplotlib.lines import Line2D

import _common as common
from granbayes import COMMAND_NAMES, PARAMETER_NAMES, CommandSettings, InputError, build_command
from granbayes.datatree import read_datatree
from granbayes.forces import terms_of
from granbayes.simulator import build_rows, simulate_rows

NAME = "optimal_jumping"

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
#: Setting columns of the grid table.
SETTING_COLUMNS = common.SETTING_COLUMNS


# ----------------------------------------------------------------------------------------
@dataclass(frozen=True)
class Grid:
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


def data_settings(ctx: common.Context) -> pd.DataFrame:
    """Distinct (amplitude, frequency) of the measured single jumps (all jumps if none)."""
    rows = ctx.table[ctx.table["command"] == "single"]
    rows = rows if not rows.empty else ctx.table
    pairs = rows[["amplitude_mm", "freq_hz"]].astype(float).drop_duplicates()
    return pairs.sort_values(["freq_hz", "amplitude_mm"]).reset_index(drop=True)


def max_amplitude_mm(ctx: common.Context) -> float:
    """The actuator limit: ``--max-amplitude-mm``, else the largest amplitude used [mm]."""
    if ctx.args.max_amplitude_mm is not None:
        value = float(ctx.args.max_amplitude_mm)
        if not (value > 0 and math.isfinite(value)):
            raise InputError(f"--max-amplitude-mm must be > 0, got {value:g}")
        return value
    used = ctx.table["amplitude_mm"].astype(float).max() if len(ctx.table) else -np.inf
    return float(max(ctx.experiment.command.amplitude_mm, used))


def make_grid(ctx: common.Context, amp_max_mm: float) -> Grid:
    """The search grid: fine in full mode, very coarse with ``--fast``.

    The measured frequencies and amplitudes (when within the limit) are always included,
    so the data's own settings are grid points.
    """
    data = data_settings(ctx)
    if ctx.fast:
        freqs = np.linspace(5.0, 20.0, 3)
        amps = np.array([0.5, 1.0]) * amp_max_mm
        delays = np.array([0.0, 50.0, 100.0, 150.0])
        settles = np.array([1.0, 3.0])
    else:
        freqs = np.linspace(5.0, 20.0, 11)
        amps = np.linspace(0.5, 1.0, 4) * amp_max_mm
        delays = np.arange(0.0, 151.0, 10.0)
        settles = np.array([1.0, 2.0, 3.0, 4.0])
    freqs = np.union1d(np.round(freqs, 6), data["freq_hz"].to_numpy())
    measured = data["amplitude_mm"].to_numpy()
    amps = np.union1d(np.round(amps, 6), measured[measured <= amp_max_mm + 1e-9])
    delays = np.union1d(delays, [PUBLISHED_DELAY_MS])
    return Grid(freqs, amps, delays, settles)


def setting_table(grid: Grid, data: pd.DataFrame) -> pd.DataFrame:
    """One row per (command, setting); ``searched`` marks the grid, not the extra data rows.

    Settings that do not apply to a command (the delay of a single jump, say) are NaN.
    """
    recs: list[dict] = []
    for command in COMMAND_NAMES:
        for freq in grid.freqs_hz:
            for amp in grid.amplitudes_mm:
                base = {"command": command, "amplitude_mm": amp, "freq_hz": freq}
                if command == "delayed_stutter":
                    recs += [{**base, "delay_ms": d} for d in grid.delays_ms]
                elif command == "delayed_stutter_preload":
                    recs += [{**base, "settle_periods": s} for s in grid.settle_periods]
                else:
                    recs.append(base)
    table = pd.DataFrame(recs, columns=["command", *SETTING_COLUMNS])
    table["searched"] = True
    extra = []
    for amp, freq in data[["amplitude_mm", "freq_hz"]].itertuples(index=False):
        extra.append({"command": "single", "amplitude_mm": amp, "freq_hz": freq})
        extra.append(
            {
                "command": "delayed_stutter",
                "amplitude_mm": amp,
                "freq_hz": freq,
                "delay_ms": PUBLISHED_DELAY_MS,
            }
        )
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


def programs_of(settings: pd.DataFrame, defaults: CommandSettings) -> list:
    """One command program per row of ``settings`` (NaN settings take ``defaults``)."""
    out = []
    for rec in settings.to_dict("records"):
        values = {
            s: float(getattr(defaults, s)) if pd.isna(rec[s]) else float(rec[s])
            for s in SETTING_COLUMNS
        }
        out.append(build_command(rec["command"], CommandSettings(**values)))
    return out


def describe(rec: pd.Series | dict) -> str:
    """A setting in words, e.g. ``"12.5 Hz, 20 mm, 50 ms delay"``."""
    text = f"{rec['freq_hz']:.3g} Hz, {rec['amplitude_mm']:.3g} mm"
    if pd.notna(rec.get("delay_ms", np.nan)):
        text += f", {rec['delay_ms']:.0f} ms delay"
    if pd.notna(rec.get("settle_periods", np.nan)):
        n = float(rec["settle_periods"])
        hold_ms = 1e3 * n / float(rec["freq_hz"])
        text += f", {n:g}-period hold (= {hold_ms:.0f} ms)"
    return text


def pretty(command: str) -> str:
    """Command name for humans."""
    return command.replace("_", " ")


# ----------------------------------------------------------------------------------------
def force_posterior(ctx: common.Context) -> tuple[xr.DataTree, str]:
    """The posterior of the force law: read from ``--posterior`` or fitted here.

    Returns
    -------
    datatree : xarray.DataTree
        Has a ``posterior`` group with force parameters and ``sigma_mm`` over ``phi``.
    source : str
        Where it came from, in words.
    """
    if ctx.args.posterior is not None:
        path = Path(ctx.args.posterior)
        if not path.is_file():
            raise InputError(f"--posterior {path}: no such file")
        try:
            dt = read_datatree(path)
        except (OSError, ValueError) as exc:
            raise InputError(f"--posterior {path}: cannot read ({exc})") from None
        if "posterior" not in dt.children or "sigma_mm" not in dt.posterior.data_vars:
            raise InputError(f"--posterior {path}: no posterior group with sigma_mm")
        names = ", ".join(force_names(dt))
        return dt, f"posterior read from `{path}` (parameters {names})"
    try:
        terms = terms_of(t.strip() for t in str(ctx.args.terms).split(",") if t.strip())
    except ValueError as exc:
        raise InputError(f"--terms: {exc}") from None
    t0 = time.perf_counter()
    result = common.run_fit(ctx, ctx.table, terms)
    seconds = time.perf_counter() - t0
    print(f"[{NAME}] fit of {'+'.join(terms)}: {seconds:.0f} s", file=sys.stderr)
    sampler = common.sampler_settings(ctx.fast)
    return result.datatree, (
        f"force law `{' + '.join(terms)}` fitted per volume fraction here "
        f"({sampler.n_ensembles} ensembles of {sampler.n_walkers} walkers, "
        f"{sampler.n_draws} kept draws each)"
    )


def force_names(dt: xr.DataTree) -> list[str]:
    """Force parameters in a posterior (everything with a ``phi`` axis but ``sigma_mm``)."""
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
    """
    names = [*force_names(dt), "sigma_mm"]
    draws = common.posterior_draws(dt, phi, names, n, rng)
    draws = {k: v for k, v in draws.items() if np.isfinite(v).any()}
    if "sigma_mm" not in draws or "k" not in draws:
        raise InputError(f"posterior has no finite k or sigma_mm at phi = {phi:g}")
    keep = np.logical_and.reduce([np.isfinite(v) for v in draws.values()])
    if keep.sum() < max(10, n // 2):
        raise InputError(f"posterior has too few finite draws at phi = {phi:g}")
    return {k: v[keep] for k, v in draws.items()}


# ----------------------------------------------------------------------------------------
@dataclass
class PhiResult:
    """Everything computed at one volume fraction.

    Attributes
    ----------
    phi : float
    settings : pandas.DataFrame
        The grid with per-setting summaries (see :func:`summarise_settings`).
    heights_mm : ndarray, shape (n_settings, n_draws)
        Simulated (noise-free) heights per setting and posterior draw; NaN if failed.
    best_per_draw : ndarray of int, shape (n_draws,)
        Row of ``settings`` that is best for each draw (-1 if none).
    optimum : int
        Row of the expected-height optimum.
    reliable : int
        Row of the 5th-percentile optimum.
    family_optimum : dict of str to int
        Expected-height optimum per command.
    family_reliable : dict of str to int
        5th-percentile optimum per command.
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


def simulate_settings(
    ctx: common.Context, phi: float, params: dict[str, np.ndarray], settings: pd.DataFrame
) -> tuple[np.ndarray, int]:
    """Heights [mm] of every setting for every draw, shape (n_settings, n_draws).

    The same parameter rows are used for every setting (common random numbers).
    """
    rows = build_rows(ctx.experiment.robot, phi, params)
    programs = programs_of(settings, ctx.experiment.command)
    n_draw, n_set = rows.shape[0], len(programs)
    heights = np.full((n_set, n_draw), np.nan)
    n_failed = 0
    chunk = max(1, 40_000 // n_draw)  # settings per call: bounded memory, visible progress
    for start in range(0, n_set, chunk):
        stop = min(n_set, start + chunk)
        index = np.repeat(np.arange(stop - start), n_draw)
        res = simulate_rows(np.tile(rows, (stop - start, 1)), programs[start:stop], index)
        h = np.where(res.ok, res.height_mm, np.nan)
        n_failed += int((~res.ok).sum())
        heights[start:stop] = h.reshape(stop - start, n_draw)
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
    lo_p, hi_p = (1 - common.CI_PROB) / 2, 1 - (1 - common.CI_PROB) / 2
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


def analyse_phi(
    ctx: common.Context,
    dt: xr.DataTree,
    phi: float,
    settings: pd.DataFrame,
    n_draws: int,
    offset: int,
) -> PhiResult:
    """Simulate the grid at ``phi`` and find the optima."""
    t0 = time.perf_counter()
    draws = draws_at(dt, phi, n_draws, ctx.rng(100 + offset))
    sigma_mm = draws.pop("sigma_mm")
    heights, n_failed = simulate_settings(ctx, phi, draws, settings)
    eps = ctx.rng(200 + offset).standard_normal((heights.shape[1], N_NOISE))
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
    print(
        f"[{NAME}] phi={phi:g}: {heights.size} jumps ({len(table)} settings x "
        f"{heights.shape[1]} draws), {n_failed} failed, {time.perf_counter() - t0:.0f} s",
        file=sys.stderr,
    )
    return PhiResult(
        phi, table, heights, best, optimum, reliable, family_optimum, family_reliable, n_failed
    )


# ----------------------------------------------------------------------------------------
def p_greater(a_mm: np.ndarray, b_mm: np.ndarray) -> float:
    """Paired probability ``a > b`` over the draws where both are finite."""
    ok = np.isfinite(a_mm) & np.isfinite(b_mm)
    return float(np.mean(a_mm[ok] > b_mm[ok])) if ok.any() else math.nan


def find_row(table: pd.DataFrame, command: str, **values: float) -> int:
    """Row position of ``command`` with the given settings (-1 if absent)."""
    mask = table["command"] == command
    for k, v in values.items():
        mask &= np.isclose(table[k].to_numpy(float), v)
    hits = np.flatnonzero(mask.to_numpy())
    return int(hits[0]) if hits.size else -1


def delay_curve(res: PhiResult, amplitude_mm: float, freq_hz: float) -> pd.DataFrame:
    """Delayed-stutter rows at one (amplitude, frequency), by delay (searched grid only)."""
    t = res.settings
    mask = (
        (t["command"] == "delayed_stutter")
        & t["searched"]
        & np.isclose(t["amplitude_mm"], amplitude_mm)
        & np.isclose(t["freq_hz"], freq_hz)
    )
    return t[mask].sort_values("delay_ms")


def robustness(res: PhiResult) -> dict:
    """How sure the posterior is about the optimum (per-draw best settings)."""
    t = res.settings
    best = res.best_per_draw
    valid = best >= 0
    opt = res.optimum
    h_opt = res.heights_mm[opt]
    h_best = res.heights_mm[best[valid], np.flatnonzero(valid)]
    regret = h_best - h_opt[valid]
    regret = regret[np.isfinite(regret)]
    best_rows = t.iloc[best[valid]]
    commands = best_rows["command"].value_counts(normalize=True)
    ds = t["eligible"] & (t["command"] == "delayed_stutter")
    masked = np.where(ds.to_numpy()[:, None], res.heights_mm, np.nan)
    ok_cols = np.isfinite(masked).any(axis=0)
    ds_best = np.nanargmax(np.where(np.isfinite(masked), masked, -np.inf)[:, ok_cols], axis=0)
    delays = t["delay_ms"].to_numpy()[ds_best]
    return {
        "p_optimum_best": float(np.mean(best[valid] == opt)) if valid.any() else math.nan,
        "p_command_best": {str(k): float(v) for k, v in commands.items()},
        "p_delayed_best": float(best_rows["command"].isin(DELAYED).mean()),
        "optimal_freq_hz": common.interval(best_rows["freq_hz"].to_numpy(float)),
        "optimal_amplitude_mm": common.interval(best_rows["amplitude_mm"].to_numpy(float)),
        "regret_mm": common.interval(regret),
        "regret_mm_p95": float(np.quantile(regret, 0.95)) if regret.size else math.nan,
        "ds_optimal_delay_ms": common.interval(delays),
        "ds_optimal_delay_p_interior": float(np.mean((delays > 0) & (delays < delays.max())))
        if delays.size
        else math.nan,
        "ds_optimal_delay_ms_all": delays,
        "optimal_freq_hz_all": best_rows["freq_hz"].to_numpy(float),
    }


def published_check(res: PhiResult, data: pd.DataFrame) -> dict:
    """Physics-model.md section 7.1 at one volume fraction."""
    t, h = res.settings, res.heights_mm
    ds, single = res.family_optimum["delayed_stutter"], res.family_optimum["single"]
    both = min(ds, single) >= 0
    out: dict = {
        "p_best_ds_beats_best_single": p_greater(h[ds], h[single]) if both else math.nan,
        "best_ds_minus_best_single_mm": common.interval(h[ds] - h[single])
        if both
        else (math.nan,) * 3,
        "at_data_settings": [],
    }
    for amp, freq in data[["amplitude_mm", "freq_hz"]].itertuples(index=False):
        i_ds = find_row(t, "delayed_stutter", amplitude_mm=amp, freq_hz=freq, delay_ms=50.0)
        i_single = find_row(t, "single", amplitude_mm=amp, freq_hz=freq)
        if min(i_ds, i_single) < 0:
            continue
        out["at_data_settings"].append(
            {
                "amplitude_mm": amp,
                "freq_hz": freq,
                "p_ds50_beats_single": p_greater(h[i_ds], h[i_single]),
                "ds50_mm": common.interval(h[i_ds]),
                "single_mm": common.interval(h[i_single]),
                "difference_mm": common.interval(h[i_ds] - h[i_single]),
            }
        )
    return out


def delay_settings(res: PhiResult, data: pd.DataFrame) -> list[dict]:
    """(amplitude, frequency) pairs whose delay curves are examined: data's, then optimum."""
    out = [
        {"amplitude_mm": float(a), "freq_hz": float(f), "role": "data"}
        for a, f in data[["amplitude_mm", "freq_hz"]].itertuples(index=False)
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


def delay_shape(res: PhiResult, amplitude_mm: float, freq_hz: float) -> dict:
    """Is there an interior optimum delay, and are delays near 0 the lowest?"""
    curve = delay_curve(res, amplitude_mm, freq_hz)
    if curve.empty:
        return {}
    rows = curve.index.to_numpy()
    h = res.heights_mm[rows]
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
        "per_draw_best_delay_ms": common.interval(per_draw),
        "p_interior_optimum": float(np.mean((per_draw > delays.min()) & (per_draw < delays.max()))),
        "p_lowest_near_zero": float(np.mean(lowest <= NEAR_ZERO_MS)),
        "p_50ms_beats_0ms": p_greater(h[i50], h[i0]),
        "expected_0ms_mm": float(mean[i0]),
        "expected_50ms_mm": float(mean[i50]),
        "expected_best_mm": float(np.nanmax(mean)),
    }


# ----------------------------------------------------------------------------------------
def _panel_grid(
    n: int, width: float = 4.1, height: float = 3.4
) -> tuple[Figure, list[Axes], Axes | None]:
    """Figure with ``n`` panels in rows of 3; returns a spare axes for the legend (or None)."""
    ncols = min(n, 3)
    nrows = math.ceil(n / ncols)
    spare = nrows * ncols > n
    fig = Figure(figsize=(width * ncols + 0.4, height * nrows + 1.0), layout="constrained")
    axes = np.atleast_1d(fig.subplots(nrows, ncols, squeeze=False)).ravel()
    legend_ax = None
    if spare:
        legend_ax = axes[n]
        for ax in axes[n:]:
            ax.set_axis_off()
    return fig, list(axes[:n]), legend_ax


def plot_frequency(ctx: common.Context, results: list[PhiResult]) -> Figure:
    """Expected height vs frequency per command (best amplitude/delay at each frequency)."""
    fig, axes, legend_ax = _panel_grid(len(results))
    f0 = ctx.experiment.robot.f0_hz
    for ax, res in zip(axes, results, strict=True):
        t = res.settings[res.settings["eligible"]]
        for command in COMMAND_NAMES:
            c = t[t["command"] == command]
            if c.empty:
                continue
            c = c[np.isfinite(c["expected_mm"])]
            if c.empty:
                continue
            best = c.loc[c.groupby("freq_hz")["expected_mm"].idxmax()]
            color = common.COMMAND_COLORS[command]
            ax.fill_between(best["freq_hz"], best["lo_mm"], best["hi_mm"], color=color, alpha=0.15)
            ax.plot(
                best["freq_hz"],
                best["expected_mm"],
                color=color,
                marker=common.COMMAND_MARKERS[command],
                ms=3.5,
                lw=1.4,
            )
        opt = res.settings.iloc[res.optimum]
        rel = res.settings.iloc[res.reliable]
        ax.plot(opt["freq_hz"], opt["expected_mm"], "*", ms=17, mfc="gold", mec="k", zorder=5)
        ax.plot(
            rel["freq_hz"],
            rel["q05_predictive_mm"],
            "*",
            ms=13,
            mfc="none",
            mec="k",
            mew=1.2,
            zorder=5,
        )
        ax.axvline(f0, color="0.5", ls=":", lw=1)
        ax.set_title(f"φ = {res.phi:g}  (φ − φc = {res.phi - ctx.phi_c:+.3f})", fontsize=10)
        ax.set_xlabel("actuator frequency [Hz]")
        ax.set_ylabel("expected jump height [mm]")
        ax.grid(alpha=0.3)
    handles = [
        Line2D(
            [],
            [],
            color=common.COMMAND_COLORS[c],
            marker=common.COMMAND_MARKERS[c],
            ms=4,
            label=pretty(c),
        )
        for c in COMMAND_NAMES
    ]
    handles += [
        Line2D([], [], ls="none", marker="*", ms=14, mfc="gold", mec="k", label="optimum"),
        Line2D(
            [],
            [],
            ls="none",
            marker="*",
            ms=11,
            mfc="none",
            mec="k",
            label="reliable optimum (its 5th pct.)",
        ),
        Line2D([], [], color="0.5", ls=":", label=f"leg resonance f0 = {f0:.1f} Hz"),
    ]
    title = f"best amplitude / delay / settle at each frequency; bands: {common.CI_PROB:.0%}"
    if legend_ax is not None:
        legend_ax.legend(handles=handles, loc="center", fontsize=9, title=title, title_fontsize=8)
    else:
        fig.legend(
            handles=handles,
            loc="outside lower center",
            ncols=4,
            fontsize=8,
            title=title,
            title_fontsize=8,
        )
    fig.suptitle(
        ctx.title("Model-optimal jumps: expected height vs actuator frequency (posterior)"),
        fontsize=11,
    )
    return fig


def plot_delay(ctx: common.Context, results: list[PhiResult], data: pd.DataFrame) -> Figure:
    """Delayed-stutter height vs delay: the loosest bed in detail, then every bed."""
    fig = Figure(figsize=(12.5, 4.8), layout="constrained")
    ax_l, ax_r = fig.subplots(1, 2)
    loose = results[0]
    t = loose.settings
    curves = delay_settings(loose, data)
    cmap = colormaps["viridis"]
    top = 0.0
    for j, spec in enumerate(curves):
        c = delay_curve(loose, spec["amplitude_mm"], spec["freq_hz"])
        color = cmap(0.1 + 0.75 * j / max(1, len(curves) - 1))
        label = f"{spec['freq_hz']:.3g} Hz, {spec['amplitude_mm']:.3g} mm ({spec['role']})"
        ax_l.fill_between(c["delay_ms"], c["lo_mm"], c["hi_mm"], color=color, alpha=0.18)
        ax_l.plot(c["delay_ms"], c["expected_mm"], color=color, marker="o", ms=3, label=label)
        top = max(top, float(np.nanmax(c["hi_mm"])))
    if loose.family_optimum["single"] >= 0:
        single = t.iloc[loose.family_optimum["single"]]
        ax_l.axhspan(single["lo_mm"], single["hi_mm"], color="0.5", alpha=0.15, lw=0)
        ax_l.axhline(
            single["expected_mm"],
            color="0.3",
            ls="--",
            lw=1.2,
            label=f"best single jump ({describe(single)})",
        )
        top = max(top, float(single["hi_mm"]))
    ax_l.axvline(PUBLISHED_DELAY_MS, color="k", ls=":", lw=1, label="published optimum, 50 ms")
    ax_l.set_title(f"loosest bed φ = {loose.phi:g}: delayed stutter", fontsize=10)
    if top > 0:
        ax_l.set_ylim(0.0, 1.4 * top)
    ax_l.legend(fontsize=8, loc="upper right")
    for j, res in enumerate(results):
        if res.family_optimum["delayed_stutter"] < 0:
            continue
        r = res.settings.iloc[res.family_optimum["delayed_stutter"]]
        c = delay_curve(res, r["amplitude_mm"], r["freq_hz"])
        color = cmap(j / max(1, len(results) - 1) * 0.9)
        ax_r.fill_between(c["delay_ms"], c["lo_mm"], c["hi_mm"], color=color, alpha=0.12)
        ax_r.plot(
            c["delay_ms"],
            c["expected_mm"],
            color=color,
            marker="o",
            ms=3,
            label=f"{res.phi - ctx.phi_c:+.3f}: {r['freq_hz']:.3g} Hz, {r['amplitude_mm']:.3g} mm",
        )
    ax_r.axvline(PUBLISHED_DELAY_MS, color="k", ls=":", lw=1)
    ax_r.set_title("every bed, at its best frequency and amplitude", fontsize=10)
    ax_r.legend(
        fontsize=8,
        loc="upper left",
        bbox_to_anchor=(1.01, 1.0),
        title="φ − φc: f, A",
        title_fontsize=8,
    )
    for ax in (ax_l, ax_r):
        ax.set_xlabel("delay [ms]")
        ax.set_ylabel("expected jump height [mm]")
        ax.grid(alpha=0.3)
    fig.suptitle(
        ctx.title(f"Delayed stutter: height vs delay (posterior, {common.CI_PROB:.0%} bands)"),
        fontsize=11,
    )
    return fig


def plot_summary(ctx: common.Context, results: list[PhiResult]) -> Figure:
    """Optimum expected height and 5th-percentile optimum vs phi - phi_c, per command."""
    fig = Figure(figsize=(11.5, 4.6), layout="constrained")
    ax_e, ax_q = fig.subplots(1, 2, sharey=True)
    x = np.array([r.phi for r in results]) - ctx.phi_c
    dx = 0.0005 * (np.ptp(x) / 0.04 if x.size > 1 else 1.0)
    offsets = dict(zip(COMMAND_NAMES, np.linspace(-2, 2, len(COMMAND_NAMES)) * dx, strict=True))
    for command in COMMAND_NAMES:
        color, marker = common.COMMAND_COLORS[command], common.COMMAND_MARKERS[command]
        if min(min(r.family_optimum[command], r.family_reliable[command]) for r in results) < 0:
            continue
        e = [r.settings.iloc[r.family_optimum[command]] for r in results]
        q = [r.settings.iloc[r.family_reliable[command]] for r in results]
        mid = np.array([s["expected_mm"] for s in e])
        lo = np.array([s["lo_mm"] for s in e])
        hi = np.array([s["hi_mm"] for s in e])
        ls = "--" if command == "delayed_stutter_preload" else "-"
        ax_e.errorbar(
            x + offsets[command],
            mid,
            yerr=[mid - lo, hi - mid],
            color=color,
            marker=marker,
            ms=5,
            capsize=3,
            lw=1.3,
            ls=ls,
            label=pretty(command),
        )
        ax_q.plot(
            x + offsets[command],
            [s["q05_predictive_mm"] for s in q],
            color=color,
            marker=marker,
            ms=5,
            lw=1.3,
            ls=ls,
            label=pretty(command),
        )
    for ax in (ax_e, ax_q):
        ax.axvline(0.0, color="0.5", ls=":", lw=1)
        ax.set_xlabel(r"$\phi - \phi_c$")
        ax.grid(alpha=0.3)
    ax_e.set_ylabel("jump height [mm]")
    ax_e.set_title(
        f"best expected height per command (posterior {common.CI_PROB:.0%} interval)", fontsize=10
    )
    ax_q.set_title(
        "most reliable jump per command: best 5th pct. of predictive height",
        fontsize=10,
    )
    ax_e.legend(fontsize=8, loc="best")
    fig.suptitle(ctx.title("Optimal jumps vs packing, by command"), fontsize=11)
    return fig


# ----------------------------------------------------------------------------------------
def _interval_text(v: tuple[float, float, float], digits: int = 3) -> str:
    """``"median [lo, hi]"`` of a precomputed (median, lo, hi) triple."""
    return common.fmt_triple(*v, fmt=f".{digits}g")


def analyse(ctx: common.Context) -> tuple[str, dict]:
    """Fit (or read) the posterior, search the settings per phi, summarise and plot."""
    amp_max_mm = max_amplitude_mm(ctx)
    n_draws = int(ctx.args.draws or (30 if ctx.fast else 200))
    if n_draws < 10:
        raise InputError(f"--draws must be >= 10, got {n_draws}")
    dt, source = force_posterior(ctx)
    phis = np.asarray(dt.posterior["phi"].values, dtype=float)
    if ctx.args.posterior is None:
        phis = ctx.phis
    missing = [p for p in ctx.phis if not np.isclose(phis, p).any()]
    if missing:
        print(f"warning: posterior has no phi = {missing}", file=sys.stderr)
    data = data_settings(ctx)
    grid = make_grid(ctx, amp_max_mm)
    settings = setting_table(grid, data)
    results = [analyse_phi(ctx, dt, float(phi), settings, n_draws, i) for i, phi in enumerate(phis)]
    full = pd.concat([r.settings for r in results], ignore_index=True)
    ctx.save_table(full, "grid_results")

    ctx.save_figure(plot_frequency(ctx, results), "optimum_vs_frequency")
    ctx.save_figure(plot_delay(ctx, results, data), "delay_curve")
    ctx.save_figure(plot_summary(ctx, results), "optimum_vs_phi")

    numbers: dict = {
        "posterior": source,
        "interval_triples": f"[median, lo, hi] with a {common.CI_PROB:.0%} equal-tailed interval",
        "max_amplitude_mm": amp_max_mm,
        "draws_per_phi": n_draws,
        "noise_replicates_per_draw": N_NOISE,
        "grid": {
            "freqs_hz": grid.freqs_hz,
            "amplitudes_mm": grid.amplitudes_mm,
            "delays_ms": grid.delays_ms,
            "settle_periods": grid.settle_periods,
            "n_settings": int(settings["searched"].sum()),
        },
        "failed_jumps": int(sum(r.n_failed for r in results)),
        "per_phi": [],
    }
    opt_rows, family_rows, pub_rows = [], [], []
    for res in results:
        t, h = res.settings, res.heights_mm
        opt, rel = t.iloc[res.optimum], t.iloc[res.reliable]
        rob = robustness(res)
        pub = published_check(res, data)
        shapes = [
            {"role": c["role"], **delay_shape(res, c["amplitude_mm"], c["freq_hz"])}
            for c in delay_settings(res, data)
        ]
        entry = {
            "phi": res.phi,
            "phi_minus_phi_c": res.phi - ctx.phi_c,
            "optimum": {
                "command": opt["command"],
                "settings": {s: opt[s] for s in SETTING_COLUMNS if pd.notna(opt[s])},
                "expected_mm": opt["expected_mm"],
                "height_mm": common.interval(h[res.optimum]),
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
                "settings": {s: rel[s] for s in SETTING_COLUMNS if pd.notna(rel[s])},
                "q05_predictive_mm": rel["q05_predictive_mm"],
                "expected_mm": rel["expected_mm"],
                "height_mm": common.interval(h[res.reliable]),
            },
            "per_command": {},
            "delayed_stutter": {
                "per_draw_optimal_delay_ms": rob["ds_optimal_delay_ms"],
                "delay_curves": shapes,
            },
            "published_check": pub,
            "failed_jumps": res.n_failed,
        }
        for command in COMMAND_NAMES:
            i_e, i_q = res.family_optimum[command], res.family_reliable[command]
            if i_e < 0:
                continue
            e, q = t.iloc[i_e], t.iloc[i_q]
            entry["per_command"][command] = {
                "settings": {s: e[s] for s in SETTING_COLUMNS if pd.notna(e[s])},
                "expected_mm": e["expected_mm"],
                "height_mm": common.interval(h[i_e]),
                "reliable_settings": {s: q[s] for s in SETTING_COLUMNS if pd.notna(q[s])},
                "reliable_q05_mm": q["q05_predictive_mm"],
            }
            family_rows.append(
                {
                    "φ": res.phi,
                    "command": pretty(command),
                    "best expected: settings": describe(e),
                    "expected [mm]": e["expected_mm"],
                    f"{common.CI_PROB:.0%} interval [mm]": f"{e['lo_mm']:.1f} – {e['hi_mm']:.1f}",
                    "most reliable: settings": describe(q),
                    "5th pct. [mm]": q["q05_predictive_mm"],
                }
            )
        numbers["per_phi"].append(entry)
        p_cmd = rob["p_command_best"].get(opt["command"], 0.0)
        opt_rows.append(
            {
                "φ": res.phi,
                "φ − φc": res.phi - ctx.phi_c,
                "optimum": pretty(opt["command"]),
                "settings": describe(opt),
                "height [mm] (median [90%])": fmt_mm(h[res.optimum]),
                "P(best)": rob["p_optimum_best"],
                "P(command best)": p_cmd,
                "P(a delayed command best)": rob["p_delayed_best"],
                "optimal f [Hz] per draw": _interval_text(rob["optimal_freq_hz"]),
                "regret [mm] (med / 95%)": (
                    f"{rob['regret_mm'][0]:.2f} / {rob['regret_mm_p95']:.2f}"
                ),
                "reliable optimum": f"{pretty(rel['command'])}, {describe(rel)}",
                "its 5th pct. [mm]": rel["q05_predictive_mm"],
            }
        )
        row = {
            "φ": res.phi,
            "P(best DS > best single)": pub["p_best_ds_beats_best_single"],
            "best DS − best single [mm]": _interval_text(pub["best_ds_minus_best_single_mm"]),
        }
        for d in pub["at_data_settings"]:
            row[f"P(DS 50 ms > single), {d['freq_hz']:g} Hz"] = d["p_ds50_beats_single"]
        row["DS optimal delay [ms] (per draw)"] = _interval_text(rob["ds_optimal_delay_ms"])
        pub_rows.append(row)

    body = _sentences(ctx, results, numbers, data)
    specs = delay_settings(results[0], data)
    spec = next((c for c in specs if "optimum" in c["role"]), specs[0] if specs else None)
    curve = (
        delay_curve(results[0], spec["amplitude_mm"], spec["freq_hz"])
        if spec is not None
        else pd.DataFrame(columns=list(results[0].settings.columns))
    )
    curve_tab = pd.DataFrame(
        {
            "delay [ms]": curve["delay_ms"],
            "expected [mm]": curve["expected_mm"],
            f"{common.CI_PROB:.0%} interval [mm]": [
                f"{lo:.1f} – {hi:.1f}"
                for lo, hi in zip(curve["lo_mm"], curve["hi_mm"], strict=True)
            ],
            "5th pct. predictive [mm]": curve["q05_predictive_mm"],
        }
    )
    body += [
        "![optimum vs frequency](optimum_vs_frequency.png)",
        "",
        "![delay curve](delay_curve.png)",
        "",
        "![optimum vs phi](optimum_vs_phi.png)",
        "",
        "## Optimum per volume fraction",
        "",
        "P(best): share of posterior draws for which the reported setting is the best of the"
        " whole grid; P(command best): share for which the best setting is of the same command;"
        " regret: how much higher the draw's own best setting jumps than the reported one.",
        "",
        common.markdown_table(pd.DataFrame(opt_rows), ".3g"),
        "",
        "## Best setting per command",
        "",
        common.markdown_table(pd.DataFrame(family_rows), ".3g"),
        "",
        "## The published finding (physics-model.md §7.1)",
        "",
        "DS: delayed stutter. 'Best' are the settings with the highest expected height; the"
        " probabilities are paired over the same posterior draws.",
        "",
        common.markdown_table(pd.DataFrame(pub_rows), ".3g"),
        "",
    ]
    if spec is not None:
        body += [
            f"### Delayed stutter vs delay at φ = {results[0].phi:g} "
            f"({spec['freq_hz']:.3g} Hz, {spec['amplitude_mm']:.3g} mm, {spec['role']})",
            "",
            common.markdown_table(curve_tab, ".3g"),
            "",
        ]
    body += [
        "## Method",
        "",
        f"Posterior: {source}. Grid ({numbers['grid']['n_settings']} settings per φ): "
        f"frequencies {_list(grid.freqs_hz)} Hz; amplitudes {_list(grid.amplitudes_mm)} mm "
        f"(actuator limit {amp_max_mm:g} mm); delayed-stutter delays {_list(grid.delays_ms)} ms;"
        f" delayed-stutter-preload holds {_list(grid.settle_periods)} periods. "
        f"{n_draws} joint posterior draws per φ, the same draws for every setting; expected "
        "height = posterior mean of the simulated height; the predictive 5th percentile adds "
        f"the trial scatter Normal(0, sigma_mm) with {N_NOISE} common noise replicates per "
        f"draw. Settings with more than {MAX_FAIL_FRACTION:.0%} failed simulations are not "
        f"searched; {numbers['failed_jumps']} simulated jumps failed in all. "
        "Full grid: `grid_results.csv`.",
    ]
    return "\n".join(body), numbers


def fmt_mm(values: np.ndarray) -> str:
    """``"median [lo, hi]"`` of heights with one decimal."""
    med, lo, hi = common.interval(values)
    return f"{med:.1f} [{lo:.1f}, {hi:.1f}]"


def _list(values: np.ndarray) -> str:
    """Comma-separated values with 3 significant digits."""
    return ", ".join(f"{v:.3g}" for v in values)


def _sentences(
    ctx: common.Context, results: list[PhiResult], numbers: dict, data: pd.DataFrame
) -> list[str]:
    """The answers, in words."""
    lines = []
    for entry in numbers["per_phi"]:
        o, r = entry["optimum"], entry["reliable_optimum"]
        med, lo, hi = o["height_mm"]
        p_cmd = o["p_command_optimal"].get(o["command"], 0.0)
        text = (
            f"- **φ = {entry['phi']:g}** (φ − φc = {entry['phi_minus_phi_c']:+.3f}): highest "
            f"expected jump **{pretty(o['command'])}** at {describe(o['settings'])}, "
            f"{o['expected_mm']:.1f} mm (median {med:.1f}, {common.CI_PROB:.0%} interval "
            f"{lo:.1f}–{hi:.1f} mm); it is the best grid setting for {o['p_optimal']:.0%} of "
            f"the posterior draws and its command for {p_cmd:.0%} (a delayed command for "
            f"{o['p_delayed_command_optimal']:.0%}; median regret "
            f"{o['regret_mm'][0]:.1f} mm). Most reliable: **{pretty(r['command'])}** at "
            f"{describe(r['settings'])}, 5th percentile {r['q05_predictive_mm']:.1f} mm."
        )
        lines.append(text)
    amp_max = numbers["max_amplitude_mm"]
    at_limit = [
        np.isclose(e["optimum"]["settings"]["amplitude_mm"], amp_max) for e in numbers["per_phi"]
    ]
    lines.append("")
    if all(at_limit):
        lines.append(
            f"Every optimum uses the full actuator amplitude ({amp_max:g} mm): within the "
            "limit, more stroke always jumps higher here."
        )
    else:
        lines.append(
            f"The optimum uses less than the actuator limit ({amp_max:g} mm) at "
            f"{sum(not a for a in at_limit)} of {len(at_limit)} volume fractions."
        )
    loose = numbers["per_phi"][0]
    pub = loose["published_check"]
    ds_better = [
        f"{e['phi']:g}: {e['published_check']['p_best_ds_beats_best_single']:.2f}"
        for e in numbers["per_phi"]
    ]
    data_txt = "; ".join(
        f"{d['freq_hz']:g} Hz, {d['amplitude_mm']:g} mm: P = {d['p_ds50_beats_single']:.2f} "
        f"(difference {_interval_text(d['difference_mm'])} mm)"
        for d in pub["at_data_settings"]
    )
    delays = numbers["grid"]["delays_ms"]
    curves = []
    for shape in loose["delayed_stutter"]["delay_curves"]:
        interior = float(np.min(delays)) < shape["best_delay_ms"] < float(np.max(delays))
        curves.append(
            f"- at {shape['freq_hz']:.3g} Hz, {shape['amplitude_mm']:.3g} mm ({shape['role']}) "
            f"the expected height peaks at {shape['best_delay_ms']:.0f} ms "
            + ("(interior" if interior else "(edge of the searched range")
            + f"; per draw {_interval_text(shape['per_draw_best_delay_ms'])} ms, interior for "
            f"{shape['p_interior_optimum']:.0%} of draws) at {shape['expected_best_mm']:.1f} mm"
            f" and is lowest at {shape['lowest_delay_ms']:.0f} ms (lowest at ≤ "
            f"{NEAR_ZERO_MS:.0f} ms for {shape['p_lowest_near_zero']:.0%} of draws); 0 ms "
            f"gives {shape['expected_0ms_mm']:.1f} mm and 50 ms "
            f"{shape['expected_50ms_mm']:.1f} mm (P(50 ms > 0 ms) = "
            f"{shape['p_50ms_beats_0ms']:.2f})."
        )
    same = [
        e["phi"]
        for e in numbers["per_phi"]
        if "delayed_stutter_preload" in e["per_command"]
        and abs(
            e["per_command"]["delayed_stutter_preload"]["expected_mm"]
            - e["per_command"]["delayed_stutter"]["expected_mm"]
        )
        < 2.0
    ]
    lines += [
        "",
        "**Published finding (§7.1).** P(best delayed stutter > best single jump) per φ: "
        + ", ".join(ds_better)
        + f". At the loosest bed (φ = {loose['phi']:g}) and the data's settings, the 50 ms "
        f"delayed stutter beats the single jump with {data_txt}. Delayed stutter against "
        f"its delay at φ = {loose['phi']:g}:",
        "",
        *curves,
        "",
        "The delayed stutter preload is the delayed stutter with its hold counted in periods "
        "(n/f instead of a delay in ms), so the two reach the same heights where their holds "
        "coincide"
        + (
            f" (best heights within 2 mm of each other at φ = {', '.join(f'{p:g}' for p in same)})"
            if same
            else ""
        )
        + "; which of them wins is a matter of the grid.",
        "",
    ]
    return lines


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Options of this analysis."""
    parser.add_argument(
        "--terms",
        default="depth,drag",
        help="comma-separated force terms to fit (default depth,drag)",
    )
    parser.add_argument(
        "--posterior",
        type=Path,
        default=None,
        metavar="PATH",
        help="use this posterior.nc (written by granbayes fit) instead of fitting",
    )
    parser.add_argument(
        "--max-amplitude-mm",
        type=float,
        default=None,
        help="actuator limit [mm] (default: the experiment's amplitude_mm)",
    )
    parser.add_argument(
        "--draws",
        type=int,
        default=None,
        help="posterior draws per volume fraction (default 200; 30 with --fast)",
    )


def main(argv: list[str] | None = None) -> int:
    """Run the analysis (see the module docstring); returns the exit code."""
    return common.main(NAME, __doc__, analyse, argv, add_arguments)


if __name__ == "__main__":
    sys.exit(main())
