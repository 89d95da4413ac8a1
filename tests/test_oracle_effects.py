"""Out-of-library physics in the oracle (granbayes.testing._effects).

The effects are ground truth for verdict studies: physics the force-term library cannot
express. The tests check that ``effects=None`` is the library model exactly as it was
(heights recorded from the oracle before effects existed), that every effect vanishes at
its neutral value and acts in the direction its physics says, that its force law reaches
the intrusion curves as documented, and that none of them lets the bed create energy (the
identity of physics-model.md section 3: with the leg undamped the robot's energy gained
over a jump never exceeds the actuator's work; on a perfectly elastic library bed the two
are equal, which checks the bookkeeping itself).
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from granbayes._experiment import Experiment, G, Robot
from granbayes.commands import build_command
from granbayes.testing import (
    DepthDependentDrag,
    JanssenSaturation,
    PauseStiffening,
    RateStiffening,
    intrusion_force_scipy,
    simulate_height_scipy,
    simulate_trajectory_scipy,
)

#: Heights of the oracle before effects existed (commit 978134b, default settings; the
#: first two are cases of tests/test_scipy_crosscheck.py), as exact hexadecimal floats.
RECORDED = [
    ("single", 0.612, {"k": 3000.0, "c_d": 50.0, "b": 20.0}, {}, "0x1.8f5df6ed7deccp+5"),
    (
        "delayed_stutter_preload",
        0.600,
        {"k": 5000.0, "kappa": 1.0, "r_unload": 10.0, "k2": 1e5},
        {},
        "0x1.5191d8b624a0fp+6",
    ),
    (
        "delayed_stutter",
        0.605,
        {"k": 3000.0, "kappa": 1.0, "r_unload": 5.0, "c_comp": 0.7},
        {},
        "0x1.8be366782e269p+6",
    ),
    (
        "preload",
        0.610,
        {"k": 1000.0, "r_unload": 1.0},
        {"freq_hz": 6.0, "amplitude_mm": 30.0, "m_foot": 0.3, "c_spring": 0.0},
        "0x1.07d3c8708f09cp+6",
    ),
    (  # the graze case of docs/physics-model.md section 10
        "delayed_stutter",
        0.607,
        {"k": 1964.0},
        {"m_motor": 0.982, "k_spring": 4857.0, "amplitude_mm": 16.4, "freq_hz": 12.0},
        "0x1.b0e4a827a00abp+3",
    ),
]

LAW = {"k": 3000.0, "c_d": 20.0, "r_unload": 20.0}
NEUTRAL = [DepthDependentDrag(0.0), JanssenSaturation(), PauseStiffening(0.0), RateStiffening(0.0)]


@pytest.mark.parametrize(("command", "phi", "params", "changes", "recorded"), RECORDED)
def test_no_effects_is_the_library_model_as_it_was(command, phi, params, changes, recorded):
    """effects=None and effects=() give the heights the oracle gave before effects existed
    (bit for bit on the machine they were recorded on; 1e-9 mm allows another libm)."""
    experiment = Experiment().replace(**changes)
    none = simulate_height_scipy(command, phi, params, experiment)
    empty = simulate_height_scipy(command, phi, params, experiment, effects=())
    assert none == empty
    assert none == pytest.approx(float.fromhex(recorded), abs=1e-9)


@pytest.mark.parametrize("effect", NEUTRAL, ids=lambda e: type(e).__name__)
@pytest.mark.parametrize("command", ["single", "preload"])
def test_an_effect_at_its_neutral_value_vanishes(effect, command) -> None:
    """Through the effects' own right-hand side (and, for PauseStiffening, an extra state
    in the step-size control) the neutral value gives the library's height: 1e-5 mm."""
    assert effect.neutral
    law = {"k": 3000.0, "c_d": 20.0, "kappa": 1.0, "k2": 5e4, "c_comp": 0.5}
    plain = simulate_height_scipy(command, 0.602, law)
    assert simulate_height_scipy(command, 0.602, law, effects=(effect,)) == pytest.approx(
        plain, abs=1e-5
    )


def test_effects_tend_to_the_library_as_they_fade() -> None:
    """Continuity at the neutral value: a nearly neutral effect is nearly the library."""
    plain = simulate_height_scipy("single", 0.62, LAW)
    for effect in (
        DepthDependentDrag(1e-3),
        JanssenSaturation(1e3),
        PauseStiffening(1e-6, initial=1.0),
        RateStiffening(1e-6),
    ):
        assert not effect.neutral
        got = simulate_height_scipy("single", 0.62, LAW, effects=(effect,))
        assert got == pytest.approx(plain, abs=1e-3), effect


# ----------------------------------------------------------------------------------------
# directions
@pytest.mark.parametrize("command", ["single", "preload", "delayed_stutter"])
def test_a_saturating_depth_force_lowers_the_jumps(command) -> None:
    """Janssen screening caps the depth force at k lambda: the foot sinks deeper and
    loses more energy in the bed, so the robot jumps lower; less so the longer lambda."""
    plain = simulate_height_scipy(command, 0.612, LAW)
    short = simulate_height_scipy(command, 0.612, LAW, effects=(JanssenSaturation(0.01),))
    long = simulate_height_scipy(command, 0.612, LAW, effects=(JanssenSaturation(0.05),))
    assert short < long < plain


@pytest.mark.parametrize("command", ["single", "preload"])
def test_depth_dependent_drag_has_opposite_trends_about_phi_c(command) -> None:
    """Above phi_c the drag grows with depth, below it fades, at phi_c nothing changes.
    For these commands the height rises with a constant c_d (checked), so the effect
    raises the jump above phi_c and lowers it below, the more the larger depth_rate. (The
    delayed stutter's height is not monotonic in c_d, so no direction is expected there.)"""
    for phi, more in ((0.632, True), (0.592, False)):
        plain = simulate_height_scipy(command, phi, LAW)
        assert simulate_height_scipy(command, phi, {**LAW, "c_d": 40.0}) > plain
        weak = simulate_height_scipy(command, phi, LAW, effects=(DepthDependentDrag(30.0),))
        strong = simulate_height_scipy(command, phi, LAW, effects=(DepthDependentDrag(60.0),))
        assert (plain < weak < strong) if more else (plain > weak > strong), phi
    at_phi_c = simulate_height_scipy(command, 0.612, LAW, effects=(DepthDependentDrag(60.0),))
    assert at_phi_c == pytest.approx(simulate_height_scipy(command, 0.612, LAW), abs=1e-9)


@pytest.mark.parametrize("command", ["single", "stutter", "delayed_stutter"])
def test_a_rate_stiffened_bed_throws_the_robot_higher(command) -> None:
    """The bed is stiffer the faster the foot pushes: less sinking, higher jumps, rising
    with the gain."""
    plain = simulate_height_scipy(command, 0.612, LAW)
    some = simulate_height_scipy(command, 0.612, LAW, effects=(RateStiffening(0.2),))
    more = simulate_height_scipy(command, 0.612, LAW, effects=(RateStiffening(0.5),))
    assert plain < some < more


@pytest.mark.parametrize(
    "law", [LAW, {"k": 2000.0, "r_unload": 20.0}, {"k": 5000.0, "r_unload": 5.0, "kappa": 1.0}]
)
def test_a_relaxed_bed_throws_the_preloaded_robot_higher(law) -> None:
    """Hubicki et al. 2017: after a pause the bed is stiffer and the jump higher. A robot
    that pushes off a bed that has relaxed under it (initial = 1) jumps higher than on the
    library's bed, and higher than on a bed just disturbed (initial = 0)."""
    plain = simulate_height_scipy("preload", 0.612, law)
    disturbed = simulate_height_scipy("preload", 0.612, law, effects=(PauseStiffening(1.0),))
    relaxed = simulate_height_scipy(
        "preload", 0.612, law, effects=(PauseStiffening(1.0, initial=1.0),)
    )
    assert plain < disturbed < relaxed


def test_the_pause_state_relaxes_at_rest_and_is_erased_by_advancing() -> None:
    """In a constant-speed intrusion the state follows its closed form; quasi-static the
    bed is fully relaxed (the force is (1 + gain) F_static), fast it is nearly erased."""
    effect = PauseStiffening(gain=1.5, tau_s=0.04, strain_m=1e-3)
    depths = np.arange(0.0, 30.5, 0.5)
    law = {"k": 2500.0}
    plain = intrusion_force_scipy(0.6, law, depths, 0.0)
    np.testing.assert_allclose(
        intrusion_force_scipy(0.6, law, depths, 0.0, effects=(effect,))[1:], 2.5 * plain[1:]
    )
    speed = 500.0  # mm/s: the state settles at 1 / (1 + v tau / l) = 1 / 21
    fast = intrusion_force_scipy(0.6, law, depths, speed, effects=(effect,))
    ratio = fast[1:] / intrusion_force_scipy(0.6, law, depths, speed)[1:]
    np.testing.assert_allclose(ratio[-10:], 1.0 + 1.5 / 21.0, rtol=1e-9)
    s = effect.state_at(1e-3 * depths, 1e-3 * speed)
    assert s[0] == 0.0 and np.all(np.diff(s) > 0.0)
    assert effect.rate(0.5, 0.0, True) == pytest.approx(0.5 / 0.04)
    assert effect.rate(0.5, 0.1, True) == pytest.approx(0.5 / 0.04 - 0.5 * 0.1 / 1e-3)


def test_effects_in_intrusion_curves() -> None:
    """Janssen: F -> k lambda deep down; depth-dependent drag: (F(v) - F(0)) / v^2 =
    c_d exp(rate (phi - phi_c) / scale z); rate stiffening: F(v) / F(0) = 1 + g ln(1 + v /
    v_ref) on the static part."""
    depths = np.arange(0.0, 200.5, 0.5)
    janssen = intrusion_force_scipy(
        0.6, {"k": 3000.0}, depths, 0.0, effects=JanssenSaturation(0.01)
    )
    assert janssen[-1] == pytest.approx(30.0, rel=1e-8)
    np.testing.assert_allclose(janssen, 30.0 * -np.expm1(-depths / 10.0), rtol=1e-12)
    assert janssen[1] == pytest.approx(3000.0 * 0.5e-3, rel=0.03)  # k z near the surface
    assert np.all(np.diff(janssen) > 0.0) and np.all(np.diff(janssen, 2) < 0.0)

    drag = DepthDependentDrag(50.0)
    law = {"k": 3000.0, "c_d": 20.0}
    for phi in (0.592, 0.632):
        diff = intrusion_force_scipy(phi, law, depths, 300.0, effects=(drag,))
        diff -= intrusion_force_scipy(phi, law, depths, 0.0, effects=(drag,))
        expected = 20.0 * np.exp(50.0 * (phi - 0.612) / 0.01 * 1e-3 * depths)
        np.testing.assert_allclose(diff / 0.3**2, expected, rtol=1e-9, atol=1e-9)

    rate = RateStiffening(0.4, v_ref=0.05)
    ratio = intrusion_force_scipy(0.6, {"k": 3000.0}, depths[1:], 200.0, effects=(rate,))
    ratio /= intrusion_force_scipy(0.6, {"k": 3000.0}, depths[1:], 0.0)
    np.testing.assert_allclose(ratio, 1.0 + 0.4 * math.log(1.0 + 0.2 / 0.05), rtol=1e-12)


def test_trajectories_carry_the_effects() -> None:
    """A trajectory with effects has the height of simulate_height_scipy with them."""
    effects = (PauseStiffening(1.0, initial=1.0), RateStiffening(0.3), JanssenSaturation(0.03))
    program = build_command("preload")
    t = np.linspace(-0.01, program.t_end + 0.2, 200)
    traj = simulate_trajectory_scipy("preload", 0.62, LAW, t, effects=effects)
    assert traj.height_mm == simulate_height_scipy("preload", 0.62, LAW, effects=effects)
    plain = simulate_trajectory_scipy("preload", 0.62, LAW, t)
    assert np.abs(traj.x_foot_mm - plain.x_foot_mm).max() > 1.0


def test_effects_are_checked() -> None:
    with pytest.raises(ValueError, match="same kind"):
        simulate_height_scipy(
            "single", 0.6, LAW, effects=(RateStiffening(1.0), RateStiffening(2.0))
        )
    with pytest.raises(TypeError, match="not an effect"):
        simulate_height_scipy("single", 0.6, LAW, effects=("drag",))
    with pytest.raises(ValueError, match="lambda_m"):
        JanssenSaturation(0.0)
    with pytest.raises(ValueError, match="initial"):
        PauseStiffening(1.0, initial=1.5)
    with pytest.raises(ValueError, match="gain"):
        RateStiffening(-0.1)
    with pytest.raises(ValueError, match="phi_scale"):
        DepthDependentDrag(1.0, phi_scale=0.0)
    # a single effect need not be wrapped in a sequence
    one = simulate_height_scipy("single", 0.6, LAW, effects=RateStiffening(0.3))
    assert one == simulate_height_scipy("single", 0.6, LAW, effects=(RateStiffening(0.3),))


def test_a_saturated_bed_that_cannot_carry_the_robot_is_refused() -> None:
    """Settled start: F_static(z0) = weight (12.75 N) has no root if k lambda is below it."""
    with pytest.raises(ValueError, match="cannot carry the robot"):
        simulate_height_scipy("preload", 0.6, {"k": 1000.0}, effects=(JanssenSaturation(0.01),))
    # with k2 the curve grows again: the robot settles deeper than without saturation
    deep = simulate_trajectory_scipy(
        "preload", 0.6, {"k": 1000.0, "k2": 1e5}, [-1.0], effects=(JanssenSaturation(0.01),)
    )
    shallow = simulate_trajectory_scipy("preload", 0.6, {"k": 1000.0, "k2": 1e5}, [-1.0])
    assert deep.x_foot_mm[0] < shallow.x_foot_mm[0] < 0.0


# ----------------------------------------------------------------------------------------
# energy
UNDAMPED = Experiment(robot=Robot(c_spring=0.0))


def _alpha_dot(program, t: np.ndarray) -> np.ndarray:
    """alpha'(t) of a command [m/s] (0 outside its segments)."""
    out = np.zeros_like(t)
    bounds = program.boundaries
    for i, seg in enumerate(program.segments):
        inside = (t >= bounds[i]) & (t <= bounds[i + 1])
        out[inside] = -seg.coef * program.omega * np.sin(program.omega * (t[inside] - bounds[i]))
    return out


def _energy_gain_and_work(command: str, params: dict, effects: tuple) -> tuple[float, float]:
    """(largest energy gained in a flight after the command, actuator work) [J].

    Touching start (x_r(0) = 0, so x_rod is x_r). The actuator's force on the motor is
    m_motor (x_r'' + alpha'' + g) = m_motor (F_s + m_rod alpha'') / M; its work is that
    force times alpha', integrated over the command on 20 kHz frames (the integrand is
    smooth and vanishes at the segment boundaries). In flight (the foot above the surface:
    the bed is unloaded) the robot's energy is kinetic + gravity + spring.
    """
    program = build_command(command)
    r = UNDAMPED.robot
    m_upper = r.m_motor + r.m_rod
    opts = {"effects": effects}
    t = np.linspace(0.0, program.t_end, 20001)
    during = simulate_trajectory_scipy(command, 0.622, params, t, UNDAMPED, **opts)
    x_r, x_f = 1e-3 * during.x_rod_mm, 1e-3 * during.x_foot_mm
    power = r.m_motor * (r.k_spring * (x_f - x_r) + r.m_rod * program.alpha_ddot(t))
    work = float(np.trapezoid(power * _alpha_dot(program, t) / m_upper, t))
    after = np.linspace(program.t_end, program.t_end + 0.6, 3001)
    flight = simulate_trajectory_scipy(command, 0.622, params, after, UNDAMPED, **opts)
    air = flight.x_foot_mm > 1.0
    assert air.any(), "no flight"
    alpha_start = float(program.alpha(np.array([-1.0]))[0])
    alpha_end = float(program.alpha(np.array([program.t_end + 1.0]))[0])
    x_r, x_f = 1e-3 * flight.x_rod_mm[air], 1e-3 * flight.x_foot_mm[air]
    v_r, v_f = flight.v_rod_m_s[air], flight.v_foot_m_s[air]
    energy = 0.5 * (r.m_rod + r.m_motor) * v_r**2 + 0.5 * r.m_foot * v_f**2
    energy += 0.5 * r.k_spring * (x_f - x_r) ** 2
    energy += G * (m_upper * x_r + r.m_motor * alpha_end + r.m_foot * x_f)
    return float(energy.max() - G * r.m_motor * alpha_start), work


def test_energy_bookkeeping_on_an_elastic_bed() -> None:
    """r_unload = 1, depth only, undamped leg: nothing dissipates, so the energy gained in
    flight equals the actuator's work (to 1e-7 J of ~0.9 J): the check below is sharp."""
    gain, work = _energy_gain_and_work("single", {"k": 3000.0, "r_unload": 1.0}, ())
    assert work > 0.5
    assert gain == pytest.approx(work, abs=1e-7)


@pytest.mark.parametrize(
    ("command", "params", "effect"),
    [
        ("single", {"k": 3000.0, "r_unload": 1.0}, JanssenSaturation(0.01)),
        pytest.param(
            "delayed_stutter",
            {"k": 3000.0, "r_unload": 1.0, "c_comp": 3.0},
            JanssenSaturation(0.02),
            marks=pytest.mark.slow,
        ),
        pytest.param(
            "single",
            {"k": 3000.0, "r_unload": 1.0, "k2": 1e5},
            PauseStiffening(3.0, initial=1.0),
            marks=pytest.mark.slow,
        ),
        ("delayed_stutter", {"k": 3000.0, "r_unload": 1.0}, PauseStiffening(3.0, initial=1.0)),
        ("stutter", {"k": 3000.0, "r_unload": 1.0}, RateStiffening(2.0)),
        ("delayed_stutter", {"k": 1000.0, "r_unload": 1.0, "c_d": 50.0}, DepthDependentDrag(100.0)),
    ],
    ids=["janssen", "janssen-compaction", "pause-k2", "pause", "rate", "depth-drag"],
)
def test_no_effect_lets_the_bed_create_energy(command, params, effect) -> None:
    """The identity of section 3 with each effect at a strong value on the most elastic
    bed allowed (r_unload = 1): the energy gained never exceeds the actuator's work."""
    gain, work = _energy_gain_and_work(command, params, (effect,))
    assert gain <= work + 1e-7, (gain, work)
