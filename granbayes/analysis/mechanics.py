"""What a simulated jump does mechanically: added-mass impulse, actuator power, rigid floor.

Quantities computed from :func:`granbayes.simulate_trajectory` records (one row per
accepted integrator step), for the analyses of the thesis's added-mass figures and of
Aguilar et al. (2012) on hard ground.

Added mass
    The snowplough momentum flux of the equations of motion (physics-model.md sections 2
    and 3), ``F_am = -(dm_a/dt) v_foot >= 0`` [N], upward: the momentum the foot hands to
    the grains it accretes into the jammed cone ``m_a = kappa rho_grain phi V(d)``. It acts
    only while the foot advances into fresh grains and the cone is still growing; the cone
    is shed without impulse when the foot stops. :func:`added_mass_impulse` gives the total
    impulse [mN s] (the Stieltjes sum ``sum -(v_i + v_{i+1})/2 (m_a,{i+1} - m_a,i)`` over
    the steps inside an advancing episode on which the added mass grows) and the interval
    (advancing episode) of greatest impulse; :func:`flux_quadrature_mN_s` checks it
    against the trapezoidal quadrature of ``kappa rho_grain phi V'(d) z'^2``.
Actuator
    :func:`actuator_power`: the mechanical power the motor drive delivers,
    ``P = F_a alpha'`` [W] with ``F_a = m_motor (x_r'' + alpha'' + g)``, the rod
    acceleration taken from the equation of motion (not from differences).
Rigid floor
    :data:`RIGID_FLOOR` (physics-model.md section 6); :func:`rigid_heights_mm` and
    :func:`best_frequency` sweep and refine the actuator frequency.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np
import pandas as pd
from scipy.optimize import minimize_scalar

from .._experiment import Experiment, G
from .._kernel import CONE_MU, CONE_TAN
from .._simulator import Status, simulate, simulate_trajectory
from ._summaries import cell_experiment

__all__ = [
    "FAILED",
    "MAX_STEP_S",
    "RIGID_FLOOR",
    "Impulse",
    "actuator_power",
    "added_mass_impulse",
    "advancing_episodes",
    "best_frequency",
    "flux_force_N",
    "flux_quadrature_mN_s",
    "integral_check",
    "rigid_heights_mm",
    "simulate_impulses",
]

#: Largest integrator step of the recorded trajectories [s] (granbayes default).
MAX_STEP_S = 5e-4
#: The rigid-floor limit of the ground model (physics-model.md section 6): ``k`` [N/m],
#: ``r_unload`` [-] (the same as ``granbayes._cli.HARD_GROUND_PARAMS``).
RIGID_FLOOR: dict[str, float] = {"k": 1.0e6, "r_unload": 50.0}
#: Volume fraction of the rigid-floor jumps [-] (irrelevant without phi-dependent terms).
RIGID_PHI = 0.612


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


#: The impulse of a jump whose simulation failed.
FAILED = Impulse(math.nan, math.nan, math.nan, math.nan, 0)


def advancing_episodes(mode: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Advancing episodes of a trajectory.

    Parameters
    ----------
    mode : ndarray of str, shape (n,)
        Regime per recorded row (``Trajectory.data["mode"]``).

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
    label, first, stop = advancing_episodes(data["mode"].to_numpy())
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
    label, first, _ = advancing_episodes(data["mode"].to_numpy())
    z_entry_m = np.where(label > 0, z_m[first[np.maximum(label - 1, 0)]], np.nan)
    h_m = CONE_MU * (z_m - z_entry_m)
    growing = (label > 0) & (h_m < radius_m * CONE_TAN)
    q_m = np.where(growing, radius_m - h_m / CONE_TAN, 0.0)
    rho_phi = kappa * experiment.robot.grain_density * phi
    return rho_phi * CONE_MU * math.pi * q_m**2 * zdot_m_s**2


def flux_quadrature_mN_s(
    data: pd.DataFrame, kappa: float, phi: float, experiment: Experiment
) -> float:
    """Trapezoidal integral of :func:`flux_force_N` over the advancing steps [mN s].

    Parameters
    ----------
    data : pandas.DataFrame
        A trajectory (granbayes.simulate_trajectory).
    kappa : float
        Added-mass coefficient [-].
    phi : float
        Volume fraction [-].
    experiment : Experiment
        Robot and command defaults.
    """
    t_s = data["t_s"].to_numpy(float)
    f_N = flux_force_N(data, kappa, phi, experiment)
    label, _, _ = advancing_episodes(data["mode"].to_numpy())
    inside = (label[:-1] > 0) & (label[1:] == label[:-1])
    return float(np.sum(np.where(inside, 0.5 * (f_N[:-1] + f_N[1:]) * np.diff(t_s), 0.0))) * 1e3


def simulate_impulses(
    command: str,
    phi: float,
    draws: Mapping[str, np.ndarray],
    experiment: Experiment,
    max_step_s: float = MAX_STEP_S,
) -> list[Impulse]:
    """:func:`added_mass_impulse` of one command for every parameter draw (failed: NaN).

    Parameters
    ----------
    command : str
    phi : float
        Volume fraction [-].
    draws : mapping of str to ndarray, shape (n,)
        Force parameters [SI], one value per draw.
    experiment : Experiment
    max_step_s : float
        Largest integrator step [s].

    Returns
    -------
    list of Impulse, length n
    """
    n = len(next(iter(draws.values())))
    out = []
    for s in range(n):
        params = {name: float(v[s]) for name, v in draws.items()}
        traj = simulate_trajectory(command, phi, params, experiment=experiment, max_step=max_step_s)
        out.append(added_mass_impulse(traj.data) if traj.status == Status.OK else FAILED)
    return out


def integral_check(
    experiment: Experiment,
    examples: Sequence[tuple[Mapping, Mapping[str, float]]],
    max_step_s: float = MAX_STEP_S,
) -> tuple[pd.DataFrame, dict[str, float]]:
    """Check the Stieltjes sum: doubled and halved largest step, and the flux quadrature.

    Parameters
    ----------
    experiment : Experiment
    examples : sequence of (cell, parameters)
        Cells (``command``, ``phi``, ``freq_hz`` and optionally the other settings) and
        the force parameters [SI] to simulate them with (``kappa`` among them).
    max_step_s : float
        The base largest integrator step [s].

    Returns
    -------
    table : pandas.DataFrame
        Per example: J_total [mN s] and the relative differences.
    numbers : dict
        Largest absolute relative differences (``max_rel_diff_double_step``,
        ``max_rel_diff_half_step``, ``max_rel_diff_flux_quadrature``).
    """
    rows = []
    for cell, params in examples:
        exp = cell_experiment(experiment, cell)
        phi = float(cell["phi"])
        j: dict[str, float] = {}
        for key, step_s in (
            ("half", max_step_s / 2),
            ("base", max_step_s),
            ("dbl", 2 * max_step_s),
        ):
            traj = simulate_trajectory(
                cell["command"], phi, params, experiment=exp, max_step=step_s
            )
            j[key] = added_mass_impulse(traj.data).total_mN_s
            if key == "base":
                j["quad"] = flux_quadrature_mN_s(traj.data, params["kappa"], phi, exp)
        rows.append(
            {
                "cell": f"{cell['command']} φ={phi:g} {cell['freq_hz']:g} Hz",
                "κ": params["kappa"],
                f"J_total, max step {1e3 * max_step_s:g} ms [mN s]": j["base"],
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


# ----------------------------------------------------------------------------------------
def rigid_heights_mm(experiment: Experiment, command: str, freqs_hz: np.ndarray) -> np.ndarray:
    """Rigid-floor jump heights [mm] of ``command`` at each frequency [Hz] (NaN if failed).

    Parameters
    ----------
    experiment : Experiment
        Robot and command defaults.
    command : str
        Jump command.
    freqs_hz : ndarray
        Frequencies [Hz].
    """
    out = np.empty(freqs_hz.size)
    for i, f in enumerate(freqs_hz):
        res = simulate(command, RIGID_PHI, RIGID_FLOOR, experiment=experiment.replace(freq_hz=f))
        out[i] = res.height_mm[0] if res.ok[0] else np.nan
    return out


def best_frequency(
    experiment: Experiment, command: str, freqs_hz: np.ndarray, heights_mm: np.ndarray
) -> tuple[float, float]:
    """Optimal rigid-floor frequency [Hz] and height [mm]: the grid maximum, refined.

    A bounded scalar search (to 0.01 Hz) between the neighbours of the grid maximum; the
    grid maximum is kept if the search does not beat it.

    Parameters
    ----------
    experiment : Experiment
        Robot and command defaults.
    command : str
        Jump command.
    freqs_hz : ndarray
        Frequency grid [Hz].
    heights_mm : ndarray
        Heights on the grid [mm].
    """
    i = int(np.nanargmax(heights_mm))
    lo, hi = freqs_hz[max(i - 1, 0)], freqs_hz[min(i + 1, freqs_hz.size - 1)]
    if lo == hi:
        return float(freqs_hz[i]), float(heights_mm[i])
    res = minimize_scalar(
        lambda f: -rigid_heights_mm(experiment, command, np.array([f]))[0],
        bounds=(lo, hi),
        method="bounded",
        options={"xatol": 0.01},
    )
    if -res.fun < heights_mm[i]:
        return float(freqs_hz[i]), float(heights_mm[i])
    return float(res.x), float(-res.fun)


def actuator_power(
    experiment: Experiment,
    command: str,
    freq_hz: float,
    phi: float = RIGID_PHI,
    params: Mapping[str, float] = RIGID_FLOOR,
) -> dict[str, float]:
    """Peak actuator power [W] and positive actuator work [J] of one jump.

    Parameters
    ----------
    experiment : Experiment
    command : str
    freq_hz : float
        Actuator frequency [Hz].
    phi : float
        Volume fraction [-].
    params : mapping of str to float
        Force parameters [SI] (default: the rigid floor).

    Returns
    -------
    dict
        ``peak_power_w`` and ``positive_work_j`` (trapezoidal integral of ``max(P, 0)``
        over the command).
    """
    exp = experiment.replace(freq_hz=freq_hz)
    traj = simulate_trajectory(command, phi, dict(params), experiment=exp, max_step=1e-4)
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
    power_w = force_n * np.gradient(traj.program.alpha(t), t)
    positive = np.clip(power_w, 0.0, None)
    work_j = float(np.sum(0.5 * (positive[1:] + positive[:-1]) * np.diff(t)))
    return {"peak_power_w": float(power_w.max()), "positive_work_j": work_j}
