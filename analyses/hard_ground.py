"""Hard ground (Aguilar et al. 2012): jump height and actuator power vs frequency on a rigid floor.

The robot of the experiment folder (its masses, spring and actuator amplitude; the jumps
are not used) jumps off a rigid floor (``k`` = 1e6 N/m, ``r_unload`` = 50: the limit of
physics-model.md section 6) with the single and the stutter command over a sweep of
actuator frequencies. The leg's resonant frequency ``f0 = sqrt(k_spring / M) / (2 pi)`` is
marked. Aguilar et al. (2012) found the best single jump above ``f0`` and the best stutter
jump below it, the stutter needing far less actuator power for a similar height; both are
checked here. Actuator power is the mechanical power the motor drive delivers,
``P = F_a alpha'`` with ``F_a = m_motor (x_r'' + alpha'' + g)``, from the recorded
trajectory (rod acceleration from the equation of motion, not from differences).
"""

from __future__ import annotations

import sys

import numpy as np
import pandas as pd
from matplotlib.figure import Figure

import _common as common
from granbayes.analysis.mechanics import actuator_power, best_frequency, rigid_heights_mm
from granbayes.figures import COMMAND_COLORS

NAME = "hard_ground"
COMMANDS = ("single", "stutter")
COLORS = {"single": COMMAND_COLORS["single"], "stutter": COMMAND_COLORS["preload"]}


def plot(ctx: common.Context, table: pd.DataFrame, power: pd.DataFrame, best: dict) -> Figure:
    """Height (left) and positive actuator work (right) against frequency, optima starred."""
    f0, freqs = ctx.experiment.robot.f0_hz, table["freq_hz"]
    fig = Figure(figsize=(11.0, 4.6), layout="constrained")
    ax_h, ax_p = fig.subplots(1, 2)
    for command in COMMANDS:
        c, b = COLORS[command], best[command]
        ax_h.plot(freqs, table[f"{command}_height_mm"], color=c, lw=1.6, label=command)
        ax_h.plot(b["freq_hz"], b["height_mm"], "*", ms=15, color=c, mec="k", mew=0.7)
        right = b["freq_hz"] > f0
        ax_h.annotate(
            f"{b['freq_hz']:.2f} Hz\n{b['height_mm']:.0f} mm",
            (b["freq_hz"], b["height_mm"]),
            xytext=(8 if right else -8, 6),
            textcoords="offset points",
            ha="left" if right else "right",
            fontsize=8,
            color=c,
        )
        ax_p.plot(
            power["freq_hz"],
            power[f"{command}_positive_work_j"],
            color=c,
            marker="o",
            ms=3,
            lw=1.4,
            label=f"{command}: positive work",
        )
        ax_p.plot(b["freq_hz"], b["positive_work_j"], "*", ms=13, color=c, mec="k", mew=0.7)
    for ax in (ax_h, ax_p):
        ax.axvline(f0, color="0.3", ls="--", lw=1.0, label=f"$f_0$ = {f0:.2f} Hz")
        ax.set_xlabel("actuator frequency $f$ [Hz]")
        ax.grid(alpha=0.3)
        sec = ax.secondary_xaxis("top", functions=(lambda x: x / f0, lambda r: r * f0))
        sec.set_xlabel("$f/f_0$ [-]")
    ax_h.set_ylabel("jump height H [mm]")
    ax_h.set_ylim(top=1.25 * max(b["height_mm"] for b in best.values()))
    ax_h.legend(fontsize=8, loc="upper right")
    ax_h.set_title("jump height (stars: optima)", fontsize=10)
    ax_p.set_ylabel("positive actuator work per jump [J]")
    ax_p.set_title("actuator work over the command", fontsize=10)
    ax_p.legend(fontsize=8, loc="upper left")
    r = ctx.experiment.robot
    fig.suptitle(
        f"Rigid floor (k = 1e6 N/m, r_unload = 50): robot M = {r.m_upper:g} kg, "
        f"m_foot = {r.m_foot:g} kg, k_spring = {r.k_spring:g} N/m, "
        f"A = {ctx.experiment.command.amplitude_mm:g} mm\n(simulation; robot from {ctx.data.name})",
        fontsize=11,
    )
    return fig


def analyse(ctx: common.Context) -> tuple[str, dict]:
    exp = ctx.experiment
    step = 1.0 if ctx.fast else 0.25
    freqs = np.arange(4.0, 30.0 + step / 2, step)
    f0 = exp.robot.f0_hz
    table = pd.DataFrame({"freq_hz": freqs})
    best: dict[str, dict] = {}
    for command in COMMANDS:
        h = table[f"{command}_height_mm"] = rigid_heights_mm(exp, command, freqs)
        f_best, h_best = best_frequency(exp, command, freqs, h)
        best[command] = {"freq_hz": f_best, "height_mm": h_best, "f_over_f0": f_best / f0}
    power = pd.DataFrame({"freq_hz": freqs[:: max(1, round(1.0 / step))]})
    for command in COMMANDS:
        runs = [actuator_power(exp, command, f) for f in power["freq_hz"]]
        for key in ("peak_power_w", "positive_work_j"):
            power[f"{command}_{key}"] = [p[key] for p in runs]
    for command in COMMANDS:
        best[command] |= actuator_power(exp, command, best[command]["freq_hz"])
    ctx.save_table(table, "hard_ground_heights")
    ctx.save_table(power, "hard_ground_power")
    ctx.save_figure(plot(ctx, table, power, best), "hard_ground")

    s, st = best["single"], best["stutter"]
    agrees = s["freq_hz"] > f0 > st["freq_hz"]
    work_ratio = st["positive_work_j"] / s["positive_work_j"]
    rows = [
        {
            "command": c,
            "best f [Hz]": b["freq_hz"],
            "f/f0": b["f_over_f0"],
            "height [mm]": b["height_mm"],
            "peak power [W]": b["peak_power_w"],
            "positive work [J]": b["positive_work_j"],
        }
        for c, b in best.items()
    ]
    body = [
        f"Resonant frequency of the leg f0 = {f0:.2f} Hz. Best single jump at "
        f"**{s['freq_hz']:.2f} Hz** (f/f0 = {s['f_over_f0']:.2f}, {s['height_mm']:.1f} mm); "
        f"best stutter jump at **{st['freq_hz']:.2f} Hz** (f/f0 = {st['f_over_f0']:.2f}, "
        f"{st['height_mm']:.1f} mm).",
        "",
        "This **reproduces** Aguilar et al. (2012): the single-jump optimum lies above f0 and "
        "the stutter optimum below it."
        if agrees
        else "This does **not** reproduce the ordering of Aguilar et al. (2012) (single "
        "optimum above f0, stutter below) for this robot.",
        "",
        f"At their optima the stutter jump needs {work_ratio:.2f}× the positive actuator work "
        f"of the single jump ({st['positive_work_j']:.2f} J vs {s['positive_work_j']:.2f} J; "
        f"peak power {st['peak_power_w']:.0f} W vs {s['peak_power_w']:.0f} W) for "
        f"{st['height_mm'] / s['height_mm']:.2f}× its height.",
        "",
        "![hard ground](hard_ground.png)",
        "",
        common.markdown_table(pd.DataFrame(rows), ".4g"),
        "",
        f"Frequency grid {freqs[0]:g}–{freqs[-1]:g} Hz in steps of {step:g} Hz; optima refined "
        "by a bounded scalar search between the neighbours of the grid maximum.",
    ]
    numbers = {
        "f0_hz": f0,
        "best": best,
        "single_above_f0": s["freq_hz"] > f0,
        "stutter_below_f0": st["freq_hz"] < f0,
        "work_ratio_stutter_over_single": work_ratio,
    }
    return "\n".join(body), numbers


def main(argv: list[str] | None = None) -> int:
    return common.main(NAME, __doc__, analyse, argv)


if __name__ == "__main__":
    sys.exit(main())
