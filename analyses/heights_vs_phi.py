"""Measured jump heights of every command against the packing phi - phi_c (thesis Fig. 8).

One panel per actuation frequency: every trial as a point, the cell mean with its standard
error, and per volume fraction the ranking of the commands. No model is involved: this is
what the data say before any fit.
"""

from __future__ import annotations

import sys

import numpy as np
import pandas as pd

import _common as common
from granbayes.figures import plot_heights_vs_phi
from granbayes.stats import cell_statistics

NAME = "heights_vs_phi"


def analyse(ctx: common.Context) -> tuple[str, dict]:
    stats = cell_statistics(ctx.table)
    ctx.save_table(stats, "cell_statistics")
    title = f"Measured jump height per command vs packing (φc = {ctx.phi_c:g})"
    ctx.save_figure(plot_heights_vs_phi(ctx.table, stats, ctx.phi_c, ctx.title(title)), NAME)
    rankings, numbers = [], {"cells": []}
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
        by_command = {
            k: dict(zip(cell["command"], cell[k], strict=True)) for k in ("mean_mm", "sd_mm")
        }
        numbers["cells"].append(
            {"freq_hz": freq, "phi": phi, "best": best["command"], **by_command}
        )
    trend = []
    for (freq, command), c in stats.groupby(["freq_hz", "command"], sort=False):
        if c["phi"].nunique() < 2:
            continue
        slope = 0.01 * np.polyfit(c["phi"] - ctx.phi_c, c["mean_mm"], 1)[0]
        span = f"{c['mean_mm'].min():.1f} – {c['mean_mm'].max():.1f}"
        trend.append(
            {
                "freq_hz": freq,
                "command": command,
                "slope [mm per 0.01 phi]": slope,
                "range of cell means [mm]": span,
            }
        )
        numbers.setdefault("slope_mm_per_0.01", {})[f"{command}@{freq:g}Hz"] = slope
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
        body += ["", "## Trend with packing (least-squares line through the cell means)", ""]
        body.append(common.markdown_table(pd.DataFrame(trend), ".3g"))
    numbers["best_at_loosest"] = best_loose
    return "\n".join(body), numbers


def main(argv: list[str] | None = None) -> int:
    return common.main(NAME, __doc__, analyse, argv)


if __name__ == "__main__":
    sys.exit(main())
