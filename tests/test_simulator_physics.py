"""Physics tests of the jump simulator (``granbayes.simulator`` and its compiled integrator).

What is checked, against ``physics-model.md``:

1. accuracy: the integrator is 5th order with exactly located events, the default
   tolerances meet the 0.05 mm contract, and an independent scipy implementation of the
   model agrees with the kernel;
2. energy: on an elastic bed with an undamped leg the mechanical energy is conserved (and
   changes exactly by the actuator's work during a command); every dissipative term only
   removes energy;
3. properties over the realistic parameter ranges (hypothesis): ground force, crater memory
   and added-mass cone follow the contract, heights are finite;
4. failures are statuses, never exceptions;
5. batches are bit-identical to single calls, for any thread count, run after run;
6. the hard-ground limit reproduces Aguilar et al. (2012);
7. start states and command waveforms;
8. the jump height is the maximum foot height in the section-5 window.

Lengths in trajectories are mm (``*_mm`` columns); everything else is SI.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Mapping

import numpy as np
import pandas as pd
import pytest
from hypothesis import given
from hypothesis import strategies as st
from scipy.integrate import solve_ivp

from granbayes import (
    COMMAND_NAMES,
    CommandProgram,
    CommandSettings,
    Experiment,
    Robot,
    Segment,
    SolverOptions,
    Status,
    Trajectory,
    build_command,
    simulate,
    simulate_table,
    simulate_trajectory,
)
from granbayes.forces import typical_ranges

G = 9.81
PHI = 0.612
CONVERGED = SolverOptions.converged()
#: Cone geometry of physics-model.md section 3.
CONE_TAN = math.tan(math.pi / 3.0)
CONE_MU = 2.0
#: Realistic parameter ranges (forces.py ``typical``; phi around the critical packing).
RANGES = typical_ranges(("k", "c_d", "kappa", "r_unload", "k2", "b"))
PHI_RANGE = (0.55, 0.65)
#: An energy scale of the robot: lifting the upper body by 1 cm (~0.12 J).
ENERGY_SCALE = Robot().m_upper * G * 0.01
#: Energy conservation bound: ~1e-6 of ENERGY_SCALE (observed drift ~1e-11 J converged).
ENERGY_TOL = 1e-7


# ----------------------------------------------------------------------------------------
# helpers
def height(
    command: str | CommandProgram,
    params: Mapping[str, float],
    *,
    options: SolverOptions | None = None,
    experiment: Experiment | None = None,
    phi: float = PHI,
) -> float:
    """Height [mm] of one jump, asserting that the integration succeeded."""
    res = simulate(command, phi, params, options=options, experiment=experiment)
    assert res.status[0] == Status.OK, res.status_labels[0]
    return float(res.height_mm[0])


def fixed_step(h: float) -> SolverOptions:
    """Options that make every step exactly ``h`` (except where clipped by an event).

    The linear regimes' closed form is off: with it their steps are exact and the error
    left (of the short advancing phases) sits at the converged floor.
    """
    return SolverOptions(
        rtol=1e6, atol_position=1e6, atol_velocity=1e6, max_step=h, closed_form=False
    )


def scaled_tolerances(rtol: float) -> SolverOptions:
    """Options with the default ratios atol_position = rtol / 100 m, atol_velocity = rtol."""
    return SolverOptions(rtol=rtol, atol_position=rtol * 1e-2, atol_velocity=rtol)


def idle_program(start_state: str = "touching", duration: float = 0.8) -> CommandProgram:
    """The actuator held still (alpha = 0) for ``duration`` seconds."""
    return CommandProgram(
        "idle", omega=2.0 * math.pi * 10.0, segments=(Segment(duration),), start_state=start_state
    )


def trajectory(
    command: str | CommandProgram,
    params: Mapping[str, float],
    *,
    experiment: Experiment | None = None,
    options: SolverOptions | None = None,
    phi: float = PHI,
) -> Trajectory:
    """A successful trajectory whose record covers the whole height window.

    The record ends at the touchdown after the command (``x_f`` falls through 0) or
    ``window_after`` after the command; anything else means the record was truncated.
    """
    traj = simulate_trajectory(command, phi, params, experiment=experiment, options=options)
    assert traj.status == Status.OK, traj.status.label
    t = traj.data["t_s"].to_numpy()
    xf = traj.data["x_foot_mm"].to_numpy()
    t_close = traj.program.t_end + (options or SolverOptions()).window_after
    touchdown = len(t) > 1 and t[-2] >= traj.program.t_end and xf[-2] >= 0.0 > xf[-1]
    assert touchdown or abs(t[-1] - t_close) < 1e-12, (
        f"record ends at t = {t[-1]:.6f} s, neither a touchdown nor the window end "
        f"{t_close:.6f} s ({len(t)} rows)"
    )
    return traj


def columns(data: pd.DataFrame) -> dict[str, np.ndarray]:
    """Trajectory columns in SI (positions in m)."""
    return {
        "t": data["t_s"].to_numpy(),
        "xr": data["x_rod_mm"].to_numpy() * 1e-3,
        "xf": data["x_foot_mm"].to_numpy() * 1e-3,
        "vr": data["v_rod_m_s"].to_numpy(),
        "vf": data["v_foot_m_s"].to_numpy(),
        "z": data["depth_mm"].to_numpy() * 1e-3,
        "zmax": data["z_max_mm"].to_numpy() * 1e-3,
        "fg": data["ground_force_N"].to_numpy(),
        "ma": data["added_mass_kg"].to_numpy(),
        "mode": data["mode"].to_numpy(),
    }


def bed_energy(data: pd.DataFrame, params: Mapping[str, float]) -> np.ndarray:
    """Elastic energy [J] stored in the bed along a trajectory.

    A force F on the unloading line (slope r_unload k) stores U_bed = F^2 / (2 r_unload k),
    with F = F_static(z) while advancing (the yield point) and F = F_g otherwise. For
    r_unload = 1 and k2 = 0 this is k z^2 / 2 for z > 0 (else 0). The work of the static
    yield force beyond U_bed is dissipated, at the rate F_static z' (1 - (1 + 2 k2 z / k) /
    r_unload): a loss whenever r_unload k >= k + 2 k2 z.
    """
    c = columns(data)
    k, k2 = params["k"], params.get("k2", 0.0)
    r = params.get("r_unload", 20.0)
    advancing = c["mode"] == "advancing"
    f_elastic = np.where(advancing, k * c["z"] + k2 * c["z"] ** 2, c["fg"])
    return f_elastic**2 / (2.0 * r * k)


def mechanical_energy(data: pd.DataFrame, robot: Robot, params: Mapping[str, float]) -> np.ndarray:
    """Mechanical energy [J] of robot and bed along a trajectory (no added mass).

    E = 1/2 M v_r^2 + 1/2 m_f v_f^2 + 1/2 k_spring (x_f - x_r)^2 + M g x_r + m_f g x_f
    + U_bed (:func:`bed_energy`), with M = m_motor + m_rod riding with the rod.
    """
    c = columns(data)
    m, mf = robot.m_upper, robot.m_foot
    return (
        0.5 * m * c["vr"] ** 2
        + 0.5 * mf * c["vf"] ** 2
        + 0.5 * robot.k_spring * (c["xf"] - c["xr"]) ** 2
        + m * G * c["xr"]
        + mf * G * c["xf"]
        + bed_energy(data, params)
    )


def actuator_work(data: pd.DataFrame, program: CommandProgram, robot: Robot) -> np.ndarray:
    """Work [J] done by the actuator on the rod since t = 0, at each recorded time.

    The actuator term of the rod equation is the force -m_motor alpha''(t), of power
    P = -m_motor alpha'' v_r. P is integrated between recorded points with the end-point
    corrected trapezoid rule h/2 (P0 + P1) + h^2/12 (P0' - P1') (local error O(h^5)), where
    P' = -m_motor (alpha''' v_r + alpha'' a_r) and a_r follows from the rod equation. The
    integrator lands on every segment boundary, where alpha'' jumps, so no interval spans
    one.
    """
    c = columns(data)
    t = c["t"]
    bounds = program.boundaries
    missing = [b for b in bounds if not np.any(t == b)]
    assert not missing, f"segment boundaries {missing} are not recorded"
    nseg = len(program.segments)
    segment = np.minimum(np.searchsorted(bounds, 0.5 * (t[1:] + t[:-1]), side="right") - 1, nseg)
    coef = np.array([s.coef for s in program.segments] + [0.0])[segment]
    t0 = bounds[segment]
    w, m_motor, m = program.omega, robot.m_motor, robot.m_upper

    def power(ends: slice) -> tuple[np.ndarray, np.ndarray]:
        phase = w * (t[ends] - t0)
        add = -coef * w**2 * np.cos(phase)
        addd = coef * w**3 * np.sin(phase)
        vr, vf, xr, xf = c["vr"][ends], c["vf"][ends], c["xr"][ends], c["xf"][ends]
        f_spring = robot.k_spring * (xf - xr) + robot.c_spring * (vf - vr)
        ar = (f_spring - m_motor * add) / m - G
        return -m_motor * add * vr, -m_motor * (addd * vr + add * ar)

    p0, dp0 = power(slice(None, -1))
    p1, dp1 = power(slice(1, None))
    h = np.diff(t)
    return np.concatenate([[0.0], np.cumsum(0.5 * h * (p0 + p1) + h**2 / 12.0 * (dp0 - dp1))])


def random_parameters(n: int, seed: int) -> tuple[np.ndarray, dict[str, np.ndarray]]:
    """``n`` uniform draws of phi and the force parameters over the realistic ranges."""
    rng = np.random.default_rng(seed)
    phi = rng.uniform(*PHI_RANGE, n)
    return phi, {name: rng.uniform(lo, hi, n) for name, (lo, hi) in RANGES.items()}


# ========================================================================================
# 1. accuracy and convergence
ORDER_CASES = [
    pytest.param("single", {"k": 3000.0, "c_d": 50.0}, id="single-drag"),
    pytest.param("preload", {"k": 3000.0, "kappa": 1.0}, id="preload-added_mass"),
    pytest.param(
        "delayed_stutter", {"k": 3000.0, "k2": 1e5, "b": 20.0}, id="delayed_stutter-k2-viscous"
    ),
    pytest.param(
        "delayed_stutter_preload",
        {"k": 6000.0, "r_unload": 5.0, "c_d": 30.0, "kappa": 0.5},
        id="delayed_stutter_preload-all",
    ),
]


@pytest.mark.parametrize(("command", "params"), ORDER_CASES)
def test_fixed_step_height_error_is_fifth_order(command: str, params: dict) -> None:
    """Halving a fixed step divides the height error by >= 2^4.3 (Dormand-Prince order 5).

    The order survives only if every non-smooth point (segment boundaries, bed regime
    changes, apex) is located exactly; a missed or coarsely located event drops it to ~1.
    Steps 4e-4 -> 2e-4 s: errors ~3e-6 -> ~1e-7 mm, observed orders 4.7-5.1, and the
    smaller error is still 100x above the ~1e-9 mm accuracy of the converged solution. At
    8e-4 s the error is pre-asymptotic for some jumps (2.4e-5 mm, order 3.2 to 4e-4 s).
    """
    exact = height(command, params, options=CONVERGED)
    errors = [abs(height(command, params, options=fixed_step(h)) - exact) for h in (4e-4, 2e-4)]
    order = math.log2(errors[0] / errors[1])
    assert errors[1] > 1e-8, f"error {errors[1]:.2e} mm too close to the converged floor"
    assert order >= 4.3, f"errors {errors[0]:.3e}, {errors[1]:.3e} mm: order {order:.2f}"


@pytest.mark.parametrize(("command", "params"), ORDER_CASES)
def test_adaptive_height_error_meets_contract_and_shrinks_with_rtol(
    command: str, params: dict
) -> None:
    """Default tolerances are within 0.05 mm of converged; rtol 1e-4 -> 1e-6 cuts the error.

    Observed: default errors 3e-5 to 3e-3 mm; the error drops 13x to 180x from rtol 1e-4
    to 1e-6 (atol scaled alike); asserted: at least 5x, leaving room for step-control noise.
    """
    exact = height(command, params, options=CONVERGED)
    default_error = abs(height(command, params) - exact)
    assert default_error < 0.05, f"default error {default_error:.4f} mm"
    coarse = abs(height(command, params, options=scaled_tolerances(1e-4)) - exact)
    fine = abs(height(command, params, options=scaled_tolerances(1e-6)) - exact)
    assert fine < coarse / 5.0, f"rtol 1e-4: {coarse:.2e} mm, rtol 1e-6: {fine:.2e} mm"


@pytest.mark.parametrize("command", COMMAND_NAMES)
def test_default_tolerances_meet_contract_on_random_realistic_jumps(command: str) -> None:
    """Over 400 random realistic parameter sets, default heights are within 0.05 mm of converged.

    This is the ``SolverOptions`` contract over the ranges of forces.py. Observed worst case
    0.028 mm (delayed_stutter_preload; the other commands stay below 0.004 mm). Rare
    violations exist (about 1 in 1000 delayed_stutter_preload jumps, up to 0.085 mm): see
    ``test_default_tolerances_catch_a_brief_glancing_contact``.
    """
    phi, params = random_parameters(400, seed=0)
    default = simulate(command, phi, params)
    exact = simulate(command, phi, params, options=CONVERGED)
    assert np.all(default.ok) and np.all(exact.ok)
    error = np.abs(default.height_mm - exact.height_mm)
    worst = int(np.argmax(error))
    assert error[worst] < 0.05, (
        f"error {error[worst]:.4f} mm at phi={phi[worst]:.4f}, "
        + ", ".join(f"{k}={v[worst]:.6g}" for k, v in params.items())
    )


def test_default_tolerances_catch_a_brief_glancing_contact() -> None:
    """A 1.1 ms, 3.5 um deep touch of the unloading line (t = 0.2848 s) must not be missed.

    While the robot settles, the foot grazes the crater (free -> contact -> free). With the
    default tolerances one step (0.28338 -> 0.28614 s) spans the whole graze, with g =
    z - z_free going -10.3 um (falling) -> +3.5 um -> -0.02 um; the glancing check only
    looks for a maximum when g rises at the step start, so the contact is skipped and the
    height is 0.085 mm off, above the 0.05 mm contract.
    """
    params = {
        "k": 8095.780718589847,
        "c_d": 82.06666614734891,
        "kappa": 0.5105663979216548,
        "r_unload": 24.463240620479965,
        "k2": 33311.00472260038,
        "b": 49.9072474805139,
    }
    phi = 0.5753970304741904
    default = height("delayed_stutter_preload", params, phi=phi)
    exact = height("delayed_stutter_preload", params, phi=phi, options=CONVERGED)
    assert abs(default - exact) < 0.05, f"default {default:.5f}, converged {exact:.5f} mm"


# ----------------------------------------------------------------------------------------
# an independent implementation of physics-model.md (scipy DOP853 with its event finder)
def independent_height(
    command: str, phi: float, params: Mapping[str, float], experiment: Experiment
) -> float:
    """Jump height [mm] written straight from physics-model.md, without the kernel.

    Regimes (advancing, contact, free) are integrated piecewise with terminal events on
    z' = 0, z = z_max, F_g = 0 on the unloading line and z = z_free; apexes in the window
    are non-terminal events. Same start-state and regime-entry choices as the contract.
    """
    robot, program = experiment.robot, build_command(command, experiment.command)
    m, m_motor, m_f = robot.m_upper, robot.m_motor, robot.m_foot
    k, c_d, kappa = params["k"], params.get("c_d", 0.0), params.get("kappa", 0.0)
    r, k2, b = params.get("r_unload", 20.0), params.get("k2", 0.0), params.get("b", 0.0)
    radius = robot.foot_radius
    cone = kappa * robot.grain_density * phi
    h_full = radius * CONE_TAN

    def f_static(z: float) -> float:
        return k * z + k2 * z * z

    def volume(h: float) -> float:
        return math.pi * h * (radius**2 - radius * h / CONE_TAN + h * h / (3.0 * CONE_TAN**2))

    bed = {"zmax": 0.0, "zentry": 0.0}
    if program.start_state == "settled":
        weight = (m + m_f) * G
        z0 = 2.0 * weight / (k + math.sqrt(k * k + 4.0 * k2 * weight))
        y = np.array([-z0 - m * G / robot.k_spring, -z0, 0.0, 0.0])
        bed.update(zmax=z0, zentry=z0)
    else:
        y = np.zeros(4)

    def ground(z: float, zd: float, mode: str) -> tuple[float, float, float]:
        if mode == "advancing":
            force = f_static(z) + c_d * zd * zd + b * zd
            h = CONE_MU * (z - bed["zentry"])
            if cone == 0.0:
                return force, 0.0, 0.0
            if h < h_full:
                q = radius - h / CONE_TAN
                return force, cone * volume(h), cone * CONE_MU * math.pi * q * q * zd * zd
            return force, cone * volume(h_full), 0.0
        if mode == "contact":
            return f_static(bed["zmax"]) - r * k * (bed["zmax"] - z), 0.0, 0.0
        return 0.0, 0.0, 0.0

    def rhs(segment: int, mode: str):
        inside = segment < len(program.segments)
        coef = program.segments[segment].coef if inside else 0.0
        t0 = program.boundaries[segment] if inside else 0.0
        w = program.omega

        def f(t: float, s: np.ndarray) -> list[float]:
            xr, xf, vr, vf = s
            alpha_dd = -coef * w * w * math.cos(w * (t - t0))
            f_spring = robot.k_spring * (xf - xr) + robot.c_spring * (vf - vr)
            fg, ma, flux = ground(-xf, -vf, mode)
            return [
                vr,
                vf,
                (f_spring - m_motor * alpha_dd) / m - G,
                (fg + flux - f_spring) / (m_f + ma) - G,
            ]

        return f

    def event(fun, direction: float, terminal: bool):
        fun.direction, fun.terminal = direction, terminal
        return fun

    mode = "advancing"
    if rhs(0, mode)(0.0, y)[3] >= 0.0:
        mode = "contact" if f_static(bed["zmax"]) > 0.0 else "free"
    t, segment, nseg = 0.0, 0, len(program.segments)
    in_window = program.pushoff_index == 0
    best = y[1] if in_window else -math.inf
    while True:
        t_stop = program.boundaries[segment + 1] if segment < nseg else program.t_end + 0.6
        zmax, fsmax = bed["zmax"], f_static(bed["zmax"])
        if mode == "advancing":
            regime = {"exit": event(lambda t, s: s[3], 1, True)}
        elif mode == "contact":
            regime = {
                "reenter": event(lambda t, s, zm=zmax: -s[1] - zm, 1, True),
                "release": event(
                    lambda t, s, zm=zmax, fm=fsmax: -(fm - r * k * (zm + s[1])), 1, True
                ),
            }
        else:
            z_free = zmax - fsmax / (r * k)
            regime = {"touch": event(lambda t, s, zf=z_free: -s[1] - zf, 1, True)}
        touchdown = event(lambda t, s: s[1], -1, segment >= nseg)
        apex = event(lambda t, s: s[3], -1, False)
        sol = solve_ivp(
            rhs(segment, mode),
            (t, t_stop),
            y,
            method="DOP853",
            rtol=1e-12,
            atol=1e-14,
            max_step=1e-3,
            events=[*regime.values(), touchdown, apex],
        )
        if in_window:
            best = max([best, sol.y[1, -1], *(ye[1] for ye in sol.y_events[-1])])
        t, y = sol.t[-1], sol.y[:, -1]
        if sol.status == 1:
            if segment >= nseg and len(sol.t_events[-2]) and sol.t_events[-2][-1] == t:
                return best * 1e3
            name = next(n for n, te in zip(regime, sol.t_events, strict=False) if len(te))
            if name == "exit":
                bed["zmax"] = -y[1]
                mode = "contact" if f_static(bed["zmax"]) > 0.0 else "free"
            elif name == "release":
                mode = "free"
            elif name == "touch" and f_static(bed["zmax"]) > 0.0:
                mode = "contact"
            else:  # reached the crater bottom: a new advancing episode
                mode, bed["zentry"] = "advancing", bed["zmax"]
            continue
        segment += 1
        if segment == program.pushoff_index:
            in_window, best = True, max(best, y[1])
        if segment > nseg:
            return best * 1e3


LAB_ROBOT = Experiment(
    robot=Robot(
        m_motor=1.3,
        m_rod=0.25,
        m_foot=0.12,
        k_spring=6500.0,
        c_spring=3.0,
        foot_radius=0.03,
        grain_density=1200.0,
    ),
    command=CommandSettings(amplitude_mm=15.0, freq_hz=12.0, delay_ms=40.0, settle_periods=2.0),
)
INDEPENDENT_CASES = [
    pytest.param("single", {"k": 3000.0, "r_unload": 1.0}, Experiment(), id="single-elastic"),
    pytest.param("preload", {"k": 3000.0, "c_d": 50.0}, Experiment(), id="preload-drag"),
    pytest.param("stutter", {"k": 3000.0, "kappa": 1.0}, Experiment(), id="stutter-added_mass"),
    pytest.param(
        "delayed_stutter", {"k": 3000.0, "k2": 1e5}, Experiment(), id="delayed_stutter-k2"
    ),
    pytest.param(
        "delayed_stutter_preload",
        {"k": 3000.0, "b": 20.0},
        Experiment(),
        id="delayed_stutter_preload-viscous",
    ),
    pytest.param(
        "delayed_stutter",
        {"k": 6000.0, "r_unload": 5.0, "c_d": 30.0, "kappa": 0.5, "k2": 5e4, "b": 10.0},
        LAB_ROBOT,
        id="delayed_stutter-all_terms-lab_robot",
    ),
]


@pytest.mark.parametrize(("command", "params", "experiment"), INDEPENDENT_CASES)
def test_kernel_agrees_with_independent_implementation(
    command: str, params: dict, experiment: Experiment
) -> None:
    """The converged kernel and a scipy re-implementation of the model agree within 1e-5 mm.

    Two codes sharing nothing but physics-model.md (equations of motion, bed regimes,
    added-mass cone, start states, height window): any difference in a term, sign or event
    shows up far above the 1e-5 mm bound (observed agreement ~1e-8 mm).
    """
    kernel = height(command, params, experiment=experiment, options=CONVERGED, phi=0.6)
    independent = independent_height(command, 0.6, params, experiment)
    assert abs(kernel - independent) < 1e-5, (
        f"kernel {kernel:.7f} mm, independent {independent:.7f} mm, "
        f"diff {kernel - independent:+.2e} mm"
    )


# ========================================================================================
# 2. energy
ELASTIC = {"k": 3000.0, "r_unload": 1.0, "c_d": 0.0, "kappa": 0.0, "k2": 0.0, "b": 0.0}
UNDAMPED = Experiment(robot=Robot(c_spring=0.0))


@pytest.mark.parametrize("start_state", ["touching", "settled"])
def test_energy_conserved_on_elastic_bed_with_idle_actuator(start_state: str) -> None:
    """c_spring = 0, r_unload = 1, no rate terms, actuator idle: E is constant within 1e-7 J.

    U_bed = k z^2 / 2 (z > 0) then makes the whole system conservative. From the touching
    start the robot falls into the bed and oscillates for 1.4 s (foot ~8.5 mm deep); 1e-7 J
    is ~1e-6 of M g * 1 cm (observed drift 4e-12 J with converged tolerances). The settled
    start must stay exactly at its (static equilibrium) energy.
    """
    traj = trajectory(idle_program(start_state), ELASTIC, experiment=UNDAMPED, options=CONVERGED)
    energy = mechanical_energy(traj.data, UNDAMPED.robot, ELASTIC)
    c = columns(traj.data)
    elastic_bed = 0.5 * ELASTIC["k"] * np.maximum(c["z"], 0.0) ** 2
    np.testing.assert_allclose(bed_energy(traj.data, ELASTIC), elastic_bed, rtol=1e-9, atol=1e-15)
    drift = np.max(np.abs(energy - energy[0]))
    assert drift < ENERGY_TOL, f"energy drift {drift:.2e} J"
    if start_state == "touching":
        assert c["z"].max() > 5e-3  # a real bounce on the bed, not a trivial rest


@pytest.mark.parametrize("command", COMMAND_NAMES)
def test_energy_changes_by_actuator_work_and_is_conserved_after_command(command: str) -> None:
    """Undamped leg on an elastic bed: E(t) - E(0) equals the actuator's work within 1e-7 J.

    The only non-conservative force is then the actuator's -m_motor alpha''(t) on the rod,
    so the energy balance checks the actuator coupling, the spring, gravity and the bed over
    the whole jump (up to ~2.7 J of work; observed imbalance <= 5e-10 J with converged
    tolerances). After the command ends (t >= T_end) the actuator is idle and E itself must
    be constant within 1e-7 J (observed <= 3e-10 J).
    """
    traj = trajectory(command, ELASTIC, experiment=UNDAMPED, options=CONVERGED)
    energy = mechanical_energy(traj.data, UNDAMPED.robot, ELASTIC)
    work = actuator_work(traj.data, traj.program, UNDAMPED.robot)
    imbalance = np.max(np.abs(energy - energy[0] - work))
    assert work[-1] > ENERGY_SCALE  # the actuator did real work
    assert imbalance < ENERGY_TOL, f"E - E0 - W up to {imbalance:.2e} J"
    after = traj.data["t_s"].to_numpy() >= traj.program.t_end
    assert after.sum() > 10
    drift = np.max(np.abs(energy[after] - energy[after][0]))
    assert drift < ENERGY_TOL, f"energy drift after the command {drift:.2e} J"


DISSIPATIVE_CASES = [
    pytest.param(Robot(c_spring=5.0), {"k": 3000.0, "r_unload": 1.0}, id="leg_damping"),
    pytest.param(Robot(c_spring=0.0), {"k": 3000.0, "r_unload": 20.0}, id="plastic_bed"),
    pytest.param(Robot(c_spring=0.0), {"k": 3000.0, "r_unload": 1.0, "c_d": 50.0}, id="drag"),
    pytest.param(
        Robot(c_spring=0.0),
        {"k": 3000.0, "r_unload": 20.0, "c_d": 50.0, "b": 20.0},
        id="plastic_bed-drag-viscous",
    ),
    pytest.param(Robot(c_spring=0.0), {"k": 3000.0, "r_unload": 3.0, "k2": 2e5}, id="stiffening"),
]


@pytest.mark.parametrize(("robot", "params"), DISSIPATIVE_CASES)
def test_dissipative_terms_only_remove_energy(robot: Robot, params: dict) -> None:
    """Leg damping, bed plasticity (r_unload > 1), drag and viscosity only dissipate.

    Actuator idle, touching start: E never rises by more than 1e-9 J between recorded
    points (observed <= 1e-14 J) and ends at least 1 mJ below its start (observed about 7
    to 100 mJ lost). With stiffening the bed is passive only while its unloading line is at
    least as steep as the loading curve, r_unload k >= k + 2 k2 z_max; the case is chosen so
    (a shallower line would return more work than the bed absorbed).
    """
    experiment = Experiment(robot=robot)
    traj = trajectory(idle_program(), params, experiment=experiment)
    energy = mechanical_energy(traj.data, robot, params)
    rise = np.max(np.diff(energy))
    assert rise < 1e-9, f"energy rose by {rise:.2e} J in one step"
    assert energy[-1] < energy[0] - 1e-3, f"only {energy[0] - energy[-1]:.2e} J dissipated"
    zmax = traj.data["z_max_mm"].max() * 1e-3
    k, k2, r = params["k"], params.get("k2", 0.0), params["r_unload"]
    assert r * k >= k + 2.0 * k2 * zmax


# ========================================================================================
# 3. properties over the realistic ranges
force_parameters = st.fixed_dictionaries(
    {name: st.floats(lo, hi) for name, (lo, hi) in RANGES.items()}
)
packing = st.floats(*PHI_RANGE)
commands = st.sampled_from(COMMAND_NAMES)


@given(command=commands, phi=packing, params=force_parameters)
def test_bed_force_and_crater_memory_follow_contract(
    command: str, phi: float, params: dict
) -> None:
    """Ground force and crater memory obey physics-model.md section 3 at every recorded point.

    * F_g >= 0; F_g = 0 when free; the recorded F_g equals the regime's law (advancing:
      k z + k2 z^2 + c_d z'^2 + b z'; contact: F_static(z_max) - r_unload k (z_max - z)),
      relative 1e-9;
    * the unloading line is used only where it pushes (contact: its force >= -r k * 1e-9 m)
      and the foot is off it when free (z <= z_free + 1e-9 m);
    * z_max never decreases; while advancing the foot is at the crater bottom (z = z_max)
      and moving down (v_f <= 1e-9 m/s); otherwise it is not below it (z <= z_max + 1e-9 m).

    1e-9 m is far above the event-location tolerance (1e-13 m) and far below any physics.
    """
    traj = trajectory(command, params, phi=phi)
    assert np.isfinite(traj.height_mm)
    c = columns(traj.data)
    k, k2, r = params["k"], params["k2"], params["r_unload"]
    z, zd, zmax, fg, mode = c["z"], -c["vf"], c["zmax"], c["fg"], c["mode"]
    advancing, contact, free = mode == "advancing", mode == "contact", mode == "free"
    line = k * zmax + k2 * zmax**2 - r * k * (zmax - z)
    law = np.where(advancing, k * z + k2 * z**2 + params["c_d"] * zd**2 + params["b"] * zd, line)
    assert np.all(fg >= 0.0)
    assert np.all(fg[free] == 0.0)
    np.testing.assert_allclose(fg[~free], np.maximum(law[~free], 0.0), rtol=1e-9, atol=1e-9)
    assert np.all(line[contact] >= -r * k * 1e-9)
    assert np.all(line[free] <= r * k * 1e-9)
    assert np.all(np.diff(zmax) >= -1e-12)
    assert np.all(np.abs(z[advancing] - zmax[advancing]) <= 1e-9)
    assert np.all(c["vf"][advancing] <= 1e-9)
    assert np.all(z[~advancing] <= zmax[~advancing] + 1e-9)


@given(command=commands, phi=packing, params=force_parameters)
def test_added_mass_is_the_jammed_cone_of_the_current_episode(
    command: str, phi: float, params: dict
) -> None:
    """m_a = kappa rho phi V(min(mu d, R tan 60)), d = z - z_entry, only while advancing.

    Checked at every recorded point: m_a is zero outside 'advancing', starts empty at each
    new advancing episode, grows monotonically within it, follows the formula within
    relative 1e-9 or 1e-10 kg (the entry depth is taken from the first recorded point of the
    episode, which the event finder places ~1e-12 m past the crater bottom: ~5e-12 kg of
    cone) and never exceeds the full cone kappa rho phi pi R^3 tan(60 deg) / 3.
    """
    experiment = Experiment()
    traj = trajectory(command, params, phi=phi, experiment=experiment)
    c = columns(traj.data)
    robot = experiment.robot
    scale = params["kappa"] * robot.grain_density * phi
    radius = robot.foot_radius
    full_cone = scale * math.pi * radius**3 * CONE_TAN / 3.0
    advancing = c["mode"] == "advancing"
    ma = c["ma"]
    assert np.all(ma[~advancing] == 0.0)
    assert np.all(ma <= full_cone * (1.0 + 1e-12))
    before = np.concatenate([[False], advancing[:-1]])
    after = np.concatenate([advancing[1:], [False]])
    starts = np.flatnonzero(advancing & ~before)
    ends = np.flatnonzero(advancing & ~after)
    assert len(starts) >= 1
    for s, e in zip(starts, ends, strict=True):
        h = np.minimum(CONE_MU * (c["z"][s : e + 1] - c["z"][s]), radius * CONE_TAN)
        volume = math.pi * h * (radius**2 - radius * h / CONE_TAN + h**2 / (3 * CONE_TAN**2))
        assert ma[s] <= 1e-10
        np.testing.assert_allclose(ma[s : e + 1], scale * volume, rtol=1e-9, atol=1e-10)
        assert np.all(np.diff(ma[s : e + 1]) >= -1e-15)  # round-off at the full cone


@given(command=commands, phi=packing, params=force_parameters)
def test_heights_finite_over_realistic_ranges(command: str, phi: float, params: dict) -> None:
    """Any realistic parameter set gives status OK and a finite height within +-1 m."""
    res = simulate(command, phi, params)
    assert res.status[0] == Status.OK, res.status_labels[0]
    assert np.isfinite(res.height_mm[0]) and abs(res.height_mm[0]) < 1000.0


@pytest.mark.parametrize("command", COMMAND_NAMES)
def test_batch_of_random_realistic_jumps_all_succeed(command: str) -> None:
    """2000 random realistic parameter sets in one batch: all status 0 with finite heights."""
    phi, params = random_parameters(2000, seed=1)
    res = simulate(command, phi, params)
    assert res.height_mm.shape == (2000,)
    assert np.all(res.status == Status.OK), np.unique(res.status, return_counts=True)
    assert np.all(np.isfinite(res.height_mm))


# ========================================================================================
# 4. failures are statuses
def test_bad_rows_give_bad_input_status_and_nan_without_raising() -> None:
    """Invalid rows (k < 0, r_unload = 0, phi = 1.5, NaN or inf) fail alone, as BAD_INPUT."""
    phi = np.array([0.6, 0.6, 0.6, 1.5, 0.6, 0.6, 0.6, 0.6])
    params = {
        "k": np.array([3000.0, -1.0, 3000.0, 3000.0, np.nan, 3000.0, 3000.0, 3000.0]),
        "r_unload": np.array([20.0, 20.0, 0.0, 20.0, 20.0, 20.0, 20.0, 20.0]),
        "c_d": np.array([0.0, 0.0, 0.0, 0.0, 0.0, -1.0, np.inf, 10.0]),
    }
    res = simulate("delayed_stutter", phi, params)
    good = np.array([True, False, False, False, False, False, False, True])
    assert np.all(res.status[good] == Status.OK)
    assert np.all(np.isfinite(res.height_mm[good]))
    assert np.all(res.status[~good] == Status.BAD_INPUT)
    assert np.all(np.isnan(res.height_mm[~good]))
    for i in np.flatnonzero(good):  # the good rows are unaffected by their neighbours
        one = simulate("delayed_stutter", phi[i], {k: v[i] for k, v in params.items()})
        assert one.height_mm[0] == res.height_mm[i]


def test_step_budget_exhaustion_gives_step_limit_status() -> None:
    """max_steps = 50 (a jump needs ~100) gives STEP_LIMIT and NaN, in batches and trajectories."""
    options = SolverOptions(max_steps=50)
    res = simulate("single", [0.6, 0.6], {"k": [3000.0, 5000.0]}, options=options)
    assert np.all(res.status == Status.STEP_LIMIT)
    assert np.all(np.isnan(res.height_mm))
    assert np.all(res.n_steps == 50)
    traj = simulate_trajectory("single", 0.6, {"k": 3000.0}, options=options)
    assert traj.status == Status.STEP_LIMIT and math.isnan(traj.height_mm)


def test_table_and_trajectory_report_bad_input_as_status() -> None:
    """simulate_table labels bad rows ``failed:bad-input``; a bad trajectory is just empty."""
    table = pd.DataFrame(
        {
            "command": ["single", "stutter", "preload"],
            "phi": [0.6, 0.6, 0.6],
            "k": [3000.0, -5.0, 3000.0],
            "r_unload": [20.0, 20.0, 0.0],
        }
    )
    out = simulate_table(table)
    assert list(out["status"]) == ["ok", "failed:bad-input", "failed:bad-input"]
    assert np.isfinite(out["height_mm"][0]) and out["height_mm"][1:].isna().all()
    traj = simulate_trajectory("single", 0.6, {"k": -3000.0})
    assert traj.status == Status.BAD_INPUT and math.isnan(traj.height_mm)
    assert traj.data.empty


# ========================================================================================
# 5. batches, threads, determinism
def test_batch_equals_single_calls_bitwise() -> None:
    """Each jump of a batch is bit-identical to the same jump simulated alone."""
    phi, params = random_parameters(16, seed=2)
    for command in ("single", "delayed_stutter_preload"):
        batch = simulate(command, phi, params)
        for i in range(len(phi)):
            one = simulate(command, phi[i], {k: v[i] for k, v in params.items()})
            assert one.height_mm[0] == batch.height_mm[i]
            assert one.status[0] == batch.status[i] and one.n_steps[0] == batch.n_steps[i]


def test_results_do_not_depend_on_thread_count_or_run() -> None:
    """One or two numba threads, and repeated runs, give bit-identical heights."""
    phi, params = random_parameters(200, seed=3)
    one = simulate("stutter", phi, params, n_threads=1)
    two = simulate("stutter", phi, params, n_threads=2)
    again = simulate("stutter", phi, params, n_threads=2)
    np.testing.assert_array_equal(one.height_mm, two.height_mm)
    np.testing.assert_array_equal(two.height_mm, again.height_mm)
    np.testing.assert_array_equal(one.n_steps, two.n_steps)


# ========================================================================================
# 6. hard ground (Aguilar et al. 2012)
def test_hard_ground_single_optimum_above_and_stutter_optimum_below_resonance() -> None:
    """On a rigid floor the best single jump is above f0 and the best stutter jump below it.

    k = 1e6 N/m with r_unload = 50 (a floor that keeps its tiny crater) approximates the
    hard ground of Aguilar et al. (2012), PRL 109, 174301. Sweep 4-30 Hz in 1 Hz steps;
    f0 = sqrt(k_spring / M) / 2 pi = 11.03 Hz. Observed optima: single 16 Hz, stutter 8 Hz.
    Both optima must be interior maxima of the sweep.
    """
    f0 = Robot().f0_hz
    freqs = np.arange(4.0, 31.0)
    hard = {"k": 1e6, "r_unload": 50.0}
    best = {}
    for command in ("single", "stutter"):
        heights = np.array(
            [
                height(command, hard, experiment=Experiment(command=CommandSettings(freq_hz=f)))
                for f in freqs
            ]
        )
        i = int(np.argmax(heights))
        assert 0 < i < len(freqs) - 1, f"{command}: maximum at the sweep edge {freqs[i]} Hz"
        best[command] = freqs[i]
    assert best["single"] > f0 > best["stutter"], f"f0 = {f0:.2f} Hz, optima {best}"


# ========================================================================================
# 7. start states and commands
def test_settled_start_is_static_equilibrium() -> None:
    """Settled start: F_static(z0) = (M + m_f) g, spring compressed M g / k_spring, at rest.

    With the actuator idle (and leg damping on) nothing may move: rod and foot stay within
    1e-9 m of the start for 1.4 s. k2 > 0 checks the root of the quadratic F_static.
    """
    robot = Robot()  # c_spring = 5
    params = {"k": 3000.0, "k2": 1e5, "c_d": 20.0, "kappa": 1.0, "r_unload": 20.0}
    traj = trajectory(idle_program("settled"), params, experiment=Experiment(robot=robot))
    c = columns(traj.data)
    weight = (robot.m_upper + robot.m_foot) * G
    z0 = c["z"][0]
    assert params["k"] * z0 + params["k2"] * z0**2 == pytest.approx(weight, rel=1e-12)
    assert c["zmax"][0] == pytest.approx(z0, rel=1e-12)
    assert c["fg"][0] == pytest.approx(weight, rel=1e-12)
    assert c["xf"][0] - c["xr"][0] == pytest.approx(robot.m_upper * G / robot.k_spring)
    assert c["vf"][0] == 0.0 and c["vr"][0] == 0.0
    assert np.max(np.abs(c["xf"] - c["xf"][0])) < 1e-9
    assert np.max(np.abs(c["xr"] - c["xr"][0])) < 1e-9


def test_touching_start_is_at_rest_on_the_surface() -> None:
    """Touching start: foot on the undisturbed surface, spring at rest length, at rest."""
    traj = trajectory("single", {"k": 3000.0})
    first = traj.data.iloc[0]
    for name in ("t_s", "x_rod_mm", "x_foot_mm", "v_rod_m_s", "v_foot_m_s", "z_max_mm"):
        assert first[name] == 0.0, name
    assert first["mode"] == "advancing"  # gravity pushes the foot into the grains


def table_alpha(command: str, s: CommandSettings, t: np.ndarray) -> np.ndarray:
    """alpha(t) [m] as tabulated in physics-model.md section 4 (held outside the commands)."""
    a, period, w = s.amplitude, s.period, 2.0 * math.pi * s.freq_hz
    out = np.empty_like(t)
    if command in ("single", "preload"):
        tt = np.clip(t, 0.0, period)
        return -a * np.cos(w * tt)
    if command == "stutter":
        tt = np.clip(t, 0.0, 1.5 * period)
        return a * np.cos(w * tt)
    hold = s.delay if command == "delayed_stutter" else s.settle_periods * period
    first = t <= 0.5 * period
    out[first] = a * np.cos(w * np.maximum(t[first], 0.0))
    held = (t > 0.5 * period) & (t <= 0.5 * period + hold)
    out[held] = -a
    last = t > 0.5 * period + hold
    out[last] = -a * np.cos(w * np.minimum(t[last] - 0.5 * period - hold, period))
    return out


@pytest.mark.parametrize("command", COMMAND_NAMES)
def test_command_waveforms_match_the_model_table(command: str) -> None:
    """alpha(t) of each command equals physics-model.md section 4 (within 1e-15 m).

    Checked for the default settings and for another amplitude, frequency, delay and
    settle time, from before the start to well after the end.
    """
    for settings in (CommandSettings(), CommandSettings(15.0, 13.0, 35.0, 2.5)):
        program = build_command(command, settings)
        t = np.linspace(-0.05, program.t_end + 0.1, 4001)
        np.testing.assert_allclose(
            program.alpha(t), table_alpha(command, settings, t), rtol=0, atol=1e-15
        )


@pytest.mark.parametrize("command", COMMAND_NAMES)
def test_command_waveform_is_c1_at_segment_boundaries(command: str) -> None:
    """alpha and alpha' are continuous at every segment boundary (only alpha'' jumps).

    A jump in alpha would be an infinite actuator force; a jump in alpha' an impulse. One-
    sided differences with eps = 1e-7 s: values agree within A w eps (1e-5 of A) and slopes
    within A w^2 eps (1e-5 of A w).
    """
    settings = CommandSettings()
    program = build_command(command, settings)
    a, w, eps = settings.amplitude, program.omega, 1e-7
    for b in program.boundaries:
        left = program.alpha(np.array([b - 2 * eps, b - eps]))
        right = program.alpha(np.array([b + eps, b + 2 * eps]))
        assert abs(right[0] - left[1]) <= 2.0 * a * w * eps + 1e-15, f"alpha jumps at {b}"
        slope_left = (left[1] - left[0]) / eps
        slope_right = (right[1] - right[0]) / eps
        assert abs(slope_right - slope_left) <= 4.0 * a * w**2 * eps, f"alpha' jumps at {b}"


@pytest.mark.parametrize("command", COMMAND_NAMES)
def test_pushoff_times_and_start_states(command: str) -> None:
    """The height window opens at 0, 0, T/2, T/2 + delay, T/2 + settle T (section 5)."""
    s = CommandSettings(freq_hz=12.0, delay_ms=30.0, settle_periods=2.0)
    expected = {
        "single": 0.0,
        "preload": 0.0,
        "stutter": s.period / 2,
        "delayed_stutter": s.period / 2 + s.delay,
        "delayed_stutter_preload": s.period / 2 + s.settle_periods * s.period,
    }[command]
    program = build_command(command, s)
    assert program.t_pushoff == pytest.approx(expected, abs=1e-15)
    assert program.start_state == ("settled" if command == "preload" else "touching")
    assert program.t_end - program.t_pushoff == pytest.approx(s.period, abs=1e-15)


@pytest.mark.parametrize("command", COMMAND_NAMES)
def test_trajectory_actuator_follows_the_program(command: str) -> None:
    """The integrator's actuator position (alpha_mm) equals the program's alpha(t), 1e-9 mm."""
    traj = trajectory(command, {"k": 3000.0, "c_d": 30.0})
    t = traj.data["t_s"].to_numpy()
    np.testing.assert_allclose(
        traj.data["alpha_mm"].to_numpy(), traj.program.alpha(t) * 1e3, rtol=0, atol=1e-9
    )


def test_zero_hold_delayed_commands_equal_the_stutter() -> None:
    """With a zero hold, both delayed stutters are the stutter waveform: equal heights.

    The zero-length hold segment is an extra (empty) segment boundary at T/2; it must not
    change the solution (within 1e-9 mm, default and converged tolerances).
    """
    params = {"k": 3000.0, "c_d": 30.0, "kappa": 0.5, "r_unload": 20.0}
    zero_delay = Experiment(command=CommandSettings(delay_ms=0.0))
    zero_settle = Experiment(command=CommandSettings(settle_periods=0.0))
    for options in (SolverOptions(), CONVERGED):
        stutter = height("stutter", params, options=options)
        assert height(
            "delayed_stutter", params, options=options, experiment=zero_delay
        ) == pytest.approx(stutter, abs=1e-9)
        assert height(
            "delayed_stutter_preload", params, options=options, experiment=zero_settle
        ) == pytest.approx(stutter, abs=1e-9)


# ========================================================================================
# 8. the jump height
HEIGHT_CASES = [
    pytest.param(command, params, id=f"{command}-{label}")
    for command in COMMAND_NAMES
    for label, params in (
        ("plastic", {"k": 3000.0, "c_d": 30.0, "kappa": 0.5}),
        ("elastic", {"k": 3000.0, "r_unload": 1.0}),
    )
]


@pytest.mark.parametrize(("command", "params"), HEIGHT_CASES)
def test_height_is_highest_foot_position_in_the_window(command: str, params: dict) -> None:
    """H = max of x_f from the push-off start until touchdown (or T_end + 0.6 s).

    The record samples the trajectory (steps <= 0.5 ms), so its maximum may fall below the
    exactly located apex by g dt^2 / 8 ~ 3e-4 mm: it must lie within 0.01 mm below H and
    never above it (1e-6 mm). The trajectory's height also equals simulate()'s, within
    1e-5 mm with converged tolerances (different step sequences).
    """
    traj = trajectory(command, params)
    window = traj.data["t_s"].to_numpy() >= traj.program.t_pushoff
    recorded = traj.data["x_foot_mm"].to_numpy()[window].max()
    assert recorded <= traj.height_mm + 1e-6
    assert traj.height_mm - recorded < 0.01, f"H {traj.height_mm:.5f}, record {recorded:.5f}"
    converged = trajectory(command, params, options=CONVERGED)
    assert converged.height_mm == pytest.approx(
        height(command, params, options=CONVERGED), abs=1e-5
    )


def test_height_window_closes_window_after_the_command_if_still_airborne() -> None:
    """Section 5: the window also closes ``window_after`` after the command, even mid-flight.

    With window_after = 0.02 s a 68 mm single jump is still rising when the window closes:
    the record ends exactly at T_end + 0.02 s with the foot in the air, and H is the height
    reached by then (the last, highest recorded point, within 1e-9 mm).
    """
    options = dataclasses.replace(CONVERGED, window_after=0.02)
    traj = trajectory("single", {"k": 3000.0, "r_unload": 1.0}, options=options)
    data = traj.data
    assert data["t_s"].iloc[-1] == pytest.approx(traj.program.t_end + 0.02, abs=1e-12)
    assert data["x_foot_mm"].iloc[-1] > 0.0 and data["v_foot_m_s"].iloc[-1] > 0.0
    assert traj.height_mm == pytest.approx(data["x_foot_mm"].max(), abs=1e-9)
    assert traj.height_mm < height("single", {"k": 3000.0, "r_unload": 1.0}) - 1.0


# ========================================================================================
# known limitation of the trajectory recorder
def test_trajectory_record_is_complete_with_tight_tolerances() -> None:
    """A converged trajectory on hard ground (~15000 steps) is recorded to its end."""
    traj = trajectory("delayed_stutter", {"k": 1e6, "r_unload": 50.0}, options=CONVERGED)
    assert traj.data["t_s"].iloc[-1] > traj.program.t_end
