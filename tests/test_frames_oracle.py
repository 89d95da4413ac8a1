"""Tracked jumps and intrusion tests against the independent scipy oracle (section 5b).

The oracle (``granbayes.testing``: ``simulate_trajectory_scipy``, ``intrusion_force_scipy``)
is written from the contract with solve_ivp and its dense output; it shares no code with
the kernel's dense output or ground force. For every command and every term of the
library: positions and velocities at frames from before the start, through the jump, the
landing and what follows, and the height of the same simulation; the intrusion force of
every term at several speeds.

Tolerances (frames at 1000 fps to 0.5 s after the command; the oracle is DOP853 at rtol
1e-9, atol 1e-12, its states' velocities from the same dense output as its positions):

* Positions: converged settings within 1e-4 mm (observed at most 1e-5 mm); the defaults
  within 0.05 mm (observed at most 0.013 mm), the contract's tolerance of a height, far
  below a camera's noise.
* Velocities (which reach 3000 mm/s): converged settings within 0.02 mm/s (observed at
  most 0.005 mm/s); the defaults within 20 mm/s (observed at most 10 mm/s, 0.3 % of the
  largest velocity, in the landing after the jump's end; at most 0.7 mm/s before it). The
  error at the defaults is the integrator's own: the frames inside the steps are as
  accurate as its states at the steps' ends (velocity error of foot and rod of the order
  of the contact's frequency, ~1000 /s, times the position error).
* As the tolerance tightens (rtol 1e-5, 1e-7, 1e-9 against the oracle at rtol 1e-11), the
  errors of positions and velocities fall by at least 10x per two decades and 1000x over
  the four (observed 18x to 1000x per two decades), closed form on and off.
"""

from __future__ import annotations

import importlib

import numpy as np
import pytest

from granbayes._experiment import Experiment, Robot
from granbayes._simulator import SolverSettings, intrusion_force, simulate_frames
from granbayes.commands import COMMAND_NAMES, CommandSettings, build_command
from granbayes.forces import TERMS

_testing = importlib.import_module("granbayes.testing")
if not (
    hasattr(_testing, "simulate_trajectory_scipy") and hasattr(_testing, "intrusion_force_scipy")
):
    pytest.skip(
        "granbayes.testing has no simulate_trajectory_scipy / intrusion_force_scipy yet",
        allow_module_level=True,
    )
simulate_trajectory_scipy = _testing.simulate_trajectory_scipy
intrusion_force_scipy = _testing.intrusion_force_scipy

PHI = 0.6
#: Each term of the library on its own (at the top of its realistic range) with the
#: required ``depth`` term, and all of them together.
LAWS: dict[str, dict[str, float]] = {
    name: {"k": 3000.0, **{p.name: p.typical[1] for p in term.parameters}}
    for name, term in TERMS.items()
}
LAWS["all"] = {
    "k": 3000.0,
    "c_d": 20.0,
    "kappa": 1.0,
    "b": 5.0,
    "k2": 5e4,
    "r_unload": 10.0,
    "c_comp": 0.5,
}

#: Tolerances of the positions [mm] and velocities [mm/s] (see the module's docstring).
CONVERGED_MM = 1e-4
DEFAULT_MM = 0.05
CONVERGED_MM_S = 0.02
DEFAULT_MM_S = 20.0

#: Every command with every term on (fast), every term on the single jump (fast), and the
#: full matrix of commands and terms (slow).
FAST_CASES = [(command, "all") for command in COMMAND_NAMES] + [("single", term) for term in TERMS]
SLOW_CASES = [
    (command, term)
    for command in COMMAND_NAMES
    for term in LAWS
    if (command, term) not in FAST_CASES
]


def frames_of(command: str, experiment: Experiment | None = None) -> np.ndarray:
    """Frames at 1000 fps from 10 ms before the start to 0.5 s after the command."""
    settings = (experiment or Experiment()).command
    t_end = build_command(command, settings).t_end
    return np.arange(-10, int((t_end + 0.5) * 1000)) / 1000.0


def check_against_oracle(
    command: str,
    law: dict[str, float],
    experiment: Experiment | None = None,
    window_after: float = 0.6,
) -> None:
    """Frames and height of the kernel (converged and default) against the oracle's."""
    frames = frames_of(command, experiment)
    oracle = simulate_trajectory_scipy(
        command, PHI, law, frames, experiment=experiment, window_after=window_after
    )
    for options, tol, tol_v in (
        (SolverSettings.converged(), CONVERGED_MM, CONVERGED_MM_S),
        (SolverSettings(), DEFAULT_MM, DEFAULT_MM_S),
    ):
        options = SolverSettings(**{**options.__dict__, "window_after": window_after})
        jump = simulate_frames(command, PHI, law, frames, experiment=experiment, settings=options)
        assert jump.height_mm == pytest.approx(oracle.height_mm, abs=tol)
        for column, want, atol in oracle_columns(oracle, tol, tol_v):
            np.testing.assert_allclose(jump.data[column], want, rtol=0, atol=atol, err_msg=column)


def oracle_columns(
    oracle: object, tol_mm: float, tol_mm_s: float
) -> list[tuple[str, np.ndarray, float]]:
    """The oracle's frames in the kernel's columns and units, each with its tolerance."""
    return [
        ("x_foot_mm", oracle.x_foot_mm, tol_mm),
        ("x_rod_mm", oracle.x_rod_mm, tol_mm),
        ("v_foot_mm_s", 1e3 * oracle.v_foot_m_s, tol_mm_s),
        ("v_rod_mm_s", 1e3 * oracle.v_rod_m_s, tol_mm_s),
    ]


@pytest.mark.parametrize(("command", "term"), FAST_CASES)
def test_frames_agree_with_the_oracle(command: str, term: str) -> None:
    check_against_oracle(command, LAWS[term])


@pytest.mark.slow
@pytest.mark.parametrize(("command", "term"), SLOW_CASES)
def test_frames_agree_with_the_oracle_for_every_command_and_term(command: str, term: str) -> None:
    check_against_oracle(command, LAWS[term])


def test_frames_agree_with_the_oracle_for_another_robot_and_settings() -> None:
    """A lab's own robot and command settings, the settled start (delayed stutter preload is
    touching; preload settled)."""
    experiment = Experiment(
        robot=Robot(m_motor=0.9, m_rod=0.25, m_foot=0.09, k_spring=4900.0, foot_radius=0.04),
        command=CommandSettings(amplitude_mm=16.0, freq_hz=12.0, delay_ms=30.0),
    )
    for command in ("preload", "delayed_stutter"):
        check_against_oracle(command, LAWS["all"], experiment=experiment)


def test_frames_agree_with_the_oracle_when_the_window_closes_mid_flight() -> None:
    """window_after = 0.02 s: the height is the window's, the frames fly on and land."""
    check_against_oracle("single", {"k": 3000.0, "r_unload": 1.0}, window_after=0.02)


@pytest.mark.parametrize("command", COMMAND_NAMES)
def test_frames_converge_to_the_oracle_as_the_tolerance_tightens(command: str) -> None:
    """Positions and velocities against a tight oracle (rtol 1e-11): the error falls by at
    least 10x per two decades of rtol and 1000x over the four, closed form on and off, and
    at rtol 1e-9 it is within 1e-5 mm and 2e-3 mm/s (observed at most 1.6e-6 mm and
    7e-4 mm/s)."""
    frames = frames_of(command)
    oracle = simulate_trajectory_scipy(command, PHI, LAWS["all"], frames, rtol=1e-11, atol=1e-13)
    want = oracle_columns(oracle, 0.0, 0.0)
    for closed in (True, False):
        x_err, v_err = [], []
        for rtol in (1e-5, 1e-7, 1e-9):
            options = SolverSettings(
                rtol=rtol, atol_position=1e-2 * rtol, atol_velocity=rtol, closed_form=closed
            )
            data = simulate_frames(command, PHI, LAWS["all"], frames, settings=options).data
            err = [float(np.abs(data[column] - values).max()) for column, values, _ in want]
            x_err.append(max(err[:2]))
            v_err.append(max(err[2:]))
        for errors in (x_err, v_err):
            assert errors[1] < errors[0] / 10.0 and errors[2] < errors[1] / 10.0, (x_err, v_err)
            assert errors[2] < errors[0] / 1000.0, (x_err, v_err)
        assert x_err[2] < 1e-5 and v_err[2] < 2e-3, (x_err, v_err)


@pytest.mark.parametrize("term", [*TERMS, "all"])
def test_intrusion_force_agrees_with_the_oracle(term: str) -> None:
    """Every term, quasi-static to fast, from the surface to beyond the full cone."""
    depth = np.linspace(0.0, 70.0, 141)
    for speed in (0.0, 10.0, 300.0, 2000.0):
        got = intrusion_force(PHI, LAWS[term], depth, speed)
        want = intrusion_force_scipy(PHI, LAWS[term], depth, speed)
        np.testing.assert_allclose(got, want, rtol=1e-12, atol=1e-10)


def test_intrusion_force_agrees_with_the_oracle_for_another_foot() -> None:
    experiment = Experiment(robot=Robot(foot_radius=0.05, grain_density=1300.0))
    depth = np.linspace(0.0, 70.0, 71)
    got = intrusion_force(0.62, LAWS["all"], depth, 500.0, experiment=experiment)
    want = intrusion_force_scipy(0.62, LAWS["all"], depth, 500.0, experiment=experiment)
    np.testing.assert_allclose(got, want, rtol=1e-12, atol=1e-10)
