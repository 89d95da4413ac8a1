"""Misfit maps of the depth + drag law over a (k, c_d) grid, for two commands at once.

The founding thesis hand-tuned ``F = k z + c_d z'^2`` and asked whether the valleys of
least misfit of two jump commands (the preload and the delayed stutter preload) intersect
in the ``(k, c_d)`` plane: is there one ``(k, c_d)`` that fits both? :func:`misfit_map`
answers it at one volume fraction, with a bootstrap uncertainty.

Definitions
-----------
cell
    The trials of one command at one volume fraction and one actuation setting (frequency,
    amplitude and, for the delayed stutter preload, settle periods); cell mean ``m`` and
    standard error ``se = sd / sqrt(n)`` of its jump heights [mm]. Cells with fewer than 2
    trials have no standard error and are left out.
grid
    ``k`` [N/m] log-spaced, ``c_d`` [kg/m] linear from 0; every other force term off and
    the bed's default ``r_unload``. Each cell is simulated once with all grid points
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
    command's cells (its largest normalised residual ``max |sim - m| / se <= 2``).
valleys intersect
    Some grid point is acceptable for both commands at once.
closest approach
    In standard errors: the minimum over the grid of ``max`` over both commands of the
    largest normalised residual (the valleys intersect exactly when it is <= 2). In mm: the
    minimum over the grid of the larger of the two commands' misfits.
uncertainty
    Seeded bootstrap: the trials of each cell are resampled with replacement and everything
    above is recomputed from the resampled cell means; the simulated grid does not change.
    The tolerance stays 2 x the observed standard error (recomputing it from resamples with
    repeated trials would shrink it towards zero).

Examples
--------
>>> import numpy as np
>>> import granbayes as gb
>>> from granbayes.analysis.maps import GridSpec, misfit_map
>>> exp = gb.load_experiment("my-lab")  # doctest: +SKIP
>>> jumps = gb.load_jumps("my-lab", exp)  # doctest: +SKIP
>>> grid = GridSpec(40, 21, 8, 300.0, 30000.0, 100.0)
>>> m = misfit_map(exp, jumps, 0.592, grid, 200, np.random.default_rng(0))  # doctest: +SKIP
>>> m.observed.intersect, m.boot["intersect"].mean()  # doctest: +SKIP

Length: about 780 lines for one job (a map, its valleys and their intersection, computed
in one simulator call); most of it is the valley geometry and its documentation.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field

import numpy as np
import pandas as pd

from .._experiment import Experiment
from .._simulator import simulate
from ..commands import COMMANDS as COMMAND_REGISTRY
from ..stats import interval

__all__ = [
    "CD_MAX_KG_PER_M",
    "COMMANDS",
    "K_RANGE_N_PER_M",
    "TOLERANCE_SE",
    "argmin_2d",
    "Cell",
    "cell_table",
    "cells_at",
    "curve_crossings",
    "evaluate",
    "Evaluation",
    "grid_table",
    "GridSpec",
    "misfit_map",
    "MisfitMap",
    "refine_k",
    "refine_log_k",
    "short",
    "valley_line",
    "valley_table",
]

#: The two commands whose valleys are compared by default.
COMMANDS: tuple[str, str] = ("preload", "delayed_stutter_preload")
#: Command settings that define a cell of each command (besides phi).
SETTINGS: dict[str, tuple[str, ...]] = {c.name: c.settings for c in COMMAND_REGISTRY.values()}
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
    """Command name for labels (``delayed stutter preload``).

    Parameters
    ----------
    command : str
        A command name (``delayed_stutter_preload``).
    """
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
        ``freq_hz`` [Hz], ``amplitude_mm`` [mm] (and ``settle_periods`` or ``delay_ms``).
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
    """The cells (with at least 2 trials) of ``command`` at ``phi``, and notes on dropped ones.

    Parameters
    ----------
    table : pandas.DataFrame
        Validated jumps (``phi``, ``command``, the settings, ``height_mm``).
    phi : float
        Volume fraction [-].
    command : str

    Returns
    -------
    cells : list of Cell
        Labelled by frequency, or by every setting where frequencies repeat.
    notes : list of str
        One line per cell left out.
    """
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
    def k_n_per_m(self) -> np.ndarray:
        """The initial simulated k grid [N/m]."""
        lo, hi = math.log(self.k_min_n_per_m), math.log(self.k_max_n_per_m)
        return np.exp(np.linspace(lo, hi, self.n_k))

    @property
    def cd_kg_per_m(self) -> np.ndarray:
        """The c_d grid [kg/m]."""
        return np.linspace(0.0, self.cd_max_kg_per_m, self.n_cd)


def refine_log_k(heights_mm: np.ndarray, factor: int) -> np.ndarray:
    """Linear interpolation in log k of ``(n_k, n_cd)`` heights to ``(n_k - 1) * factor + 1``.

    NaN (failed simulations) propagates to every interpolated point next to it.

    Parameters
    ----------
    heights_mm : ndarray, shape (n_k, n_cd)
        Simulated heights [mm].
    factor : int
        Refinement factor.
    """
    if factor <= 1:
        return heights_mm.copy()
    lo, hi = heights_mm[:-1], heights_mm[1:]
    t = (np.arange(factor) / factor)[None, :, None]
    inner = (1.0 - t) * lo[:, None, :] + t * hi[:, None, :]
    n_cd = heights_mm.shape[1]
    return np.concatenate([inner.reshape(-1, n_cd), heights_mm[-1:]], axis=0)


def refine_k(k_n_per_m: np.ndarray, factor: int) -> np.ndarray:
    """The refined k grid [N/m] matching :func:`refine_log_k`.

    Parameters
    ----------
    k_n_per_m : ndarray
        Simulated k grid [N/m].
    factor : int
        Refinement factor.
    """
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
        Smallest ``|log10(k_valley(second) / k_valley(first))|`` over c_d.
    curve_gap_cd_kg_per_m : float
        The c_d [kg/m] where the valley curves come closest.
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


def argmin_2d(values: np.ndarray) -> tuple[int, int] | None:
    """Index of the smallest finite value of a 2-d array (None if there is none).

    Parameters
    ----------
    values : numpy.ndarray
        A 2-d array (NaN and infinite values are ignored).
    """
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
    commands: tuple[str, str] = COMMANDS,
) -> Evaluation:
    """Misfit maps, valleys and closest approach of two commands.

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
    commands : tuple of two str
        The commands compared (keys of the mappings).

    Returns
    -------
    Evaluation
    """
    rms, mse, ok, vk, vmm = {}, {}, {}, {}, {}
    for command in commands:
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
        at = argmin_2d(both)
        if at is None:
            return math.nan, (math.nan, math.nan)
        return float(both[at]), (float(k_n_per_m[at[0]]), float(cd_kg_per_m[at[1]]))

    p, d = commands
    c_se, at_se = closest(mse[p], mse[d])
    c_mm, at_mm = closest(rms[p], rms[d])
    gap = np.abs(np.log10(vk[d]) - np.log10(vk[p]))
    if np.isfinite(gap).any():
        j = int(np.nanargmin(gap))
        gap_dex, gap_cd = float(gap[j]), float(cd_kg_per_m[j])
    else:
        gap_dex, gap_cd = math.nan, math.nan
    return Evaluation(rms, mse, ok, vk, vmm, c_se, c_mm, at_se, at_mm, gap_dex, gap_cd)


def jump_log(sim_log_step: float) -> float:
    """A valley curve jumping by more than this in ln k switches branch (not a crossing)."""
    return max(2.0 * sim_log_step, math.log(1.25))


def valley_line(k_n_per_m: np.ndarray, sim_log_step: float) -> np.ndarray:
    """The valley curve k(c_d) [N/m] with NaN where it jumps between branches (to plot).

    Parameters
    ----------
    k_n_per_m : ndarray
        Valley k per c_d [N/m].
    sim_log_step : float
        Step of the simulated log-k grid.
    """
    out = np.asarray(k_n_per_m, float).copy()
    jumps = np.abs(np.diff(np.log(out))) > jump_log(sim_log_step)
    out[1:][jumps] = np.nan
    return out


def curve_crossings(
    ev: Evaluation,
    cd_kg_per_m: np.ndarray,
    sim_log_step: float,
    commands: tuple[str, str] = COMMANDS,
) -> list[float]:
    """c_d [kg/m] where the two valley curves k(c_d) cross (continuous stretches only).

    A sign change of ``log k_second - log k_first`` between neighbouring c_d counts only if
    neither curve jumps there by more than :func:`jump_log` (a jump is a switch between two
    branches of a valley, not a crossing).

    Parameters
    ----------
    ev : Evaluation
        A grid evaluation.
    cd_kg_per_m : ndarray
        The c_d grid [kg/m].
    sim_log_step : float
        Step of the simulated log-k grid.
    commands : tuple of str
        The two commands whose valleys are compared.
    """
    p, d = commands
    lp, ld = np.log(ev.valley_k_n_per_m[p]), np.log(ev.valley_k_n_per_m[d])
    diff = ld - lp
    out: list[float] = []
    for j in range(len(cd_kg_per_m) - 1):
        a, b = diff[j], diff[j + 1]
        if not (np.isfinite(a) and np.isfinite(b)) or not (a * b < 0 or a == 0):
            continue
        if all(abs(x[j + 1] - x[j]) <= jump_log(sim_log_step) for x in (lp, ld)):
            t = a / (a - b) if a != b else 0.0
            x = float(cd_kg_per_m[j] + t * (cd_kg_per_m[j + 1] - cd_kg_per_m[j]))
            step = cd_kg_per_m[j + 1] - cd_kg_per_m[j]
            if not out or x - out[-1] > 1.5 * step:  # touching over a stretch: report once
                out.append(x)
    return out


# ----------------------------------------------------------------------------------------
@dataclass
class MisfitMap:
    """Everything computed at one volume fraction by :func:`misfit_map`.

    Attributes
    ----------
    phi : float
        Volume fraction [-].
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
    commands : tuple of two str
        The commands compared.
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
    commands: tuple[str, str] = COMMANDS
    by_cell: list[dict] = field(default_factory=list)

    @property
    def sim_log_step(self) -> float:
        """Step of the simulated k grid in ln k."""
        return math.log(self.k_sim_n_per_m[1] / self.k_sim_n_per_m[0])

    def means(self) -> dict[str, np.ndarray]:
        """Observed cell means [mm] per command."""
        return {c: np.array([x.mean_mm for x in self.cells[c]]) for c in self.commands}

    def ses(self) -> dict[str, np.ndarray]:
        """Observed standard errors [mm] per command."""
        return {c: np.array([x.se_mm for x in self.cells[c]]) for c in self.commands}

    def crossings(self) -> list[float]:
        """c_d [kg/m] where the observed valley curves cross (:func:`curve_crossings`)."""
        return curve_crossings(self.observed, self.cd_kg_per_m, self.sim_log_step, self.commands)

    def summary(self) -> dict:
        """The answer at this phi, JSON-ready.

        Returns
        -------
        dict
            ``phi``; ``intersect_observed`` and ``intersect_fraction`` (of the bootstrap
            resamples); the closest approach in standard errors and in mm (bootstrap
            (median, lo, hi) and observed); per command the fraction of resamples with an
            acceptable point; the c_d [kg/m] where the valley curves cross; the k range
            [N/m] of the (extended) grid.
        """
        boot = self.boot
        return {
            "phi": self.phi,
            "intersect_observed": self.observed.intersect,
            "intersect_fraction": float(boot["intersect"].mean()),
            "closest_approach_se": list(interval(boot["closest_se"].to_numpy())),
            "closest_approach_mm": list(interval(boot["closest_mm"].to_numpy())),
            "closest_approach_se_observed": self.observed.closest_se,
            "closest_approach_mm_observed": self.observed.closest_mm,
            "acceptable_fraction": {
                c: float(boot[f"acceptable_{c}"].mean()) for c in self.commands
            },
            "valley_crossings_c_d_kg_per_m": self.crossings(),
            "k_range_N_per_m": [float(self.k_n_per_m[0]), float(self.k_n_per_m[-1])],
        }


def simulate_cells(
    experiment: Experiment, phi: float, cells: Sequence[Cell], k: np.ndarray, cd: np.ndarray
) -> np.ndarray:
    """Heights [mm] of each cell's command on the grid ``k x cd``: shape (n_cells, n_k, n_cd).

    One batched simulate call per cell (its settings applied to ``experiment``); failed
    jumps are NaN. ``k`` in N/m, ``cd`` in kg/m, ``phi`` [-].
    """
    kk, cc = np.meshgrid(k, cd, indexing="ij")
    out = np.empty((len(cells), k.size, cd.size))
    for i, cell in enumerate(cells):
        res = simulate(
            cell.command,
            phi,
            {"k": kk.ravel(), "c_d": cc.ravel()},
            experiment=experiment.replace(**cell.settings),
        )
        out[i] = np.where(res.ok, res.height_mm, np.nan).reshape(kk.shape)
    return out


def _refined(sim: Mapping[str, np.ndarray], refine: int) -> dict[str, np.ndarray]:
    return {c: np.stack([refine_log_k(h, refine) for h in v]) for c, v in sim.items()}


def _edges_hit(sim_mm, means, k, cd, refine, commands) -> tuple[bool, bool]:
    """Whether the observed valley of either command reaches the low / high k edge."""
    ones = {c: np.ones_like(means[c]) for c in commands}
    k_fine = refine_k(k, refine)
    ev = evaluate(_refined(sim_mm, refine), means, ones, k_fine, cd, commands)
    valleys = np.concatenate([ev.valley_k_n_per_m[c] for c in commands])
    return bool(np.any(valleys <= k_fine[0])), bool(np.any(valleys >= k_fine[-1]))


def misfit_map(
    experiment: Experiment,
    table: pd.DataFrame,
    phi: float,
    grid: GridSpec,
    n_boot: int,
    rng: np.random.Generator,
    notes: list[str] | None = None,
    commands: tuple[str, str] = COMMANDS,
) -> MisfitMap | None:
    """Simulate, evaluate and bootstrap the misfit maps of two commands at one phi.

    Parameters
    ----------
    experiment : Experiment
        Robot and default settings (each cell's own settings are applied).
    table : pandas.DataFrame
        Validated jumps.
    phi : float
        Volume fraction [-].
    grid : GridSpec
    n_boot : int
        Bootstrap resamples of the trials of every cell.
    rng : numpy.random.Generator
        Draws the bootstrap resamples.
    notes : list of str, optional
        Messages for a summary are appended here (dropped cells, grid extensions, failed
        simulations).
    commands : tuple of two str
        The commands compared (default preload and delayed stutter preload).

    Returns
    -------
    MisfitMap or None
        None if either command has no usable cell at ``phi``.
    """
    notes = [] if notes is None else notes
    cells: dict[str, list[Cell]] = {}
    for command in commands:
        cells[command], dropped = cells_at(table, phi, command)
        notes += dropped
        if not cells[command]:
            notes.append(f"φ = {phi:g}: no usable {short(command)} cell; φ skipped")
            return None
    means = {c: np.array([x.mean_mm for x in cells[c]]) for c in commands}
    ses = {c: np.array([x.se_mm for x in cells[c]]) for c in commands}
    cd, step, k = grid.cd_kg_per_m, grid.log_step, grid.k_n_per_m
    sim = {c: simulate_cells(experiment, phi, cells[c], k, cd) for c in commands}
    n_ext = max(1, round(math.log(K_EXTEND_FACTOR) / step))
    for _ in range(K_EXTEND_MAX):
        low, high = _edges_hit(sim, means, k, cd, grid.refine, commands)
        low &= k[0] * math.exp(-n_ext * step) >= K_LIMITS_N_PER_M[0]
        high &= k[-1] * math.exp(n_ext * step) <= K_LIMITS_N_PER_M[1]
        if not (low or high):
            break
        for side, go in ((0, low), (1, high)):
            if not go:
                continue
            if side == 0:
                new = k[0] * np.exp(-step * np.arange(n_ext, 0, -1))
            else:
                new = k[-1] * np.exp(step * np.arange(1, n_ext + 1))
            for c in commands:
                more = simulate_cells(experiment, phi, cells[c], new, cd)
                sim[c] = np.concatenate([more, sim[c]] if side == 0 else [sim[c], more], axis=1)
            k = np.concatenate([new, k] if side == 0 else [k, new])
        notes.append(
            f"φ = {phi:g}: a valley reached the k edge; k grid extended to "
            f"{k[0]:.4g} – {k[-1]:.4g} N/m"
        )
    low, high = _edges_hit(sim, means, k, cd, grid.refine, commands)
    if low or high:
        notes.append(
            f"φ = {phi:g}: a valley still runs into the {'low' if low else 'high'} k edge "
            f"({k[0] if low else k[-1]:.4g} N/m): the law cannot reach the measured heights "
            "there"
        )
    for c in commands:
        n_bad = int(np.isnan(sim[c]).sum())
        if n_bad:
            notes.append(
                f"φ = {phi:g}, {short(c)}: {n_bad} of {sim[c].size} simulations failed "
                "(their neighbourhood is never acceptable)"
            )
    k_fine = refine_k(k, grid.refine)
    fine = _refined(sim, grid.refine)
    observed = evaluate(fine, means, ses, k_fine, cd, commands)

    # Bootstrap: resample the trials of every cell; the simulated grid does not change.
    boot_means = {
        c: np.stack(
            [x.heights_mm[rng.integers(0, x.n, size=(n_boot, x.n))].mean(axis=1) for x in cells[c]],
            axis=1,
        )
        for c in commands
    }
    rows = []
    for b in range(n_boot):
        ev = evaluate(fine, {c: boot_means[c][b] for c in commands}, ses, k_fine, cd, commands)
        rows.append(
            {
                "closest_se": ev.closest_se,
                "closest_mm": ev.closest_mm,
                "intersect": ev.intersect,
                **{f"acceptable_{c}": bool(ev.acceptable[c].any()) for c in commands},
                "curve_gap_dex": ev.curve_gap_dex,
            }
        )
    result = MisfitMap(phi, cells, k, cd, sim, k_fine, fine, observed, pd.DataFrame(rows), commands)
    # Each frequency (setting) alone, where both commands have it.
    first, second = commands
    labels = [x.label for x in cells[first] if x.label in {y.label for y in cells[second]}]
    if not any(len(cells[c]) > 1 for c in commands):
        return result
    for label in labels:
        idx = {c: [i for i, x in enumerate(cells[c]) if x.label == label] for c in commands}
        sub = {c: fine[c][idx[c]] for c in commands}
        sub_ses = {c: ses[c][idx[c]] for c in commands}
        obs = evaluate(sub, {c: means[c][idx[c]] for c in commands}, sub_ses, k_fine, cd, commands)
        hits, closest = [], []
        for b in range(n_boot):
            means_b = {c: boot_means[c][b, idx[c]] for c in commands}
            ev = evaluate(sub, means_b, sub_ses, k_fine, cd, commands)
            hits.append(ev.intersect)
            closest.append(ev.closest_se)
        result.by_cell.append(
            {
                "cell": label,
                "intersect_observed": obs.intersect,
                "intersect_fraction": float(np.mean(hits)),
                "closest_approach_se": interval(np.array(closest)),
                **{f"acceptable_{c}_observed": bool(obs.acceptable[c].any()) for c in commands},
            }
        )
    return result


# ----------------------------------------------------------------------------------------
def grid_table(m: MisfitMap) -> pd.DataFrame:
    """One row per simulated grid point: heights per cell, misfits and acceptability.

    Parameters
    ----------
    m : MisfitMap
        One volume fraction's map.
    """
    kk, cc = np.meshgrid(m.k_sim_n_per_m, m.cd_kg_per_m, indexing="ij")
    out = {"phi": m.phi, "k_N_per_m": kk.ravel(), "c_d_kg_per_m": cc.ravel()}
    means, ses = m.means(), m.ses()
    for c in m.commands:
        res = m.sim_mm[c] - means[c][:, None, None]
        for i, cell in enumerate(m.cells[c]):
            out[f"height_mm_{c}_{cell.label.replace(' ', '')}"] = m.sim_mm[c][i].ravel()
        out[f"misfit_mm_{c}"] = np.sqrt(np.mean(res * res, axis=0)).ravel()
        with np.errstate(divide="ignore", invalid="ignore"):
            mse = np.max(np.abs(res) / ses[c][:, None, None], axis=0)
        out[f"max_residual_se_{c}"] = mse.ravel()
        out[f"acceptable_{c}"] = (mse <= TOLERANCE_SE).ravel()
    return pd.DataFrame(out)


def valley_table(maps: Sequence[MisfitMap]) -> pd.DataFrame:
    """Valley k(c_d) [N/m] and the acceptable k range per phi, command and c_d [kg/m].

    Parameters
    ----------
    maps : sequence of MisfitMap
        The maps of every volume fraction.
    """
    rows = []
    for m in maps:
        ev = m.observed
        for c in m.commands:
            acc = ev.acceptable[c]
            for j, cd in enumerate(m.cd_kg_per_m):
                ks = m.k_n_per_m[acc[:, j]]
                rows.append(
                    {
                        "phi": m.phi,
                        "command": c,
                        "c_d_kg_per_m": cd,
                        "k_valley_N_per_m": ev.valley_k_n_per_m[c][j],
                        "misfit_valley_mm": ev.valley_mm[c][j],
                        "k_acceptable_min_N_per_m": ks.min() if ks.size else np.nan,
                        "k_acceptable_max_N_per_m": ks.max() if ks.size else np.nan,
                    }
                )
    return pd.DataFrame(rows)


def cell_table(maps: Sequence[MisfitMap]) -> pd.DataFrame:
    """The measured cells used: settings, count, mean, sd and standard error [mm].

    Parameters
    ----------
    maps : sequence of MisfitMap
        The maps of every volume fraction.
    """
    rows = [
        {
            "phi": m.phi,
            "command": c,
            **x.settings,
            "n": x.n,
            "mean_mm": x.mean_mm,
            "sd_mm": x.sd_mm,
            "se_mm": x.se_mm,
        }
        for m in maps
        for c in m.commands
        for x in m.cells[c]
    ]
    return pd.DataFrame(rows)
