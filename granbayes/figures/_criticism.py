"""Figures of model criticism: where a law fails, per cell."""

from __future__ import annotations

import numpy as np
import pandas as pd
from matplotlib.figure import Figure

from ..commands import COMMAND_NAMES
from ._style import suptitle

_SETTING_UNITS = {"amplitude_mm": "mm", "delay_ms": "ms", "settle_periods": "T"}


def _row_labels(residuals: pd.DataFrame) -> tuple[pd.Series, list[int]]:
    """Heat-map row of every cell: its command, plus the settings that vary for it."""
    varying = [
        k
        for k in _SETTING_UNITS
        if k in residuals and residuals.groupby("command")[k].nunique().max() > 1
    ]
    labels = []
    for r in residuals.to_dict("records"):
        extra = [f"{r[k]:g} {_SETTING_UNITS[k]}" for k in varying]
        labels.append(r["command"] + (f" ({', '.join(extra)})" if extra else ""))
    order = [COMMAND_NAMES.index(c) for c in residuals["command"]]
    return pd.Series(labels, index=residuals.index), order


def plot_residual_heatmap(residuals: pd.DataFrame, title: str, z_threshold: float = 3.0) -> Figure:
    """Mean residual (observed - simulated) per command x phi, one panel per frequency.

    Cells are coloured by the mean residual [mm] (red: the model under-predicts) and
    annotated with it and the z-score; cells with |z| above ``z_threshold`` are framed.

    Parameters
    ----------
    residuals : pandas.DataFrame
        Cells (:func:`granbayes.residual_table`).
    title : str
        Figure title.
    z_threshold : float
        Misfit threshold of |z|.

    Returns
    -------
    matplotlib.figure.Figure
    """
    rows, order = _row_labels(residuals)
    residuals = residuals.assign(row=rows, order=order)
    freqs = sorted(residuals["freq_hz"].unique())
    phis = sorted(residuals["phi"].unique())
    commands = list(dict.fromkeys(residuals.sort_values("order")["row"]))
    vmax = max(5.0, float(np.nanmax(np.abs(residuals["mean_residual_mm"]))))
    fig = Figure(
        figsize=(max(5.0, 1.25 * len(phis) * len(freqs) + 3.0), 0.55 * len(commands) + 1.8),
        layout="constrained",
    )
    axes = fig.subplots(1, len(freqs), squeeze=False, sharey=True)[0]
    image = None
    for ax, f in zip(axes, freqs, strict=True):
        grid = np.full((len(commands), len(phis)), np.nan)
        zs = np.full_like(grid, np.nan)
        sub = residuals[residuals["freq_hz"] == f]
        for r in sub.itertuples():
            i, j = commands.index(r.row), phis.index(r.phi)
            grid[i, j], zs[i, j] = r.mean_residual_mm, r.z
        image = ax.imshow(grid, cmap="RdBu_r", vmin=-vmax, vmax=vmax, aspect="auto")
        for i in range(len(commands)):
            for j in range(len(phis)):
                if np.isnan(grid[i, j]):
                    continue
                strong = abs(zs[i, j]) > z_threshold
                dark = abs(grid[i, j]) > 0.55 * vmax
                ax.text(
                    j,
                    i,
                    f"{grid[i, j]:+.1f}\nz={zs[i, j]:+.1f}",
                    ha="center",
                    va="center",
                    fontsize=7,
                    color="white" if dark else "black",
                    fontweight="bold" if strong else "normal",
                )
                if strong:
                    ax.add_patch(_frame(j, i))
        ax.set_xticks(range(len(phis)), [f"{p:g}" for p in phis])
        ax.set_yticks(range(len(commands)), [c.replace("_", " ") for c in commands])
        ax.set_xlabel("volume fraction φ [-]")
        ax.set_title(f"{f:g} Hz" if f else "")
    fig.colorbar(image, ax=list(axes), label="mean residual: observed − simulated [mm]")
    suptitle(
        fig,
        title + f"\nmean residual [mm] and lack-of-fit z per cell (framed: |z| > {z_threshold:g})",
        fontsize=10,
    )
    return fig


def _frame(j: int, i: int):
    from matplotlib.patches import Rectangle

    return Rectangle((j - 0.5, i - 0.5), 1, 1, fill=False, lw=2, ec="k")
