"""Added-mass impulse and its duration against the added-mass coefficient kappa (Figs. 9, 10).

The thesis fitted, per jump command and volume fraction, a depth + drag + added-mass law
and plotted against the best kappa the duration of the interval of greatest added-mass
impulse (its Fig. 9) and the total added-mass impulse of the jump (its Fig. 10). Here the
uncertainty of the fit is carried through to both quantities and to their correlation
coefficients.

Fits. For every command separately, terms ``depth``, ``drag`` and ``added_mass`` are fitted
per volume fraction (all frequencies of that command together). A *cell* is one
(command, phi, actuation frequency) combination; each cell is its own point.

Added-mass force. The snowplough momentum flux of the equations of motion
(physics-model.md sections 2 and 3), ``F_am = -(dm_a/dt) v_foot >= 0`` [N], upward: the
momentum the foot hands to the grains it accretes into the jammed cone
``m_a = kappa rho_grain phi V(d)``. It acts only while the foot advances into fresh grains
and the cone is still growing; the cone is shed without impulse when the foot stops.

From a simulated trajectory (one row per accepted integrator step):

* total added-mass impulse ``J_total = integral F_am dt`` over the whole simulated jump
  [mN s], as the Stieltjes sum ``sum -(v_i + v_{i+1})/2 (m_a,{i+1} - m_a,i)`` over the steps
  inside an advancing episode on which the added mass grows (shedding the cone, where m_a
  drops, carries no impulse and is excluded);
* added-mass intervals: the advancing episodes (maximal runs of ``mode == "advancing"``,
  the contiguous runs with ``m_a > 0`` when kappa > 0), from the entry event to the exit
  event;
* the interval of greatest impulse and its duration [ms].

The sum is checked against the trapezoidal quadrature of
``kappa rho_grain phi V'(d) z'^2`` and against the same sum with the integrator's largest
step doubled.

Uncertainty. Per cell, joint posterior draws of all fitted force parameters at that phi
(the same draws for every frequency of a (command, phi) fit) are simulated; the best kappa
is the posterior median, and intervals are 90% equal-tailed. Correlations across cells are
given the thesis's way (Pearson r of the cells' medians) and propagated (r computed across
cells for every draw index, then summarised), with Spearman's rank correlation alongside.
J_total is proportional to kappa by construction, so the kinematic factor J_total / kappa
is reported too.

Outputs: ``cells.csv`` (per-cell medians and 90% intervals), ``duration_vs_kappa`` (Fig. 9),
``impulse_vs_kappa`` (Fig. 10) and ``example_trajectory`` (depth, m_a and F_am of one jump).
"""

from __future__ import annotations

import math
import sys
from dataclasses import dataclass

import numpy as np
import pandas as pd
from matplotlib.figure import Figure
from matplotlib.lines import Line2D
from scipy.stats import rankdata

import _common as common
import granbayes
from granbayes import COMMAND_NAMES, Experiment, InputError, Status
from granbayes.priors import default_priors

NAME = "added_mass_impulse"

#: Force law fitted per command and volume fraction (the thesis's law).
TERMS = ("depth", "drag", "added_mass")
#: Posterior draws simulated per (command, phi): production and fast mode.
N_DRAWS = 100
N_DRAWS_FAST = 8
#: Largest integrator step of the recorded trajectories [s] (granbayes default).
MAX_STEP_S = 5e-4
#: Jammed-cone geometry of physics-model.md section 3 (used only by the quadrature check).
CONE_TAN = math.tan(math.radians(60.0))
CONE_MU = 2.0
#: Width of the kappa prior of the fit (uniform): the yardstick of how well kappa is known.
KAPPA_PRIOR_WIDTH = default_priors()["kappa"].upper - default_priors()["kappa"].lower
#: Markers that tell the volume fractions apart (colour is the command).
PHI_MARKERS = ("v", "s", "o", "^", "D", "P", "X", "*", "h", "<", ">")
#: The quantities correlated with kappa: column stem -> (words, axis label).
QUANTITIES = {
    "duration_ms": ("duration of the interval of greatest impulse", "duration [ms]"),
    "impulse_mN_s": ("total added-mass impulse J_total", r"$J_\mathrm{total}$ [mN s]"),
    "impulse_per_kappa_mN_s": (
        "kinematic factor J_total / kappa",
        r"$J_\mathrm{total}/\kappa$ [mN s]",
    ),
}


# ----------------------------------------------------------------------------------------
@dataclass(frozen=True)
class Impulse:
    """Added-mass impulse of one simulated jump.

    Attributes
    ----------
    total_mN_s : float
        Total added-mass impulse over the jump [mN s].
    peak_mN_s : float
        Impulse of the interval of greatest impulse [mN s].
    duration_ms : float
        Duration of that interval [ms] (NaN if no interval carries impulse).
    start_ms : float
        Start of that interval [ms] after the command starts.
    n_intervals : int
        Number of advancing episodes.
    """

    total_mN_s: float
    peak_mN_s: float
    duration_ms: float
    start_ms: float
    n_intervals: int


FAILED = Impulse(math.nan, math.nan, math.nan, math.nan, 0)


def _episodes(mode: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Advancing episodes of a trajectory.

    Parameters
    ----------
    mode : ndarray of str, shape (n,)
        Regime per recorded row.

    Returns
    -------
    label : ndarray of int, shape (n,)
        Episode number per row (1, 2, ...), 0 where the foot is not advancing.
    first, stop : ndarray of int
        Per episode, the index of its first row and of the row that ends it (the exit
        event, the first non-advancing row; the last row if the trajectory ends advancing).
    """
    adv = mode == "advancing"
    start = adv & ~np.r_[False, adv[:-1]]
    label = np.cumsum(start) * adv
    first = np.flatnonzero(start)
    last = np.flatnonzero(adv & ~np.r_[adv[1:], False])
    stop = np.minimum(last + 1, len(mode) - 1)
    return label, first, stop


def added_mass_impulse(data: pd.DataFrame) -> Impulse:
    """Total added-mass impulse and the interval of greatest impulse of a trajectory.

    ``J = sum over steps inside an advancing episode with dm_a > 0 of -v_mean dm_a``
    (Stieltjes sum of ``F_am dt = -v_foot dm_a``; the cone is shed without impulse).

    Parameters
    ----------
    data : pandas.DataFrame
        ``Trajectory.data``: ``t_s``, ``v_foot_m_s``, ``added_mass_kg``, ``mode``.

    Returns
    -------
    Impulse
    """
    t_s = data["t_s"].to_numpy(float)
    v_m_s = data["v_foot_m_s"].to_numpy(float)
    m_kg = data["added_mass_kg"].to_numpy(float)
    label, first, stop = _episodes(data["mode"].to_numpy())
    inside = (label[:-1] > 0) & (label[1:] == label[:-1])
    dm_kg = np.diff(m_kg)
    dj_N_s = np.where(inside & (dm_kg > 0.0), -0.5 * (v_m_s[:-1] + v_m_s[1:]) * dm_kg, 0.0)
    per_episode = np.bincount(label[:-1], weights=dj_N_s, minlength=len(first) + 1)[1:]
    total = float(dj_N_s.sum()) * 1e3
    if len(first) == 0 or not per_episode.max() > 0.0:
        return Impulse(total, 0.0, math.nan, math.nan, len(first))
    best = int(np.argmax(per_episode))
    return Impulse(
        total_mN_s=total,
        peak_mN_s=float(per_episode[best]) * 1e3,
        duration_ms=float(t_s[stop[best]] - t_s[first[best]]) * 1e3,
        start_ms=float(t_s[first[best]]) * 1e3,
        n_intervals=len(first),
    )


def flux_force_N(
    data: pd.DataFrame, kappa: float, phi: float, experiment: Experiment
) -> np.ndarray:
    """The flux ``kappa rho_grain phi V'(d) z'^2`` [N] per row, from the cone geometry.

    An independent evaluation of ``F_am`` (physics-model.md section 3), used to check
    :func:`added_mass_impulse`: ``d = z - z_entry`` with ``z_entry`` the depth at the start
    of the episode; zero outside advancing episodes and once the cone is fully formed.

    Parameters
    ----------
    data : pandas.DataFrame
        ``Trajectory.data``.
    kappa : float
        Added-mass coefficient [-].
    phi : float
        Volume fraction [-].
    experiment : Experiment
        Supplies the foot radius [m] and grain density [kg/m^3].

    Returns
    -------
    ndarray, shape (n,)
    """
    radius_m = experiment.robot.foot_radius
    z_m = data["depth_mm"].to_numpy(float) * 1e-3
    zdot_m_s = -data["v_foot_m_s"].to_numpy(float)
    label, first, _ = _episodes(data["mode"].to_numpy())
    z_entry_m = np.where(label > 0, z_m[first[np.maximum(label - 1, 0)]], np.nan)
    h_m = CONE_MU * (z_m - z_entry_m)
    growing = (label > 0) & (h_m < radius_m * CONE_TAN)
    q_m = np.where(growing, radius_m - h_m / CONE_TAN, 0.0)
    rho_phi = kappa * experiment.robot.grain_density * phi
    return rho_phi * CONE_MU * math.pi * q_m**2 * zdot_m_s**2


def flux_quadrature_mN_s(
    data: pd.DataFrame, kappa: float, phi: float, experiment: Experiment
) -> float:
    """Trapezoidal integral of :func:`flux_force_N` over the advancing steps [mN s]."""
    t_s = data["t_s"].to_numpy(float)
    f_N = flux_force_N(data, kappa, phi, experiment)
    label, _, _ = _episodes(data["mode"].to_numpy())
    inside = (label[:-1] > 0) & (label[1:] == label[:-1])
    return float(np.sum(np.where(inside, 0.5 * (f_N[:-1] + f_N[1:]) * np.diff(t_s), 0.0))) * 1e3


# ----------------------------------------------------------------------------------------
def cells_of(table: pd.DataFrame) -> pd.DataFrame:
    """The (command, phi, command settings) cells of the data, with their jump counts."""
    keys = ["command", "phi", *common.SETTING_COLUMNS]
    cells = table.groupby(keys, sort=False).size().rename("n_jumps").reset_index()
    order = {c: i for i, c in enumerate(COMMAND_NAMES)}
    cells = cells.sort_values(
        ["command", "phi", "freq_hz"], key=lambda s: s.map(order) if s.name == "command" else s
    )
    return cells.reset_index(drop=True)


def simulate_impulses(
    command: str,
    phi: float,
    draws: dict[str, np.ndarray],
    experiment: Experiment,
    max_step_s: float = MAX_STEP_S,
) -> list[Impulse]:
    """:func:`added_mass_impulse` of one cell for every posterior draw (failed: NaN)."""
    n = len(next(iter(draws.values())))
    out = []
    for s in range(n):
        params = {name: float(v[s]) for name, v in draws.items()}
        traj = granbayes.simulate_trajectory(
            command, phi, params, experiment=experiment, max_step=max_step_s
        )
        out.append(added_mass_impulse(traj.data) if traj.status == Status.OK else FAILED)
    return out


def _pearson_rows(x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """Pearson r across columns for every row (NaN pairs dropped; NaN if < 3 pairs)."""
    out = np.full(x.shape[0], np.nan)
    for s in range(x.shape[0]):
        ok = np.isfinite(x[s]) & np.isfinite(y[s])
        if ok.sum() >= 3 and np.std(x[s, ok]) > 0 and np.std(y[s, ok]) > 0:
            out[s] = np.corrcoef(x[s, ok], y[s, ok])[0, 1]
    return out


def _spearman_rows(x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """Spearman rank correlation across columns for every row (NaN pairs dropped)."""
    out = np.full(x.shape[0], np.nan)
    for s in range(x.shape[0]):
        ok = np.isfinite(x[s]) & np.isfinite(y[s])
        if ok.sum() >= 3:
            out[s] = _pearson_rows(rankdata(x[s, ok])[None], rankdata(y[s, ok])[None])[0]
    return out


def correlation(
    kappa_med: np.ndarray, y_med: np.ndarray, kappa_draws: np.ndarray, y_draws: np.ndarray
) -> dict:
    """Correlation of a quantity with kappa across cells: point (medians) and propagated.

    Parameters
    ----------
    kappa_med, y_med : ndarray, shape (n_cell,)
        Posterior medians per cell.
    kappa_draws, y_draws : ndarray, shape (n_draw, n_cell)
        Draw ``s`` of every cell.

    Returns
    -------
    dict
        Pearson (``point``, ``median``, ``interval``, ``p_positive``) with a ``spearman``
        entry of the same form.
    """
    out: dict = {}
    for name, rows in (("pearson", _pearson_rows), ("spearman", _spearman_rows)):
        point = float(rows(kappa_med[None], y_med[None])[0])
        per_draw = rows(kappa_draws, y_draws)
        med, lo, hi = common.interval(per_draw)
        finite = per_draw[np.isfinite(per_draw)]
        out[name] = {
            "point": point,
            "median": med,
            "interval": [lo, hi],
            "p_positive": float(np.mean(finite > 0)) if finite.size else math.nan,
            "n_draws": int(finite.size),
        }
    return {**out["pearson"], "spearman": out["spearman"]}


def _decisive(p: float) -> str:
    """How sure a 'largest' is: its probability over draw indices, in words."""
    words = "clear" if p >= 0.9 else "likely" if p >= 0.6 else "not decisive"
    return f"P = {p:.2f} over draws: {words}"


def _fmt_r(r: dict) -> str:
    """A correlation entry of :func:`correlation` in words."""
    return (
        f"{r['point']:+.2f} from the medians; propagated "
        f"{common.fmt_triple(r['median'], *r['interval'], '+.2f')}, "
        f"P(r > 0) = {r['p_positive']:.2f}"
    )


# ----------------------------------------------------------------------------------------
def _marker_handles(
    items: list[tuple[str, str, str]],
) -> list[Line2D]:
    """Legend entries (label, marker, face colour) with black edges."""
    return [
        Line2D([], [], ls="none", marker=m, ms=7, mfc=c, mec="black", mew=0.6, label=label)
        for label, m, c in items
    ]


def plot_vs_kappa(
    ctx: common.Context, cells: pd.DataFrame, quantity: str, corr: dict, fig_no: int
) -> Figure:
    """A quantity against the best kappa, one panel per actuation frequency.

    Colour: command; marker: phi - phi_c; error bars: 90% posterior intervals both ways.

    Parameters
    ----------
    ctx : Context
    cells : pandas.DataFrame
        Per-cell medians and intervals (``<quantity>_median``, ``_lo``, ``_hi``).
    quantity : str
        A key of :data:`QUANTITIES`.
    corr : dict
        Its correlation with kappa (:func:`correlation`).
    fig_no : int
        The thesis's figure number.

    Returns
    -------
    Figure
    """
    words, ylabel = QUANTITIES[quantity]
    freqs = np.unique(cells["freq_hz"])
    fig = Figure(figsize=(max(10.5, 4.4 * len(freqs) + 1.8), 4.8), layout="constrained")
    axes = np.atleast_1d(fig.subplots(1, len(freqs), sharex=True, sharey=True))
    phis = np.unique(cells["phi"])
    markers = {p: PHI_MARKERS[i % len(PHI_MARKERS)] for i, p in enumerate(phis)}
    for ax, freq in zip(axes, freqs, strict=True):
        for row in cells[cells["freq_hz"] == freq].to_dict("records"):
            color = common.COMMAND_COLORS[row["command"]]
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
                x, y, ls="none", marker=markers[row["phi"]], ms=7, mfc=color, mec="black",
                mew=0.6, zorder=3,
            )  # fmt: skip
        ax.set_title(f"actuator {freq:g} Hz", fontsize=10)
        ax.set_xlabel(r"best $\kappa$ (posterior median) [-]")
        ax.grid(alpha=0.3)
    top = np.nanmax(cells[[f"{quantity}_hi", f"{quantity}_median"]].to_numpy())
    axes[0].set_xlim(0.0, 1.03 * max(KAPPA_PRIOR_WIDTH, np.nanmax(cells["kappa_hi"])))
    axes[0].set_ylim(0.0, 1.05 * top if np.isfinite(top) and top > 0 else 1.0)
    axes[0].set_ylabel(ylabel)
    present = [c for c in COMMAND_NAMES if c in set(cells["command"])]
    handles = _marker_handles(
        [(c.replace("_", " "), "o", common.COMMAND_COLORS[c]) for c in present]
    )
    handles.append(Line2D([], [], ls="none", label="\n" + r"$\phi - \phi_c$:"))
    handles += _marker_handles([(f"{p - ctx.phi_c:+.3f}", markers[p], "0.8") for p in phis])
    fig.legend(
        handles=handles, loc="outside right upper", title="command", fontsize=8, title_fontsize=8
    )
    sp = corr["spearman"]
    fig.supxlabel(
        f"r(κ, {quantity.split('_')[0]}) across {len(cells)} cells. Pearson: {_fmt_r(corr)}.\n"
        f"Spearman: {sp['point']:+.2f} from the medians; propagated "
        f"{common.fmt_triple(sp['median'], *sp['interval'], '+.2f')}. "
        "Bars: 90% posterior intervals "
        f"(κ: fit posterior, prior uniform on [0, {KAPPA_PRIOR_WIDTH:g}]; y: simulated draws).",
        fontsize=8,
    )
    fig.suptitle(ctx.title(f"Thesis Fig. {fig_no}: {words} vs added-mass κ"), fontsize=11)
    return fig


def plot_example(
    ctx: common.Context,
    data: pd.DataFrame,
    experiment: Experiment,
    kappa: float,
    phi: float,
    label: str,
) -> Figure:
    """Depth, added mass and F_am of one trajectory; the interval of greatest impulse shaded.

    Parameters
    ----------
    ctx : Context
    data : pandas.DataFrame
        ``Trajectory.data``.
    experiment : Experiment
        The cell's experiment.
    kappa : float
        Added-mass coefficient of the trajectory [-].
    phi : float
        Volume fraction [-].
    label : str
        What was simulated (for the title).

    Returns
    -------
    Figure
    """
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
    _, first, stop = _episodes(data["mode"].to_numpy())
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
    fig.suptitle(ctx.title(f"Added-mass impulse of one jump: {label}"), fontsize=11)
    return fig


# ----------------------------------------------------------------------------------------
def integral_check(
    ctx: common.Context, examples: list[tuple[dict, dict[str, float]]]
) -> tuple[pd.DataFrame, dict]:
    """Check the Stieltjes sum: doubled and halved largest step, and the flux quadrature.

    Parameters
    ----------
    ctx : Context
    examples : list of (cell, parameters)
        Cells (rows of the cell table) and the parameters to simulate them with.

    Returns
    -------
    table : pandas.DataFrame
        Per example: J_total and the relative differences.
    numbers : dict
        Largest absolute relative differences.
    """
    rows = []
    for cell, params in examples:
        exp = common.cell_experiment(ctx.experiment, cell)
        phi = float(cell["phi"])
        j: dict[str, float] = {}
        for key, step_s in (
            ("half", MAX_STEP_S / 2),
            ("base", MAX_STEP_S),
            ("dbl", 2 * MAX_STEP_S),
        ):
            traj = granbayes.simulate_trajectory(
                cell["command"], phi, params, experiment=exp, max_step=step_s
            )
            j[key] = added_mass_impulse(traj.data).total_mN_s
            if key == "base":
                j["quad"] = flux_quadrature_mN_s(traj.data, params["kappa"], phi, exp)
        rows.append(
            {
                "cell": f"{cell['command']} φ={phi:g} {cell['freq_hz']:g} Hz",
                "κ": params["kappa"],
                f"J_total, max step {1e3 * MAX_STEP_S:g} ms [mN s]": j["base"],
                "rel. diff, step ×2": j["dbl"] / j["base"] - 1,
                "rel. diff, step ×½": j["half"] / j["base"] - 1,
                "rel. diff, flux quadrature": j["quad"] / j["base"] - 1,
            }
        )
    table = pd.DataFrame(rows)
    numbers = {
        "max_rel_diff_double_step": float(table["rel. diff, step ×2"].abs().max()),
        "max_rel_diff_half_step": float(table["rel. diff, step ×½"].abs().max()),
        "max_rel_diff_flux_quadrature": float(table["rel. diff, flux quadrature"].abs().max()),
    }
    return table, numbers


def _summary_cols(prefix: str, values: np.ndarray) -> dict[str, float]:
    med, lo, hi = common.interval(values)
    return {f"{prefix}_median": med, f"{prefix}_lo": lo, f"{prefix}_hi": hi}


def run_cells(
    ctx: common.Context, n_draws: int
) -> tuple[pd.DataFrame, dict[str, np.ndarray], list[dict[str, float]], list[str]]:
    """Fit every command, simulate every cell for its posterior draws.

    Parameters
    ----------
    ctx : Context
    n_draws : int
        Joint posterior draws per (command, phi).

    Returns
    -------
    table : pandas.DataFrame
        One row per cell: settings, kappa posterior summary (all kept samples) and the
        medians and 90% intervals of the simulated quantities.
    draws : dict of str to ndarray, shape (n_draws, n_cells)
        ``kappa`` and every key of :data:`QUANTITIES`, draw ``s`` of every cell.
    medians : list of dict
        Per cell, the marginal posterior medians of the force parameters.
    warnings : list of str
        Fit warnings.
    """
    rows: list[dict] = []
    columns: dict[str, list[np.ndarray]] = {"kappa": [], **{q: [] for q in QUANTITIES}}
    medians: list[dict[str, float]] = []
    warnings: list[str] = []
    cells = cells_of(ctx.table)
    for ic, command in enumerate(COMMAND_NAMES):
        mine = cells[cells["command"] == command]
        if mine.empty:
            continue
        data = ctx.table[ctx.table["command"] == command]
        result = common.run_fit(ctx, data, TERMS, seed_offset=ic)
        warnings += [f"{command}: {w}" for w in result.warnings]
        post = result.datatree.posterior.to_dataset()
        names = [str(v) for v in post.data_vars if v != "sigma_mm"]
        for phi in np.unique(mine["phi"]):
            ip = int(np.searchsorted(ctx.phis, phi))
            rng = ctx.rng(1000 + 100 * ic + ip)
            draws = common.posterior_draws(result.datatree, phi, names, n_draws, rng)
            at_phi = post.sel(phi=phi, method="nearest")
            k_med, k_lo, k_hi = common.interval(at_phi["kappa"].values.ravel())
            median = {n: float(np.median(at_phi[n].values)) for n in names}
            for cell in mine[mine["phi"] == phi].to_dict("records"):
                imps = simulate_impulses(
                    command, float(phi), draws, common.cell_experiment(ctx.experiment, cell)
                )
                values = {
                    "kappa": draws["kappa"],
                    "duration_ms": np.array([i.duration_ms for i in imps]),
                    "impulse_mN_s": np.array([i.total_mN_s for i in imps]),
                }
                values["impulse_per_kappa_mN_s"] = values["impulse_mN_s"] / draws["kappa"]
                for key, v in values.items():
                    columns[key].append(v)
                rows.append(
                    {
                        **cell,
                        "phi_minus_phi_c": float(phi) - ctx.phi_c,
                        "n_draws": n_draws,
                        "n_failed": int(np.sum(~np.isfinite(values["impulse_mN_s"]))),
                        "kappa_median": k_med,
                        "kappa_lo": k_lo,
                        "kappa_hi": k_hi,
                        "kappa_width_over_prior": (k_hi - k_lo)
                        / (common.CI_PROB * KAPPA_PRIOR_WIDTH),
                        **{n: median[n] for n in names if n != "kappa"},
                        **{
                            c: v for q in QUANTITIES for c, v in _summary_cols(q, values[q]).items()
                        },
                        "interval_start_ms_median": common.interval([i.start_ms for i in imps])[0],
                        "n_intervals_median": float(np.median([i.n_intervals for i in imps])),
                    }
                )
                medians.append(median)
    if not rows:
        raise InputError("no jumps to fit")
    draws_out = {k: np.column_stack(v) for k, v in columns.items()}
    return pd.DataFrame(rows), draws_out, medians, warnings


def per_command_summary(
    table: pd.DataFrame, draws: dict[str, np.ndarray]
) -> tuple[pd.DataFrame, dict[str, dict]]:
    """Per command: kappa, J_total, J_total/kappa and duration averaged over its cells.

    The average is taken per draw index. Also the probability (over draw indices) that the
    command has the largest mean kappa, J_total and J_total/kappa.

    Returns
    -------
    table : pandas.DataFrame
        For the summary.
    numbers : dict
        Per command: medians, intervals, probabilities.
    """
    present = [c for c in COMMAND_NAMES if c in set(table["command"])]
    keys = ("kappa", "impulse_mN_s", "impulse_per_kappa_mN_s", "duration_ms")
    mean = {
        q: np.column_stack(
            [np.nanmean(draws[q][:, (table["command"] == c).to_numpy()], axis=1) for c in present]
        )
        for q in keys
    }
    best = {q: np.argmax(np.nan_to_num(mean[q], nan=-np.inf), axis=1) for q in keys[:3]}
    rows, numbers = [], {}
    for j, c in enumerate(present):
        entry: dict = {}
        for q in keys:
            med, lo, hi = common.interval(mean[q][:, j])
            entry[q] = {"median": med, "interval": [lo, hi]}
        for q in keys[:3]:
            entry[f"p_largest_{q}"] = float(np.mean(best[q] == j))
        numbers[c] = entry
        rows.append(
            {
                "command": c.replace("_", " "),
                "κ": common.fmt_interval(mean["kappa"][:, j], 2),
                "P(largest κ)": entry["p_largest_kappa"],
                "J_total [mN s]": common.fmt_interval(mean["impulse_mN_s"][:, j]),
                "P(largest J_total)": entry["p_largest_impulse_mN_s"],
                "J_total/κ [mN s]": common.fmt_interval(mean["impulse_per_kappa_mN_s"][:, j]),
                "P(largest J_total/κ)": entry["p_largest_impulse_per_kappa_mN_s"],
                "duration [ms]": common.fmt_interval(mean["duration_ms"][:, j]),
            }
        )
    return pd.DataFrame(rows), numbers


def _cell_markdown(table: pd.DataFrame) -> str:
    """The per-cell table of the summary."""

    def col(stem: str, fmt: str) -> list[str]:
        return [
            common.fmt_triple(*v, fmt)
            for v in table[[f"{stem}_median", f"{stem}_lo", f"{stem}_hi"]].to_numpy()
        ]

    return common.markdown_table(
        pd.DataFrame(
            {
                "command": table["command"].str.replace("_", " "),
                "φ − φc": table["phi_minus_phi_c"].map(lambda v: f"{v:+.3f}"),
                "f [Hz]": table["freq_hz"].map(lambda v: f"{v:g}"),
                "κ": col("kappa", ".2f"),
                "duration [ms]": col("duration_ms", ".1f"),
                "J_total [mN s]": col("impulse_mN_s", ".3g"),
                "J_total/κ [mN s]": col("impulse_per_kappa_mN_s", ".3g"),
                "failed": table["n_failed"],
            }
        )
    )


def analyse(ctx: common.Context) -> tuple[str, dict]:
    """Fit, simulate, correlate, plot; return the summary body and its numbers."""
    n_draws = N_DRAWS_FAST if ctx.fast else N_DRAWS
    table, draws, medians, warnings = run_cells(ctx, n_draws)
    ctx.save_table(table, "cells")
    corr = {
        q: correlation(
            table["kappa_median"].to_numpy(),
            table[f"{q}_median"].to_numpy(),
            draws["kappa"],
            draws[q],
        )
        for q in QUANTITIES
    }
    for quantity, stem, fig_no in (
        ("duration_ms", "duration_vs_kappa", 9),
        ("impulse_mN_s", "impulse_vs_kappa", 10),
    ):
        ctx.save_figure(plot_vs_kappa(ctx, table, quantity, corr[quantity], fig_no), stem)
    command_table, per_command = per_command_summary(table, draws)
    largest_j = max(per_command, key=lambda c: per_command[c]["impulse_mN_s"]["median"])
    largest_k = max(per_command, key=lambda c: per_command[c]["kappa"]["median"])
    largest_pk = max(per_command, key=lambda c: per_command[c]["impulse_per_kappa_mN_s"]["median"])

    # the integral check on the median parameters of each command's largest-J cell
    top = [int(table[table["command"] == c]["impulse_mN_s_median"].idxmax()) for c in per_command]
    records = table.to_dict("records")
    check_table, check = integral_check(ctx, [(records[i], medians[i]) for i in top])
    # example: the largest-J stutter cell (several advancing episodes), else the largest
    has_stutter = table["command"] == "stutter"
    pool = table[has_stutter] if has_stutter.any() else table
    ex_i = int(pool["impulse_mN_s_median"].idxmax())
    ex, ex_params = records[ex_i], medians[ex_i]
    ex_exp = common.cell_experiment(ctx.experiment, ex)
    traj = granbayes.simulate_trajectory(
        ex["command"], ex["phi"], ex_params, experiment=ex_exp, max_step=MAX_STEP_S
    )
    ex_label = (
        f"{ex['command'].replace('_', ' ')}, φ = {ex['phi']:g}, {ex['freq_hz']:g} Hz\n"
        f"(marginal posterior medians: "
        + ", ".join(f"{n} = {v:.3g}" for n, v in ex_params.items())
        + ")"
    )
    fig = plot_example(ctx, traj.data, ex_exp, ex_params["kappa"], ex["phi"], ex_label)
    ctx.save_figure(fig, "example_trajectory")

    fits = table.drop_duplicates(["command", "phi"])
    width = fits["kappa_width_over_prior"]
    n_loose = int((width > 0.5).sum())
    rd, rj, rpk = corr["duration_ms"], corr["impulse_mN_s"], corr["impulse_per_kappa_mN_s"]
    pk = "impulse_per_kappa_mN_s"
    spread_k = float(np.nanmedian((table["kappa_hi"] - table["kappa_lo"]) / table["kappa_median"]))
    spread_pk = float(np.nanmedian((table[f"{pk}_hi"] - table[f"{pk}_lo"]) / table[f"{pk}_median"]))

    def spearman(r: dict) -> str:
        s = r["spearman"]
        propagated = common.fmt_triple(s["median"], *s["interval"], "+.2f")
        return f"{s['point']:+.2f} from the medians, propagated {propagated}"

    body = [
        f"{len(table)} cells (command × φ × frequency), {n_draws} joint posterior draws per "
        f"(command, φ); the law `{' + '.join(TERMS)}` fitted per command and volume fraction.",
        "",
        "**Definitions.** The added-mass force is the snowplough momentum flux "
        "F_am = −(dm_a/dt)·v_foot ≥ 0 [N] (upward; physics-model.md §2–3); it acts only "
        "while the foot advances into fresh grains and the jammed cone grows. "
        "J_total = ∫F_am dt over the whole simulated jump [mN s], computed as the Stieltjes "
        "sum of −v̄_foot·Δm_a over the integrator steps inside an advancing episode where "
        "m_a grows (the cone is shed without impulse). An *added-mass interval* is an "
        "advancing episode (entry event to exit event; m_a > 0 there); the *duration* is "
        "that of the interval with the greatest impulse. Every actuation frequency is its "
        "own cell; the frequencies of one (command, φ) share that fit's posterior draws. "
        "Best κ = posterior median.",
        "",
        "## Answers",
        "",
        f"- **Duration vs κ (thesis Fig. 9):** Pearson r = {_fmt_r(rd)}; Spearman {spearman(rd)}.",
        f"- **J_total vs κ (thesis Fig. 10):** Pearson r = {_fmt_r(rj)}; Spearman {spearman(rj)}.",
        "- J_total is proportional to κ by construction (J = κ ρ φ ∫V'(d) ż² dt), and the "
        "kinematic factor J_total/κ is much better determined than κ (median relative 90% "
        f"width {100 * spread_pk:.0f}% against {100 * spread_k:.0f}% for κ), so a positive "
        "r for J_total is largely built in. Within "
        "one draw κ varies across cells as widely as the posteriors allow and J_total "
        "follows it, which is why the propagated r can exceed the r of the medians. "
        f"J_total/κ against κ: Pearson r = {_fmt_r(rpk)}.",
        f"- **Per command** (the thesis: added mass matters most for the stutter jump): the "
        f"largest mean J_total is the **{largest_j.replace('_', ' ')}** "
        f"({_decisive(per_command[largest_j]['p_largest_impulse_mN_s'])}), the largest "
        f"mean κ the **{largest_k.replace('_', ' ')}** "
        f"({_decisive(per_command[largest_k]['p_largest_kappa'])}), the largest kinematic "
        f"factor J_total/κ the **{largest_pk.replace('_', ' ')}** "
        f"({_decisive(per_command[largest_pk]['p_largest_impulse_per_kappa_mN_s'])}). "
        "J_total/κ is the impulse a command's intrusions would deliver per unit κ (how fast "
        "and how deep the foot advances); unlike κ it is well determined by the fits.",
        f"- **How well κ is constrained:** in {n_loose} of {len(fits)} fits (command × φ) "
        f"the 90% interval of κ is wider than half of the prior's 90% range (prior uniform "
        f"on [0, {KAPPA_PRIOR_WIDTH:g}]); median ratio {float(np.median(width)):.2f}. "
        "Where κ is that loose, the 'best κ' is mostly the prior and the correlations "
        "say little about the physics.",
        f"- **Integral check** ({len(check_table)} trajectories): doubling the largest "
        f"integrator step to {2e3 * MAX_STEP_S:g} ms changes J_total by at most "
        f"{100 * check['max_rel_diff_double_step']:.2g}% (halving it: "
        f"{100 * check['max_rel_diff_half_step']:.2g}%); the trapezoidal quadrature of "
        f"κρφV'(d)ż² differs from the Stieltjes sum by at most "
        f"{100 * check['max_rel_diff_flux_quadrature']:.2g}%.",
    ]
    if "data/generate_reference.py" in ctx.label:
        body.append(
            "- **These are the SYNTHETIC reference data, whose documented generating law "
            "(granbayes/data/reference/TRUTH.md) has no added mass** (κ = 0; a compaction term "
            "instead): a κ found here is the fit absorbing compaction or the prior, not "
            "evidence for a jammed cone."
        )
    if warnings:
        body.append(
            f"- **{len(warnings)} fit warning(s)** (listed at the end)"
            + (": expected with fast mode's short chains." if ctx.fast else ".")
        )
    corr_rows = [
        {
            "quantity vs κ": QUANTITIES[q][0],
            "Pearson (medians)": c["point"],
            "Pearson propagated": common.fmt_triple(c["median"], *c["interval"], "+.2f"),
            "P(r > 0)": f"{c['p_positive']:.2f}",
            "Spearman (medians)": c["spearman"]["point"],
            "Spearman propagated": common.fmt_triple(
                c["spearman"]["median"], *c["spearman"]["interval"], "+.2f"
            ),
        }
        for q, c in corr.items()
    ]
    body += [
        "",
        "![duration vs kappa](duration_vs_kappa.png)",
        "",
        "![impulse vs kappa](impulse_vs_kappa.png)",
        "",
        "![example trajectory](example_trajectory.png)",
        "",
        "## Correlations with κ across cells",
        "",
        "From the medians: Pearson r of the cells' posterior medians (the thesis's way). "
        "Propagated: r across cells for every draw index, median [90% interval].",
        "",
        common.markdown_table(pd.DataFrame(corr_rows), "+.2f"),
        "",
        "## Per command (mean over the command's cells, per draw)",
        "",
        common.markdown_table(command_table, ".2f"),
        "",
        "## Per cell (posterior medians and 90% intervals)",
        "",
        _cell_markdown(table),
        "",
        "## Integral check (marginal posterior medians of each command's largest-J cell)",
        "",
        common.markdown_table(check_table, ".3g"),
    ]
    if warnings:
        body += ["", "## Fit warnings", "", *[f"- {w}" for w in warnings]]
    numbers = {
        "definitions": {
            "F_am": "-(dm_a/dt) v_foot >= 0 [N], snowplough flux (physics-model.md 2-3)",
            "J_total_mN_s": "sum of -mean(v_foot) dm_a over integrator steps inside an "
            "advancing episode with dm_a > 0, whole simulated jump",
            "interval": "advancing episode (m_a > 0), entry event to exit event",
            "duration_ms": "duration of the interval with the greatest impulse",
            "cell": "(command, phi, freq_hz); frequencies of one (command, phi) share draws",
            "best_kappa": "posterior median",
        },
        "n_draws": n_draws,
        "r_duration": rd,
        "r_impulse": rj,
        "r_impulse_per_kappa": rpk,
        "per_command": per_command,
        "largest_impulse_command": largest_j,
        "largest_kappa_command": largest_k,
        "largest_impulse_per_kappa_command": largest_pk,
        "n_fits_kappa_loose": n_loose,
        "n_fits": len(fits),
        "impulse_per_kappa_relative_width": spread_pk,
        "integral_check": check,
        "fit_warnings": warnings,
        "cells": table.to_dict("records"),
    }
    return "\n".join(body), numbers


def main(argv: list[str] | None = None) -> int:
    return common.main(NAME, __doc__, analyse, argv)


if __name__ == "__main__":
    sys.exit(main())
