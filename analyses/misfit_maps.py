"""Least-misfit valleys of the depth + drag law in the (k, c_d) plane (thesis Fig. 7).

The founding thesis hand-tuned the law F = k z + c_d z'^2 and found that, at the loosest
packing, the (k, c_d) valleys of least misfit of the preload jump and of the delayed
stutter preload jump do not intersect: no single (k, c_d) fits both. This analysis redoes
that test on any experiment folder, with an uncertainty.

Definitions
-----------
cell
    The trials of one command at one volume fraction and one actuation setting (frequency,
    amplitude and, for the delayed stutter preload, settle periods); cell mean ``m`` and
    standard error ``se = sd / sqrt(n)`` of its jump heights. Cells with fewer than 2
    trials have no standard error and are left out.
grid
    ``k`` [N/m] log-spaced, ``c_d`` [kg/m] linear from 0; every other force term off and the
    bed's default ``r_unload``. Each (command, cell) is simulated once with all grid points
    batched. Heights are then interpolated linearly in ``log k`` between simulated points
    (``refine`` sub-steps) so that narrow valleys are not missed; a failed simulation makes
    its neighbouring intervals unusable (never acceptable). If a valley reaches the ``k``
    edge the grid is extended there (at most twice by a factor 3, within 30 - 1e6 N/m).
misfit [mm]
    Per grid point and command: the RMS over the command's cells of ``|sim - m|``.
valley
    Per ``c_d``: the ``k`` of least misfit (on the refined grid).
acceptable
    A grid point is acceptable for a command if ``|sim - m| <= 2 se`` in every one of the
    command's cells (i.e. its largest normalised residual ``max |sim - m| / se <= 2``).
valleys intersect
    Some grid point is acceptable for both commands at once.
closest approach
    In standard errors: the minimum over the grid of ``max`` over both commands of the
    largest normalised residual (the valleys intersect exactly when it is <= 2). In mm: the
    minimum over the grid of the larger of the two commands' misfits.
uncertainty
    Seeded bootstrap: the trials of each cell are resampled with replacement (500 times,
    100 in ``--fast``) and everything above is recomputed from the resampled cell means;
    the simulated grid does not change. The tolerance stays 2 x the observed standard error
    (recomputing it from resamples with repeated trials would shrink it towards zero).
    Reported: the fraction of resamples in which the valleys intersect, and medians with
    90% equal-tailed intervals.

The same answer is computed at every other volume fraction in the data.
"""

from __future__ import annotations

import argparse
import math
import sys
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field

import numpy as np
import pandas as pd
from matplotlib import colors as mcolors
from matplotlib.axes import Axes
from matplotlib.colors import LogNorm
from matplotlib.figure import Figure
from matplotlib.lines import Line2D
from matplotlib.patches import Patch

import _common as common
from granbayes import InputError, simulate

NAME = "misfit_maps"

#: The two commands whose valleys are compared.
COMMANDS: tuple[str, str] = ("preload", "delayed_stutter_preload")
#: Line style and hatch of each command in the overlays (its colour is the project's).
STYLES: dict[str, dict[str, str]] = {
    "preload": {"ls": "-", "hatch": "\\\\\\"},
    "delayed_stutter_preload": {"ls": "--", "hatch": "///"},
}
#: Command settings that change each command's actuation (the cell keys besides phi).
SETTINGS: dict[str, tuple[str, ...]] = {
    "preload": ("freq_hz", "amplitude_mm"),
    "delayed_stutter_preload": ("freq_hz", "amplitude_mm", "settle_periods"),
}
#: A grid point is acceptable if |sim - mean| <= TOLERANCE_SE standard errors in every cell.
TOLERANCE_SE = 2.0
#: Default k range [N/m] and c_d maximum [kg/m].
K_RANGE_N_PER_M = (300.0, 30000.0)
CD_MAX_KG_PER_M = 100.0
#: Hard limits of the automatic k extension [N/m], its factor and number of steps per side.
K_LIMITS_N_PER_M = (30.0, 1.0e6)
K_EXTEND_FACTOR = 3.0
K_EXTEND_MAX = 2


def short(command: str) -> str:
    """Command name for labels (``delayed stutter preload``)."""
    return command.replace("_", " ")


# ----------------------------------------------------------------------------------------
@dataclass(frozen=True)
class Cell:
    """The trials of one command at one volume fraction and actuation setting.

    Attributes
    ----------
    command : str
        Command name.
    settings : dict of str to float
        ``freq_hz``, ``amplitude_mm`` (and ``settle_periods``) of the cell.
    label : str
        Short label (``"8 Hz"``).
    heights_mm : ndarray
        Measured jump heights [mm].
    """

    command: str
    settings: dict[str, float]
    label: str
    heights_mm: np.ndarray

    @property
    def n(self) -> int:
        """Number of trials."""
        return int(self.heights_mm.size)

    @property
    def mean_mm(self) -> float:
        """Cell mean [mm]."""
        return float(np.mean(self.heights_mm))

    @property
    def sd_mm(self) -> float:
        """Trial standard deviation [mm]."""
        return float(np.std(self.heights_mm, ddof=1))

    @property
    def se_mm(self) -> float:
        """Standard error of the cell mean [mm]."""
        return self.sd_mm / math.sqrt(self.n)


def cells_at(table: pd.DataFrame, phi: float, command: str) -> tuple[list[Cell], list[str]]:
    """The cells (with at least 2 trials) of ``command`` at ``phi``, and notes on dropped ones."""
    keys = list(SETTINGS[command])
    rows = table[np.isclose(table["phi"].to_numpy(float), phi) & (table["command"] == command)]
    cells: list[Cell] = []
    notes: list[str] = []
    for values, group in rows.groupby(keys, sort=True):
        settings = dict(zip(keys, map(float, np.atleast_1d(values)), strict=True))
        heights = group["height_mm"].to_numpy(float)
        heights = heights[np.isfinite(heights)]
        label = f"{settings['freq_hz']:g} Hz"
        if heights.size < 2:
            notes.append(
                f"φ = {phi:g}, {short(command)}, {label}: {heights.size} trial(s), no standard "
                "error; cell left out"
            )
            continue
        cells.append(Cell(command, settings, label, heights))
    labels = [c.label for c in cells]
    if len(set(labels)) < len(labels):  # same frequency, other settings: spell them out
        cells = [
            Cell(
                c.command,
                c.settings,
                ", ".join(f"{k} {v:g}" for k, v in c.settings.items()),
                c.heights_mm,
            )
            for c in cells
        ]
    return cells, notes


# ----------------------------------------------------------------------------------------
@dataclass(frozen=True)
class GridSpec:
    """Size and range of the (k, c_d) grid.

    Attributes
    ----------
    n_k, n_cd : int
        Simulated points along k and c_d.
    refine : int
        Interpolated sub-steps per simulated k interval.
    k_min_n_per_m, k_max_n_per_m : float
        Initial k range [N/m].
    cd_max_kg_per_m : float
        Largest c_d [kg/m].
    """

    n_k: int
    n_cd: int
    refine: int
    k_min_n_per_m: float
    k_max_n_per_m: float
    cd_max_kg_per_m: float

    @property
    def log_step(self) -> float:
        """Step of the simulated k grid in ln k."""
        return math.log(self.k_max_n_per_m / self.k_min_n_per_m) / (self.n_k - 1)

    @property
    def cd_kg_per_m(self) -> np.ndarray:
        """The c_d grid [kg/m]."""
        return np.linspace(0.0, self.cd_max_kg_per_m, self.n_cd)


def refine_log_k(heights_mm: np.ndarray, factor: int) -> np.ndarray:
    """Linear interpolation in log k of ``(n_k, n_cd)`` heights to ``(n_k - 1) * factor + 1``.

    NaN (failed simulations) propagates to every interpolated point next to it.
    """
    if factor <= 1:
        return heights_mm.copy()
    lo, hi = heights_mm[:-1], heights_mm[1:]
    t = (np.arange(factor) / factor)[None, :, None]
    inner = (1.0 - t) * lo[:, None, :] + t * hi[:, None, :]
    n_cd = heights_mm.shape[1]
    return np.concatenate([inner.reshape(-1, n_cd), heights_mm[-1:]], axis=0)


def refine_k(k_n_per_m: np.ndarray, factor: int) -> np.ndarray:
    """The refined k grid [N/m] matching :func:`refine_log_k`."""
    logs = np.log(k_n_per_m)
    return np.exp(refine_log_k(logs[:, None], factor)[:, 0])


# ----------------------------------------------------------------------------------------
@dataclass(frozen=True)
class Evaluation:
    """Misfits, valleys and the intersection answer for one set of cell means.

    Attributes
    ----------
    rms_mm, max_se : dict of str to ndarray, shape (n_k_fine, n_cd)
        Per command: RMS residual over cells [mm]; largest |residual| / se over cells.
    acceptable : dict of str to ndarray of bool
        ``max_se <= TOLERANCE_SE``.
    valley_k_n_per_m, valley_mm : dict of str to ndarray, shape (n_cd,)
        Per command and c_d: k of least misfit [N/m] and that misfit [mm].
    closest_se, closest_mm : float
        Closest approach of the two commands (module docstring).
    closest_se_at, closest_mm_at : tuple of float
        ``(k [N/m], c_d [kg/m])`` where it is reached.
    curve_gap_dex : float
        Smallest ``|log10(k_valley(dsp) / k_valley(preload))|`` over c_d.
    curve_gap_cd_kg_per_m : float
        The c_d where the valley curves come closest.
    """

    rms_mm: dict[str, np.ndarray]
    max_se: dict[str, np.ndarray]
    acceptable: dict[str, np.ndarray]
    valley_k_n_per_m: dict[str, np.ndarray]
    valley_mm: dict[str, np.ndarray]
    closest_se: float
    closest_mm: float
    closest_se_at: tuple[float, float]
    closest_mm_at: tuple[float, float]
    curve_gap_dex: float
    curve_gap_cd_kg_per_m: float

    @property
    def intersect(self) -> bool:
        """Whether some grid point is acceptable for both commands."""
        return bool(self.closest_se <= TOLERANCE_SE)


def _argmin_2d(values: np.ndarray) -> tuple[int, int] | None:
    """Index of the smallest finite value of a 2-d array (None if there is none)."""
    if not np.isfinite(values).any():
        return None
    i = int(np.nanargmin(values))
    return int(i // values.shape[1]), int(i % values.shape[1])


def evaluate(
    heights_mm: Mapping[str, np.ndarray],
    means_mm: Mapping[str, np.ndarray],
    ses_mm: Mapping[str, np.ndarray],
    k_n_per_m: np.ndarray,
    cd_kg_per_m: np.ndarray,
) -> Evaluation:
    """Misfit maps, valleys and closest approach of the two commands.

    Parameters
    ----------
    heights_mm : mapping of command to ndarray, shape (n_cells, n_k, n_cd)
        Simulated heights [mm] per cell on the (refined) grid.
    means_mm, ses_mm : mapping of command to ndarray, shape (n_cells,)
        Cell means and standard errors [mm].
    k_n_per_m : ndarray, shape (n_k,)
        k grid [N/m].
    cd_kg_per_m : ndarray, shape (n_cd,)
        c_d grid [kg/m].

    Returns
    -------
    Evaluation
    """
    rms, mse, ok, vk, vmm = {}, {}, {}, {}, {}
    for command in COMMANDS:
        res = heights_mm[command] - means_mm[command][:, None, None]
        rms[command] = np.sqrt(np.mean(res * res, axis=0))
        with np.errstate(divide="ignore", invalid="ignore"):  # se = 0: never acceptable
            mse[command] = np.max(np.abs(res) / ses_mm[command][:, None, None], axis=0)
        ok[command] = mse[command] <= TOLERANCE_SE
        finite = np.where(np.isfinite(rms[command]), rms[command], np.inf)
        i = np.argmin(finite, axis=0)
        best = finite[i, np.arange(finite.shape[1])]
        vk[command] = np.where(np.isfinite(best), k_n_per_m[i], np.nan)
        vmm[command] = np.where(np.isfinite(best), best, np.nan)

    def closest(a: np.ndarray, b: np.ndarray) -> tuple[float, tuple[float, float]]:
        both = np.maximum(a, b)
        at = _argmin_2d(both)
        if at is None:
            return math.nan, (math.nan, math.nan)
        return float(both[at]), (float(k_n_per_m[at[0]]), float(cd_kg_per_m[at[1]]))

    p, d = COMMANDS
    c_se, at_se = closest(mse[p], mse[d])
    c_mm, at_mm = closest(rms[p], rms[d])
    gap = np.abs(np.log10(vk[d]) - np.log10(vk[p]))
    if np.isfinite(gap).any():
        j = int(np.nanargmin(gap))
        gap_dex, gap_cd = float(gap[j]), float(cd_kg_per_m[j])
    else:
        gap_dex, gap_cd = math.nan, math.nan
    return Evaluation(rms, mse, ok, vk, vmm, c_se, c_mm, at_se, at_mm, gap_dex, gap_cd)


def curve_crossings(ev: Evaluation, cd_kg_per_m: np.ndarray, sim_log_step: float) -> list[float]:
    """c_d [kg/m] where the two valley curves k(c_d) cross (continuous stretches only).

    A sign change of ``log k_dsp - log k_preload`` between neighbouring c_d counts only if
    neither curve jumps there by more than ``_jump_log`` (a jump is a switch between two
    branches of a valley, not a crossing).
    """
    p, d = COMMANDS
    lp, ld = np.log(ev.valley_k_n_per_m[p]), np.log(ev.valley_k_n_per_m[d])
    diff = ld - lp
    out = []
    for j in range(len(cd_kg_per_m) - 1):
        a, b = diff[j], diff[j + 1]
        if not (np.isfinite(a) and np.isfinite(b)) or not (a * b < 0 or a == 0):
            continue
        smooth = all(abs(x[j + 1] - x[j]) <= _jump_log(sim_log_step) for x in (lp, ld))
        if smooth:
            t = a / (a - b) if a != b else 0.0
            x = float(cd_kg_per_m[j] + t * (cd_kg_per_m[j + 1] - cd_kg_per_m[j]))
            step = cd_kg_per_m[j + 1] - cd_kg_per_m[j]
            if not out or x - out[-1] > 1.5 * step:  # touching over a stretch: report once
                out.append(x)
    return out


# ----------------------------------------------------------------------------------------
@dataclass
class PhiResult:
    """Everything computed at one volume fraction.

    Attributes
    ----------
    phi : float
    cells : dict of command to list of Cell
    k_sim_n_per_m : ndarray
        Simulated k grid [N/m].
    cd_kg_per_m : ndarray
        c_d grid [kg/m].
    sim_mm : dict of command to ndarray, shape (n_cells, n_k, n_cd)
        Simulated heights [mm] (NaN where the integration failed).
    k_n_per_m : ndarray
        Refined k grid [N/m].
    fine_mm : dict of command to ndarray
        Heights interpolated to the refined grid [mm].
    observed : Evaluation
        Answer for the measured cell means.
    boot : pandas.DataFrame
        One row per bootstrap resample: ``closest_se``, ``closest_mm``, ``intersect``,
        ``acceptable_<command>``, ``curve_gap_dex``.
    by_cell : list of dict
        The answer for each setting (frequency) present for both commands, used alone.
    """

    phi: float
    cells: dict[str, list[Cell]]
    k_sim_n_per_m: np.ndarray
    cd_kg_per_m: np.ndarray
    sim_mm: dict[str, np.ndarray]
    k_n_per_m: np.ndarray
    fine_mm: dict[str, np.ndarray]
    observed: Evaluation
    boot: pd.DataFrame
    by_cell: list[dict] = field(default_factory=list)

    @property
    def sim_log_step(self) -> float:
        """Step of the simulated k grid in ln k."""
        return math.log(self.k_sim_n_per_m[1] / self.k_sim_n_per_m[0])

    def means(self) -> dict[str, np.ndarray]:
        """Observed cell means [mm] per command."""
        return {c: np.array([x.mean_mm for x in self.cells[c]]) for c in COMMANDS}

    def ses(self) -> dict[str, np.ndarray]:
        """Observed standard errors [mm] per command."""
        return {c: np.array([x.se_mm for x in self.cells[c]]) for c in COMMANDS}


def simulate_cells(
    ctx: common.Context, phi: float, cells: Sequence[Cell], k: np.ndarray, cd: np.ndarray
) -> np.ndarray:
    """Heights [mm] of each cell's command on the grid ``k x cd``: shape (n_cells, n_k, n_cd).

    One batched simulate call per cell; failed jumps are NaN.
    """
    kk, cc = np.meshgrid(k, cd, indexing="ij")
    out = np.empty((len(cells), k.size, cd.size))
    for i, cell in enumerate(cells):
        experiment = ctx.experiment.replace(**cell.settings)
        res = simulate(
            cell.command, phi, {"k": kk.ravel(), "c_d": cc.ravel()}, experiment=experiment
        )
        out[i] = np.where(res.ok, res.height_mm, np.nan).reshape(kk.shape)
    return out


def _edges_hit(
    sim_mm: Mapping[str, np.ndarray],
    means: Mapping[str, np.ndarray],
    k: np.ndarray,
    cd: np.ndarray,
    refine: int,
) -> tuple[bool, bool]:
    """Whether the observed valley of either command reaches the low / high k edge."""
    fine = {c: np.stack([refine_log_k(h, refine) for h in sim_mm[c]]) for c in COMMANDS}
    ones = {c: np.ones_like(means[c]) for c in COMMANDS}
    k_fine = refine_k(k, refine)
    ev = evaluate(fine, means, ones, k_fine, cd)
    valleys = np.concatenate([ev.valley_k_n_per_m[c] for c in COMMANDS])
    return bool(np.any(valleys <= k_fine[0])), bool(np.any(valleys >= k_fine[-1]))


def analyse_phi(
    ctx: common.Context,
    phi: float,
    grid: GridSpec,
    n_boot: int,
    seed_offset: int,
    notes: list[str],
) -> PhiResult | None:
    """Simulate, evaluate and bootstrap at one volume fraction.

    Parameters
    ----------
    ctx : Context
    phi : float
        Volume fraction [-].
    grid : GridSpec
    n_boot : int
        Bootstrap resamples.
    seed_offset : int
        Stream of ``ctx.rng``.
    notes : list of str
        Messages for the summary are appended here (dropped cells, grid extensions, failed
        simulations).

    Returns
    -------
    PhiResult or None
        None if either command has no usable cell at ``phi``.
    """
    cells: dict[str, list[Cell]] = {}
    for command in COMMANDS:
        cells[command], dropped = cells_at(ctx.table, phi, command)
        notes += dropped
        if not cells[command]:
            notes.append(f"φ = {phi:g}: no usable {short(command)} cell; φ skipped")
            return None
    means = {c: np.array([x.mean_mm for x in cells[c]]) for c in COMMANDS}
    cd = grid.cd_kg_per_m
    step = grid.log_step
    k = np.exp(np.linspace(math.log(grid.k_min_n_per_m), math.log(grid.k_max_n_per_m), grid.n_k))
    sim = {c: simulate_cells(ctx, phi, cells[c], k, cd) for c in COMMANDS}
    n_ext = max(1, round(math.log(K_EXTEND_FACTOR) / step))
    for _ in range(K_EXTEND_MAX):
        low, high = _edges_hit(sim, means, k, cd, grid.refine)
        low &= k[0] * math.exp(-n_ext * step) >= K_LIMITS_N_PER_M[0]
        high &= k[-1] * math.exp(n_ext * step) <= K_LIMITS_N_PER_M[1]
        if not (low or high):
            break
        if low:
            new = k[0] * np.exp(-step * np.arange(n_ext, 0, -1))
            sim = {
                c: np.concatenate([simulate_cells(ctx, phi, cells[c], new, cd), sim[c]], axis=1)
                for c in COMMANDS
            }
            k = np.concatenate([new, k])
        if high:
            new = k[-1] * np.exp(step * np.arange(1, n_ext + 1))
            sim = {
                c: np.concatenate([sim[c], simulate_cells(ctx, phi, cells[c], new, cd)], axis=1)
                for c in COMMANDS
            }
            k = np.concatenate([k, new])
        notes.append(
            f"φ = {phi:g}: a valley reached the k edge; k grid extended to "
            f"{k[0]:.4g} – {k[-1]:.4g} N/m"
        )
    low, high = _edges_hit(sim, means, k, cd, grid.refine)
    if low or high:
        notes.append(
            f"φ = {phi:g}: a valley still runs into the {'low' if low else 'high'} k edge "
            f"({k[0] if low else k[-1]:.4g} N/m): the law cannot reach the measured heights "
            "there"
        )
    for c in COMMANDS:
        n_bad = int(np.isnan(sim[c]).sum())
        if n_bad:
            notes.append(
                f"φ = {phi:g}, {short(c)}: {n_bad} of {sim[c].size} simulations failed "
                "(their neighbourhood is never acceptable)"
            )
    k_fine = refine_k(k, grid.refine)
    fine = {c: np.stack([refine_log_k(h, grid.refine) for h in sim[c]]) for c in COMMANDS}
    ses = {c: np.array([x.se_mm for x in cells[c]]) for c in COMMANDS}
    observed = evaluate(fine, means, ses, k_fine, cd)

    # Bootstrap: resample the trials of every cell; the simulated grid does not change.
    rng = ctx.rng(seed_offset)
    boot_means = {
        c: np.stack(
            [x.heights_mm[rng.integers(0, x.n, size=(n_boot, x.n))].mean(axis=1) for x in cells[c]],
            axis=1,
        )
        for c in COMMANDS
    }
    rows = []
    for b in range(n_boot):
        ev = evaluate(fine, {c: boot_means[c][b] for c in COMMANDS}, ses, k_fine, cd)
        rows.append(
            {
                "closest_se": ev.closest_se,
                "closest_mm": ev.closest_mm,
                "intersect": ev.intersect,
                **{f"acceptable_{c}": bool(ev.acceptable[c].any()) for c in COMMANDS},
                "curve_gap_dex": ev.curve_gap_dex,
            }
        )
    result = PhiResult(phi, cells, k, cd, sim, k_fine, fine, observed, pd.DataFrame(rows))

    # Each frequency (setting) alone, where both commands have it.
    labels = [
        x.label for x in cells[COMMANDS[0]] if x.label in {y.label for y in cells[COMMANDS[1]]}
    ]
    if any(len(cells[c]) > 1 for c in COMMANDS):
        for label in labels:
            idx = {c: [i for i, x in enumerate(cells[c]) if x.label == label] for c in COMMANDS}
            sub = {c: fine[c][idx[c]] for c in COMMANDS}
            obs = evaluate(
                sub,
                {c: means[c][idx[c]] for c in COMMANDS},
                {c: ses[c][idx[c]] for c in COMMANDS},
                k_fine,
                cd,
            )
            hits, closest = [], []
            for b in range(n_boot):
                ev = evaluate(
                    sub,
                    {c: boot_means[c][b, idx[c]] for c in COMMANDS},
                    {c: ses[c][idx[c]] for c in COMMANDS},
                    k_fine,
                    cd,
                )
                hits.append(ev.intersect)
                closest.append(ev.closest_se)
            result.by_cell.append(
                {
                    "cell": label,
                    "intersect_observed": obs.intersect,
                    "intersect_fraction": float(np.mean(hits)),
                    "closest_approach_se": common.interval(np.array(closest)),
                    **{f"acceptable_{c}_observed": bool(obs.acceptable[c].any()) for c in COMMANDS},
                }
            )
    return result


# ----------------------------------------------------------------------------------------
def _valley_line(k: np.ndarray, sim_log_step: float) -> np.ndarray:
    """The valley curve with NaN inserted where it jumps between branches (for plotting)."""
    out = np.asarray(k, float).copy()
    jumps = np.abs(np.diff(np.log(out))) > _jump_log(sim_log_step)
    out[1:][jumps] = np.nan
    return out


def _jump_log(sim_log_step: float) -> float:
    """A valley curve jumping by more than this in ln k switches branch (not a crossing)."""
    return max(2.0 * sim_log_step, math.log(1.25))


def _cd_limits(r: PhiResult) -> tuple[float, float]:
    """c_d axis limits of the pcolormesh cells (half a step beyond the grid) [kg/m]."""
    half = 0.5 * (r.cd_kg_per_m[1] - r.cd_kg_per_m[0]) if r.cd_kg_per_m.size > 1 else 0.5
    return float(r.cd_kg_per_m[0] - half), float(r.cd_kg_per_m[-1] + half)


def _norm(r: PhiResult) -> LogNorm:
    """Log colour scale of the misfit maps: from half the smallest standard error [mm]."""
    values = np.concatenate([r.observed.rms_mm[c].ravel() for c in COMMANDS])
    values = values[np.isfinite(values)]
    se_min = min(float(r.ses()[c].min()) for c in COMMANDS)
    vmin = max(0.05, 0.5 * se_min, float(values.min()) if values.size else 0.0)
    vmax = max(10 * vmin, float(np.quantile(values, 0.995))) if values.size else 100.0
    return LogNorm(vmin=vmin, vmax=vmax, clip=True)


def _shade(ax: Axes, r: PhiResult, command: str) -> None:
    """Acceptable region (hatched) and valley line of ``command`` on ``ax``."""
    ev = r.observed
    mask = ev.acceptable[command].astype(float)
    color = common.COMMAND_COLORS[command]
    style = STYLES[command]
    if mask.any():
        ax.contourf(r.cd_kg_per_m, r.k_n_per_m, mask, levels=[0.5, 1.5], colors=[color], alpha=0.25)
        ax.contourf(
            r.cd_kg_per_m,
            r.k_n_per_m,
            mask,
            levels=[0.5, 1.5],
            colors="none",
            hatches=[style["hatch"]],
            edgecolor=color,
        )
        ax.contour(
            r.cd_kg_per_m,
            r.k_n_per_m,
            mask,
            levels=[0.5],
            colors=[color],
            linewidths=1.0,
            linestyles=style["ls"],
        )
    ax.plot(
        r.cd_kg_per_m,
        _valley_line(ev.valley_k_n_per_m[command], r.sim_log_step),
        color=color,
        ls=style["ls"],
        lw=2.2,
    )


def _legend_handles(r: PhiResult | None = None) -> list:
    """Legend entries of :func:`_shade` (``r``: mark commands without acceptable points)."""
    lines, patches = [], []
    for c in COMMANDS:
        color, style = common.COMMAND_COLORS[c], STYLES[c]
        none = r is not None and not r.observed.acceptable[c].any()
        lines.append(
            Line2D([], [], color=color, ls=style["ls"], lw=2.2, label=f"{short(c)} valley")
        )
        patches.append(
            Patch(
                facecolor=mcolors.to_rgba(color, 0.25),
                edgecolor=color,
                hatch=style["hatch"],
                label=f"{short(c)} acceptable" + (": none" if none else ""),
            )
        )
    return lines + patches


def plot_maps(ctx: common.Context, r: PhiResult, n_boot: int) -> Figure:
    """Misfit maps of both commands with their valleys, and the overlay of the valleys."""
    fig = Figure(figsize=(15.5, 5.2), layout="constrained")
    axes = fig.subplots(1, 3, sharey=True)
    norm = _norm(r)
    ev = r.observed
    mesh = None
    for ax, command in zip(axes[:2], COMMANDS, strict=True):
        mesh = ax.pcolormesh(
            r.cd_kg_per_m,
            r.k_n_per_m,
            ev.rms_mm[command],
            norm=norm,
            cmap="viridis",
            shading="nearest",
            rasterized=True,
        )
        mask = ev.acceptable[command].astype(float)
        if mask.any():
            ax.contour(
                r.cd_kg_per_m, r.k_n_per_m, mask, levels=[0.5], colors="#FF8C00", linewidths=1.6
            )
        ax.plot(
            r.cd_kg_per_m,
            _valley_line(ev.valley_k_n_per_m[command], r.sim_log_step),
            color="white",
            ls="--",
            lw=1.6,
        )
        cells = ", ".join(f"{x.label} {x.mean_mm:.1f}±{x.se_mm:.1f}" for x in r.cells[command])
        ax.set_title(f"{short(command)}\nmeasured mean ± s.e. [mm]: {cells}", fontsize=10)
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
    for command in COMMANDS:
        _shade(ax, r, command)
    p, d = COMMANDS
    k_at, cd_at = ev.closest_se_at
    if math.isfinite(k_at):
        ax.plot(cd_at, k_at, marker="*", ms=14, color="black", ls="none", clip_on=False, zorder=5)
    gap = ev.curve_gap_cd_kg_per_m
    if math.isfinite(gap):
        j = int(np.argmin(np.abs(r.cd_kg_per_m - gap)))
        ax.plot(
            [gap, gap],
            [ev.valley_k_n_per_m[p][j], ev.valley_k_n_per_m[d][j]],
            color="black",
            ls=":",
            lw=2.0,
        )
    frac = float(r.boot["intersect"].mean())
    med, lo, hi = common.interval(r.boot["closest_se"].to_numpy())
    mm = common.interval(r.boot["closest_mm"].to_numpy())
    answer = "intersect" if ev.intersect else "do not intersect"
    ax.text(
        0.03,
        0.03,
        f"valleys {answer} (data)\n"
        f"intersect in {frac:.0%} of {n_boot} resamples\n"
        f"closest approach {med:.2g} s.e. [{lo:.2g}, {hi:.2g}]\n"
        f"= {mm[0]:.2g} mm [{mm[1]:.2g}, {mm[2]:.2g}] (90%)",
        transform=ax.transAxes,
        fontsize=8.5,
        va="bottom",
        bbox={"facecolor": "white", "alpha": 0.9, "edgecolor": "0.6"},
    )
    handles = _legend_handles(r)
    handles += [
        Line2D([], [], marker="*", ms=10, color="black", ls="none", label="closest approach"),
        Line2D([], [], color="black", ls=":", lw=2.0, label="valley curves closest"),
    ]
    ax.legend(handles=handles, loc="upper right", fontsize=8, framealpha=0.85)
    ax.set_title("overlay of the two valleys", fontsize=10)
    ax.set_xlabel(r"drag coefficient $c_d$ [kg/m]")
    ax.grid(alpha=0.3)
    ax.set_xlim(*_cd_limits(r))
    ax.set_ylim(r.k_n_per_m[0], r.k_n_per_m[-1])
    fig.suptitle(
        ctx.title(
            f"Depth + drag law F = k z + c_d z'² at φ = {r.phi:g} "
            f"(φ − φc = {r.phi - ctx.phi_c:+.3f}): misfit maps and least-misfit valleys"
        ),
        fontsize=11,
    )
    return fig


def plot_all_phi(ctx: common.Context, results: Sequence[PhiResult]) -> Figure:
    """Valley overlays at every volume fraction (top) and the answer against phi (bottom)."""
    n = len(results)
    fig = Figure(figsize=(max(8.0, 3.3 * n), 7.6), layout="constrained")
    top, bottom = fig.subfigures(2, 1, height_ratios=[1.15, 1.0])
    axes = np.atleast_1d(top.subplots(1, n, sharey=True))
    for ax, r in zip(axes, results, strict=True):
        for command in COMMANDS:
            _shade(ax, r, command)
        frac = float(r.boot["intersect"].mean())
        ax.set_title(
            f"φ = {r.phi:g} (φ − φc = {r.phi - ctx.phi_c:+.3f})\nintersect in {frac:.0%}",
            fontsize=9,
        )
        ax.set_xlabel(r"$c_d$ [kg/m]")
        ax.set_xlim(*_cd_limits(r))
        ax.grid(alpha=0.3)
    axes[0].set_yscale("log")
    axes[0].set_ylabel(r"$k$ [N/m]")
    # Zoom on the valleys (and acceptable regions), the same k range in every panel.
    shown = [r.observed.valley_k_n_per_m[c] for r in results for c in COMMANDS]
    shown += [r.k_n_per_m[r.observed.acceptable[c].any(axis=1)] for r in results for c in COMMANDS]
    shown_k = np.concatenate(shown)
    shown_k = shown_k[np.isfinite(shown_k)]
    k_lo = min(r.k_n_per_m[0] for r in results)
    k_hi = max(r.k_n_per_m[-1] for r in results)
    if shown_k.size:
        k_lo, k_hi = max(k_lo, shown_k.min() / 1.6), min(k_hi, shown_k.max() * 1.6)
    axes[0].set_ylim(k_lo, k_hi)
    handles = _legend_handles()
    top.legend(handles=handles, loc="outside lower center", ncols=4, fontsize=8, frameon=False)

    ax1, ax2 = bottom.subplots(1, 2)
    x = np.array([r.phi - ctx.phi_c for r in results])
    for ax, key, unit, thr in (
        (ax1, "closest_se", "standard errors", TOLERANCE_SE),
        (ax2, "closest_mm", "mm", None),
    ):
        iv = np.array([common.interval(r.boot[key].to_numpy()) for r in results])
        obs = np.array([getattr(r.observed, key) for r in results])
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
    fig.suptitle(
        ctx.title("Do the preload and delayed stutter preload valleys intersect at every φ?"),
        fontsize=11,
    )
    return fig


# ----------------------------------------------------------------------------------------
def grid_table(r: PhiResult) -> pd.DataFrame:
    """One row per simulated grid point: heights per cell, misfits and acceptability."""
    kk, cc = np.meshgrid(r.k_sim_n_per_m, r.cd_kg_per_m, indexing="ij")
    out = {"phi": r.phi, "k_N_per_m": kk.ravel(), "c_d_kg_per_m": cc.ravel()}
    means, ses = r.means(), r.ses()
    for c in COMMANDS:
        res = r.sim_mm[c] - means[c][:, None, None]
        for i, cell in enumerate(r.cells[c]):
            tag = cell.label.replace(" ", "")
            out[f"height_mm_{c}_{tag}"] = r.sim_mm[c][i].ravel()
        out[f"misfit_mm_{c}"] = np.sqrt(np.mean(res * res, axis=0)).ravel()
        with np.errstate(divide="ignore", invalid="ignore"):
            mse = np.max(np.abs(res) / ses[c][:, None, None], axis=0)
        out[f"max_residual_se_{c}"] = mse.ravel()
        out[f"acceptable_{c}"] = (mse <= TOLERANCE_SE).ravel()
    return pd.DataFrame(out)


def valley_table(results: Sequence[PhiResult]) -> pd.DataFrame:
    """Valley k(c_d) and the acceptable k range per phi, command and c_d."""
    rows = []
    for r in results:
        ev = r.observed
        for c in COMMANDS:
            acc = ev.acceptable[c]
            for j, cd in enumerate(r.cd_kg_per_m):
                ks = r.k_n_per_m[acc[:, j]]
                rows.append(
                    {
                        "phi": r.phi,
                        "command": c,
                        "c_d_kg_per_m": cd,
                        "k_valley_N_per_m": ev.valley_k_n_per_m[c][j],
                        "misfit_valley_mm": ev.valley_mm[c][j],
                        "k_acceptable_min_N_per_m": ks.min() if ks.size else np.nan,
                        "k_acceptable_max_N_per_m": ks.max() if ks.size else np.nan,
                    }
                )
    return pd.DataFrame(rows)


def cell_table(results: Sequence[PhiResult]) -> pd.DataFrame:
    """The measured cells used."""
    rows = []
    for r in results:
        for c in COMMANDS:
            for x in r.cells[c]:
                rows.append(
                    {
                        "phi": r.phi,
                        "command": c,
                        **x.settings,
                        "n": x.n,
                        "mean_mm": x.mean_mm,
                        "sd_mm": x.sd_mm,
                        "se_mm": x.se_mm,
                    }
                )
    return pd.DataFrame(rows)


def _fmt(iv: tuple[float, float, float], digits: int = 2) -> str:
    return common.fmt_triple(*iv, fmt=f".{digits}g")


def _acceptable_extent(r: PhiResult, command: str) -> str:
    acc = r.observed.acceptable[command]
    if not acc.any():
        return "none"
    ik, ic = np.nonzero(acc)
    return (
        f"k {r.k_n_per_m[ik].min():.4g} – {r.k_n_per_m[ik].max():.4g} N/m, "
        f"c_d {r.cd_kg_per_m[ic].min():.3g} – {r.cd_kg_per_m[ic].max():.3g} kg/m "
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


def analyse(ctx: common.Context) -> tuple[str, dict]:
    """Maps at the chosen phi, the answer at every phi, figures, tables and the summary."""
    args = ctx.args
    k_min, k_max = (float(v) for v in args.k_range)
    if not (0 < k_min < k_max) or not args.cd_max > 0:
        raise InputError("--k-range needs 0 < K_MIN < K_MAX and --cd-max must be > 0")
    n_boot = int(args.n_boot) if args.n_boot is not None else (100 if ctx.fast else 500)
    if n_boot < 1:
        raise InputError("--n-boot must be >= 1")
    grid = (
        GridSpec(16, 12, 8, k_min, k_max, float(args.cd_max))
        if ctx.fast
        else GridSpec(100, 81, 8, k_min, k_max, float(args.cd_max))
    )
    phis = ctx.phis
    phi_main = float(phis[0]) if args.phi is None else float(args.phi)
    if not np.isclose(phis, phi_main).any():
        raise InputError(
            f"--phi {phi_main:g} is not in the data (present: {', '.join(f'{p:g}' for p in phis)})"
        )
    phi_main = float(phis[np.isclose(phis, phi_main)][0])

    results: list[PhiResult] = []
    notes: list[str] = []
    for i, phi in enumerate(phis):
        r = analyse_phi(ctx, float(phi), grid, n_boot, 100 + i, notes)
        if r is not None:
            results.append(r)
    for r in results:
        cds = [r.observed.closest_se_at[1], r.observed.closest_mm_at[1]]
        if any(math.isclose(x, r.cd_kg_per_m[-1]) for x in cds):
            notes.append(
                f"φ = {r.phi:g}: the closest approach lies on the largest c_d "
                f"({r.cd_kg_per_m[-1]:g} kg/m); a wider range (--cd-max) might come closer"
            )
    main_r = next((r for r in results if r.phi == phi_main), None)
    if main_r is None:
        raise InputError(
            f"φ = {phi_main:g} has no usable preload and delayed stutter preload cells "
            "(at least 2 trials each)"
        )

    ctx.save_figure(plot_maps(ctx, main_r, n_boot), "misfit_maps")
    ctx.save_figure(plot_all_phi(ctx, results), "valleys_all_phi")
    ctx.save_table(grid_table(main_r), "misfit_grid")
    ctx.save_table(valley_table(results), "valleys")
    ctx.save_table(cell_table(results), "cells")

    p, d = COMMANDS
    ev = main_r.observed
    boot = main_r.boot
    frac = float(boot["intersect"].mean())
    c_se = common.interval(boot["closest_se"].to_numpy())
    c_mm = common.interval(boot["closest_mm"].to_numpy())
    gap = common.interval(10 ** boot["curve_gap_dex"].to_numpy())
    crossings = curve_crossings(ev, main_r.cd_kg_per_m, main_r.sim_log_step)
    j = int(np.argmin(np.abs(main_r.cd_kg_per_m - ev.curve_gap_cd_kg_per_m)))
    kp_gap, kd_gap = ev.valley_k_n_per_m[p][j], ev.valley_k_n_per_m[d][j]

    per_phi_rows, per_phi_numbers = [], []
    for r in results:
        iv_se = common.interval(r.boot["closest_se"].to_numpy())
        iv_mm = common.interval(r.boot["closest_mm"].to_numpy())
        f = float(r.boot["intersect"].mean())
        cross = curve_crossings(r.observed, r.cd_kg_per_m, r.sim_log_step)
        per_phi_rows.append(
            {
                "φ": f"{r.phi:g}",
                "φ − φc": f"{r.phi - ctx.phi_c:+.3f}",
                "valleys intersect (fraction of resamples)": f"{f:.0%}"
                + (" (data: yes)" if r.observed.intersect else " (data: no)"),
                "closest approach [mm]": _fmt(iv_mm),
                "closest approach [s.e.]": _fmt(iv_se),
                f"{short(p)} alone acceptable": f"{r.boot[f'acceptable_{p}'].mean():.0%}",
                f"{short(d)} alone acceptable": f"{r.boot[f'acceptable_{d}'].mean():.0%}",
                "valley floors cross at c_d [kg/m]": ", ".join(f"{x:.3g}" for x in cross) or "no",
            }
        )
        per_phi_numbers.append(
            {
                "phi": r.phi,
                "intersect_observed": r.observed.intersect,
                "intersect_fraction": f,
                "closest_approach_se": list(iv_se),
                "closest_approach_mm": list(iv_mm),
                "closest_approach_se_observed": r.observed.closest_se,
                "closest_approach_mm_observed": r.observed.closest_mm,
                "acceptable_fraction": {
                    c: float(r.boot[f"acceptable_{c}"].mean()) for c in COMMANDS
                },
                "valley_crossings_c_d_kg_per_m": cross,
                "k_range_N_per_m": [float(r.k_n_per_m[0]), float(r.k_n_per_m[-1])],
            }
        )

    verdict = "**intersect**" if ev.intersect else "**do not intersect**"
    if frac >= 0.95:
        robust = "in nearly every resample"
    elif frac <= 0.05:
        robust = "in almost no resample"
    else:
        robust = "in only part of the resamples, so the answer is uncertain"
    body = [
        f"At φ = {main_r.phi:g} (φ − φc = {main_r.phi - ctx.phi_c:+.3f}) the least-misfit "
        f"valleys of the depth + drag law for the preload and the delayed stutter preload "
        f"jump {verdict}: a (k, c_d) within {TOLERANCE_SE:g} standard errors of every cell "
        f"mean of both commands exists in {frac:.0%} of {n_boot} bootstrap resamples "
        f"({robust}); the closest approach is {_fmt(c_se)} standard errors "
        f"({_fmt(c_mm)} mm, median [90% interval]).",
        "",
    ]
    alone = [c for c in COMMANDS if not ev.acceptable[c].any()]
    if alone:
        caveat = (
            f"Caveat: {' and '.join(short(c) for c in alone)} alone has no acceptable point "
            "(its frequency cells are not fitted together by any (k, c_d) on the grid), so "
            "part of the answer is that one valley is missing rather than that two valleys miss "
            "each other."
        )
        if main_r.by_cell:
            per = "; ".join(
                f"{b['cell']}: intersect in {b['intersect_fraction']:.0%}, closest "
                f"{_fmt(b['closest_approach_se'])} standard errors"
                for b in main_r.by_cell
            )
            caveat += f" Taking each frequency cell alone: {per}."
        body += [caveat, ""]
    body += [
        "![misfit maps](misfit_maps.png)",
        "",
        "## Definitions",
        "",
        f"- **Grid**: k log-spaced {main_r.k_n_per_m[0]:.4g} – {main_r.k_n_per_m[-1]:.4g} N/m "
        f"({main_r.k_sim_n_per_m.size} simulated points, linearly interpolated in log k to "
        f"{main_r.k_n_per_m.size}), c_d {main_r.cd_kg_per_m[0]:g} – "
        f"{main_r.cd_kg_per_m[-1]:g} kg/m ({main_r.cd_kg_per_m.size} points); other terms off, "
        "default r_unload.",
        "- **Misfit** [mm]: RMS over the command's frequency cells of |simulated − measured "
        "cell mean|. **Valley**: for each c_d the k of least misfit.",
        f"- **Acceptable**: |simulated − mean| ≤ {TOLERANCE_SE:g} × standard error of the cell "
        "mean in every frequency cell of the command. **Valleys intersect**: some grid point "
        "is acceptable for both commands.",
        "- **Closest approach**: min over the grid of the larger of the two commands' largest "
        "normalised residuals |sim − mean| / s.e. (intersect ⇔ ≤ "
        f"{TOLERANCE_SE:g}); in mm: min over the grid of the larger of the two RMS misfits.",
        f"- **Uncertainty**: {n_boot} bootstrap resamples of the trials of every cell (seed "
        f"{ctx.seed}); the tolerance stays at the observed standard errors.",
        "",
        f"## φ = {main_r.phi:g}",
        "",
        "Measured cells:",
        "",
        common.markdown_table(
            pd.DataFrame(
                [
                    {
                        "command": short(c),
                        "cell": x.label,
                        "n": x.n,
                        "mean [mm]": x.mean_mm,
                        "s.e. [mm]": x.se_mm,
                    }
                    for c in COMMANDS
                    for x in main_r.cells[c]
                ]
            ),
            ".3g",
        ),
        "",
    ]
    per_command = []
    for c in COMMANDS:
        at = _argmin_2d(ev.rms_mm[c])
        per_command.append(
            {
                "command": short(c),
                "least misfit [mm]": ev.rms_mm[c][at] if at else math.nan,
                "at k [N/m]": main_r.k_n_per_m[at[0]] if at else math.nan,
                "at c_d [kg/m]": main_r.cd_kg_per_m[at[1]] if at else math.nan,
                "acceptable region (data)": _acceptable_extent(main_r, c),
                "resamples with an acceptable point": f"{boot[f'acceptable_{c}'].mean():.0%}",
            }
        )
    body += [common.markdown_table(pd.DataFrame(per_command), ".4g"), ""]
    k_at, cd_at = ev.closest_se_at
    body += [
        f"Closest approach on the data: {ev.closest_se:.3g} s.e. at k = {k_at:.4g} N/m, "
        f"c_d = {cd_at:.3g} kg/m; {ev.closest_mm:.3g} mm at k = {ev.closest_mm_at[0]:.4g} N/m, "
        f"c_d = {ev.closest_mm_at[1]:.3g} kg/m.",
        "",
    ]
    if crossings:
        body.append(
            "The least-misfit curves k(c_d) cross at c_d ≈ "
            + ", ".join(f"{x:.3g}" for x in crossings)
            + " kg/m (crossing of the valley floors; the misfits there need not be small)."
        )
    else:
        body.append("The least-misfit curves k(c_d) do not cross on the grid.")
    body += [
        f"They come closest at c_d = {ev.curve_gap_cd_kg_per_m:.3g} kg/m: k = {kp_gap:.4g} N/m "
        f"({short(p)}) vs {kd_gap:.4g} N/m ({short(d)}), a factor "
        f"{10**ev.curve_gap_dex:.3g} apart (bootstrap {_fmt(gap, 3)}).",
        "",
    ]
    if main_r.by_cell:
        body += [
            "Each frequency cell alone:",
            "",
            common.markdown_table(
                pd.DataFrame(
                    [
                        {
                            "cell": b["cell"],
                            "valleys intersect (data)": "yes" if b["intersect_observed"] else "no",
                            "intersect (fraction of resamples)": f"{b['intersect_fraction']:.0%}",
                            "closest approach [s.e.]": _fmt(b["closest_approach_se"]),
                            **{
                                f"{short(c)} alone acceptable (data)": "yes"
                                if b[f"acceptable_{c}_observed"]
                                else "no"
                                for c in COMMANDS
                            },
                        }
                        for b in main_r.by_cell
                    ]
                )
            ),
            "",
        ]
    body += [
        "## Every volume fraction",
        "",
        "The thesis: the valleys do not intersect at low φ, while the law is fine at high φ.",
        "",
        common.markdown_table(pd.DataFrame(per_phi_rows)),
        "",
        "![valleys at every phi](valleys_all_phi.png)",
        "",
    ]
    if notes:
        body += ["## Notes", "", *[f"- {n}" for n in dict.fromkeys(notes)], ""]

    numbers = {
        "phi": main_r.phi,
        "tolerance_se": TOLERANCE_SE,
        "n_boot": n_boot,
        "intersect_observed": ev.intersect,
        "intersect_fraction": frac,
        "closest_approach_se": list(c_se),
        "closest_approach_mm": list(c_mm),
        "closest_approach_se_observed": ev.closest_se,
        "closest_approach_mm_observed": ev.closest_mm,
        "closest_point_se": {"k_N_per_m": k_at, "c_d_kg_per_m": cd_at},
        "closest_point_mm": {
            "k_N_per_m": ev.closest_mm_at[0],
            "c_d_kg_per_m": ev.closest_mm_at[1],
        },
        "acceptable_fraction": {c: float(boot[f"acceptable_{c}"].mean()) for c in COMMANDS},
        "valley_curves": {
            "crossings_c_d_kg_per_m": crossings,
            "closest_c_d_kg_per_m": ev.curve_gap_cd_kg_per_m,
            "closest_k_N_per_m": {p: kp_gap, d: kd_gap},
            "closest_factor": 10**ev.curve_gap_dex,
            "closest_factor_boot": list(gap),
        },
        "by_cell": main_r.by_cell,
        "grid": {
            "k_N_per_m": [float(main_r.k_n_per_m[0]), float(main_r.k_n_per_m[-1])],
            "n_k_simulated": int(main_r.k_sim_n_per_m.size),
            "refine": grid.refine,
            "c_d_kg_per_m": [0.0, grid.cd_max_kg_per_m],
            "n_cd": grid.n_cd,
        },
        "per_phi": per_phi_numbers,
        "notes": list(dict.fromkeys(notes)),
    }
    return "\n".join(body), numbers


def main(argv: list[str] | None = None) -> int:
    """Run the analysis (see the module docstring); returns the exit code."""
    return common.main(NAME, __doc__, analyse, argv, add_arguments)


if __name__ == "__main__":
    sys.exit(main())
