"""The oracle's other measurements (physics-model.md section 5b): trajectories and intrusions.

:func:`granbayes.testing.simulate_trajectory_scipy` reads the foot height and the rod's
displacement at arbitrary frame times from solve_ivp's dense output, with the height of
the same simulation; :func:`granbayes.testing.intrusion_force_scipy` is the closed-form
force of a constant-speed intrusion into a fresh bed. The tests check them against the
height oracle, the start states of section 4, their own tolerance refinement, free-flight
mechanics, and the identities of section 5b (the quasi-static loading curve, the rate
terms, the depth dependence of the added-mass flux).
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from granbayes._experiment import Experiment, G
from granbayes.commands import build_command
from granbayes.testing import (
    TRACK_AFTER_END,
    intrusion_force_scipy,
    simulate_height_scipy,
    simulate_trajectory_scipy,
)

LAW = {"k": 3000.0, "c_d": 20.0, "r_unload": 20.0}
#: A law with every jump-relevant term (added mass, stiffening, viscous, compaction).
FULL = {"k": 3000.0, "c_d": 30.0, "kappa": 1.0, "k2": 5e4, "b": 10.0, "c_comp": 0.5}


def _window_end(traj, program, h_flight_mm: float = 1.0) -> float:
    """End of the height window, from fine frames: the first downward crossing of x_f = 0
    after the command that follows a flight of h_flight (section 5), else end + 0.6 s."""
    t, x = traj.t_s, traj.x_foot_mm
    after = t >= program.t_end
    flown = np.maximum.accumulate(np.where(after, x, -np.inf)) >= h_flight_mm
    down = np.flatnonzero(after[1:] & flown[:-1] & (x[:-1] >= 0.0) & (x[1:] < 0.0))
    return float(t[down[0] + 1]) if down.size else program.t_end + 0.6


@pytest.mark.parametrize(
    ("command", "params"),
    [("single", LAW), ("preload", FULL), ("delayed_stutter", LAW)],
)
def test_trajectory_height_is_the_height_oracle_and_the_highest_frame(command, params) -> None:
    """The trajectory's height is simulate_height_scipy's, bit for bit (the same solve_ivp
    runs), and the highest of 20 kHz frames in the height window is that height within
    1e-4 mm (at the apex x_f' = 0: a frame misses it by at most g (25 us)^2 / 8 ~ 1e-9 m)."""
    program = build_command(command)
    t = np.arange(0.0, program.t_end + 0.6, 5e-5)
    traj = simulate_trajectory_scipy(command, 0.605, params, t)
    height = simulate_height_scipy(command, 0.605, params)
    assert traj.height_mm == height
    window = (t >= program.t_pushoff) & (t <= _window_end(traj, program))
    assert traj.x_foot_mm[window].max() == pytest.approx(height, abs=1e-4)
    assert traj.t_end_s == program.t_end


@pytest.mark.parametrize("command", ["single", "preload"])
def test_before_the_command_the_robot_rests_in_its_start_state(command) -> None:
    """t < 0: touching (x_f = 0) or settled (F_static(z0) = weight, z0 = W / k), at rest,
    rod displacement 0; the motion at t >= 0 starts from there (continuous at t = 0)."""
    t = np.array([-1.0, -1e-3, 0.0, 1e-9])
    traj = simulate_trajectory_scipy(command, 0.6, {"k": 3000.0}, t)
    robot = Experiment().robot
    z0 = 0.0 if command == "single" else (robot.m_upper + robot.m_foot) * G / 3000.0
    np.testing.assert_array_equal(traj.x_foot_mm[:3], -1e3 * z0)
    np.testing.assert_array_equal(traj.x_rod_mm[:3], 0.0)
    np.testing.assert_array_equal(traj.v_foot_m_s[:2], 0.0)
    np.testing.assert_array_equal(traj.v_rod_m_s[:2], 0.0)
    assert abs(traj.x_foot_mm[3] + 1e3 * z0) < 1e-9


def test_trajectory_converges_under_tolerance_refinement() -> None:
    """Frames (through the landing, beyond the height window) at rtol 1e-7, 1e-9, 1e-11
    against rtol 1e-12: the error falls with the tolerance, to below 1e-5 mm at 1e-11."""
    command = "single"
    program = build_command(command)
    t = np.linspace(-0.01, program.t_end + 0.4, 400)
    reference = simulate_trajectory_scipy(command, 0.6, LAW, t, rtol=1e-12, atol=1e-14)
    errors = []
    for rtol in (1e-7, 1e-9, 1e-11):
        traj = simulate_trajectory_scipy(command, 0.6, LAW, t, rtol=rtol, atol=rtol * 1e-3)
        errors.append(
            max(
                np.abs(traj.x_foot_mm - reference.x_foot_mm).max(),
                np.abs(traj.x_rod_mm - reference.x_rod_mm).max(),
            )
        )
    assert errors[0] > errors[1] > errors[2]
    assert errors[2] < 1e-5, errors
    assert errors[0] < 0.05, errors


def test_frames_in_any_order_and_across_restarts() -> None:
    """Shuffled and repeated frame times give the same values; the dense output is
    continuous across the restarts of solve_ivp (regime changes, touchdown)."""
    program = build_command("single")
    t = np.linspace(-0.02, program.t_end + 0.4, 301)
    traj = simulate_trajectory_scipy("single", 0.6, LAW, t)
    order = np.random.default_rng(3).permutation(t.size)
    again = simulate_trajectory_scipy("single", 0.6, LAW, np.concatenate([t[order], t[:5]]))
    np.testing.assert_array_equal(again.x_foot_mm[: t.size], traj.x_foot_mm[order])
    np.testing.assert_array_equal(again.x_rod_mm[t.size :], traj.x_rod_mm[:5])
    fine = np.linspace(0.0, program.t_end + 0.4, 10001)  # 50 us apart
    dense = simulate_trajectory_scipy("single", 0.6, LAW, fine)
    # |x(t + dt) - x(t)| <= max|v| dt + tiny: no jump of the position anywhere
    dt = np.diff(fine)
    bound = np.maximum(np.abs(dense.v_foot_m_s[1:]), np.abs(dense.v_foot_m_s[:-1])) * dt
    assert np.all(np.abs(np.diff(dense.x_foot_mm)) <= 1e3 * bound * 1.5 + 1e-6)


def test_in_flight_the_centre_of_mass_falls_freely() -> None:
    """After the command the actuator holds; while the foot is in the air the robot's
    centre of mass, from the frames (x_r = its displacement, touching start), follows
    a parabola of curvature -g to 1e-6 mm (a check of x_rod and x_foot together)."""
    command = "single"
    program = build_command(command)
    robot = Experiment().robot
    alpha_end = float(program.alpha(np.array([program.t_end + 1.0]))[0])
    t = np.linspace(program.t_end, program.t_end + 0.6, 3001)
    traj = simulate_trajectory_scipy(command, 0.612, {"k": 3000.0}, t)
    flight = np.flatnonzero(traj.x_foot_mm > 0.0)
    first = flight[: np.argmax(np.diff(flight) > 1)] if np.any(np.diff(flight) > 1) else flight
    tf = t[first]
    x_rod, x_foot = 1e-3 * traj.x_rod_mm[first], 1e-3 * traj.x_foot_mm[first]
    mass = robot.m_rod + robot.m_motor + robot.m_foot
    com = (robot.m_rod * x_rod + robot.m_motor * (x_rod + alpha_end) + robot.m_foot * x_foot) / mass
    coef = np.polyfit(tf - tf[0], com, 2)
    assert coef[0] == pytest.approx(-G / 2.0, rel=1e-7)
    assert np.abs(np.polyval(coef, tf - tf[0]) - com).max() < 1e-9


def test_the_motion_goes_on_after_the_landing() -> None:
    """Frames beyond the height window: the robot has landed back in the bed 0.3 s after
    the command (the height window closed at the touchdown, ~0.2 s)."""
    program = build_command("single")
    t = np.array([program.t_end + 0.3])
    traj = simulate_trajectory_scipy("single", 0.6, LAW, t)
    assert traj.x_foot_mm[0] < -10.0


@pytest.mark.slow
def test_the_robot_comes_to_rest_in_the_bed() -> None:
    """Up to the limit of 5 s after the command: the robot settles in its crater."""
    program = build_command("single")
    t = np.array([program.t_end + 2.0, program.t_end + TRACK_AFTER_END])
    traj = simulate_trajectory_scipy("single", 0.6, LAW, t)
    assert np.all(traj.x_foot_mm < 0.0)
    assert np.all(np.abs(traj.v_foot_m_s) < 1e-2)
    assert abs(traj.v_foot_m_s[-1]) < 1e-4


def test_frames_too_late_or_not_finite_are_refused() -> None:
    program = build_command("single")
    limit = program.t_end + TRACK_AFTER_END
    with pytest.raises(ValueError, match="after the command's end"):
        simulate_trajectory_scipy("single", 0.6, LAW, [0.0, limit + 1e-3])
    with pytest.raises(ValueError, match="finite"):
        simulate_trajectory_scipy("single", 0.6, LAW, [0.0, math.nan])
    with pytest.raises(ValueError, match="one-dimensional"):
        simulate_trajectory_scipy("single", 0.6, LAW, [[0.0, 0.1]])
    empty = simulate_trajectory_scipy("single", 0.6, LAW, [])
    assert empty.x_foot_mm.shape == (0,)
    assert empty.height_mm == simulate_height_scipy("single", 0.6, LAW)
    frame = simulate_trajectory_scipy("single", 0.6, LAW, [0.0, 0.05]).frame()
    assert list(frame.columns) == ["t_s", "x_foot_mm", "x_rod_mm"]


# ----------------------------------------------------------------------------------------
# intrusion tests
DEPTHS = np.arange(0.0, 60.5, 0.5)  # [mm]; the default cone is full at 30.3 mm
R = Experiment().robot.foot_radius
RHO = Experiment().robot.grain_density
Z_FULL_MM = 1e3 * R * math.tan(math.radians(60.0)) / 2.0


def test_quasi_static_intrusion_reads_the_loading_curve() -> None:
    """v = 0, no cone: F = F_static(z) = k z + k2 z^2; the other terms do not act. With
    the cone, F_static - m_a(z) g (the carried grains' weight, <= 0.5 N here), and a
    vanishing speed tends to v = 0."""
    law = {"k": 2500.0, "k2": 4e4, "c_d": 50.0, "b": 20.0, "c_comp": 1.0, "r_unload": 3.0}
    z = 1e-3 * DEPTHS
    static = intrusion_force_scipy(0.6, law, DEPTHS, 0.0)
    np.testing.assert_allclose(static, 2500.0 * z + 4e4 * z**2, rtol=1e-14, atol=1e-12)
    with_cone = intrusion_force_scipy(0.6, {**law, "kappa": 1.0}, DEPTHS, 0.0)
    weight = static - with_cone
    assert weight[0] == 0.0 and np.all(np.diff(weight) >= -1e-12)  # round-off of F - F
    assert 0.4 < weight[-1] < 0.6
    np.testing.assert_allclose(weight[DEPTHS >= Z_FULL_MM + 0.5], weight[-1], atol=1e-12)
    slow = intrusion_force_scipy(0.6, {**law, "kappa": 1.0}, DEPTHS, 1e-6)
    np.testing.assert_allclose(slow, with_cone, atol=1e-6)


def test_rate_terms_of_an_intrusion() -> None:
    """Without the cone, F(z, v) - F(z, 0) = c_d v^2 + b v at every depth."""
    law = {"k": 2500.0, "c_d": 50.0, "b": 20.0}
    for speed in (10.0, 300.0):
        v = 1e-3 * speed
        diff = intrusion_force_scipy(0.6, law, DEPTHS, speed) - intrusion_force_scipy(
            0.6, law, DEPTHS, 0.0
        )
        np.testing.assert_allclose(diff, 50.0 * v**2 + 20.0 * v, rtol=1e-9)


def test_added_mass_flux_falls_with_depth() -> None:
    """(F(z, v) - F(z, 0)) / v^2 with only the cone = kappa rho phi V'(z): mu pi R^2 at the
    surface, falling to 0 where the cone is full (z = R tan(theta) / mu = 30.3 mm), 0
    beyond; integrated over depth it gives the full cone's mass (V' is dV/dz)."""
    phi, kappa, speed = 0.6, 1.5, 400.0
    law = {"k": 2000.0, "kappa": kappa}
    v = 1e-3 * speed
    fine = np.linspace(0.0, 40.0, 40001)
    flux = (
        intrusion_force_scipy(phi, law, fine, speed) - intrusion_force_scipy(phi, law, fine, 0.0)
    ) / v**2
    density = kappa * RHO * phi
    assert flux[0] == pytest.approx(density * 2.0 * math.pi * R**2, rel=1e-12)
    inside = fine < Z_FULL_MM
    assert np.all(np.diff(flux[inside]) < 0.0)
    np.testing.assert_array_equal(flux[fine >= Z_FULL_MM], 0.0)
    # the carried mass at depth: the quasi-static force's deficit below k z, over g
    deficit = (2000.0 * 1e-3 * fine - intrusion_force_scipy(phi, law, fine, 0.0)) / G
    mass_from_flux = np.concatenate([[0.0], np.cumsum(0.5 * (flux[1:] + flux[:-1]) * 1e-6)])
    np.testing.assert_allclose(mass_from_flux, deficit, atol=1e-9)
    assert deficit[-1] == pytest.approx(deficit[inside][-1], rel=1e-4)


def test_intrusion_is_vectorised_and_checks_its_input() -> None:
    grid = np.arange(12.0).reshape(3, 4)
    out = intrusion_force_scipy(0.6, LAW, grid, 100.0)
    assert out.shape == (3, 4)
    np.testing.assert_array_equal(out.ravel(), intrusion_force_scipy(0.6, LAW, grid.ravel(), 100.0))
    assert intrusion_force_scipy(0.6, LAW, 5.0, 0.0).shape == ()
    with pytest.raises(ValueError, match="depths"):
        intrusion_force_scipy(0.6, LAW, [-1.0], 1.0)
    with pytest.raises(ValueError, match="speed"):
        intrusion_force_scipy(0.6, LAW, [1.0], -1.0)
    with pytest.raises(KeyError, match="dilation"):
        intrusion_force_scipy(0.6, {"k": 1.0, "dilation": 2.0}, [1.0], 1.0)
    smaller = Experiment().replace(foot_radius=0.02)
    at_surface = intrusion_force_scipy(0.6, {"k": 1.0, "kappa": 1.0}, [0.0], 100.0, smaller)
    assert at_surface[0] == pytest.approx(RHO * 0.6 * 2.0 * math.pi * 0.02**2 * 0.1**2)
