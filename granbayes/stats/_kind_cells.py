"""Residual cells of the measurements beyond jump heights: trajectories and intrusions.

A jump height's cell is one command setting (:mod:`granbayes.stats._cells`); a tracked
jump's cells are its phases (stance, push-off, flight, descent) per position, command and
setting; an intrusion curve's cells are its depth bins per volume fraction and speed.
Frames and force samples are not independent repeats (a trajectory's frames drift
together, one curve's samples share its test), so a cell's misfit is judged against the
posterior predictive distribution of the cell's mean (replicates carry the fitted noise
model, its correlation and the clock offset): ``z`` is the observed mean's distance from
the mean of the replicated cell means in their standard deviations, ``p_value`` its
two-sided predictive tail probability.
"""

from __future__ import annotations

import numpy as np
import pandas as pd
import xarray as xr
from scipy import stats as sps

__all__ = ["intrusion_cells", "predictive_cells", "trajectory_cells"]

#: Width of the depth bins of intrusion cells [mm].
DEPTH_BIN_MM = 5.0


def predictive_cells(
    keys: pd.DataFrame, y: np.ndarray, rep: np.ndarray, sim: np.ndarray, unit: str
) -> pd.DataFrame:
    """Cells of observations against the posterior predictive of their mean.

    Parameters
    ----------
    keys : pandas.DataFrame
        One row per observation: the columns that define its cell.
    y : ndarray, shape (n_obs,)
        The observations.
    rep, sim : ndarray, shape (n_draws, n_obs)
        Replicated observations (noise included) and the noise-free simulations.
    unit : str
        Unit of the observations (for the ``unit`` column).

    Returns
    -------
    pandas.DataFrame
        One row per cell, worst (largest |z|) first: the keys, ``n``, ``observed``,
        ``simulated``, ``mean_residual`` (observed - simulated, in ``unit``), ``unit``,
        ``z``, ``p_value``, ``dof`` (0: a predictive z), ``z_predictive``,
        ``p_predictive``.
    """
    rows = []
    cols = list(keys.columns)
    for key, idx in keys.groupby(cols, sort=True).indices.items():
        idx = np.asarray(idx)
        key = key if isinstance(key, tuple) else (key,)
        y_mean = float(np.mean(y[idx]))
        rep_mean = np.nanmean(rep[:, idx], axis=1)
        sim_mean = float(np.nanmean(sim[:, idx]))
        sd = float(np.nanstd(rep_mean))
        z = (y_mean - float(np.nanmean(rep_mean))) / sd if sd > 0 else np.inf
        tail = min(np.mean(rep_mean >= y_mean), np.mean(rep_mean <= y_mean))
        p = min(1.0, 2.0 * tail if tail > 0 else 2.0 * sps.norm.sf(abs(z)))
        rows.append(
            {
                **dict(zip(cols, key, strict=True)),
                "n": len(idx),
                "observed": y_mean,
                "simulated": sim_mean,
                "mean_residual": y_mean - sim_mean,
                "unit": unit,
                "z": z,
                "p_value": p,
                "dof": 0.0,
                "z_predictive": z,
                "p_predictive": p,
            }
        )
    table = pd.DataFrame(rows)
    if table.empty:
        return table
    order = table["z"].abs().sort_values(ascending=False).index
    return table.reindex(order).reset_index(drop=True)


def _draws(var: xr.DataArray, dim: str) -> np.ndarray:
    """A predictive variable as (draws, elements)."""
    other = [d for d in var.dims if d != dim]
    return var.transpose(*other, dim).values.reshape(-1, var.sizes[dim])


def trajectory_cells(dt: xr.DataTree) -> pd.DataFrame:
    """Residual cells of the tracked jumps: each phase per position, command and setting.

    Parameters
    ----------
    dt : xarray.DataTree
        A fit with tracked jumps (``observed_data`` frames with ``frame_phase`` and
        ``frame_trajectory``; their replicates in ``posterior_predictive``).

    Returns
    -------
    pandas.DataFrame
        :func:`predictive_cells` with ``kind = "trajectories"`` and the keys
        ``position``, ``phase``, ``phi``, ``command`` and the settings [mm].
    """
    obs = dt["observed_data"].to_dataset()
    pp = dt["posterior_predictive"].to_dataset()
    unit = obs["frame_trajectory"].values
    base = {"phase": obs["frame_phase"].values.astype(str)}
    for c in ("phi", "command", "freq_hz", "amplitude_mm", "delay_ms", "settle_periods"):
        name = f"trajectory_{c}"
        if name in obs.coords:
            base[c] = obs[name].values[unit]
    tables = []
    for position in ("x_foot_mm", "x_rod_mm"):
        if position not in obs or position not in pp:
            continue
        keys = pd.DataFrame({"position": position, **base})
        rep = _draws(pp[position], "frame")
        sim = _draws(pp[position.replace("_mm", "_sim_mm")], "frame")
        tables.append(predictive_cells(keys, obs[position].values, rep, sim, "mm"))
    if not tables:
        return pd.DataFrame()
    out = pd.concat(tables, ignore_index=True)
    out.insert(0, "kind", "trajectories")
    order = out["z"].abs().sort_values(ascending=False).index
    return out.reindex(order).reset_index(drop=True)


def intrusion_cells(dt: xr.DataTree, depth_bin_mm: float = DEPTH_BIN_MM) -> pd.DataFrame:
    """Residual cells of the intrusion curves: depth bins per volume fraction and speed.

    Parameters
    ----------
    dt : xarray.DataTree
        A fit with intrusion tests.
    depth_bin_mm : float
        Width of the depth bins [mm]; a cell is ``[lower, lower + width)``.

    Returns
    -------
    pandas.DataFrame
        :func:`predictive_cells` with ``kind = "intrusions"`` and the keys ``phi``,
        ``speed_mm_s``, ``depth_from_mm`` and ``depth_to_mm`` [N].
    """
    obs = dt["observed_data"].to_dataset()
    pp = dt["posterior_predictive"].to_dataset()
    test = obs["reading_test"].values
    depth = obs["depth_mm"].values
    lower = np.floor(depth / depth_bin_mm) * depth_bin_mm
    keys = pd.DataFrame(
        {
            "phi": obs["test_phi"].values[test],
            "speed_mm_s": obs["test_speed_mm_s"].values[test],
            "depth_from_mm": lower,
            "depth_to_mm": lower + depth_bin_mm,
        }
    )
    rep = _draws(pp["force_N"], "reading")
    sim = _draws(pp["force_sim_N"], "reading")
    out = predictive_cells(keys, obs["force_N"].values, rep, sim, "N")
    out.insert(0, "kind", "intrusions")
    return out
