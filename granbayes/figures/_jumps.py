"""Figures of simulated jumps: one jump's trajectory, the five jumps, the hard ground.

Every function builds a :class:`matplotlib.figure.Figure` directly, without ``pyplot``, so
nothing here selects a backend or opens a window; ``fig.savefig("out.png")`` renders with
Agg. Heights and positions are in mm, forces in N, masses in g and times in s, measured
from the start of the command (physics-model.md sections 4 and 5).

Examples
--------
>>> from granbayes import simulate_trajectory
>>> from granbayes.figures import plot_trajectory
>>> traj = simulate_trajectory("single", 0.612, {"k": 3000.0, "c_d": 50.0})
>>> fig = plot_trajectory(traj)
>>> fig.savefig("single.png", dpi=150)  # doctest: +SKIP
"""

from __future__ import annotations

import math
import textwrap
from collections.abc import Mapping, Sequence
from typing import TYPE_CHECKING

import numpy as np
from matplotlib.artist import Artist
from matplotlib.axes import Axes
from matplotlib.collections import PolyCollection
from matplotlib.figure import Figure, SubFigure
from matplotlib.patches import Patch
from numpy.typing import ArrayLike

from .._simulator import Status, Trajectory
from ._style import suptitle

if TYPE_CHECKING:
    pass


#: Background colour of each ground regime (``Trajectory.data["mode"]``).
REGIME_COLORS: dict[str, str] = {
    "advancing": "#E69F00",  # foot pushing into undisturbed grains
    "contact": "#56B4E9",  # foot in its crater, bed unloading elastically
    "free": "#D9D9D9",  # foot off the bed
}

_REGIME_LABELS: dict[str, str] = {
    "advancing": "advancing (yielding)",
    "contact": "contact (elastic unloading)",
    "free": "free (airborne)",
}

# Okabe-Ito colours: distinguishable with colour-vision deficiencies and in greyscale.
_FOOT = "#0072B2"
_ROD = "#D55E00"
_CRATER = "#7F4F24"
_BED = "#D8C3A5"
_WINDOW = "#F0E442"
_ACTUATOR = "#009E73"
_ADDED = "#CC79A7"
_FORCE = "black"

#: Text sizes (points) shared by the figures.
_FONT = {"label": 10, "tick": 9, "title": 11, "suptitle": 13, "legend": 9}


# ----------------------------------------------------------------------------------------
# Building blocks: one panel of one trajectory
# ----------------------------------------------------------------------------------------


def _label(command: str, width: int = 18) -> str:
    """Readable, wrapped command name (``delayed_stutter`` -> ``delayed stutter``)."""
    return "\n".join(textwrap.wrap(command.replace("_", " "), width=width))


def _style(ax: Axes) -> None:
    """Common axis styling: light grid, inward ticks, readable tick labels."""
    ax.grid(True, color="0.88", linewidth=0.6)
    ax.set_axisbelow(True)
    ax.tick_params(labelsize=_FONT["tick"], direction="in", top=True, right=True)


def _window(traj: Trajectory) -> tuple[float, float]:
    """Start and end [s] of the jump-height window (physics-model.md section 5)."""
    t = traj.data["t_s"].to_numpy()
    return traj.program.t_pushoff, float(t[-1])


def _apex(traj: Trajectory) -> tuple[float, float] | None:
    """Time [s] and foot height [mm] of the highest point inside the height window."""
    d = traj.data
    t = d["t_s"].to_numpy()
    x = d["x_foot_mm"].to_numpy()
    inside = np.flatnonzero(t >= traj.program.t_pushoff)
    if inside.size == 0 or not np.isfinite(x[inside]).any():
        return None
    i = inside[np.nanargmax(x[inside])]
    return float(t[i]), float(x[i])


def _regime_runs(traj: Trajectory) -> list[tuple[str, float, float]]:
    """Contiguous runs of the ground regime as ``(mode, t_start [s], t_end [s])``."""
    t = traj.data["t_s"].to_numpy()
    mode = traj.data["mode"].to_numpy().astype(str)
    if t.size == 0:
        return []
    change = np.flatnonzero(mode[1:] != mode[:-1]) + 1
    starts = np.concatenate([[0], change])
    ends = np.concatenate([change, [t.size - 1]])
    return [(mode[s], float(t[s]), float(t[e])) for s, e in zip(starts, ends, strict=True)]


def _height_limits(trajs: Sequence[Trajectory]) -> tuple[float, float]:
    """y-limits [mm] of the height panel that show rod, foot, crater and the annotation."""
    lows, highs = [0.0], [0.0]
    for traj in trajs:
        d = traj.data
        for col in ("x_rod_mm", "x_foot_mm"):
            lows.append(float(np.nanmin(d[col])))
            highs.append(float(np.nanmax(d[col])))
        lows.append(-float(np.nanmax(d["z_max_mm"])))
    low, high = min(lows), max(highs)
    span = max(high - low, 1.0)
    # room below for a visible layer of bed, above for the height annotation
    return low - 0.12 * span, high + 0.2 * span


def _draw_heights(ax: Axes, traj: Trajectory, *, annotate: bool = True) -> None:
    """Foot and rod heights, surface, crater bottom, height window and apex [mm].

    The grains below the crater bottom are shaded; the caller sets the y-limits.
    """
    d = traj.data
    t = d["t_s"].to_numpy()
    crater = -d["z_max_mm"].to_numpy()
    t0, t1 = _window(traj)
    ax.axvspan(t0, t1, color=_WINDOW, alpha=0.22, lw=0, label="height window")
    ax.fill_between(t, crater, -1e6, color=_BED, alpha=0.55, lw=0, label="granular bed")
    ax.axhline(0.0, color="0.3", ls="--", lw=0.9, label="undisturbed surface (0)")
    ax.plot(t, crater, color=_CRATER, lw=1.3, label=r"crater bottom $-z_\mathrm{max}$")
    ax.plot(
        t,
        d["x_rod_mm"],
        color=_ROD,
        lw=1.4,
        label=r"rod $x_\mathrm{rod}$ (minus spring rest length)",
    )
    ax.plot(t, d["x_foot_mm"], color=_FOOT, lw=1.8, label=r"foot $x_\mathrm{foot}$")
    apex = _apex(traj)
    if apex is not None:
        ta, xa = apex
        ax.plot(ta, xa, marker="v", color="black", ms=6, ls="none", label="jump height H")
        if annotate:
            text = f"H = {traj.height_mm:.1f} mm" if math.isfinite(traj.height_mm) else "H: n/a"
            if traj.height_mm < 0:
                text += "\n(no lift-off)"
            ax.annotate(
                text,
                (ta, xa),
                xytext=(0, 7),
                textcoords="offset points",
                ha="center",
                va="bottom",
                fontsize=_FONT["legend"],
                bbox={"boxstyle": "round,pad=0.2", "fc": "white", "ec": "0.6", "lw": 0.6},
            )
    ax.set_xlim(t[0], t[-1])


def _draw_regimes(ax: Axes, traj: Trajectory) -> None:
    """Shade the ground regime (advancing, contact, free) as background spans."""
    spans: dict[str, list[list[tuple[float, float]]]] = {}
    for mode, start, end in _regime_runs(traj):
        spans.setdefault(mode, []).append([(start, 0.0), (end, 0.0), (end, 1.0), (start, 1.0)])
    for mode, verts in spans.items():
        # one collection per regime (a chattering contact can switch thousands of times)
        shading = PolyCollection(
            verts,
            transform=ax.get_xaxis_transform(),
            facecolor=REGIME_COLORS.get(mode, "white"),
            alpha=0.35,
            linewidth=0,
            zorder=0,
        )
        ax.add_collection(shading, autolim=False)


def _draw_force(ax: Axes, traj: Trajectory) -> None:
    """Ground reaction force [N] over the regime spans."""
    d = traj.data
    _draw_regimes(ax, traj)
    ax.plot(d["t_s"], d["ground_force_N"], color=_FORCE, lw=1.3, label=r"ground force $F_g$")


def _force_limit(trajs: Sequence[Trajectory]) -> float:
    """Upper y-limit [N] of the force panel (the largest force plus a margin)."""
    peak = max(float(np.nanmax(t.data["ground_force_N"], initial=0.0)) for t in trajs)
    return 1.08 * peak if peak > 0 else 1.0


def _draw_alpha(ax: Axes, traj: Trajectory) -> None:
    """Actuator position alpha [mm] and the end of the command."""
    d = traj.data
    ax.axhline(0.0, color="0.6", lw=0.6)
    ax.plot(d["t_s"], d["alpha_mm"], color=_ACTUATOR, lw=1.5, label=r"actuator $\alpha$")


def _draw_command_end(axes: Sequence[Axes], traj: Trajectory) -> None:
    """Dotted vertical line where the command ends, in every panel."""
    for i, ax in enumerate(axes):
        label = "command ends" if i == 0 else "_nolegend_"
        ax.axvline(traj.program.t_end, color="0.35", ls=":", lw=1.0, label=label)


def _regime_handles() -> list[Artist]:
    """Legend patches of the regime colours."""
    return [
        Patch(facecolor=REGIME_COLORS[m], alpha=0.35, edgecolor="0.6", lw=0.4, label=label)
        for m, label in _REGIME_LABELS.items()
    ]


def _has_added_mass(traj: Trajectory) -> bool:
    return bool(np.nanmax(np.abs(traj.data["added_mass_kg"].to_numpy()), initial=0.0) > 0.0)


# ----------------------------------------------------------------------------------------
# Public figures
# ----------------------------------------------------------------------------------------


def plot_trajectory(
    traj: Trajectory,
    ax_or_fig: Figure | SubFigure | Sequence[Axes] | None = None,
    *,
    title: str | None = None,
) -> Figure:
    """Time series of one jump, in stacked panels that share the time axis.

    Panels, top to bottom: (1) foot and rod heights [mm] with the undisturbed surface, the
    crater bottom ``-z_max`` and the bed below it, the height window of physics-model.md
    section 5 shaded and the jump height marked and annotated; (2) ground reaction force
    [N] over coloured spans of the ground regime (advancing, contact, free); (3) actuator
    position ``alpha`` [mm]; (4) added mass [g], only if it is non-zero somewhere. A dotted
    line marks the end of the command in every panel.

    Parameters
    ----------
    traj : Trajectory
        From :func:`granbayes.simulate_trajectory`.
    ax_or_fig : Figure, SubFigure or sequence of Axes, optional
        Where to draw: a (sub)figure to fill with the panels, or exactly as many axes as
        panels (3, or 4 with added mass). Default: a new figure.
    title : str, optional
        Figure title (default: command, jump height and status).

    Returns
    -------
    matplotlib.figure.Figure
        The figure drawn into (the root figure for a SubFigure).
    """
    n_panels = 4 if _has_added_mass(traj) else 3
    ratios = [3.0, 1.7, 1.3, 1.3][:n_panels]
    if ax_or_fig is None:
        ax_or_fig = Figure(figsize=(9.0, 2.0 + 1.5 * n_panels), layout="constrained")
    if isinstance(ax_or_fig, Figure | SubFigure):
        container = ax_or_fig
        axes = list(container.subplots(n_panels, 1, sharex=True, height_ratios=ratios))
    else:
        axes = list(ax_or_fig)
        if len(axes) != n_panels:
            raise ValueError(f"this trajectory needs {n_panels} axes, got {len(axes)}")
        container = axes[0].figure
    fig = container
    while isinstance(fig, SubFigure):  # the root figure, whatever the nesting
        fig = fig.figure

    ax_h, ax_f, ax_a = axes[:3]
    _draw_heights(ax_h, traj)
    ax_h.set_ylim(*_height_limits([traj]))
    ax_h.set_ylabel("height [mm]", fontsize=_FONT["label"])
    _draw_force(ax_f, traj)
    ax_f.set_ylim(0.0, _force_limit([traj]))
    ax_f.set_ylabel("ground force [N]", fontsize=_FONT["label"])
    _draw_alpha(ax_a, traj)
    ax_a.set_ylabel(r"actuator $\alpha$ [mm]", fontsize=_FONT["label"])
    if n_panels == 4:
        ax_m = axes[3]
        d = traj.data
        _draw_regimes(ax_m, traj)
        ax_m.plot(d["t_s"], d["added_mass_kg"] * 1e3, color=_ADDED, lw=1.5, label="added mass")
        ax_m.set_ylim(bottom=0.0)
        ax_m.set_ylabel("added mass [g]", fontsize=_FONT["label"])
    _draw_command_end(axes, traj)
    for ax in axes:
        _style(ax)
    axes[-1].set_xlabel("time since command start [s]", fontsize=_FONT["label"])

    legend = {"loc": "upper left", "bbox_to_anchor": (1.01, 1.0), "fontsize": _FONT["legend"]}
    ax_h.legend(**legend, title="positions", title_fontsize=_FONT["legend"])
    force_handles, _ = ax_f.get_legend_handles_labels()
    ax_f.legend(
        handles=force_handles + _regime_handles(),
        **legend,
        title="ground regime",
        title_fontsize=_FONT["legend"],
    )
    ax_a.legend(**legend)
    if n_panels == 4:
        axes[3].legend(**legend)

    if title is None:
        status = traj.status.label if isinstance(traj.status, Status) else str(traj.status)
        shown = f"height {traj.height_mm:.1f} mm" if math.isfinite(traj.height_mm) else "no height"
        title = f"{_label(traj.program.name, 60)} jump: {shown} ({status})"
    suptitle(container, title, fontsize=_FONT["suptitle"])
    return fig


def plot_jumps(trajs: Mapping[str, Trajectory], title: str) -> Figure:
    """The jump commands side by side: one column per command, common scales per row.

    Rows: (1) foot and rod heights [mm] with the undisturbed surface, the crater bottom and
    the bed, the height window shaded and the apex marked; (2) ground reaction force [N]
    over the ground regime; (3) actuator position ``alpha`` [mm]. Each column is titled
    with the command and its jump height. Every column has its own time axis (the commands
    last different times); the y-axes are shared along each row so the columns compare.

    Parameters
    ----------
    trajs : mapping of str to Trajectory
        Column label (the command name) to trajectory, in column order.
    title : str
        Figure title (say which robot, bed and force law are shown).

    Returns
    -------
    matplotlib.figure.Figure
    """
    if not trajs:
        raise ValueError("plot_jumps needs at least one trajectory")
    n = len(trajs)
    fig = Figure(figsize=(3.4 * n + 1.0, 8.6), layout="constrained")
    axes = fig.subplots(
        3, n, sharex="col", sharey="row", squeeze=False, height_ratios=[2.6, 1.5, 1.2]
    )
    limits = _height_limits(list(trajs.values()))
    for j, (name, traj) in enumerate(trajs.items()):
        ax_h, ax_f, ax_a = axes[:, j]
        _draw_heights(ax_h, traj, annotate=False)
        _draw_force(ax_f, traj)
        _draw_alpha(ax_a, traj)
        _draw_command_end(axes[:, j], traj)
        for ax in axes[:, j]:
            _style(ax)
        height = f"H = {traj.height_mm:.1f} mm" if math.isfinite(traj.height_mm) else "H: n/a"
        if traj.status != Status.OK:
            height += f" ({Status(traj.status).label})"
        ax_h.set_title(f"{_label(name)}\n{height}", fontsize=_FONT["title"])
        ax_a.set_xlabel("time [s]", fontsize=_FONT["label"])
    axes[0, 0].set_ylim(*limits)
    axes[1, 0].set_ylim(0.0, _force_limit(list(trajs.values())))
    axes[0, 0].set_ylabel("height [mm]", fontsize=_FONT["label"])
    axes[1, 0].set_ylabel("ground force [N]", fontsize=_FONT["label"])
    axes[2, 0].set_ylabel(r"actuator $\alpha$ [mm]", fontsize=_FONT["label"])

    entries: dict[str, Artist] = {}
    for ax in axes[:, 0]:
        handles, labels = ax.get_legend_handles_labels()
        entries.update(zip(labels, handles, strict=True))
    entries.update((h.get_label(), h) for h in _regime_handles())
    fig.legend(
        handles=list(entries.values()),
        labels=list(entries),
        loc="outside lower center",
        ncols=6,
        fontsize=_FONT["legend"],
        frameon=False,
    )
    suptitle(fig, title, fontsize=_FONT["suptitle"])
    return fig


def plot_hard_ground(
    freqs_hz: ArrayLike,
    heights_single_mm: ArrayLike,
    heights_stutter_mm: ArrayLike,
    f0_hz: float,
    *,
    title: str | None = None,
) -> Figure:
    """Jump height against actuator frequency on a rigid floor, single and stutter.

    Reproduces the hard-ground result of Aguilar et al. (2012): the best single jump lies
    above the leg's resonant frequency ``f0``, the best stutter jump below it. ``f0`` is
    drawn as a vertical line, the optimum of each command as a star with its frequency
    and height, and a top axis gives ``f / f0``.

    Parameters
    ----------
    freqs_hz : array_like, shape (n,)
        Actuator frequencies [Hz].
    heights_single_mm, heights_stutter_mm : array_like, shape (n,)
        Jump heights [mm] of the single and stutter commands (NaN for failed jumps).
    f0_hz : float
        Resonant frequency ``sqrt(k_spring / M) / (2 pi)`` [Hz].
    title : str, optional
        Figure title (default: what is shown).

    Returns
    -------
    matplotlib.figure.Figure
    """
    f = np.asarray(freqs_hz, dtype=float)
    series = {
        "single": (np.asarray(heights_single_mm, dtype=float), _FOOT, "o"),
        "stutter": (np.asarray(heights_stutter_mm, dtype=float), _ROD, "s"),
    }
    for name, (h, _, _) in series.items():
        if h.shape != f.shape:
            raise ValueError(f"heights_{name}_mm has shape {h.shape}, freqs_hz {f.shape}")
    fig = Figure(figsize=(7.5, 5.0), layout="constrained")
    ax = fig.subplots()
    ax.axvline(f0_hz, color="0.3", ls="--", lw=1.1, label=f"resonance $f_0$ = {f0_hz:.1f} Hz")
    tops = []
    for name, (h, color, marker) in series.items():
        ax.plot(f, h, color=color, marker=marker, ms=4, lw=1.5, label=name)
        if np.isfinite(h).any():
            i = int(np.nanargmax(h))
            tops.append(h[i])
            ax.plot(f[i], h[i], marker="*", ms=15, color=color, mec="black", mew=0.7, ls="none")
            side = "left" if f[i] > f0_hz else "right"
            ax.annotate(
                f"best {name}\n{f[i]:g} Hz, {h[i]:.0f} mm",
                (f[i], h[i]),
                xytext=(10 if side == "left" else -10, 8),
                textcoords="offset points",
                ha=side,
                va="bottom",
                fontsize=_FONT["legend"],
                color=color,
            )
    ax.plot([], [], marker="*", ms=11, color="white", mec="black", ls="none", label="optimum")
    top = max([*tops, 1.0])
    ax.set_ylim(
        min(0.0, float(np.nanmin([*series["single"][0], *series["stutter"][0]]))), 1.2 * top
    )
    ax.set_xlim(f.min() - 0.5, f.max() + 0.5)
    ax.text(
        f0_hz,
        0.03,
        f" $f_0$ = {f0_hz:.1f} Hz",
        transform=ax.get_xaxis_transform(),
        rotation=90,
        ha="right",
        va="bottom",
        fontsize=_FONT["legend"],
        color="0.3",
    )
    ax.set_xlabel("actuator frequency $f$ [Hz]", fontsize=_FONT["label"])
    ax.set_ylabel("jump height H [mm]", fontsize=_FONT["label"])
    secondary = ax.secondary_xaxis("top", functions=(lambda x: x / f0_hz, lambda r: r * f0_hz))
    secondary.set_xlabel("$f / f_0$ [-]", fontsize=_FONT["label"])
    secondary.tick_params(labelsize=_FONT["tick"], direction="in")
    _style(ax)
    ax.tick_params(top=False)
    ax.legend(loc="upper right", fontsize=_FONT["legend"])
    suptitle(
        fig, title or "Rigid floor: jump height vs actuator frequency", fontsize=_FONT["suptitle"]
    )
    return fig
