"""Figures of the analyses (``analyses/``).

Measured heights, misfit maps, optimal jumping, added-mass impulse and coefficients per
command, with one colour and marker per command (:data:`COMMAND_COLORS`,
:data:`COMMAND_MARKERS`) shared by every analysis figure.

Length: about 900 lines, one function per figure of the analyses, each short; they share
the command colours and markers defined here, which is why they are in one module.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from typing import TYPE_CHECKING

import numpy as np
import pandas as pd
from matplotlib import colormaps
from matplotlib.artist import Artist
from matplotlib.axes import Axes
from matplotlib.colors import LogNorm, to_rgba
from matplotlib.figure import Figure
from matplotlib.lines import Line2D
from matplotlib.patches import Patch
from numpy.typing import ArrayLike

from .._experiment import Experiment
from ..commands import COMMAND_NAMES
from ._style import suptitle

if TYPE_CHECKING:
    from ..analysis.maps import MisfitMap
    from ..analysis.optimal import OptimumSearch


# Okabe-Ito colours: distinguishable with colour-vision deficiencies and in greyscale.


# ----------------------------------------------------------------------------------------
# Building blocks: one panel of one trajectory
# ----------------------------------------------------------------------------------------


# ----------------------------------------------------------------------------------------
# Figures of the analyses (analyses/): measured heights, misfit maps, optimal jumping,
# added-mass impulse, coefficients per command. Colour = command everywhere.
# ----------------------------------------------------------------------------------------

#: One colour per command (Okabe-Ito, colour-blind safe), in ``COMMAND_NAMES`` order.
COMMAND_COLORS: dict[str, str] = dict(
    zip(COMMAND_NAMES, ("#0072B2", "#D55E00", "#009E73", "#CC79A7", "#E69F00"), strict=True)
)
#: One marker per command, in ``COMMAND_NAMES`` order.
COMMAND_MARKERS: dict[str, str] = dict(zip(COMMAND_NAMES, ("o", "s", "^", "D", "v"), strict=True))
#: Line style and hatch of the first and second command of a misfit-map pair.
_PAIR_STYLES = ({"ls": "-", "hatch": "\\\\\\"}, {"ls": "--", "hatch": "///"})
#: Markers that tell volume fractions apart where colour is the command.
_PHI_MARKERS = ("v", "s", "o", "^", "D", "P", "X", "*", "h", "<", ">")


def _short(command: str) -> str:
    return command.replace("_", " ")


def command_offsets(x: ArrayLike, step: float) -> dict[str, float]:
    """Horizontal offsets per command so that error bars at the same x do not overlap.

    Parameters
    ----------
    x : array_like
        The x values shown (e.g. ``phi - phi_c``).
    step : float
        Offset between neighbouring commands for an x range of 0.04 (scaled with the range).

    Returns
    -------
    dict of str to float
    """
    x = np.asarray(x, dtype=float)
    dx = step * (np.ptp(x) / 0.04 if x.size > 1 else 1.0)
    return dict(zip(COMMAND_NAMES, np.linspace(-2, 2, len(COMMAND_NAMES)) * dx, strict=True))


def panel_grid(
    n: int, width: float = 4.1, height: float = 3.4
) -> tuple[Figure, list[Axes], Axes | None]:
    """Figure with ``n`` panels in rows of 3; returns a spare axes for a legend (or None).

    Parameters
    ----------
    n : int
        Number of panels.
    width, height : float
        Size of a panel [in].
    """
    ncols = min(n, 3)
    nrows = math.ceil(n / ncols)
    fig = Figure(figsize=(width * ncols + 0.4, height * nrows + 1.0), layout="constrained")
    axes = np.atleast_1d(fig.subplots(nrows, ncols, squeeze=False)).ravel()
    legend_ax = None
    if nrows * ncols > n:
        legend_ax = axes[n]
        for ax in axes[n:]:
            ax.set_axis_off()
    return fig, list(axes[:n]), legend_ax


def plot_heights_vs_phi(
    table: pd.DataFrame, stats: pd.DataFrame, phi_c: float, title: str
) -> Figure:
    """Measured heights against ``phi - phi_c``, one panel per actuation frequency.

    Parameters
    ----------
    table : pandas.DataFrame
        The jumps (``freq_hz``, ``phi``, ``command``, ``height_mm`` [mm]): one dot each.
    stats : pandas.DataFrame
        :func:`granbayes.stats.cell_statistics`: cell mean with its standard error.
    phi_c : float
        Critical packing [-].
    title : str

    Returns
    -------
    matplotlib.figure.Figure
    """
    freqs = np.unique(stats["freq_hz"])
    fig = Figure(figsize=(5.2 * len(freqs) + 0.6, 4.6), layout="constrained")
    axes = np.atleast_1d(fig.subplots(1, len(freqs), sharey=True))
    offsets = command_offsets(np.unique(table["phi"].to_numpy(float)), 0.0006)
    for ax, freq in zip(axes, freqs, strict=True):
        raw = table[table["freq_hz"] == freq]
        cell = stats[stats["freq_hz"] == freq]
        for command in COMMAND_NAMES:
            r, c = raw[raw["command"] == command], cell[cell["command"] == command]
            if c.empty:
                continue
            color, marker = COMMAND_COLORS[command], COMMAND_MARKERS[command]
            x = c["phi"].to_numpy() - phi_c + offsets[command]
            ax.plot(
                r["phi"].to_numpy() - phi_c + offsets[command],
                r["height_mm"],
                ls="none",
                marker=marker,
                ms=3,
                alpha=0.35,
                color=color,
            )
            ax.errorbar(
                x,
                c["mean_mm"],
                yerr=c["se_mm"].fillna(0.0),
                color=color,
                marker=marker,
                ms=6,
                lw=1.4,
                capsize=3,
                label=_short(command),
            )
        ax.axvline(0.0, color="0.5", ls=":", lw=1)
        ax.set_title(f"actuator {freq:g} Hz", fontsize=10)
        ax.set_xlabel(r"$\phi - \phi_c$")
        ax.grid(alpha=0.3)
    axes[0].set_ylabel("jump height [mm]")
    axes[0].legend(fontsize=8, loc="best", title="mean ± s.e.; dots: trials", title_fontsize=8)
    suptitle(fig, title, fontsize=11)
    return fig


# -- misfit maps (granbayes.analysis.maps) ---------------------------------------------------------
def _cd_limits(m: MisfitMap) -> tuple[float, float]:
    """c_d axis limits of the pcolormesh cells (half a step beyond the grid) [kg/m]."""
    half = 0.5 * (m.cd_kg_per_m[1] - m.cd_kg_per_m[0]) if m.cd_kg_per_m.size > 1 else 0.5
    return float(m.cd_kg_per_m[0] - half), float(m.cd_kg_per_m[-1] + half)


def _misfit_norm(m: MisfitMap) -> LogNorm:
    """Log colour scale of the misfit maps: from half the smallest standard error [mm]."""
    values = np.concatenate([m.observed.rms_mm[c].ravel() for c in m.commands])
    values = values[np.isfinite(values)]
    se_min = min(float(m.ses()[c].min()) for c in m.commands)
    vmin = max(0.05, 0.5 * se_min, float(values.min()) if values.size else 0.0)
    vmax = max(10 * vmin, float(np.quantile(values, 0.995))) if values.size else 100.0
    return LogNorm(vmin=vmin, vmax=vmax, clip=True)


def _shade_valley(ax: Axes, m: MisfitMap, command: str) -> None:
    """Acceptable region (hatched) and valley line of ``command`` on ``ax``."""
    from ..analysis.maps import valley_line

    ev = m.observed
    mask = ev.acceptable[command].astype(float)
    color, style = COMMAND_COLORS[command], _PAIR_STYLES[m.commands.index(command)]
    if mask.any():
        cd, k = m.cd_kg_per_m, m.k_n_per_m
        ax.contourf(cd, k, mask, levels=[0.5, 1.5], colors=[color], alpha=0.25)
        ax.contourf(
            cd, k, mask, levels=[0.5, 1.5], colors="none", hatches=[style["hatch"]], edgecolor=color
        )
        ax.contour(
            cd, k, mask, levels=[0.5], colors=[color], linewidths=1.0, linestyles=style["ls"]
        )
    ax.plot(
        m.cd_kg_per_m,
        valley_line(ev.valley_k_n_per_m[command], m.sim_log_step),
        color=color,
        ls=style["ls"],
        lw=2.2,
    )


def _valley_handles(commands: Sequence[str], m: MisfitMap | None = None) -> list[Artist]:
    """Legend entries of :func:`_shade_valley` (``m``: mark commands without acceptable points)."""
    lines, patches = [], []
    for c, style in zip(commands, _PAIR_STYLES, strict=True):
        color = COMMAND_COLORS[c]
        none = m is not None and not m.observed.acceptable[c].any()
        lines.append(
            Line2D([], [], color=color, ls=style["ls"], lw=2.2, label=f"{_short(c)} valley")
        )
        patches.append(
            Patch(
                facecolor=to_rgba(color, 0.25),
                edgecolor=color,
                hatch=style["hatch"],
                label=f"{_short(c)} acceptable" + (": none" if none else ""),
            )
        )
    return lines + patches


def plot_misfit_maps(m: MisfitMap, phi_c: float, title: str) -> Figure:
    """Misfit maps of both commands with their valleys, and the overlay of the valleys.

    Parameters
    ----------
    m : granbayes.analysis.maps.MisfitMap
    phi_c : float
        Critical packing [-].
    title : str

    Returns
    -------
    matplotlib.figure.Figure
    """
    from ..analysis.maps import TOLERANCE_SE, valley_line
    from ..stats import interval

    fig = Figure(figsize=(15.5, 5.2), layout="constrained")
    axes = fig.subplots(1, 3, sharey=True)
    norm = _misfit_norm(m)
    ev = m.observed
    mesh = None
    for ax, command in zip(axes[:2], m.commands, strict=True):
        mesh = ax.pcolormesh(
            m.cd_kg_per_m,
            m.k_n_per_m,
            ev.rms_mm[command],
            norm=norm,
            cmap="viridis",
            shading="nearest",
            rasterized=True,
        )
        mask = ev.acceptable[command].astype(float)
        if mask.any():
            ax.contour(
                m.cd_kg_per_m, m.k_n_per_m, mask, levels=[0.5], colors="#FF8C00", linewidths=1.6
            )
        ax.plot(
            m.cd_kg_per_m,
            valley_line(ev.valley_k_n_per_m[command], m.sim_log_step),
            color="white",
            ls="--",
            lw=1.6,
        )
        cells = ", ".join(f"{x.label} {x.mean_mm:.1f}±{x.se_mm:.1f}" for x in m.cells[command])
        ax.set_title(f"{_short(command)}\nmeasured mean ± s.e. [mm]: {cells}", fontsize=10)
        ax.set_xlabel(r"drag coefficient $c_d$ [kg/m]")
        handles = [
            Line2D([], [], color="white", ls="--", lw=1.6, label="valley: least-misfit k"),
            Line2D(
                [],
                [],
                color="#FF8C00",
                lw=1.6,
                label=f"acceptable (≤{TOLERANCE_SE:g} s.e. in every cell)"
                + ("" if mask.any() else ": none"),
            ),
        ]
        ax.legend(
            handles=handles,
            loc="upper right",
            fontsize=8,
            facecolor="0.2",
            edgecolor="0.2",
            labelcolor="white",
            framealpha=0.8,
        )
    axes[0].set_ylabel(r"depth stiffness $k$ [N/m]")
    axes[0].set_yscale("log")
    cbar = fig.colorbar(mesh, ax=axes[:2], location="right", pad=0.01, extend="both")
    cbar.set_label("misfit: RMS over cells of |sim − mean| [mm]")

    ax = axes[2]
    for command in m.commands:
        _shade_valley(ax, m, command)
    p, d = m.commands
    k_at, cd_at = ev.closest_se_at
    if math.isfinite(k_at):
        ax.plot(cd_at, k_at, marker="*", ms=14, color="black", ls="none", clip_on=False, zorder=5)
    gap = ev.curve_gap_cd_kg_per_m
    if math.isfinite(gap):
        j = int(np.argmin(np.abs(m.cd_kg_per_m - gap)))
        ax.plot(
            [gap, gap],
            [ev.valley_k_n_per_m[p][j], ev.valley_k_n_per_m[d][j]],
            color="black",
            ls=":",
            lw=2.0,
        )
    frac = float(m.boot["intersect"].mean())
    med, lo, hi = interval(m.boot["closest_se"].to_numpy())
    mm = interval(m.boot["closest_mm"].to_numpy())
    answer = "intersect" if ev.intersect else "do not intersect"
    ax.text(
        0.03,
        0.03,
        f"valleys {answer} (data)\nintersect in {frac:.0%} of {len(m.boot)} resamples\n"
        f"closest approach {med:.2g} s.e. [{lo:.2g}, {hi:.2g}]\n"
        f"= {mm[0]:.2g} mm [{mm[1]:.2g}, {mm[2]:.2g}] (90%)",
        transform=ax.transAxes,
        fontsize=8.5,
        va="bottom",
        bbox={"facecolor": "white", "alpha": 0.9, "edgecolor": "0.6"},
    )
    handles = [
        *_valley_handles(m.commands, m),
        Line2D([], [], marker="*", ms=10, color="black", ls="none", label="closest approach"),
        Line2D([], [], color="black", ls=":", lw=2.0, label="valley curves closest"),
    ]
    ax.legend(handles=handles, loc="upper right", fontsize=8, framealpha=0.85)
    ax.set_title("overlay of the two valleys", fontsize=10)
    ax.set_xlabel(r"drag coefficient $c_d$ [kg/m]")
    ax.grid(alpha=0.3)
    ax.set_xlim(*_cd_limits(m))
    ax.set_ylim(m.k_n_per_m[0], m.k_n_per_m[-1])
    suptitle(fig, title, fontsize=11)
    return fig


def plot_valleys(maps: Sequence[MisfitMap], phi_c: float, title: str) -> Figure:
    """Valley overlays at every volume fraction (top) and the closest approach vs phi.

    Parameters
    ----------
    maps : sequence of granbayes.analysis.maps.MisfitMap
        One per volume fraction, ascending, all of the same command pair.
    phi_c : float
        Critical packing [-].
    title : str

    Returns
    -------
    matplotlib.figure.Figure
    """
    from ..analysis.maps import TOLERANCE_SE
    from ..stats import interval

    n = len(maps)
    fig = Figure(figsize=(max(8.0, 3.3 * n), 7.6), layout="constrained")
    top, bottom = fig.subfigures(2, 1, height_ratios=[1.15, 1.0])
    axes = np.atleast_1d(top.subplots(1, n, sharey=True))
    for ax, m in zip(axes, maps, strict=True):
        for command in m.commands:
            _shade_valley(ax, m, command)
        frac = float(m.boot["intersect"].mean())
        ax.set_title(
            f"φ = {m.phi:g} (φ − φc = {m.phi - phi_c:+.3f})\nintersect in {frac:.0%}", fontsize=9
        )
        ax.set_xlabel(r"$c_d$ [kg/m]")
        ax.set_xlim(*_cd_limits(m))
        ax.grid(alpha=0.3)
    axes[0].set_yscale("log")
    axes[0].set_ylabel(r"$k$ [N/m]")
    # Zoom on the valleys (and acceptable regions), the same k range in every panel.
    shown = [m.observed.valley_k_n_per_m[c] for m in maps for c in m.commands]
    shown += [m.k_n_per_m[m.observed.acceptable[c].any(axis=1)] for m in maps for c in m.commands]
    shown_k = np.concatenate(shown)
    shown_k = shown_k[np.isfinite(shown_k)]
    k_lo, k_hi = min(m.k_n_per_m[0] for m in maps), max(m.k_n_per_m[-1] for m in maps)
    if shown_k.size:
        k_lo, k_hi = max(k_lo, shown_k.min() / 1.6), min(k_hi, shown_k.max() * 1.6)
    axes[0].set_ylim(k_lo, k_hi)
    top.legend(
        handles=_valley_handles(maps[0].commands),
        loc="outside lower center",
        ncols=4,
        fontsize=8,
        frameon=False,
    )

    ax1, ax2 = bottom.subplots(1, 2)
    x = np.array([m.phi - phi_c for m in maps])
    for ax, key, unit, thr in (
        (ax1, "closest_se", "standard errors", TOLERANCE_SE),
        (ax2, "closest_mm", "mm", None),
    ):
        iv = np.array([interval(m.boot[key].to_numpy()) for m in maps])
        obs = np.array([getattr(m.observed, key) for m in maps])
        ax.errorbar(
            x,
            iv[:, 0],
            yerr=[iv[:, 0] - iv[:, 1], iv[:, 2] - iv[:, 0]],
            color="black",
            marker="o",
            capsize=3,
            ls="none",
            label="bootstrap median, 90% interval",
        )
        ax.plot(x, obs, marker="x", color="#D55E00", ls="none", ms=8, label="measured means")
        if thr is not None:
            ax.axhline(thr, color="0.4", ls="--", lw=1, label=f"acceptance ({thr:g} s.e.)")
        ax.set_yscale("log")
        ax.set_xlabel(r"$\phi - \phi_c$")
        ax.set_ylabel(f"closest approach [{unit}]")
        ax.grid(alpha=0.3)
        ax.legend(fontsize=8)
    ax1.set_title("max over both commands of the largest |sim − mean| / s.e.", fontsize=9)
    ax2.set_title("larger of the two RMS misfits [mm]", fontsize=9)
    suptitle(fig, title, fontsize=11)
    return fig


# -- optimal jumping (granbayes.analysis.optimal) -------------------------------------------------
def plot_optimum_vs_frequency(
    results: Sequence[OptimumSearch], phi_c: float, f0_hz: float, title: str
) -> Figure:
    """Expected height vs frequency per command (best amplitude/delay/hold per frequency).

    One panel per volume fraction, with the optimum (gold star) and the reliable optimum
    (open star at its 5th percentile); ``f0_hz`` [Hz] is the leg's resonance.

    Parameters
    ----------
    results : sequence of OptimumSearch
        One search per volume fraction.
    phi_c : float
        Critical packing fraction [-].
    f0_hz : float
        Leg resonance [Hz].
    title : str
        Figure title.
    """
    from ..stats import CI_PROB

    fig, axes, legend_ax = panel_grid(len(results))
    for ax, res in zip(axes, results, strict=True):
        t = res.settings[res.settings["eligible"]]
        for command in COMMAND_NAMES:
            c = t[t["command"] == command]
            c = c[np.isfinite(c["expected_mm"])]
            if c.empty:
                continue
            best = c.loc[c.groupby("freq_hz")["expected_mm"].idxmax()]
            color = COMMAND_COLORS[command]
            ax.fill_between(best["freq_hz"], best["lo_mm"], best["hi_mm"], color=color, alpha=0.15)
            ax.plot(
                best["freq_hz"],
                best["expected_mm"],
                color=color,
                marker=COMMAND_MARKERS[command],
                ms=3.5,
                lw=1.4,
            )
        opt, rel = res.settings.iloc[res.optimum], res.settings.iloc[res.reliable]
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
        ax.axvline(f0_hz, color="0.5", ls=":", lw=1)
        ax.set_title(f"φ = {res.phi:g}  (φ − φc = {res.phi - phi_c:+.3f})", fontsize=10)
        ax.set_xlabel("actuator frequency [Hz]")
        ax.set_ylabel("expected jump height [mm]")
        ax.grid(alpha=0.3)
    handles = [
        Line2D([], [], color=COMMAND_COLORS[c], marker=COMMAND_MARKERS[c], ms=4, label=_short(c))
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
        Line2D([], [], color="0.5", ls=":", label=f"leg resonance f0 = {f0_hz:.1f} Hz"),
    ]
    text = f"best amplitude / delay / settle at each frequency; bands: {CI_PROB:.0%}"
    if legend_ax is not None:
        legend_ax.legend(handles=handles, loc="center", fontsize=9, title=text, title_fontsize=8)
    else:
        fig.legend(
            handles=handles,
            loc="outside lower center",
            ncols=4,
            fontsize=8,
            title=text,
            title_fontsize=8,
        )
    suptitle(fig, title, fontsize=11)
    return fig


def plot_delay_curves(
    results: Sequence[OptimumSearch], measured: pd.DataFrame, phi_c: float, title: str
) -> Figure:
    """Delayed-stutter height vs delay: the loosest bed in detail (left), every bed (right).

    Parameters
    ----------
    results : sequence of granbayes.analysis.optimal.OptimumSearch
        One per volume fraction, ascending (the first is the loosest bed).
    measured : pandas.DataFrame
        :func:`granbayes.analysis.optimal.measured_settings` (their delay curves are drawn).
    phi_c : float
        Critical packing [-].
    title : str
    """
    from ..analysis.optimal import PUBLISHED_DELAY_MS, delay_curve, delay_settings, describe_setting

    fig = Figure(figsize=(12.5, 4.8), layout="constrained")
    ax_l, ax_r = fig.subplots(1, 2)
    loose = results[0]
    curves = delay_settings(loose, measured)
    cmap = colormaps["viridis"]
    top, bottom = 0.0, 0.0
    for j, spec in enumerate(curves):
        c = delay_curve(loose, spec["amplitude_mm"], spec["freq_hz"])
        color = cmap(0.1 + 0.75 * j / max(1, len(curves) - 1))
        label = f"{spec['freq_hz']:.3g} Hz, {spec['amplitude_mm']:.3g} mm ({spec['role']})"
        ax_l.fill_between(c["delay_ms"], c["lo_mm"], c["hi_mm"], color=color, alpha=0.18)
        ax_l.plot(c["delay_ms"], c["expected_mm"], color=color, marker="o", ms=3, label=label)
        top = max(top, float(np.nanmax(c["hi_mm"])))
        # heights can be negative (the robot never left the bed): never clip them
        bottom = min(bottom, float(np.nanmin(c["lo_mm"])), float(np.nanmin(c["expected_mm"])))
    if loose.family_optimum["single"] >= 0:
        single = loose.settings.iloc[loose.family_optimum["single"]]
        ax_l.axhspan(single["lo_mm"], single["hi_mm"], color="0.5", alpha=0.15, lw=0)
        ax_l.axhline(
            single["expected_mm"],
            color="0.3",
            ls="--",
            lw=1.2,
            label=f"best single jump ({describe_setting(single)})",
        )
        top = max(top, float(single["hi_mm"]))
    ax_l.axvline(PUBLISHED_DELAY_MS, color="k", ls=":", lw=1, label="published optimum, 50 ms")
    ax_l.set_title(f"loosest bed φ = {loose.phi:g}: delayed stutter", fontsize=10)
    if top > 0:
        ax_l.set_ylim(bottom - 0.05 * (top - bottom), 1.4 * top)
    ax_l.legend(fontsize=8, loc="upper right")
    for j, res in enumerate(results):
        if res.family_optimum["delayed_stutter"] < 0:
            continue
        r = res.settings.iloc[res.family_optimum["delayed_stutter"]]
        c = delay_curve(res, r["amplitude_mm"], r["freq_hz"])
        color = cmap(j / max(1, len(results) - 1) * 0.9)
        ax_r.fill_between(c["delay_ms"], c["lo_mm"], c["hi_mm"], color=color, alpha=0.12)
        label = f"{res.phi - phi_c:+.3f}: {r['freq_hz']:.3g} Hz, {r['amplitude_mm']:.3g} mm"
        ax_r.plot(c["delay_ms"], c["expected_mm"], color=color, marker="o", ms=3, label=label)
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
    suptitle(fig, title, fontsize=11)
    return fig


def plot_optimum_vs_phi(results: Sequence[OptimumSearch], phi_c: float, title: str) -> Figure:
    """Best expected height and best predictive 5th percentile per command vs phi - phi_c.

    Parameters
    ----------
    results : sequence of OptimumSearch
        One search per volume fraction.
    phi_c : float
        Critical packing fraction [-].
    title : str
        Figure title.
    """
    from ..stats import CI_PROB

    fig = Figure(figsize=(11.5, 4.6), layout="constrained")
    ax_e, ax_q = fig.subplots(1, 2, sharey=True)
    x = np.array([r.phi for r in results]) - phi_c
    offsets = command_offsets(x, 0.0005)
    for command in COMMAND_NAMES:
        color, marker = COMMAND_COLORS[command], COMMAND_MARKERS[command]
        if min(min(r.family_optimum[command], r.family_reliable[command]) for r in results) < 0:
            continue
        e = [r.settings.iloc[r.family_optimum[command]] for r in results]
        q = [r.settings.iloc[r.family_reliable[command]] for r in results]
        mid = np.array([s["expected_mm"] for s in e])
        lo, hi = np.array([s["lo_mm"] for s in e]), np.array([s["hi_mm"] for s in e])
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
            label=_short(command),
        )
        ax_q.plot(
            x + offsets[command],
            [s["q05_predictive_mm"] for s in q],
            color=color,
            marker=marker,
            ms=5,
            lw=1.3,
            ls=ls,
            label=_short(command),
        )
    for ax in (ax_e, ax_q):
        ax.axvline(0.0, color="0.5", ls=":", lw=1)
        ax.set_xlabel(r"$\phi - \phi_c$")
        ax.grid(alpha=0.3)
    ax_e.set_ylabel("jump height [mm]")
    ax_e.set_title(
        f"best expected height per command (posterior {CI_PROB:.0%} interval)", fontsize=10
    )
    ax_q.set_title(
        "most reliable jump per command: best 5th pct. of predictive height", fontsize=10
    )
    ax_e.legend(fontsize=8, loc="best")
    suptitle(fig, title, fontsize=11)
    return fig


# -- added-mass impulse (granbayes.analysis.mechanics) --------------------------------------------
def _marker_handles(items: Sequence[tuple[str, str, str]]) -> list[Line2D]:
    """Legend entries (label, marker, face colour) with black edges."""
    return [
        Line2D([], [], ls="none", marker=m, ms=7, mfc=c, mec="black", mew=0.6, label=label)
        for label, m, c in items
    ]


def plot_vs_kappa(
    cells: pd.DataFrame,
    quantity: str,
    ylabel: str,
    phi_c: float,
    kappa_max: float,
    caption: str,
    title: str,
) -> Figure:
    """A per-cell quantity against the best kappa, one panel per actuation frequency.

    Colour: command; marker: ``phi - phi_c``; error bars: posterior intervals both ways.

    Parameters
    ----------
    cells : pandas.DataFrame
        One row per cell: ``command``, ``phi``, ``freq_hz``, ``kappa_median``, ``kappa_lo``,
        ``kappa_hi`` and ``<quantity>_median``, ``_lo``, ``_hi``.
    quantity : str
        Column stem of the y quantity.
    ylabel : str
        Its axis label (with unit).
    phi_c : float
        Critical packing [-].
    kappa_max : float
        Smallest upper end of the kappa axis [-] (the prior's upper bound).
    caption : str
        Text under the panels (the correlations).
    title : str

    Returns
    -------
    matplotlib.figure.Figure
    """
    freqs = np.unique(cells["freq_hz"])
    fig = Figure(figsize=(max(10.5, 4.4 * len(freqs) + 1.8), 4.8), layout="constrained")
    axes = np.atleast_1d(fig.subplots(1, len(freqs), sharex=True, sharey=True))
    phis = np.unique(cells["phi"])
    markers = {p: _PHI_MARKERS[i % len(_PHI_MARKERS)] for i, p in enumerate(phis)}
    for ax, freq in zip(axes, freqs, strict=True):
        for row in cells[cells["freq_hz"] == freq].to_dict("records"):
            color = COMMAND_COLORS[row["command"]]
            x, y = row["kappa_median"], row[f"{quantity}_median"]
            ax.errorbar(
                x,
                y,
                xerr=[[x - row["kappa_lo"]], [row["kappa_hi"] - x]],
                yerr=[[max(y - row[f"{quantity}_lo"], 0.0)], [max(row[f"{quantity}_hi"] - y, 0.0)]],
                ls="none",
                color=color,
                alpha=0.4,
                lw=0.9,
            )
            ax.plot(
                x,
                y,
                ls="none",
                marker=markers[row["phi"]],
                ms=7,
                mfc=color,
                mec="black",
                mew=0.6,
                zorder=3,
            )
        ax.set_title(f"actuator {freq:g} Hz", fontsize=10)
        ax.set_xlabel(r"best $\kappa$ (posterior median) [-]")
        ax.grid(alpha=0.3)
    top = np.nanmax(cells[[f"{quantity}_hi", f"{quantity}_median"]].to_numpy())
    axes[0].set_xlim(0.0, 1.03 * max(kappa_max, np.nanmax(cells["kappa_hi"])))
    axes[0].set_ylim(0.0, 1.05 * top if np.isfinite(top) and top > 0 else 1.0)
    axes[0].set_ylabel(ylabel)
    present = [c for c in COMMAND_NAMES if c in set(cells["command"])]
    handles = _marker_handles([(_short(c), "o", COMMAND_COLORS[c]) for c in present])
    handles.append(Line2D([], [], ls="none", label="\n" + r"$\phi - \phi_c$:"))
    handles += _marker_handles([(f"{p - phi_c:+.3f}", markers[p], "0.8") for p in phis])
    fig.legend(
        handles=handles, loc="outside right upper", title="command", fontsize=8, title_fontsize=8
    )
    fig.supxlabel(caption, fontsize=8)
    suptitle(fig, title, fontsize=11)
    return fig


def plot_added_mass(
    data: pd.DataFrame, experiment: Experiment, kappa: float, phi: float, title: str
) -> Figure:
    """Depth, added mass and F_am of one trajectory; the interval of greatest impulse shaded.

    Parameters
    ----------
    data : pandas.DataFrame
        ``Trajectory.data`` of a jump with added mass.
    experiment : Experiment
        Its experiment (foot radius, grain density).
    kappa : float
        Added-mass coefficient of the trajectory [-].
    phi : float
        Volume fraction [-].
    title : str

    Returns
    -------
    matplotlib.figure.Figure
    """
    from ..analysis.mechanics import added_mass_impulse, advancing_episodes, flux_force_N

    imp = added_mass_impulse(data)
    t_ms = data["t_s"].to_numpy(float) * 1e3
    fig = Figure(figsize=(7.0, 6.4), layout="constrained")
    ax_z, ax_m, ax_f = fig.subplots(3, 1, sharex=True)
    ax_z.plot(t_ms, data["depth_mm"], color="0.15", lw=1.2, label="foot depth z")
    ax_z.plot(t_ms, data["z_max_mm"], color="0.5", lw=1.0, ls="--", label="crater depth")
    ax_z.invert_yaxis()
    ax_z.set_ylabel("depth [mm]\n(down)")
    ax_z.legend(fontsize=8, loc="lower right")
    ax_m.plot(t_ms, data["added_mass_kg"] * 1e3, color="#0072B2", lw=1.2)
    ax_m.set_ylabel("added mass\n$m_a$ [g]")
    ax_f.plot(t_ms, flux_force_N(data, kappa, phi, experiment), color="#D55E00", lw=1.2)
    ax_f.set_ylabel(r"$F_\mathrm{am} = -\dot m_a v_\mathrm{foot}$" + "\n[N]")
    ax_f.set_xlabel("time since the command started [ms]")
    _, first, stop = advancing_episodes(data["mode"].to_numpy())
    shown: set[str] = set()
    for a, b in zip(first, stop, strict=True):
        peak = math.isclose(t_ms[a], imp.start_ms, abs_tol=1e-9)
        what = "interval of greatest impulse" if peak else "other advancing episodes"
        for ax in (ax_z, ax_m, ax_f):
            ax.axvspan(
                t_ms[a],
                t_ms[b],
                color="#E69F00" if peak else "0.6",
                alpha=0.3,
                lw=0,
                label=what if ax is ax_f and what not in shown else None,
            )
        shown.add(what)
    ax_f.legend(fontsize=8, loc="upper right")
    for ax in (ax_z, ax_m, ax_f):
        ax.grid(alpha=0.3)
    ax_z.set_title(
        f"J_total = {imp.total_mN_s:.3g} mN s; greatest interval: {imp.peak_mN_s:.3g} mN s "
        f"over {imp.duration_ms:.1f} ms ({imp.n_intervals} advancing episode(s))",
        fontsize=9,
    )
    suptitle(fig, title, fontsize=11)
    return fig


# -- one force law for every command (granbayes.compare_commands) ------------------------
def plot_coefficients_vs_phi(
    laws: Sequence[Mapping], phis: ArrayLike, phi_c: float, title: str
) -> Figure:
    """Per-command and shared posterior intervals of each coefficient vs phi - phi_c.

    Parameters
    ----------
    laws : sequence of mapping
        One per force law (one row of panels each): ``terms`` (tuple of str),
        ``parameters`` (tuple of str; one panel each) and ``intervals`` (DataFrame with
        ``phi``, ``command`` (``"shared"`` or a command), ``parameter``, ``median``,
        ``lo``, ``hi``, as from :func:`granbayes.compare_commands` with ``details=True``
        plus the shared fit's rows).
    phis : array_like
        Volume fractions of the data [-] (sets the offsets between commands).
    phi_c : float
        Critical packing [-].
    title : str

    Returns
    -------
    matplotlib.figure.Figure
    """
    from ..forces import PARAMETERS

    units = {p.name: p.unit for p in PARAMETERS}
    phis = np.asarray(phis, dtype=float)
    n_col = max(len(law["parameters"]) for law in laws)
    fig = Figure(figsize=(4.3 * n_col + 0.8, 3.7 * len(laws) + 0.9), layout="constrained")
    axes = np.atleast_2d(fig.subplots(len(laws), n_col, squeeze=False))
    span = np.ptp(phis) if phis.size > 1 else 0.02
    offsets = dict(
        zip(COMMAND_NAMES, np.linspace(-0.25, 0.25, len(COMMAND_NAMES)) * span / 4, strict=True)
    )
    for i, law in enumerate(laws):
        iv = law["intervals"]
        for j in range(n_col):
            ax = axes[i, j]
            if j >= len(law["parameters"]):
                ax.set_visible(False)
                continue
            pname = law["parameters"][j]
            sub = iv[iv["parameter"] == pname]
            s = sub[sub["command"] == "shared"].sort_values("phi")
            x = s["phi"] - phi_c
            ax.fill_between(x, s["lo"], s["hi"], color="0.8", lw=0, label="shared (one law)")
            ax.plot(x, s["median"], color="black", lw=1.5)
            for command in COMMAND_NAMES:
                c = sub[sub["command"] == command].sort_values("phi")
                if c.empty:
                    continue
                ax.errorbar(
                    c["phi"] - phi_c + offsets[command],
                    c["median"],
                    yerr=[c["median"] - c["lo"], c["hi"] - c["median"]],
                    fmt=COMMAND_MARKERS[command],
                    ms=4,
                    capsize=2,
                    color=COMMAND_COLORS[command],
                    label=_short(command),
                )
            if pname in {"k", "k2", "c_d", "b"} and (sub["lo"] > 0).all():
                ax.set_yscale("log")
            ax.set_ylabel(f"{pname} [{units.get(pname, '')}]")
            ax.set_xlabel(r"$\phi - \phi_c$")
            ax.axvline(0, color="0.5", ls=":", lw=1)
            ax.grid(alpha=0.3, which="both")
            ax.set_title(f"{' + '.join(law['terms'])}: {pname}", fontsize=10)
    axes[0, 0].legend(fontsize=7.5, loc="best", title="90% intervals", title_fontsize=7.5)
    suptitle(fig, title, fontsize=11)
    return fig
