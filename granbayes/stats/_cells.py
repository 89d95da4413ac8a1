"""Residual cells of jump heights: the misfit of a law per command and setting.

A *cell* is one command at one volume fraction and one setting (:data:`CELL_KEYS`):
the jumps of a cell are repeats of one simulation, so their spread measures the
trial-to-trial scatter and their mean the law's misfit there.
"""

from __future__ import annotations

import json
import math
from collections.abc import Mapping, Sequence

import numpy as np
import pandas as pd
import xarray as xr
from scipy import stats

from ..commands import COMMAND_NAMES, COMMANDS
from ._intervals import CI_PROB, interval

#: The settings that define one cell of repeated jumps.
CELL_KEYS = ("command", "phi", "freq_hz", "amplitude_mm", "delay_ms", "settle_periods")


#: How a command's own setting reads in a cell's description.
_SETTING_TEXT = {"delay_ms": "{:g} ms delay", "settle_periods": "{:g} periods settled"}


def cell_keys(observed: pd.DataFrame) -> list[str]:
    """The cell keys (:data:`CELL_KEYS`) a table of jumps has columns for.

    Parameters
    ----------
    observed : pandas.DataFrame
        Jumps.

    Returns
    -------
    list of str
    """
    return [k for k in CELL_KEYS if k in observed.columns]


def observed_jumps(dt: xr.DataTree) -> pd.DataFrame:
    """The measured jumps of a fit: one row per jump, ``height_mm`` and its coordinates.

    Parameters
    ----------
    dt : xarray.DataTree
        A fit (its ``observed_data`` group).

    Returns
    -------
    pandas.DataFrame
    """
    obs = dt["observed_data"].to_dataset()
    on_jump = [c for c in obs.coords if obs[c].dims == ("jump",) and c != "jump"]
    frame = pd.DataFrame({c: obs[c].values for c in on_jump})
    frame["height_mm"] = obs["height_mm"].values
    return frame


def _pure_error(frame: pd.DataFrame, keys: Sequence[str]) -> dict[float, tuple[float, float]]:
    """Pure-error variance [mm^2] and its degrees of freedom at each volume fraction.

    The spread of repeated jumps about their cell's mean, pooled over the cells of a volume
    fraction (``keys``: the cell keys other than ``phi``; ``frame`` has ``phi`` and the
    heights ``y`` [mm]). ``(nan, 0.0)`` where no cell has a repeat.
    """
    pooled = {}
    for phi, g in frame.groupby("phi", sort=True):
        cells = g.groupby(list(keys))["y"]
        dof = float((cells.size() - 1).sum())
        ss = float(((g["y"] - cells.transform("mean")) ** 2).sum())
        pooled[phi] = (ss / dof, dof) if dof > 0 else (math.nan, 0.0)
    return pooled


def residual_table(dt: xr.DataTree) -> pd.DataFrame:
    """Residuals of a fitted law per cell of repeated jumps, with significance.

    A cell is one command at one volume fraction and one setting (``CELL_KEYS``: frequency,
    amplitude, delay, settle periods). For each cell of ``n`` jumps: the observed mean, the
    posterior mean of the simulated height and ``mean_residual_mm`` = observed - simulated.

    ``z`` (lack of fit, used for decisions)
        the residual over ``sqrt(s^2 / n + var_post(simulated))``, where ``s^2`` is the
        trial-to-trial variance *measured* from the repeated jumps (pooled over the cells
        at the same volume fraction, ``dof`` degrees of freedom) rather than the model's
        fitted scatter, which a wrong law inflates to absorb its own misfit; ``p_value`` is
        its two-sided Student-t tail probability. Without repeats the predictive
        statistics below are used instead (``dof`` = 0).
    ``z_predictive``, ``p_predictive``
        the observed cell mean against the posterior predictive distribution of the mean
        of ``n`` replicated jumps (model scatter included).

    Parameters
    ----------
    dt : xarray.DataTree
        A fit (its ``observed_data`` and ``posterior_predictive`` groups are read).

    Returns
    -------
    pandas.DataFrame
        One row per cell, worst (largest |z|) first.
    """
    obs = dt["observed_data"].to_dataset()
    pp = dt["posterior_predictive"].to_dataset()
    y = obs["height_mm"].values
    rep = pp["height_mm"].values.reshape(-1, len(y))
    sim = pp["height_sim_mm"].values.reshape(-1, len(y))
    observed = observed_jumps(dt).drop(columns="height_mm")
    keys = cell_keys(observed)
    cells = observed[keys].copy()
    cells["phi"] = cells["phi"].astype(float)
    cells["y"] = y
    grouped = cells.groupby(keys, sort=True)
    pooled = _pure_error(cells, [k for k in keys if k != "phi"])
    rows = []
    for key, idx in grouped.indices.items():
        idx = np.asarray(idx)
        cell = dict(zip(keys, key, strict=True))
        n = len(idx)
        y_mean = float(np.mean(y[idx]))
        rep_mean = rep[:, idx].mean(axis=1)
        sim_cell = sim[:, idx].mean(axis=1)
        sim_mean = float(np.mean(sim_cell))
        sd_pred = float(np.std(rep_mean))
        z_pred = (y_mean - float(np.mean(rep_mean))) / sd_pred if sd_pred > 0 else np.inf
        tail = min(np.mean(rep_mean >= y_mean), np.mean(rep_mean <= y_mean))
        # the Monte Carlo p-value resolves 1/draws; beyond it, the normal tail of z
        p_pred = min(1.0, 2.0 * tail if tail > 0 else 2.0 * stats.norm.sf(abs(z_pred)))
        s2, dof = pooled[cell["phi"]]
        if dof > 0:
            se = math.sqrt(s2 / n + float(np.var(sim_cell)))
            z = (y_mean - sim_mean) / se if se > 0 else np.inf
            p = float(2.0 * stats.t.sf(abs(z), dof))
        else:
            z, p = z_pred, p_pred
        rows.append(
            {
                **cell,
                "phi": float(cell["phi"]),
                "n": n,
                "observed_mm": y_mean,
                "simulated_mm": sim_mean,
                "mean_residual_mm": y_mean - sim_mean,
                "z": z,
                "p_value": p,
                "dof": dof,
                "z_predictive": z_pred,
                "p_predictive": p_pred,
            }
        )
    table = pd.DataFrame(rows)
    order = table["z"].abs().sort_values(ascending=False).index
    return table.reindex(order).reset_index(drop=True)


def misfit_threshold(residuals: pd.DataFrame, family_alpha: float) -> float:
    """|z| beyond which a cell is misfit, for a family-wise false-alarm rate ``family_alpha``.

    Bonferroni over the ``n`` cells of the data set with the Student-t distribution of the
    pooled scatter's degrees of freedom (the smallest over volume fractions):
    ``t.isf(family_alpha / (2 n), dof)``; the normal quantile without repeats. Fitting
    shrinks residuals, so under a correct law the realised rate is at most about this.

    Parameters
    ----------
    residuals : pandas.DataFrame
        The cells (:func:`residual_table`; column ``dof``).
    family_alpha : float
        Family-wise false-alarm rate.

    Returns
    -------
    float
        The |z| threshold.
    """
    n = max(len(residuals), 1)
    dof = float(residuals["dof"].min()) if len(residuals) else 0.0
    q = family_alpha / (2.0 * n)
    return float(stats.t.isf(q, dof) if dof > 0 else stats.norm.isf(q))


def _fitted_coordinates(dt: xr.DataTree) -> dict[str, int]:
    """Per sampler run, how many of its coordinates the law's mean heights depend on.

    The force law's coordinates and the calibrated robot's; not the noise scales.
    """
    shaping = set(json.loads(dt.attrs.get("parameters", "[]")))
    shaping |= set(json.loads(dt.attrs.get("calibrated", "{}")))
    out = {}
    for run in json.loads(dt.attrs.get("runs", "[]")):
        names = [c.split("[")[0].split(":")[0] for c in run["coordinates"]]
        out[run["label"]] = sum(n in shaping for n in names)
    return out


def lack_of_fit(dt: xr.DataTree, *, n_null: int = 200_000, rng: int = 0) -> dict:
    """Omnibus lack-of-fit test of a law's jump heights against their pure error.

    The classic test of a regression with repeated observations (Fisher 1922; e.g. Draper &
    Smith, *Applied Regression Analysis*, 3rd ed., ch. 2.1), one volume fraction at a time
    because the scatter is fitted per volume fraction: at volume fraction ``phi`` with
    ``C`` cells, the cell means' squared distance from the law's posterior-mean heights,

        T_phi = sum_cells n_c (ybar_c - yhat_c)^2 / s_phi^2,

    over the pure-error variance ``s_phi^2`` of the repeats (``d_phi`` = jumps - cells
    degrees of freedom), is summed into ``T``. Under a law that is right and linear
    enough in its ``p`` fitted coordinates, ``T_phi`` is distributed as
    ``chi2(C - p) / (chi2(d_phi) / d_phi)``, independently across volume fractions; the
    p-value is ``T``'s tail in the sum of those (``n_null`` Monte Carlo draws, seeded:
    deterministic). A ``quadratic`` law's coordinates are shared: they are counted once,
    spread over the volume fractions in proportion to their cells.

    The cell test (:func:`misfit_threshold`) asks whether *one* cell is off; this one
    whether the cells are off *together*: many small misfits, each below a cell's
    threshold, that a law's wrong shape leaves across the design.

    Parameters
    ----------
    dt : xarray.DataTree
        A fit with jump heights (its ``observed_data`` and ``posterior_predictive``
        groups, and the runs' coordinates in its attributes).
    n_null : int
        Monte Carlo draws of the reference distribution.
    rng : int
        Seed of those draws.

    Returns
    -------
    dict
        ``statistic`` (``T``), ``dof_lack`` (``C - p`` over the volume fractions used),
        ``dof_pure``, ``p_value`` (NaN where no volume fraction has repeats and more cells
        than coordinates) and ``by_phi`` (a table: ``phi``, ``cells``, ``coordinates``,
        ``dof_lack``, ``dof_pure``, ``s_mm`` (the pure-error SD), ``statistic``).
    """
    obs = observed_jumps(dt)
    y = obs["height_mm"].to_numpy(float)
    sim = dt["posterior_predictive"]["height_sim_mm"].values.reshape(-1, len(y)).mean(axis=0)
    keys = [k for k in cell_keys(obs) if k != "phi"]
    frame = obs[["phi", *keys]].assign(y=y, sim=sim)
    coords = _fitted_coordinates(dt)
    runs = json.loads(dt.attrs.get("runs", "[]"))
    n_cells_total = frame.groupby(["phi", *keys]).ngroups
    rows = []
    pure = _pure_error(frame, keys)
    for phi, g in frame.groupby("phi", sort=True):
        cells = g.groupby(keys)
        n = cells["y"].size()
        s2, dof_pure = pure[phi]
        per_phi = [r["label"] for r in runs if r["label"] == f"phi={phi:g}"]
        if per_phi:
            p = float(coords[per_phi[0]])
        else:  # one run for every volume fraction: its coordinates spread over the cells
            p = float(sum(coords.values())) * len(n) / max(n_cells_total, 1)
        ss_lack = float((n * (cells["y"].mean() - cells["sim"].mean()) ** 2).sum())
        rows.append(
            {
                "phi": float(phi),
                "cells": len(n),
                "coordinates": p,
                "dof_lack": len(n) - p,
                "dof_pure": dof_pure,
                "s_mm": math.sqrt(s2) if s2 == s2 else math.nan,
                "statistic": ss_lack / s2 if s2 > 0 else math.nan,
            }
        )
    table = pd.DataFrame(rows)
    used = table[(table["dof_pure"] > 0) & (table["dof_lack"] > 0) & table["statistic"].notna()]
    out = {
        "statistic": float(used["statistic"].sum()),
        "dof_lack": float(used["dof_lack"].sum()),
        "dof_pure": float(used["dof_pure"].sum()),
        "p_value": math.nan,
        "by_phi": table,
    }
    if used.empty:
        return out
    gen = np.random.default_rng(rng)
    null = np.zeros(n_null)
    for a, d in zip(used["dof_lack"], used["dof_pure"], strict=True):
        null += gen.chisquare(a, n_null) / (gen.chisquare(d, n_null) / d)
    # the Monte Carlo tail, never below its resolution
    out["p_value"] = float(max(np.mean(null >= out["statistic"]), 1.0 / n_null))
    return out


def describe_cell(row: Mapping) -> str:
    """A misfit cell in words.

    For example "delayed stutter preload at phi = 0.592 (12 Hz, 20 mm, 3 periods settled)
    is under-predicted by 18.1 mm (z = 5.3)". The settings that distinguish cells are
    named: frequency and amplitude, the delay of a delayed stutter, the settle periods of a
    delayed stutter preload.

    Parameters
    ----------
    row : mapping
        A row of :func:`residual_table` (or of :func:`predictive_cells` with a ``kind``:
        a tracked jump's phase, an intrusion curve's depth bin).

    Returns
    -------
    str
    """
    kind = row.get("kind", "heights")
    residual = row["mean_residual"] if "mean_residual" in row else row["mean_residual_mm"]
    verb = "under-predicted" if residual > 0 else "over-predicted"
    unit = row.get("unit", "mm") if "mean_residual" in row else "mm"
    if kind == "intrusions":
        return (
            f"the intrusion force at phi = {row['phi']:g}, {row['speed_mm_s']:g} mm/s, "
            f"{row['depth_from_mm']:g}-{row['depth_to_mm']:g} mm deep is {verb} by "
            f"{abs(residual):.2f} {unit} (z = {row['z']:+.1f})"
        )
    setting = []
    if row.get("freq_hz"):
        setting.append(f"{row['freq_hz']:g} Hz")
    if row.get("amplitude_mm"):
        setting.append(f"{row['amplitude_mm']:g} mm")
    command = COMMANDS.get(str(row.get("command")))
    for name in command.uses if command is not None else ():
        if name in row:
            setting.append(_SETTING_TEXT[name].format(row[name]))
    setting_text = f" ({', '.join(setting)})" if setting else ""
    if kind == "trajectories":
        what = "the foot's height" if row.get("position") == "x_foot_mm" else "the rod"
        return (
            f"{what} in the {row['phase']} of the {str(row['command']).replace('_', ' ')} at "
            f"phi = {row['phi']:g}{setting_text} is {verb} by {abs(residual):.2f} {unit} "
            f"(z = {row['z']:+.1f})"
        )
    return (
        f"{str(row['command']).replace('_', ' ')} at phi = {row['phi']:g}{setting_text} is "
        f"{verb} by {abs(row['mean_residual_mm']):.1f} mm (z = {row['z']:+.1f})"
    )


def rmse_mm(dt: xr.DataTree) -> float:
    """Root-mean-square of observed minus posterior-mean simulated height [mm].

    Parameters
    ----------
    dt : xarray.DataTree
        A fit.

    Returns
    -------
    float
    """
    if "height_mm" not in dt["observed_data"]:
        return float("nan")
    y = dt["observed_data"]["height_mm"].values
    sim = dt["posterior_predictive"]["height_sim_mm"].values.reshape(-1, len(y)).mean(axis=0)
    return float(np.sqrt(np.mean((y - sim) ** 2)))


def cell_statistics(
    table: pd.DataFrame, keys: Sequence[str] = ("freq_hz", "phi", "command")
) -> pd.DataFrame:
    """Count, mean, standard deviation and standard error of heights per cell.

    Parameters
    ----------
    table : pandas.DataFrame
        Jumps (``height_mm`` [mm] and the ``keys`` columns).
    keys : sequence of str
        Columns that define a cell.

    Returns
    -------
    pandas.DataFrame
        ``keys``, ``n``, ``mean_mm``, ``sd_mm``, ``se_mm`` [mm], sorted by ``keys``
        (commands in the order of ``COMMAND_NAMES``).
    """
    keys = list(keys)
    g = table.groupby(keys, sort=True)["height_mm"]
    stats = g.agg(n="count", mean_mm="mean", sd_mm="std").reset_index()
    stats["se_mm"] = stats["sd_mm"] / np.sqrt(stats["n"])
    order = {c: i for i, c in enumerate(COMMAND_NAMES)}
    return stats.sort_values(
        keys, key=lambda s: s.map(order) if s.name == "command" else s
    ).reset_index(drop=True)


def mean_discrepancy(
    mean_mm: float,
    n: int,
    sim_mm: np.ndarray,
    sigma_mm: np.ndarray,
    rng: np.random.Generator,
    ci_prob: float = CI_PROB,
) -> tuple[float, float, float, float]:
    """A measured cell mean against the posterior predictive of the mean of ``n`` jumps.

    The predictive mean of draw ``s`` is ``sim_mm[s] + e_s sigma_mm[s] / sqrt(n)`` with
    ``e_s ~ Normal(0, 1)`` (one ``rng.normal`` call of size ``len(sim_mm)``).

    Parameters
    ----------
    mean_mm : float
        Measured cell mean [mm].
    n : int
        Jumps in the cell.
    sim_mm, sigma_mm : ndarray, shape (n_draws,)
        Simulated height [mm] and trial scatter [mm] per posterior draw (NaN: failed).
    rng : numpy.random.Generator
    ci_prob : float
        Probability of the interval.

    Returns
    -------
    tuple of float
        Median, lo and hi of ``measured - predicted`` [mm], and ``z``: the median over the
        predictive standard deviation ``sqrt(var(sim) + mean(sigma^2) / n)`` (NaN if that
        is not positive).
    """
    predicted = sim_mm + rng.normal(size=len(sim_mm)) * sigma_mm / np.sqrt(n)
    med, lo, hi = interval(mean_mm - predicted, ci_prob)
    sd_mean = np.sqrt(np.nanvar(sim_mm) + np.nanmean(sigma_mm**2) / n)
    z = med / sd_mean if np.isfinite(sd_mean) and sd_mean > 0 else np.nan
    return med, lo, hi, z
