"""Least-misfit valleys of the depth + drag law in the (k, c_d) plane (thesis Fig. 7).

The founding thesis hand-tuned the law F = k z + c_d z'^2 and found that, at the loosest
packing, the (k, c_d) valleys of least misfit of the preload jump and of the delayed
stutter preload jump do not intersect: no single (k, c_d) fits both. This analysis redoes
that test on any experiment folder, with an uncertainty, at every volume fraction in the
data. The computation is ``granbayes.analysis.maps`` (its docstring defines cell, grid, misfit,
valley, acceptable, closest approach); the bootstrap resamples the trials of each cell 500
times (100 with ``--fast``).
"""

from __future__ import annotations

import argparse
import math
import sys

import numpy as np
import pandas as pd

import _common as common
from granbayes import InputError
from granbayes.analysis.maps import (
    CD_MAX_KG_PER_M,
    K_RANGE_N_PER_M,
    TOLERANCE_SE,
    GridSpec,
    MisfitMap,
    argmin_2d,
    cell_table,
    grid_table,
    misfit_map,
    short,
    valley_table,
)
from granbayes.figures import plot_misfit_maps, plot_valleys
from granbayes.stats import fmt_triple, interval

NAME = "misfit_maps"


def _fmt(iv: tuple[float, float, float], digits: int = 2) -> str:
    return fmt_triple(*iv, fmt=f".{digits}g")


def _acceptable_extent(m: MisfitMap, command: str) -> str:
    acc = m.observed.acceptable[command]
    if not acc.any():
        return "none"
    ik, ic = np.nonzero(acc)
    return (
        f"k {m.k_n_per_m[ik].min():.4g} – {m.k_n_per_m[ik].max():.4g} N/m, "
        f"c_d {m.cd_kg_per_m[ic].min():.3g} – {m.cd_kg_per_m[ic].max():.3g} kg/m "
        f"({acc.mean():.1%} of the grid)"
    )


def add_arguments(p: argparse.ArgumentParser) -> None:
    """The options of this analysis (``--phi``, ``--k-range``, ``--cd-max``, ``--n-boot``)."""
    p.add_argument(
        "--phi",
        type=float,
        default=None,
        help="volume fraction of the main maps (default: the loosest in the data)",
    )
    p.add_argument(
        "--k-range",
        nargs=2,
        type=float,
        metavar=("K_MIN", "K_MAX"),
        default=K_RANGE_N_PER_M,
        help="initial k range [N/m] (log-spaced; extended automatically if a valley reaches "
        "an edge; default %(default)s)",
    )
    p.add_argument(
        "--cd-max",
        type=float,
        default=CD_MAX_KG_PER_M,
        help="largest c_d [kg/m] (default %(default)s)",
    )
    p.add_argument(
        "--n-boot",
        type=int,
        default=None,
        help="bootstrap resamples (default 500, 100 with --fast)",
    )


def per_phi_row(ctx: common.Context, m: MisfitMap) -> dict:
    """The row of the every-phi table."""
    p, d, n = *m.commands, m.summary()
    return {
        "φ": f"{m.phi:g}",
        "φ − φc": f"{m.phi - ctx.phi_c:+.3f}",
        "valleys intersect (fraction of resamples)": f"{n['intersect_fraction']:.0%}"
        + (" (data: yes)" if m.observed.intersect else " (data: no)"),
        "closest approach [mm]": _fmt(n["closest_approach_mm"]),
        "closest approach [s.e.]": _fmt(n["closest_approach_se"]),
        f"{short(p)} alone acceptable": f"{n['acceptable_fraction'][p]:.0%}",
        f"{short(d)} alone acceptable": f"{n['acceptable_fraction'][d]:.0%}",
        "valley floors cross at c_d [kg/m]": ", ".join(
            f"{x:.3g}" for x in n["valley_crossings_c_d_kg_per_m"]
        )
        or "no",
    }


def options(ctx: common.Context) -> tuple[GridSpec, int, float]:
    """The grid, the number of resamples and the phi of the main maps, checked."""
    args = ctx.args
    k_min, k_max = (float(v) for v in args.k_range)
    if not (0 < k_min < k_max) or not args.cd_max > 0:
        raise InputError("--k-range needs 0 < K_MIN < K_MAX and --cd-max must be > 0")
    n_boot = int(args.n_boot) if args.n_boot is not None else (100 if ctx.fast else 500)
    if n_boot < 1:
        raise InputError("--n-boot must be >= 1")
    size = (16, 12) if ctx.fast else (100, 81)
    phis = ctx.phis
    phi_main = float(phis[0]) if args.phi is None else float(args.phi)
    if not np.isclose(phis, phi_main).any():
        present = ", ".join(f"{p:g}" for p in phis)
        raise InputError(f"--phi {phi_main:g} is not in the data (present: {present})")
    grid = GridSpec(*size, 8, k_min, k_max, float(args.cd_max))
    return grid, n_boot, float(phis[np.isclose(phis, phi_main)][0])


def compute(ctx: common.Context, grid: GridSpec, n_boot: int) -> tuple[list[MisfitMap], list[str]]:
    """The maps at every phi with usable cells, and the notes for the summary."""
    notes: list[str] = []
    maps = [
        misfit_map(ctx.experiment, ctx.table, float(phi), grid, n_boot, ctx.rng(100 + i), notes)
        for i, phi in enumerate(ctx.phis)
    ]
    maps = [m for m in maps if m is not None]
    for m in maps:
        cds = [m.observed.closest_se_at[1], m.observed.closest_mm_at[1]]
        if any(math.isclose(x, m.cd_kg_per_m[-1]) for x in cds):
            notes.append(
                f"φ = {m.phi:g}: the closest approach lies on the largest c_d "
                f"({m.cd_kg_per_m[-1]:g} kg/m); a wider range (--cd-max) might come closer"
            )
    return maps, list(dict.fromkeys(notes))


def key_numbers(m: MisfitMap, maps: list[MisfitMap], grid: GridSpec, notes: list[str]) -> dict:
    """The numbers of summary.json: the main maps in detail, every phi in brief."""
    p, d = m.commands
    ev, boot = m.observed, m.boot
    j = int(np.argmin(np.abs(m.cd_kg_per_m - ev.curve_gap_cd_kg_per_m)))
    s = m.summary()
    return {
        "phi": m.phi,
        "tolerance_se": TOLERANCE_SE,
        "n_boot": len(boot),
        **{k: s[k] for k in ("intersect_observed", "intersect_fraction")},
        **{k: s[k] for k in ("closest_approach_se", "closest_approach_mm")},
        **{k: s[k] for k in ("closest_approach_se_observed", "closest_approach_mm_observed")},
        "closest_point_se": {"k_N_per_m": ev.closest_se_at[0], "c_d_kg_per_m": ev.closest_se_at[1]},
        "closest_point_mm": {"k_N_per_m": ev.closest_mm_at[0], "c_d_kg_per_m": ev.closest_mm_at[1]},
        "acceptable_fraction": s["acceptable_fraction"],
        "valley_curves": {
            "crossings_c_d_kg_per_m": s["valley_crossings_c_d_kg_per_m"],
            "closest_c_d_kg_per_m": ev.curve_gap_cd_kg_per_m,
            "closest_k_N_per_m": {c: ev.valley_k_n_per_m[c][j] for c in (p, d)},
            "closest_factor": 10**ev.curve_gap_dex,
            "closest_factor_boot": list(interval(10 ** boot["curve_gap_dex"].to_numpy())),
        },
        "by_cell": m.by_cell,
        "grid": {
            "k_N_per_m": [float(m.k_n_per_m[0]), float(m.k_n_per_m[-1])],
            "n_k_simulated": int(m.k_sim_n_per_m.size),
            "refine": grid.refine,
            "c_d_kg_per_m": [0.0, grid.cd_max_kg_per_m],
            "n_cd": grid.n_cd,
        },
        "per_phi": [x.summary() for x in maps],
        "notes": notes,
    }


def write_up(ctx: common.Context, m: MisfitMap, maps: list[MisfitMap], n: dict) -> list[str]:
    """The summary in words and tables, from the maps and their numbers."""
    p, d = m.commands
    ev, frac, curves = m.observed, n["intersect_fraction"], n["valley_curves"]
    verdict = "**intersect**" if ev.intersect else "**do not intersect**"
    if frac >= 0.95:
        robust = "in nearly every resample"
    elif frac <= 0.05:
        robust = "in almost no resample"
    else:
        robust = "in only part of the resamples, so the answer is uncertain"
    body = [
        f"At φ = {m.phi:g} (φ − φc = {m.phi - ctx.phi_c:+.3f}) the least-misfit "
        f"valleys of the depth + drag law for the preload and the delayed stutter preload "
        f"jump {verdict}: a (k, c_d) within {TOLERANCE_SE:g} standard errors of every cell "
        f"mean of both commands exists in {frac:.0%} of {n['n_boot']} bootstrap resamples "
        f"({robust}); the closest approach is {_fmt(n['closest_approach_se'])} standard errors "
        f"({_fmt(n['closest_approach_mm'])} mm, median [90% interval]).",
        "",
    ]
    alone = [c for c in m.commands if not ev.acceptable[c].any()]
    if alone:
        caveat = (
            f"Caveat: {' and '.join(short(c) for c in alone)} alone has no acceptable point "
            "(its frequency cells are not fitted together by any (k, c_d) on the grid), so "
            "part of the answer is that one valley is missing rather than that two valleys miss "
            "each other."
        )
        if m.by_cell:
            per = "; ".join(
                f"{b['cell']}: intersect in {b['intersect_fraction']:.0%}, closest "
                f"{_fmt(b['closest_approach_se'])} standard errors"
                for b in m.by_cell
            )
            caveat += f" Taking each frequency cell alone: {per}."
        body += [caveat, ""]
    measured = [
        {"command": short(c), "cell": x.label, "n": x.n, "mean [mm]": x.mean_mm}
        | {"s.e. [mm]": x.se_mm}
        for c in m.commands
        for x in m.cells[c]
    ]
    body += [
        "![misfit maps](misfit_maps.png)",
        "",
        "## Definitions",
        "",
        f"- **Grid**: k log-spaced {m.k_n_per_m[0]:.4g} – {m.k_n_per_m[-1]:.4g} N/m "
        f"({m.k_sim_n_per_m.size} simulated points, linearly interpolated in log k to "
        f"{m.k_n_per_m.size}), c_d {m.cd_kg_per_m[0]:g} – {m.cd_kg_per_m[-1]:g} kg/m "
        f"({m.cd_kg_per_m.size} points); other terms off, default r_unload.",
        "- **Misfit** [mm]: RMS over the command's frequency cells of |simulated − measured "
        "cell mean|. **Valley**: for each c_d the k of least misfit.",
        f"- **Acceptable**: |simulated − mean| ≤ {TOLERANCE_SE:g} × standard error of the cell "
        "mean in every frequency cell of the command. **Valleys intersect**: some grid point "
        "is acceptable for both commands.",
        "- **Closest approach**: min over the grid of the larger of the two commands' largest "
        "normalised residuals |sim − mean| / s.e. (intersect ⇔ ≤ "
        f"{TOLERANCE_SE:g}); in mm: min over the grid of the larger of the two RMS misfits.",
        f"- **Uncertainty**: {n['n_boot']} bootstrap resamples of the trials of every cell (seed "
        f"{ctx.seed}); the tolerance stays at the observed standard errors.",
        "",
        f"## φ = {m.phi:g}",
        "",
        "Measured cells:",
        "",
        common.markdown_table(pd.DataFrame(measured), ".3g"),
        "",
    ]
    per_command = []
    for c in m.commands:
        at = argmin_2d(ev.rms_mm[c])
        per_command.append(
            {
                "command": short(c),
                "least misfit [mm]": ev.rms_mm[c][at] if at else math.nan,
                "at k [N/m]": m.k_n_per_m[at[0]] if at else math.nan,
                "at c_d [kg/m]": m.cd_kg_per_m[at[1]] if at else math.nan,
                "acceptable region (data)": _acceptable_extent(m, c),
                "resamples with an acceptable point": f"{n['acceptable_fraction'][c]:.0%}",
            }
        )
    crossings, (kp, kd) = curves["crossings_c_d_kg_per_m"], curves["closest_k_N_per_m"].values()
    body += [
        common.markdown_table(pd.DataFrame(per_command), ".4g"),
        "",
        f"Closest approach on the data: {ev.closest_se:.3g} s.e. at k = "
        f"{ev.closest_se_at[0]:.4g} N/m, c_d = {ev.closest_se_at[1]:.3g} kg/m; "
        f"{ev.closest_mm:.3g} mm at k = {ev.closest_mm_at[0]:.4g} N/m, "
        f"c_d = {ev.closest_mm_at[1]:.3g} kg/m.",
        "",
        "The least-misfit curves k(c_d) cross at c_d ≈ "
        + ", ".join(f"{x:.3g}" for x in crossings)
        + " kg/m (crossing of the valley floors; the misfits there need not be small)."
        if crossings
        else "The least-misfit curves k(c_d) do not cross on the grid.",
        f"They come closest at c_d = {ev.curve_gap_cd_kg_per_m:.3g} kg/m: k = {kp:.4g} N/m "
        f"({short(p)}) vs {kd:.4g} N/m ({short(d)}), a factor {10**ev.curve_gap_dex:.3g} "
        f"apart (bootstrap {_fmt(curves['closest_factor_boot'], 3)}).",
        "",
    ]
    if m.by_cell:
        alone_rows = [
            {
                "cell": b["cell"],
                "valleys intersect (data)": "yes" if b["intersect_observed"] else "no",
                "intersect (fraction of resamples)": f"{b['intersect_fraction']:.0%}",
                "closest approach [s.e.]": _fmt(b["closest_approach_se"]),
                **{
                    f"{short(c)} alone acceptable (data)": "yes"
                    if b[f"acceptable_{c}_observed"]
                    else "no"
                    for c in m.commands
                },
            }
            for b in m.by_cell
        ]
        body += ["Each frequency cell alone:", "", common.markdown_table(pd.DataFrame(alone_rows))]
        body += [""]
    body += [
        "## Every volume fraction",
        "",
        "The thesis: the valleys do not intersect at low φ, while the law is fine at high φ.",
        "",
        common.markdown_table(pd.DataFrame([per_phi_row(ctx, x) for x in maps])),
        "",
        "![valleys at every phi](valleys_all_phi.png)",
        "",
    ]
    if n["notes"]:
        body += ["## Notes", "", *[f"- {note}" for note in n["notes"]], ""]
    return body


def analyse(ctx: common.Context) -> tuple[str, dict]:
    """Maps at the chosen phi, the answer at every phi, figures, tables and the summary."""
    grid, n_boot, phi_main = options(ctx)
    maps, notes = compute(ctx, grid, n_boot)
    m = next((m for m in maps if m.phi == phi_main), None)
    if m is None:
        raise InputError(
            f"φ = {phi_main:g} has no usable preload and delayed stutter preload cells "
            "(at least 2 trials each)"
        )
    title = (
        f"Depth + drag law F = k z + c_d z'² at φ = {m.phi:g} "
        f"(φ − φc = {m.phi - ctx.phi_c:+.3f}): misfit maps and least-misfit valleys"
    )
    ctx.save_figure(plot_misfit_maps(m, ctx.phi_c, ctx.title(title)), "misfit_maps")
    title = "Do the preload and delayed stutter preload valleys intersect at every φ?"
    ctx.save_figure(plot_valleys(maps, ctx.phi_c, ctx.title(title)), "valleys_all_phi")
    ctx.save_table(grid_table(m), "misfit_grid")
    ctx.save_table(valley_table(maps), "valleys")
    ctx.save_table(cell_table(maps), "cells")
    numbers = key_numbers(m, maps, grid, notes)
    return "\n".join(write_up(ctx, m, maps, numbers)), numbers


def main(argv: list[str] | None = None) -> int:
    """Run the analysis (see the module docstring); returns the exit code."""
    return common.main(NAME, __doc__, analyse, argv, add_arguments)


if __name__ == "__main__":
    sys.exit(main())
