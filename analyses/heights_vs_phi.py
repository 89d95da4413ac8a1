"""Measured jump heights of every command against the packing phi - phi_c (thesis Fig. 8).

One panel per actuation frequency: every trial as a point, the cell mean with its standard
error, and per volume fraction the ranking of the commands. No model is involved: this is
what the data say before any fit.
"""

from __future__ import annotations

import sys

import numpy as np
import pandas as pd
from matplotlib.figure import Figure

import _common as common
from granbayes import COMMAND_NAMES

NAME = "heights_vs_phi"


def cell_statistics(table: pd.DataFrame) -> pd.DataFrame:
    """Mean, standard deviation, standard error and count per (freq, phi, command) cell."""
    g = table.groupby(["freq_hz", "phi", "command"], sort=True)["height_mm"]
    stats = g.agg(n="count", mean_mm="mean", sd_mm="std").reset_index()
    stats["se_mm"] = stats["sd_mm"] / np.sqrt(stats["n"])
    order = {c: i for i, c in enumerate(COMMAND_NAMES)}
    return stats.sort_values(
        ["freq_hz", "phi", "command"], key=lambda s: s.map(order) if s.name == "command" else s
    ).reset_index(drop=True)


def plot(ctx: common.Context, stats: pd.DataFrame) -> Figure:
    """Heights against phi - phi_c, one panel per frequency."""
    freqs = np.unique(stats["freq_hz"])
    fig = Figure(figsize=(5.2 * len(freqs) + 0.6, 4.6), layout="constrained")
    axes = np.atleast_1d(fig.subplots(1, len(freqs), sharey=True))
    dx = 0.0006 * (np.ptp(ctx.phis) / 0.04 if ctx.phis.size > 1 else 1.0)
    offsets = dict(zip(COMMAND_NAMES, np.linspace(-2, 2, len(COMMAND_NAMES)) * dx, strict=True))
    for ax, freq in zip(axes, freqs, strict=True):
        raw = ctx.table[ctx.table["freq_hz"] == freq]
        cell = stats[stats["freq_hz"] == freq]
        for command in COMMAND_NAMES:
            r = raw[raw["command"] == command]
            c = cell[cell["command"] == command]
            if c.empty:
                continue
            color = common.COMMAND_COLORS[command]
            x = c["phi"].to_numpy() - ctx.phi_c + offsets[command]
            ax.plot(
                r["phi"].to_numpy() - ctx.phi_c + offsets[command],
                r["height_mm"],
                ls="none",
                marker=common.COMMAND_MARKERS[command],
                ms=3,
                alpha=0.35,
                color=color,
            )
            ax.errorbar(
                x,
                c["mean_mm"],
                yerr=c["se_mm"].fillna(0.0),
                color=color,
                marker=common.COMMAND_MARKERS[command],
                ms=6,
                lw=1.4,
                capsize=3,
                label=command.replace("_", " "),
            )
        ax.axvline(0.0, color="0.5", ls=":", lw=1)
        ax.set_title(f"actuator {freq:g} Hz", fontsize=10)
        ax.set_xlabel(r"$\phi - \phi_c$")
        ax.grid(alpha=0.3)
    axes[0].set_ylabel("jump height [mm]")
    axes[0].legend(fontsize=8, loc="best", title="mean ± s.e.; dots: trials", title_fontsize=8)
    fig.suptitle(
        ctx.title(f"Measured jump height per command vs packing (φc = {ctx.phi_c:g})"),
        fontsize=11,
    )
    return fig


def analyse(ctx: common.Context) -> tuple[str, dict]:
    stats = cell_statistics(ctx.table)
    ctx.save_table(stats, "cell_statistics")
    ctx.save_figure(plot(ctx, stats), "heights_vs_phi")
    rankings = []
    numbers: dict = {"cells": []}
    for (freq, phi), cell in stats.groupby(["freq_hz", "phi"]):
        ranked = cell.sort_values("mean_mm", ascending=False)
        best, worst = ranked.iloc[0], ranked.iloc[-1]
        rankings.append(
            {
                "freq_hz": freq,
                "phi - phi_c": phi - ctx.phi_c,
                "ranking (highest first)": " > ".join(ranked["command"]),
                "best [mm]": f"{best['mean_mm']:.1f} ± {best['se_mm']:.1f}",
                "lowest [mm]": f"{worst['mean_mm']:.1f} ± {worst['se_mm']:.1f}",
            }
        )
        numbers["cells"].append(
            {
                "freq_hz": freq,
                "phi": phi,
                "best": best["command"],
                "mean_mm": dict(zip(cell["command"], cell["mean_mm"], strict=True)),
                "sd_mm": dict(zip(cell["command"], cell["sd_mm"], strict=True)),
            }
        )
    trend = []
    for (freq, command), c in stats.groupby(["freq_hz", "command"], sort=False):
        if c["phi"].nunique() < 2:
            continue
        slope = np.polyfit(c["phi"] - ctx.phi_c, c["mean_mm"], 1)[0]
        trend.append(
            {
                "freq_hz": freq,
                "command": command,
                "slope [mm per 0.01 phi]": 0.01 * slope,
                "range of cell means [mm]": f"{c['mean_mm'].min():.1f} – {c['mean_mm'].max():.1f}",
            }
        )
        numbers.setdefault("slope_mm_per_0.01", {})[f"{command}@{freq:g}Hz"] = 0.01 * slope
    loosest = stats[stats["phi"] == stats["phi"].min()]
    best_loose = loosest.groupby("command")["mean_mm"].mean().idxmax()
    body = [
        f"{len(ctx.table)} jumps in {len(stats)} cells (command × φ × frequency).",
        "",
        f"At the loosest packing (φ = {stats['phi'].min():g}) the highest mean jump is "
        f"**{best_loose.replace('_', ' ')}** (averaged over frequencies).",
        "",
        "![heights vs phi](heights_vs_phi.png)",
        "",
        "## Ranking per cell",
        "",
        common.markdown_table(pd.DataFrame(rankings), ".3g"),
    ]
    if trend:
        body += [
            "",
            "## Trend with packing (least-squares line through the cell means)",
            "",
            common.markdown_table(pd.DataFrame(trend), ".3g"),
        ]
    numbers["best_at_loosest"] = best_loose
    return "\n".join(body), numbers


def main(argv: list[str] | None = None) -> int:
    return common.main(NAME, __doc__, analyse, argv)


if __name__ == "__main__":
    sys.exit(main())
