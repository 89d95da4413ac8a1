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
from scipy.optimize import minimize_scalar

import _common as common
from granbayes import Experiment, simulate, simulate_trajectory
from granbayes.experiment import G

NAME = "hard_ground"

#: The rigid-floor limit of the ground model (physics-model.md section 6).
RIGID_FLOOR = {"k": 1.0e6, "r_unload": 50.0}
COMMANDS = ("single", "stutter")


def heights_mm(experiment: Experiment, command: str, freqs_hz: np.ndarray) -> np.ndarray:
    """Rigid-floor jump heights [mm] of ``command`` at each frequency (NaN if failed)."""
    out = np.empty(freqs_hz.size)
    for i, f in enumerate(freqs_hz):
        res = simulate(command, 0.612, RIGID_FLOOR, experiment=experiment.replace(freq_hz=f))
        out[i] = res.height_mm[0] if res.ok[0] else np.nan
    return out


def best_frequency(
    experiment: Experiment, command: str, freqs_hz: np.ndarray, h_mm: np.ndarray
) -> tuple[float, float]:
    """Optimal frequency [Hz] and height [mm]: grid maximum refined by a bounded search."""
    i = int(np.nanargmax(h_mm))
    lo, hi = freqs_hz[max(i - 1, 0)], freqs_hz[min(i + 1, freqs_hz.size - 1)]
    if lo == hi:
        return float(freqs_hz[i]), float(h_mm[i])
    res = minimize_scalar(
        lambda f: -heights_mm(experiment, command, np.array([f]))[0],
        bounds=(lo, hi),
        method="bounded",
        options={"xatol": 0.01},
    )
    if -res.fun < h_mm[i]:
        return float(freqs_hz[i]), float(h_mm[i])
    return float(res.x), float(-res.fun)


def actuator_power(experiment: Experiment, command: str, freq_hz: float) -> dict[str, float]:
    """Peak actuator power [W] and positive actuator work [J] of one rigid-floor jump."""
    exp = experiment.replace(freq_hz=freq_hz)
    traj = simulate_trajectory(command, 0.612, RIGID_FLOOR, experiment=exp, max_step=1e-4)
    d = traj.data.drop_duplicates("t_s")
    d = d[d["t_s"] <= traj.program.t_end]
    t = d["t_s"].to_numpy()
    r = exp.robot
    m_upper = r.m_motor + r.m_rod
    spring_n = (
        r.k_spring * (d["x_foot_mm"] - d["x_rod_mm"]).to_numpy() * 1e-3
        + r.c_spring * (d["v_foot_m_s"] - d["v_rod_m_s"]).to_numpy()
    )
    alpha_ddot = traj.program.alpha_ddot(t)
    a_rod = (spring_n - r.m_motor * alpha_ddot) / m_upper - G
    force_n = r.m_motor * (a_rod + alpha_ddot + G)
    alpha_dot = np.gradient(traj.program.alpha(t), t)
    power_w = force_n * alpha_dot
    positive = np.clip(power_w, 0.0, None)
    work_j = float(np.sum(0.5 * (positive[1:] + positive[:-1]) * np.diff(t)))
    return {"peak_power_w": float(power_w.max()), "positive_work_j": work_j}


def analyse(ctx: common.Context) -> tuple[str, dict]:
    exp = ctx.experiment
    step = 1.0 if ctx.fast else 0.25
    freqs = np.arange(4.0, 30.0 + step / 2, step)
    f0 = exp.robot.f0_hz
    table = pd.DataFrame({"freq_hz": freqs})
    best: dict[str, dict] = {}
    for command in COMMANDS:
        h = heights_mm(exp, command, freqs)
        table[f"{command}_height_mm"] = h
        f_best, h_best = best_frequency(exp, command, freqs, h)
        best[command] = {"freq_hz": f_best, "height_mm": h_best, "f_over_f0": f_best / f0}
    power_freqs = freqs[:: max(1, round(1.0 / step))]
    power = {c: [actuator_power(exp, c, f) for f in power_freqs] for c in COMMANDS}
    for command in COMMANDS:
        best[command] |= actuator_power(exp, command, best[command]["freq_hz"])
    ctx.save_table(table, "hard_ground_heights")
    ctx.save_table(
        pd.DataFrame(
            {"freq_hz": power_freqs}
            | {
                f"{c}_{key}": [p[key] for p in power[c]]
                for c in COMMANDS
                for key in ("peak_power_w", "positive_work_j")
            }
        ),
        "hard_ground_power",
    )

    colors = {
        "single": common.COMMAND_COLORS["single"],
        "stutter": common.COMMAND_COLORS["preload"],
    }
    fig = Figure(figsize=(11.0, 4.6), layout="constrained")
    ax_h, ax_p = fig.subplots(1, 2)
    for command in COMMANDS:
        c = colors[command]
        ax_h.plot(freqs, table[f"{command}_height_mm"], color=c, lw=1.6, label=command)
        b = best[command]
        ax_h.plot(b["freq_hz"], b["height_mm"], "*", ms=15, color=c, mec="k", mew=0.7)
        ax_h.annotate(
            f"{b['freq_hz']:.2f} Hz\n{b['height_mm']:.0f} mm",
            (b["freq_hz"], b["height_mm"]),
            xytext=(8 if b["freq_hz"] > f0 else -8, 6),
            textcoords="offset points",
            ha="left" if b["freq_hz"] > f0 else "right",
            fontsize=8,
            color=c,
        )
        ax_p.plot(
            power_freqs,
            [p["positive_work_j"] for p in power[command]],
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
    r = exp.robot
    fig.suptitle(
        f"Rigid floor (k = 1e6 N/m, r_unload = 50): robot M = {r.m_upper:g} kg, "
        f"m_foot = {r.m_foot:g} kg, k_spring = {r.k_spring:g} N/m, "
        f"A = {exp.command.amplitude_mm:g} mm\n(simulation; robot from {ctx.data.name})",
        fontsize=11,
    )
    ctx.save_figure(fig, "hard_ground")

    s, st = best["single"], best["stutter"]
    agrees = s["freq_hz"] > f0 > st["freq_hz"]
    work_ratio = st["positive_work_j"] / s["positive_work_j"]
    body = [
        f"Resonant frequency of the leg f0 = {f0:.2f} Hz. Best single jump at "
        f"**{s['freq_hz']:.2f} Hz** (f/f0 = {s['f_over_f0']:.2f}, {s['height_mm']:.1f} mm); "
        f"best stutter jump at **{st['freq_hz']:.2f} Hz** (f/f0 = {st['f_over_f0']:.2f}, "
        f"{st['height_mm']:.1f} mm).",
        "",
        (
            "This **reproduces** Aguilar et al. (2012): the single-jump optimum lies above "
            "f0 and the stutter optimum below it."
            if agrees
            else "This does **not** reproduce the ordering of Aguilar et al. (2012) "
            "(single optimum above f0, stutter below) for this robot."
        ),
        "",
        f"At their optima the stutter jump needs {work_ratio:.2f}× the positive actuator work "
        f"of the single jump ({st['positive_work_j']:.2f} J vs {s['positive_work_j']:.2f} J; "
        f"peak power {st['peak_power_w']:.0f} W vs {s['peak_power_w']:.0f} W) for "
        f"{st['height_mm'] / s['height_mm']:.2f}× its height.",
        "",
        "![hard ground](hard_ground.png)",
        "",
        common.markdown_table(
            pd.DataFrame(
                [
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
            ),
            ".4g",
        ),
        "",
        "Frequency grid "
        f"{freqs[0]:g}–{freqs[-1]:g} Hz in steps of {step:g} Hz; optima refined by a bounded "
        "scalar search between the neighbours of the grid maximum.",
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
