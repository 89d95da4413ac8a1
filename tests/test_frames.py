"""Measurements beyond jump heights (physics-model.md section 5b): tracked jumps and
intrusion tests.

Tracked jumps: the positions and velocities at frame times come from the dense output of
the integrator's own accepted steps (exact closed form and its derivative in the linear
regimes, a quintic Hermite interpolant and its derivative in the Dormand-Prince ones).
They are checked against the recorded states of ``simulate_trajectory`` (exact integrator
states), against a very tight reference as the tolerance tightens, with fixed steps for
the order, and for the semantics of the contract: heights bit for bit those of untracked
jumps, the start state before t = 0, the motion on after the jump's end, NaN and the
status for a failed jump; and the layout of the result (``frames``: jumps x frames x
``FRAME_COLUMNS``).

Intrusion tests: the force is the kernel's own advancing-regime ground force on a fresh
bed; checked against the contract's formula, its quasi-static limit (the loading curve),
the depth dependence of the added-mass flux and the sign of every term's contribution.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

import granbayes as gb
from granbayes import _kernel
from granbayes._experiment import Experiment, Robot
from granbayes._simulator import (
    FRAME_COLUMNS,
    MAX_FRAME_AFTER_S,
    SolverSettings,
    Status,
    build_rows,
    intrusion_force,
    intrusion_force_rows,
    simulate_frames,
    simulate_frames_rows,
    simulate_rows,
    simulate_trajectory,
)
from granbayes.commands import COMMAND_NAMES, build_command
from granbayes.forces import PARAMETER_NAMES, TERMS, typical_ranges

#: A law with every term of the library on (realistic values).
LAW = {
    "k": 3000.0,
    "c_d": 20.0,
    "kappa": 1.0,
    "b": 5.0,
    "k2": 5e4,
    "r_unload": 10.0,
    "c_comp": 0.5,
}
PHI = 0.6
#: The recorded trajectory's largest step [s] (simulate_trajectory's default).
RECORD_STEP = 5e-4
TIGHT = SolverSettings(rtol=1e-12, atol_position=1e-14, atol_velocity=1e-12)
POSITIONS = ["x_foot_mm", "x_rod_mm"]
VELOCITIES = ["v_foot_mm_s", "v_rod_mm_s"]


def max_error(got, ref, columns: list[str]) -> float:
    """Largest absolute difference of the given columns of two frame tables."""
    return float(np.abs(got[columns].to_numpy() - ref[columns].to_numpy()).max())


def random_rows(n: int, seed: int) -> tuple[np.ndarray, np.ndarray]:
    """Rows of realistic random laws and the command of each (the five in turn)."""
    rng = np.random.default_rng(seed)
    params = {name: rng.uniform(lo, hi, n) for name, (lo, hi) in typical_ranges().items()}
    phi = rng.uniform(0.592, 0.632, n)
    return build_rows(Robot(), phi, params), np.arange(n) % len(COMMAND_NAMES)


PROGRAMS = [build_command(name) for name in COMMAND_NAMES]


def flight_end(command: str, params: dict, options: SolverSettings | None = None) -> float:
    """Time [s] of the touchdown that ends a jump (the last recorded state)."""
    return float(simulate_trajectory(command, PHI, params, settings=options).data["t_s"].iloc[-1])


# ----------------------------------------------------------------------------------------
# tracked jumps: accuracy
@pytest.mark.parametrize("command", COMMAND_NAMES)
def test_frames_at_recorded_times_are_the_recorded_states(command: str) -> None:
    """With the recording's settings, frames at its times are its states (to ~1e-9 m).

    The record's points are exact integrator states. With the same settings the
    Dormand-Prince steps of the tracked jump are the record's (a frame at a step's end is
    that state); in the linear regimes the record takes steps of ``max_step`` and the
    tracked jump longer ones, and the frames there are the exact closed form and its
    derivative. Positions agree within 1e-6 mm, velocities within 1e-3 mm/s (of up to 3 m/s).
    With the default settings (different steps) they agree to the integrator's tolerance:
    0.01 mm and 2 mm/s.
    """
    options = SolverSettings(max_step=RECORD_STEP)
    rec = simulate_trajectory(command, PHI, LAW, settings=options).data
    want = {
        "x_foot_mm": rec["x_foot_mm"].to_numpy(),
        "x_rod_mm": rec["x_rod_mm"].to_numpy() - rec["x_rod_mm"].iloc[0],
        "v_foot_mm_s": 1e3 * rec["v_foot_m_s"].to_numpy(),
        "v_rod_mm_s": 1e3 * rec["v_rod_m_s"].to_numpy(),
    }
    tracked = simulate_frames(command, PHI, LAW, rec["t_s"], settings=options)
    default = simulate_frames(command, PHI, LAW, rec["t_s"])
    assert tracked.status == Status.OK and default.status == Status.OK
    for column, expect in want.items():
        same, loose = (1e-6, 0.01) if column in POSITIONS else (1e-3, 2.0)
        np.testing.assert_allclose(tracked.data[column], expect, rtol=0, atol=same)
        np.testing.assert_allclose(default.data[column], expect, rtol=0, atol=loose)


@pytest.mark.parametrize("command", COMMAND_NAMES)
def test_frames_converge_with_the_tolerance(command: str) -> None:
    """Against a very tight reference the error of the frames follows the tolerance.

    Frames at 2000 fps from before the start to 0.75 s (through the landing after the
    jump), closed form on and off (all Dormand-Prince, every frame from the quintic
    Hermite interpolant and its derivative): the error of the positions and of the
    velocities shrinks by a factor of at least 5 per decade of tolerance; at the defaults
    it is at most 0.05 mm and 5 mm/s (velocities reach 3 m/s).
    """
    frames = np.arange(-10, 1500) / 2000.0
    ref = simulate_frames(command, PHI, LAW, frames, settings=TIGHT).data
    for closed in (True, False):
        errors = []
        for rtol in (1e-5, 1e-7, 1e-9):
            options = SolverSettings(
                rtol=rtol, atol_position=1e-2 * rtol, atol_velocity=rtol, closed_form=closed
            )
            got = simulate_frames(command, PHI, LAW, frames, settings=options).data
            errors.append((max_error(got, ref, POSITIONS), max_error(got, ref, VELOCITIES)))
        x_err, v_err = np.array(errors).T
        assert x_err[0] < 0.05 and v_err[0] < 5.0, errors
        assert np.all(x_err[1:] < x_err[:-1] / 5.0), errors
        assert np.all(v_err[1:] < v_err[:-1] / 5.0), errors
    default = simulate_frames(command, PHI, LAW, frames).data
    assert max_error(default, ref, POSITIONS) < 0.05
    assert max_error(default, ref, VELOCITIES) < 5.0


@pytest.mark.parametrize("command", ["single", "stutter"])
def test_dense_output_of_dormand_prince_steps_is_fifth_order(command: str) -> None:
    """With (nearly) fixed steps h the error of frames inside the steps falls as h^5.

    Closed form off and tolerances so loose that only ``max_step`` sets the steps (they are
    clipped at events only): frames at irregular times inside the command, against a very
    tight reference. Halving h divides the error of the positions by at least 2^4.5
    (observed 40 to 120: the quintic Hermite interpolant, 6th order, adds nothing to the
    states' 5th-order error) and that of the velocities (the interpolant's derivative,
    5th order) by at least 2^4.
    """
    frames = np.arange(1, 100) * 0.987e-3
    ref = simulate_frames(
        command,
        PHI,
        LAW,
        frames,
        settings=SolverSettings(
            rtol=1e-13, atol_position=1e-15, atol_velocity=1e-13, closed_form=False
        ),
    ).data
    x_err, v_err = [], []
    for h in (1e-3, 5e-4, 2.5e-4):
        loose = SolverSettings(
            rtol=1e6, atol_position=1e6, atol_velocity=1e6, max_step=h, closed_form=False
        )
        got = simulate_frames(command, PHI, LAW, frames, settings=loose).data
        x_err.append(max_error(got, ref, POSITIONS))
        v_err.append(max_error(got, ref, VELOCITIES))
    assert x_err[0] / x_err[1] > 2**4.5 and x_err[1] / x_err[2] > 2**4.5, x_err
    assert v_err[0] / v_err[1] > 2**4 and v_err[1] / v_err[2] > 2**4, v_err


def test_quintic_hermite_reproduces_quintics_exactly() -> None:
    """The interpolant of a Dormand-Prince step is exact for polynomials of degree <= 5,
    and its velocities are their derivatives."""
    coef = np.array([0.3, -1.2, 2.5, 0.7, -4.0, 1.9])
    poly = np.polynomial.Polynomial(coef)
    t, h = 0.1, 0.02

    def state(p: np.polynomial.Polynomial, s: float) -> tuple[float, float, float]:
        return p(s), p.deriv()(s), p.deriv(2)(s)

    rod = np.polynomial.Polynomial(coef[::-1])
    x0, v0, a0 = state(poly, t)
    x1, v1, a1 = state(poly, t + h)
    r0, w0, b0 = state(rod, t)
    r1, w1, b1 = state(rod, t + h)
    frames = t + h * np.linspace(0.05, 1.0, 9)
    out = np.empty((frames.size, _kernel.FRAME_SIZE))
    k = _kernel._hermite_frames(
        t, (r0, x0, w0, v0), (b0, a0), (r1, x1, w1, v1), (b1, a1), h, frames, 0, t + h, out, 0.0
    )
    assert k == frames.size
    np.testing.assert_allclose(out[:, _kernel.FRAME_X_FOOT], poly(frames), rtol=0, atol=1e-13)
    np.testing.assert_allclose(out[:, _kernel.FRAME_X_ROD], rod(frames), rtol=0, atol=1e-13)
    np.testing.assert_allclose(
        out[:, _kernel.FRAME_V_FOOT], poly.deriv()(frames), rtol=0, atol=1e-11
    )
    np.testing.assert_allclose(out[:, _kernel.FRAME_V_ROD], rod.deriv()(frames), rtol=0, atol=1e-11)


# ----------------------------------------------------------------------------------------
# tracked jumps: semantics
def test_heights_of_tracked_jumps_are_bit_identical_to_untracked() -> None:
    """Random realistic laws, all five commands: frames from before the start to 1 s after
    the command change neither a height nor a status, bit for bit."""
    rows, index = random_rows(60, seed=5)
    plain = simulate_rows(rows, PROGRAMS, index)
    n_frames = np.arange(rows.shape[0]) % 7 * 40  # some jumps with no frame at all
    offsets = np.concatenate(([0], np.cumsum(n_frames)))
    t_end = np.array([p.t_end for p in PROGRAMS])[index]
    times = np.concatenate([np.linspace(-0.05, t_end[i] + 1.0, n) for i, n in enumerate(n_frames)])
    tracked = simulate_frames_rows(rows, PROGRAMS, index, times, offsets)
    assert np.array_equal(tracked.status, plain.status)
    assert np.array_equal(tracked.height_mm, plain.height_mm, equal_nan=True)
    assert tracked.ok.all() and np.isfinite(tracked.frames_flat).all()
    assert tracked.positions(3).shape == (n_frames[3], 2)


@pytest.mark.parametrize("command", COMMAND_NAMES)
def test_before_the_start_the_robot_rests_in_its_start_state(command: str) -> None:
    """Frames at t <= 0 are the start state: on the surface (touching) or at the depth where
    the bed carries the robot (settled), rod displacement 0, at rest."""
    law = {"k": 3000.0, "k2": 5e4, "c_d": 10.0}
    frames = np.array([-1.0, -0.01, -1e-9, 0.0])
    data = simulate_frames(command, PHI, law, frames).data
    program = build_command(command)
    if program.start_state == "settled":
        weight = (1.0 + 0.2 + 0.1) * 9.81
        z0 = (-3000.0 + math.sqrt(3000.0**2 + 4 * 5e4 * weight)) / (2 * 5e4)
        assert data["x_foot_mm"].to_numpy() == pytest.approx(-z0 * 1e3, abs=1e-9)
    else:
        assert (data["x_foot_mm"] == 0.0).all()
    assert (data["x_rod_mm"] == 0.0).all()
    assert (data[VELOCITIES] == 0.0).all().all()
    assert data["x_foot_mm"].nunique() == 1


def test_the_motion_goes_on_after_the_touchdown() -> None:
    """Frames after the touchdown that ends the jump follow the landing and the settling.

    The foot falls into the bed, the robot comes to rest (its bounce on the bed decays, the
    spring carries the upper body), and the positions after the touchdown do not depend on whether
    earlier frames were asked for (same steps; same values within 1e-9 mm).
    """
    command = "single"
    t_td = flight_end(command, LAW)
    t_end = build_command(command).t_end
    late = np.linspace(t_td + 0.01, t_end + MAX_FRAME_AFTER_S, 400)
    early = np.linspace(0.0, t_td, 300)
    both = simulate_frames(command, PHI, LAW, np.concatenate((early, late)))
    only_late = simulate_frames(command, PHI, LAW, late)
    assert both.status == Status.OK and both.height_mm == only_late.height_mm
    foot = both.data["x_foot_mm"].to_numpy()[early.size :]
    np.testing.assert_allclose(only_late.data["x_foot_mm"], foot, rtol=0, atol=1e-9)
    assert foot.min() < 0.0  # landed in the bed
    # the bounce on the bed's unloading line decays (the leg's damper), the leg's own
    # oscillation has died out
    t_s = both.data["t_s"]
    first = both.data[(t_s > t_td) & (t_s < t_td + 1.0)]
    rest = both.data[t_s > t_end + MAX_FRAME_AFTER_S - 1.0]
    for column in ("x_foot_mm", "x_rod_mm"):
        assert np.ptp(rest[column]) < 0.1 * np.ptp(first[column])
    # at rest the spring (compression x_f - x_r, the rod starting at 0) carries the upper body
    robot = Robot()
    compression = (rest["x_foot_mm"] - rest["x_rod_mm"]).mean() * 1e-3
    upper = (robot.m_motor + robot.m_rod) * 9.81
    assert compression == pytest.approx(upper / robot.k_spring, rel=1e-2)


def test_frames_after_the_window_continue_the_flight() -> None:
    """When the window closes mid-flight, later frames follow the flight on.

    With window_after = 0.02 s the single jump's height is the height reached when the
    window closes; the frames after it keep rising above that height, then fall back
    into the bed.
    """
    options = SolverSettings(window_after=0.02)
    t_end = build_command("single").t_end
    frames = np.linspace(t_end, t_end + 0.4, 401)
    jump = simulate_frames("single", PHI, {"k": 3000.0, "r_unload": 1.0}, frames, settings=options)
    plain = gb.simulate("single", PHI, {"k": 3000.0, "r_unload": 1.0}, settings=options)
    assert jump.height_mm == plain.height_mm[0]
    foot = jump.data["x_foot_mm"].to_numpy()
    assert foot.max() > jump.height_mm + 1.0
    assert foot.min() < 0.0  # and lands (on an elastic bed, to bounce again)


def test_failed_jumps_give_nan_positions_and_their_status() -> None:
    """A bad row and an exhausted step budget: NaN height and positions and the status; the
    other jumps of the batch are unaffected."""
    rows, index = random_rows(5, seed=2)
    rows[1, _kernel.ROW_FORCE0 + PARAMETER_NAMES.index("k")] = -1.0
    frames = np.tile(np.linspace(-0.01, 0.5, 50), 5)
    offsets = np.arange(6) * 50
    res = simulate_frames_rows(rows, PROGRAMS, index, frames, offsets)
    assert res.status[1] == Status.BAD_INPUT and np.isnan(res.height_mm[1])
    assert np.isnan(res.frames_of(1)).all() and np.isnan(res.frames[1]).all()
    for i in (0, 2, 3, 4):
        alone = simulate_frames_rows(rows[i : i + 1], PROGRAMS, index[i : i + 1],
                                     frames[:50], offsets[:2])  # fmt: skip
        assert res.status[i] == Status.OK
        assert np.array_equal(res.frames_of(i), alone.frames_flat)
    starved = simulate_frames_rows(
        rows, PROGRAMS, index, frames, offsets, settings=SolverSettings(max_steps=5)
    )
    assert (starved.status == Status.STEP_LIMIT)[[0, 2, 3, 4]].all()
    assert np.isnan(starved.frames_flat).all() and np.isnan(starved.height_mm).all()


def test_frames_in_any_order_and_repeated() -> None:
    """Frames are returned in the order given, whatever it is; repeated times agree."""
    rng = np.random.default_rng(7)
    frames = np.linspace(-0.02, 0.6, 200)
    shuffled = rng.permutation(np.concatenate((frames, frames[::10])))
    ordered = simulate_frames("stutter", PHI, LAW, frames).data.set_index("t_s")
    mixed = simulate_frames("stutter", PHI, LAW, shuffled).data
    assert np.array_equal(mixed["t_s"], shuffled)
    expect = ordered.loc[shuffled]
    for column in FRAME_COLUMNS:
        np.testing.assert_array_equal(mixed[column], expect[column])


def test_batch_equals_single_jumps_and_threads_do_not_matter() -> None:
    """A batch of tracked jumps equals the jumps one by one, on 1 or 2 threads, bit for bit."""
    rows, index = random_rows(10, seed=3)
    frames = np.concatenate([np.linspace(-0.01, 0.3 + 0.05 * i, 30 + i) for i in range(10)])
    offsets = np.concatenate(([0], np.cumsum([30 + i for i in range(10)])))
    one = simulate_frames_rows(rows, PROGRAMS, index, frames, offsets, n_threads=1)
    two = simulate_frames_rows(rows, PROGRAMS, index, frames, offsets, n_threads=2)
    assert np.array_equal(one.frames_flat, two.frames_flat)
    assert np.array_equal(one.height_mm, two.height_mm)
    exp = Experiment()
    for i in (0, 6):
        params = {name: rows[i, _kernel.ROW_FORCE0 + j] for j, name in enumerate(PARAMETER_NAMES)}
        jump = simulate_frames(
            COMMAND_NAMES[index[i]],
            rows[i, _kernel.ROW_PHI],
            params,
            frames[offsets[i] : offsets[i + 1]],
            experiment=exp,
        )
        assert np.array_equal(jump.data[list(FRAME_COLUMNS)].to_numpy(), one.frames_of(i))
        assert jump.height_mm == one.height_mm[i]


def test_bad_frames_are_refused() -> None:
    """Frames later than the command's end + 5 s, non-finite times and inconsistent offsets
    are refused before any computation."""
    t_end = build_command("single").t_end
    with pytest.raises(ValueError, match="after its command ends"):
        simulate_frames("single", PHI, LAW, [0.0, t_end + MAX_FRAME_AFTER_S + 1e-6])
    simulate_frames("single", PHI, LAW, [t_end + MAX_FRAME_AFTER_S])  # the limit itself
    with pytest.raises(ValueError, match="not finite"):
        simulate_frames("single", PHI, LAW, [0.0, np.nan])
    rows = build_rows(Robot(), PHI, LAW)
    with pytest.raises(ValueError, match="frame_offsets"):
        simulate_frames_rows(rows, PROGRAMS, None, [0.0, 0.1], [0, 1])
    with pytest.raises(ValueError, match="program_index"):
        simulate_frames_rows(rows, PROGRAMS, [7], [0.0], [0, 1])


def test_tracked_result_types() -> None:
    """The public names: a TrackedJump with its table, a TrackedHeights that is Heights."""
    jump = gb.simulate_frames("preload", PHI, {"k": 3000.0}, [0.0, 0.05])
    assert isinstance(jump, gb.TrackedJump)
    assert list(jump.data.columns) == ["t_s", "x_foot_mm", "x_rod_mm", "v_foot_mm_s", "v_rod_mm_s"]
    batch = gb.simulate_frames_rows(
        build_rows(Robot(), PHI, {"k": 3000.0}), PROGRAMS[:1], None, [0.1], [0, 1]
    )
    assert isinstance(batch, gb.TrackedHeights) and isinstance(batch, gb.Heights)
    assert batch.status_labels == ["ok"]


def test_frames_layout_jumps_by_frames_by_columns() -> None:
    """``frames`` is (jumps, frames, FRAME_COLUMNS): a view of ``frames_flat`` when every
    jump has the same number of frames, NaN-padded when not; the helpers are its slices.

    Frame times may also be given without offsets: one row per jump (n, F), or one row
    shared by every jump (F,); the results equal those of the concatenated form.
    """
    assert FRAME_COLUMNS == ("x_foot_mm", "x_rod_mm", "v_foot_mm_s", "v_rod_mm_s")
    rows, index = random_rows(4, seed=11)
    grid = np.linspace(-0.01, 0.4, 25)
    per_jump = grid[None, :] + 0.01 * np.arange(4)[:, None]
    flat = simulate_frames_rows(rows, PROGRAMS, index, per_jump.ravel(), np.arange(5) * 25)
    assert flat.frames.shape == (4, 25, 4) and np.shares_memory(flat.frames, flat.frames_flat)
    assert np.array_equal(flat.n_frames, [25] * 4)
    for i in range(4):
        view = flat.frames[i]
        assert np.array_equal(view, flat.frames_of(i))
        assert np.array_equal(view[:, :2], flat.positions(i))
        assert np.array_equal(view[:, 2:], flat.velocities(i))
    assert np.array_equal(flat.positions_mm, flat.frames_flat[:, :2])
    assert np.array_equal(flat.velocities_mm_s, flat.frames_flat[:, 2:])
    two_d = simulate_frames_rows(rows, PROGRAMS, index, per_jump)
    assert np.array_equal(two_d.frames, flat.frames) and two_d.frames.shape == (4, 25, 4)
    shared = simulate_frames_rows(rows, PROGRAMS, index, grid)
    tiled = simulate_frames_rows(rows, PROGRAMS, index, np.tile(grid, 4), np.arange(5) * 25)
    assert np.array_equal(shared.frames, tiled.frames)
    # ragged: padded with NaN beyond each jump's frames
    counts = np.array([3, 0, 5, 2])
    times = np.concatenate([grid[:c] for c in counts])
    ragged = simulate_frames_rows(rows, PROGRAMS, index, times, np.r_[0, np.cumsum(counts)])
    assert ragged.frames.shape == (4, 5, 4)
    for i, c in enumerate(counts):
        assert np.array_equal(ragged.frames[i, :c], ragged.frames_of(i))
        assert np.isnan(ragged.frames[i, c:]).all()
    with pytest.raises(ValueError, match="without frame_offsets"):
        simulate_frames_rows(rows, PROGRAMS, index, per_jump[:3])
    with pytest.raises(ValueError, match="one-dimensional"):
        simulate_frames_rows(rows, PROGRAMS, index, per_jump, np.arange(5) * 25)


def test_velocities_are_the_derivative_of_the_positions() -> None:
    """A central difference of the frames' positions over +-1 us gives their velocities
    within 1e-3 mm/s (observed 5e-5 mm/s, the difference's rounding), closed form on and
    off, at the defaults and converged: the velocities are the dense output's derivative,
    continuous across steps and regime changes (velocities reach 3000 mm/s)."""
    centre = np.linspace(0.005, 0.595, 60)
    eps = 1e-6
    frames = np.concatenate((centre - eps, centre, centre + eps))
    for command in ("single", "delayed_stutter_preload"):
        for closed in (True, False):
            for settings in (SolverSettings(), SolverSettings.converged()):
                options = dataclasses.replace(settings, closed_form=closed)
                data = simulate_frames(command, PHI, LAW, frames, settings=options).data
                x = data[POSITIONS].to_numpy().reshape(3, -1, 2)
                v = data[VELOCITIES].to_numpy().reshape(3, -1, 2)[1]
                np.testing.assert_allclose((x[2] - x[0]) / (2 * eps), v, rtol=0, atol=1e-3)


# ----------------------------------------------------------------------------------------
# intrusion tests
def _cone(z: np.ndarray, radius: float) -> tuple[np.ndarray, np.ndarray]:
    """V(z) [m^3] and V'(z) [m^2] of the contract's jammed cone."""
    tan = math.tan(math.pi / 3)
    h = np.minimum(2.0 * z, radius * tan)
    vol = np.pi * h * (radius**2 - radius * h / tan + h**2 / (3 * tan**2))
    slope = np.where(2.0 * z < radius * tan, 2.0 * np.pi * (radius - h / tan) ** 2, 0.0)
    return vol, slope


def test_intrusion_force_is_the_contract_formula() -> None:
    """F = F_static(z) + c_d v^2 + b v + kappa rho phi V'(z) v^2 - m_a(z) g (section 5b)."""
    robot = Robot()
    law = {"k": 2500.0, "k2": 1e5, "c_d": 30.0, "b": 8.0, "kappa": 1.4, "c_comp": 1.0}
    depth = np.linspace(0.0, 60.0, 61)
    for speed in (0.0, 50.0, 400.0, 1500.0):
        z, v = depth * 1e-3, speed * 1e-3
        vol, slope = _cone(z, robot.foot_radius)
        am = law["kappa"] * robot.grain_density * PHI
        expect = (
            law["k"] * z
            + law["k2"] * z**2
            + law["c_d"] * v**2
            + law["b"] * v
            + am * slope * v**2
            - am * vol * 9.81
        )
        got = intrusion_force(PHI, law, depth, speed)
        np.testing.assert_allclose(got, expect, rtol=1e-12, atol=1e-12)


@pytest.mark.parametrize("term", [name for name in TERMS if name != "depth"])
def test_quasi_static_intrusion_reads_the_loading_curve(term: str) -> None:
    """At speed 0 the force is the loading curve F_static(z) = k z + k2 z^2 (the kernel's
    ``static_strength``) less the weight of the carried cone, whatever the other terms."""
    law = {"k": 3000.0}
    for p in TERMS[term].parameters:
        law[p.name] = p.typical[1]
    depth = np.linspace(0.0, 50.0, 26)
    z = depth * 1e-3
    cone = _cone(z, Robot().foot_radius)[0] * law.get("kappa", 0.0) * 1100.0 * PHI * 9.81
    loading = _kernel.static_strength(z, law["k"], law.get("k2", 0.0))
    got = intrusion_force(PHI, law, depth, 0.0)
    np.testing.assert_allclose(got, loading - cone, rtol=1e-12, atol=1e-12)
    tiny = intrusion_force(PHI, law, depth, 1e-3)  # 1 um/s
    np.testing.assert_allclose(tiny, got, rtol=0, atol=1e-4)


def test_added_mass_flux_vanishes_where_the_cone_is_full() -> None:
    """The flux's depth dependence: V'(z) falls from mu pi R^2 at the surface to 0 at
    z = R tan(theta) / mu (about 30 mm) and stays 0 beyond."""
    radius = Robot().foot_radius
    z_full = radius * math.tan(math.pi / 3) / 2.0
    depth = np.linspace(0.0, 2.0 * z_full * 1e3, 201)
    law = {"k": 3000.0, "kappa": 1.0}
    v = 1.0  # m/s
    flux = intrusion_force(PHI, law, depth, v * 1e3) - intrusion_force(PHI, law, depth, 0.0)
    am = 1100.0 * PHI
    assert flux[0] == pytest.approx(am * 2.0 * math.pi * radius**2 * v**2, rel=1e-12)
    inside = depth * 1e-3 < z_full
    assert np.all(np.diff(flux[inside]) < 0.0)
    assert np.all(flux[~inside] == 0.0)
    np.testing.assert_allclose(flux, am * _cone(depth * 1e-3, radius)[1] * v**2, atol=1e-12)


#: The sign of each parameter's contribution to the intrusion force at a shallow depth
#: (10 mm) and a speed of 0.5 m/s (+1 raises it, 0 none); every parameter of the registry
#: must be listed, so that a new term states its sign here.
CONTRIBUTION_SIGN = {
    "k": +1,  # depth: k z
    "c_d": +1,  # drag: c_d v^2
    "kappa": +1,  # added mass: flux kappa rho phi V' v^2 > cone weight at 0.5 m/s
    "k2": +1,  # stiffening: k2 z^2
    "b": +1,  # viscous: b v
    "c_comp": 0,  # compaction: a fresh bed has no history
    "r_unload": 0,  # unloading: nothing unloads
}


def test_every_terms_contribution_has_its_sign() -> None:
    """Raising each parameter from its 'off' value moves the force as its physics says;
    the cone's weight alone (speed 0, below the full cone) lowers it."""
    assert set(CONTRIBUTION_SIGN) == set(PARAMETER_NAMES)
    base = {"k": 3000.0}
    f0 = intrusion_force(PHI, base, 10.0, 500.0)
    for name, sign in CONTRIBUTION_SIGN.items():
        p = gb.forces.parameter(name)
        law = {**base, name: base.get(name, p.typical[1]) * (2.0 if name == "k" else 1.0)}
        diff = float(intrusion_force(PHI, law, 10.0, 500.0) - f0)
        assert np.sign(diff) == sign, (name, diff)
    weight = intrusion_force(PHI, {"k": 3000.0, "kappa": 1.0}, [10.0, 50.0], 0.0)
    bare = intrusion_force(PHI, {"k": 3000.0}, [10.0, 50.0], 0.0)
    assert np.all(weight < bare)


def test_intrusion_batched_form_and_bad_input() -> None:
    """The low-level form evaluates many (row, depth, speed) at once, equal to the public
    one; NaN for a bad row (no exception); the public form refuses bad depths and speeds."""
    rows, _ = random_rows(8, seed=4)
    rows[5, _kernel.ROW_FORCE0 + PARAMETER_NAMES.index("k")] = 0.0
    depth = np.tile(np.linspace(0.0, 40.0, 9), 8)
    speed = np.repeat(np.linspace(0.0, 700.0, 8), 9)
    index = np.repeat(np.arange(8), 9)
    force = intrusion_force_rows(rows, depth, speed, index)
    assert np.isnan(force[index == 5]).all() and np.isfinite(force[index != 5]).all()
    for i in (0, 3):
        params = {name: rows[i, _kernel.ROW_FORCE0 + j] for j, name in enumerate(PARAMETER_NAMES)}
        one = intrusion_force(
            rows[i, _kernel.ROW_PHI], params, depth[index == i], speed[index == i]
        )
        np.testing.assert_array_equal(one, force[index == i])
    # broadcasting: laws x depths
    grid = intrusion_force(np.array([[0.6], [0.62]]), {"k": 3000.0, "kappa": 1.0}, depth[:9], 100.0)
    assert grid.shape == (2, 9)
    assert np.isnan(intrusion_force_rows(rows[:1], [-1.0], [0.0])).all()
    with pytest.raises(ValueError, match="depth_mm"):
        intrusion_force(PHI, {"k": 3000.0}, -1.0, 10.0)
    with pytest.raises(ValueError, match="speed_mm_s"):
        intrusion_force(PHI, {"k": 3000.0}, 1.0, np.inf)
    with pytest.raises(KeyError):
        intrusion_force(PHI, {"k": 3000.0, "nope": 1.0}, 1.0, 1.0)


def test_intrusion_follows_the_experiments_robot() -> None:
    """Foot radius and grain density come from the experiment (the cone scales with them)."""
    big = Experiment(robot=dataclasses.replace(Robot(), foot_radius=0.05, grain_density=1300.0))
    law = {"k": 3000.0, "kappa": 1.0}
    got = intrusion_force(PHI, law, 5.0, 800.0, experiment=big)
    vol, slope = _cone(np.array(5e-3), 0.05)
    am = 1300.0 * PHI
    expect = 3000.0 * 5e-3 + am * slope * 0.8**2 - am * vol * 9.81
    assert float(got) == pytest.approx(float(expect), rel=1e-12)
