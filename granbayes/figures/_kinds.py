"""Figures of the measurements beyond jump heights: tracked jumps and intrusion curves."""

from __future__ import annotations

import numpy as np
import xarray as xr
from matplotlib.figure import Figure

from ..stats import CI_PROB, eti_probs
from ._style import COLORS, data_label, suptitle

__all__ = ["plot_intrusions", "plot_tracked_jumps"]

_POSITION_LABELS = {"x_foot_mm": "foot height x_f [mm]", "x_rod_mm": "rod displacement [mm]"}
_PHASE_SHADES = {"push-off": "#E69F00", "flight": "#56B4E9"}


def _draws(var: xr.DataArray, dim: str) -> np.ndarray:
    other = [d for d in var.dims if d != dim]
    return var.transpose(*other, dim).values.reshape(-1, var.sizes[dim])


def _quantiles(values: np.ndarray, q) -> np.ndarray:
    """Quantiles over the draws (axis 0), ignoring NaN (failed simulations) where any."""
    if np.isnan(values).any():
        return np.nanquantile(values, q, axis=0)
    return np.quantile(values, q, axis=0)


def plot_tracked_jumps(dt: xr.DataTree, ci_prob: float = CI_PROB, max_jumps: int = 6) -> Figure:
    """Measured trajectories over posterior predictive bands, with residuals against time.

    One column per tracked jump (the first of each command and setting, at most
    ``max_jumps``); per position measured: its frames (points) over the band of replicated
    frames (light, ``ci_prob`` equal-tailed: noise, clock offset and force law) and of the
    simulation (dark), and below it the residual (measured - posterior median of the
    simulation) with the replicates' residual band. The push-off and flight phases (the
    residual cells) are shaded.

    Parameters
    ----------
    dt : xarray.DataTree
        A fit with tracked jumps.
    ci_prob : float
        Probability of the bands.
    max_jumps : int
        Most tracked jumps drawn.

    Returns
    -------
    matplotlib.figure.Figure
    """
    obs = dt.observed_data.to_dataset()
    pp = dt.posterior_predictive.to_dataset()
    unit = obs["frame_trajectory"].values
    positions = [c for c in ("x_foot_mm", "x_rod_mm") if c in obs and c in pp]
    keys = [
        f"trajectory_{c}" for c in ("phi", "command", "freq_hz") if f"trajectory_{c}" in obs.coords
    ]
    seen, chosen = set(), []
    for j in range(obs.sizes["trajectory"]):
        key = tuple(obs[k].values[j] for k in keys)
        if key not in seen:
            seen.add(key)
            chosen.append(j)
    chosen = chosen[:max_jumps]
    q = eti_probs(ci_prob)
    rows = 2 * len(positions)
    fig = Figure(figsize=(3.2 * len(chosen), 2.0 * rows + 0.6), layout="constrained")
    axes = fig.subplots(
        rows, len(chosen), squeeze=False, sharex="col", height_ratios=[2, 1] * len(positions)
    )
    t_all = obs["t_s"].values
    phase = obs["frame_phase"].values.astype(str)
    # every draw of every frame, read once (not once per jump drawn)
    reps = {c: _draws(pp[c], "frame") for c in positions}
    sims = {c: _draws(pp[c.replace("_mm", "_sim_mm")], "frame") for c in positions}
    for col, j in enumerate(chosen):
        sel = np.flatnonzero(unit == j)
        t = 1e3 * t_all[sel]
        for p, position in enumerate(positions):
            ax, rax = axes[2 * p, col], axes[2 * p + 1, col]
            y = obs[position].values[sel]
            rep = reps[position][:, sel]
            lo_r, _, hi_r = _quantiles(rep, q)
            lo_s, med, hi_s = _quantiles(sims[position][:, sel], q)
            for name, shade in _PHASE_SHADES.items():
                inside = np.flatnonzero(phase[sel] == name)
                if len(inside):
                    for a in (ax, rax):
                        a.axvspan(t[inside[0]], t[inside[-1]], color=shade, alpha=0.12, lw=0)
            ax.fill_between(t, lo_r, hi_r, color=COLORS[0], alpha=0.18, lw=0, label="new frames")
            ax.fill_between(t, lo_s, hi_s, color=COLORS[0], alpha=0.45, lw=0, label="simulation")
            ax.plot(t, med, color=COLORS[0], lw=1.0)
            ax.plot(t, y, ".", ms=2.0, color="k", label="measured")
            res_lo, res_hi = _quantiles(rep - med, [q[0], q[2]])
            rax.fill_between(t, res_lo, res_hi, color=COLORS[0], alpha=0.18, lw=0)
            rax.axhline(0.0, color="0.4", lw=0.6)
            rax.plot(t, y - med, ".", ms=2.0, color="k")
            if col == 0:
                ax.set_ylabel(_POSITION_LABELS[position])
                rax.set_ylabel("residual [mm]")
            ax.grid(alpha=0.3)
            rax.grid(alpha=0.3)
        parts = []
        for k in keys:
            value = obs[k].values[j]
            if k.endswith("phi"):
                parts.append(f"φ = {float(value):g}")
            elif k.endswith("freq_hz"):
                parts.append(f"{float(value):g} Hz")
            else:
                parts.append(str(value).replace("_", " "))
        axes[0, col].set_title(", ".join(parts), fontsize=9)
        axes[-1, col].set_xlabel("time on the command's clock t [ms]")
    axes[0, 0].legend(fontsize=7, loc="upper left")
    head = f"Tracked jumps: measured frames over {ci_prob:.0%} posterior predictive bands"
    head += " (shaded: push-off, flight)"
    label = data_label(dt)
    suptitle(fig, f"{label}\n{head}" if label else head)
    return fig


def plot_intrusions(dt: xr.DataTree, ci_prob: float = CI_PROB) -> Figure:
    """Force-depth curves per volume fraction: measured samples over predictive bands.

    One panel per volume fraction, one colour per intrusion speed: measured samples
    (points), the band of replicated forces (light) and of the model's force (dark), both
    ``ci_prob`` equal-tailed, and the posterior median of the model's force (line).

    Parameters
    ----------
    dt : xarray.DataTree
        A fit with intrusion tests.
    ci_prob : float
        Probability of the bands.

    Returns
    -------
    matplotlib.figure.Figure
    """
    obs = dt.observed_data.to_dataset()
    pp = dt.posterior_predictive.to_dataset()
    test = obs["reading_test"].values
    phi = obs["test_phi"].values[test]
    speed = obs["test_speed_mm_s"].values[test]
    depth = obs["depth_mm"].values
    force = obs["force_N"].values
    rep = _draws(pp["force_N"], "reading")
    sim = _draws(pp["force_sim_N"], "reading")
    phis, speeds = np.unique(phi), np.unique(speed)
    q = eti_probs(ci_prob)
    fig = Figure(figsize=(3.3 * len(phis), 3.4), layout="constrained")
    axes = fig.subplots(1, len(phis), sharey=True, squeeze=False)[0]
    for ax, p in zip(axes, phis, strict=True):
        for k, v in enumerate(speeds):
            color = COLORS[k % len(COLORS)]
            sel = np.flatnonzero((phi == p) & (speed == v))
            if not len(sel):
                continue
            order = sel[np.argsort(depth[sel], kind="stable")]
            d = depth[order]
            lo_r, _, hi_r = _quantiles(rep[:, order], q)
            lo_s, med, hi_s = _quantiles(sim[:, order], q)
            ax.fill_between(d, lo_r, hi_r, color=color, alpha=0.15, lw=0)
            ax.fill_between(d, lo_s, hi_s, color=color, alpha=0.4, lw=0)
            ax.plot(d, med, color=color, lw=1.0, label=f"{v:g} mm/s")
            ax.plot(depth[sel], force[sel], "o", ms=2.2, color=color, mec="k", mew=0.2)
        ax.set_title(f"φ = {p:g}")
        ax.set_xlabel("depth z [mm]")
        ax.grid(alpha=0.3)
    axes[0].set_ylabel("intrusion force [N]")
    axes[0].legend(title="speed", fontsize=7)
    head = f"Intrusion tests: measured force over {ci_prob:.0%} posterior predictive bands"
    label = data_label(dt)
    suptitle(fig, f"{label}\n{head}" if label else head)
    return fig
