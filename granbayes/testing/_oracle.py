"""The independent oracle: a ``scipy.integrate.solve_ivp`` implementation of the model.

It makes every kind of measurement of ``docs/physics-model.md`` (sections 5 and 5b) from
the contract directly, and is the source of the data that test the fitting code (the
compiled kernel never makes its own test data):

* :func:`simulate_height_scipy`, the jump height (section 5);
* :func:`simulate_trajectory_scipy`, the foot height and the rod's displacement at
  arbitrary frame times, from solve_ivp's dense output, with the jump height of the same
  simulation (section 5b);
* :func:`intrusion_force_scipy`, the force-depth curve of a constant-speed intrusion into
  a fresh bed, in closed form (section 5b).

All three accept ``effects=(...)``: out-of-library ground physics
(:mod:`granbayes.testing._effects`) for studies whose truth the library cannot express;
``effects=None`` (or ``()``) is the library model, computed by exactly the arithmetic of
the oracle before effects existed (bit for bit).

It shares nothing with the compiled integrator (``granbayes._kernel``) except the command
waveforms (:func:`granbayes.commands.build_command`), the robot/settings containers
(:mod:`granbayes._experiment`) and the parameter bounds and "off" values of the force-term
registry (:mod:`granbayes.forces`); its only numerical dependency is scipy. Never import
the kernel, the simulator's numerics, the likelihood or :mod:`granbayes._synthetic` here.

How the non-smooth model is integrated
--------------------------------------
* The command is integrated segment by segment (``alpha''`` jumps at segment boundaries),
  followed by a hold segment of ``window_after`` seconds after the command ends (and, for a
  trajectory whose frames go on, a further hold up to the last frame).
* Within a segment the bed regime is fixed: ``advancing`` (the foot pushes into undisturbed
  grains), ``contact`` (on the elastic unloading line of the crater) or ``free``. Each
  regime change is a terminal solve_ivp event, after which the bed memory is updated and
  solve_ivp is restarted from the event state:

  - advancing -> contact/free when ``z'`` crosses 0 downward (the crater bottom ``z_max``
    is set to the current depth, the added-mass cone is shed and, with the ``compaction``
    term, the loading curve below is re-anchored there);
  - contact -> advancing when ``z`` reaches ``z_max`` (a new added-mass episode starts);
  - contact -> free when the unloading force reaches 0;
  - free -> contact (or advancing, for an empty crater) when the foot comes back down to
    the depth where the unloading line starts.
* solve_ivp detects events by sign changes between step ends, so two details need care.
  A regime starts exactly on the zero of its own event functions, which are therefore
  offset by a round-off margin (:func:`_armed`). And a condition can be met and undone
  within one step (a glancing contact: the foot just reaches the crater bottom, or leaves
  the unloading line and falls straight back). Each event function is therefore also
  watched for a local maximum (a second terminal event on its time derivative); if the
  function is positive there, the crossing is located on the dense output and the regime
  changes from that point.
* The jump height is the largest foot height ``x_f`` from the start of the push-off
  segment until the first downward crossing of ``x_f = 0`` after the command has ended that
  follows a flight (the foot at least :data:`H_FLIGHT` above the surface at the command's
  end or later: a terminal event on ``x_f = H_FLIGHT`` upward arms the touchdown, itself a
  terminal event), or ``window_after`` after the command end. Interior maxima are found
  with a non-terminal event on ``x_f' = 0`` (downward), and the states at every restart
  are included.

What it costs
-------------
Measured on the development machine (2 cores shared with other work, Python 3.12, scipy
1.18; process time, best of 3 rounds of 3 calls after a first one), default settings
(DOP853, ``rtol = 1e-9``, ``atol = 1e-12``, ``max_step = 10 ms``), for the law ``k = 3000
N/m, c_d = 20 kg/m, kappa = 1, r_unload = 20`` at ``phi = 0.6``:

=========================  ==============  ===========  ==========================
command                    height, before  height, now  tracked jump, now [#]_
=========================  ==============  ===========  ==========================
single                     61 ms           40 ms        92 ms
preload                    77 ms           42 ms        96 ms
stutter                    59 ms           40 ms        91 ms
delayed_stutter            73 ms           49 ms        88 ms
delayed_stutter_preload    171 ms          112 ms       177 ms
=========================  ==============  ===========  ==========================

.. [#] :func:`simulate_trajectory_scipy` at 1000 frames per second from 50 ms before the
   command to 0.3 s after its end, with the height of the same simulation. Frames later
   after the landing cost more: the robot rests on the stiff crater, ~0.3 s of
   integration per second of frames.

The cost is solve_ivp's: about half of it is its Runge-Kutta step (12 stages of small
NumPy operations, ~0.1 ms per step, a few hundred steps per jump: the foot on the
unloading line, ``sqrt(r_unload F_yield' / m_foot)`` ~ 800 rad/s, sets the step while the
robot stands on the bed, so the settling hold of ``delayed_stutter_preload`` is its most
expensive part), the rest its event handling and a restart at every regime change. What
was done (1.4 to 1.8 times faster than before): a right-hand side per regime with its
constants bound once and the state unpacked to Python floats, doing the same
floating-point operations in the same order as the generic one, so every height is
unchanged bit for bit; and dense output only where it is used (trajectories, and the rare
glancing contact, whose run is repeated with it: the same steps). Not done: a step of our
own (Python floats instead of NumPy for the 4-component state would roughly halve the step
again) changes results at round-off level; ``max_step`` stays at 10 ms because the foot's
oscillation on the leg spring in flight (~40 Hz) needs it for the event detection by sign
change; solve_ivp's ``vectorized`` option serves only implicit methods' Jacobians. A looser
tolerance is the caller's choice: ``rtol = 1e-7, atol = 1e-10`` costs 0.4 to 0.8 of the
default and stays within 5e-6 mm of it for the cases above. The intrusion curves are
closed forms, vectorised over depths, and cost microseconds. With effects
(:mod:`granbayes.testing._effects`) a jump runs through a generic right-hand side and
costs 0.8 to 2 times the library's (noisy measurements; the physics changes the steps).

Length: about 1,170 lines: an independent implementation of the whole contract (every
force term, the bed's memory, every command, heights, frames and intrusion curves)
written to be read against physics-model.md rather than to be short.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Iterable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Literal

import numpy as np
import pandas as pd
from scipy.integrate import OdeSolution, solve_ivp
from scipy.optimize import OptimizeResult, brentq

from .._experiment import Experiment
from ..commands import CommandProgram, build_command
from ..forces import PARAMETERS
from ._effects import Effect, JanssenSaturation, _EffectSet, resolve_effects

G = 9.81
#: Geometry of the jammed cone (Aguilar & Goldman 2016): tan(theta), theta = 60 deg, and mu.
CONE_TAN = math.tan(math.radians(60.0))
CONE_MU = 2.0
#: Grain-scale compaction length l_c [m] of the ``compaction`` term (physics-model.md s. 8).
COMPACTION_LENGTH = 1e-3
#: The flight after which a touchdown ends the jump [m] (physics-model.md section 5).
H_FLIGHT = 1e-3
#: The latest frame a trajectory may ask for, after the end of the command [s].
TRACK_AFTER_END = 5.0

#: The optional force parameters whose physics this oracle implements. Listed here rather
#: than read from the registry, so that a term added to :mod:`granbayes.forces` but not to
#: this oracle is refused (``KeyError``) instead of silently ignored.
_IMPLEMENTED = ("c_d", "kappa", "k2", "b", "c_comp", "r_unload")

#: Values of the force parameters that are not given (term switched off; default bed): the
#: ``absent`` values of the registry, for the parameters this oracle implements.
PARAMETER_DEFAULTS: dict[str, float] = {
    p.name: p.absent for p in PARAMETERS if p.name in _IMPLEMENTED and p.absent is not None
}

ADVANCING, CONTACT, FREE = "advancing", "contact", "free"

#: Absolute tolerance of the bed state of :class:`PauseStiffening` when ``atol`` is given
#: per component for the robot's four [-].
_STATE_ATOL = 1e-12

State = np.ndarray
Rhs = Callable[[float, State], list[float]]


@dataclass(frozen=True)
class _Constants:
    """Robot and bed constants of one jump (SI), and the out-of-library effects."""

    m_upper: float  # motor + rod
    m_motor: float
    m_foot: float
    k_spring: float
    c_spring: float
    radius: float
    k: float
    c_d: float
    cone_density: float  # kappa * grain_density * phi [kg/m^3]
    r_unload: float
    k2: float
    b: float
    c_comp: float
    phi: float = 0.6
    phi_c: float = 0.612
    effects: _EffectSet | None = None  # None: the library model (the fast right-hand side)

    @property
    def janssen(self) -> JanssenSaturation | None:
        """The saturating depth force, if any."""
        return None if self.effects is None else self.effects.janssen

    def static_strength(self, z: float) -> float:
        """Yield force ``F_static(z) = k z + k2 z^2`` of the fresh bed at depth ``z`` [N]."""
        janssen = self.janssen
        if janssen is None:
            return self.k * z + self.k2 * z * z
        return janssen.depth_force(self.k, z) + self.k2 * z * z

    def static_slope(self, z: float) -> float:
        """Slope ``F_static'(z)`` of the fresh bed's loading curve [N/m]."""
        janssen = self.janssen
        if janssen is None:
            return self.k + 2.0 * self.k2 * z
        return janssen.depth_slope(self.k, z) + 2.0 * self.k2 * z

    def static_work(self, z: float) -> float:
        """Work ``int_0^z F_static`` of pushing through the fresh bed to depth ``z`` [J]."""
        janssen = self.janssen if self.janssen is not None else JanssenSaturation()
        return janssen.depth_work(self.k, z) + self.k2 * z**3 / 3.0


@dataclass
class _Bed:
    """The bed's memory [m, N, J].

    ``z_max`` is the crater depth and ``z_entry`` the depth where the current advancing
    episode started. The loading curve is anchored at depth ``z_c`` (force ``f_c``, fresh
    strength ``fs_c`` there, static work ``w_c`` absorbed above it) with stiffness
    multiplier ``mult`` below it: every advancing episode that ends at depth ``z``
    re-anchors it there with ``mult = 1 + c_comp (1 - exp(-z / l_c))`` (the ``compaction``
    term; ``mult = 1`` without it). ``top_mult`` is the :class:`PauseStiffening` factor of
    the bed when the last episode ended (1 without it): the unloading line starts at
    ``top_mult F_yield(z_max)``.
    """

    z_max: float
    z_entry: float
    z_c: float = 0.0
    f_c: float = 0.0
    fs_c: float = 0.0
    mult: float = 1.0
    w_c: float = 0.0
    top_mult: float = 1.0

    def yield_force(self, z: float, const: _Constants) -> float:
        """Force needed to advance the foot at depth ``z >= z_c`` (rate terms excluded) [N]."""
        return self.f_c + self.mult * (const.static_strength(z) - self.fs_c)

    def yield_slope(self, z: float, const: _Constants) -> float:
        """Slope ``F_yield'(z)`` of the loading curve at depth ``z >= z_c`` [N/m]."""
        return self.mult * const.static_slope(z)

    def absorbed_work(self, z: float, const: _Constants) -> float:
        """Static work absorbed along the loading curve from the surface to ``z >= z_c`` [J]."""
        dz = z - self.z_c
        rest = const.static_work(z) - const.static_work(self.z_c) - self.fs_c * dz
        return self.w_c + self.f_c * dz + self.mult * rest

    def end_episode(self, z: float, const: _Constants, top_mult: float = 1.0) -> None:
        """The foot stopped advancing at depth ``z``: the crater bottom is there."""
        if const.c_comp > 0.0:
            f_c = self.yield_force(z, const)
            if const.janssen is not None:
                self.w_c = self.absorbed_work(z, const)
            self.z_c, self.f_c, self.fs_c = z, f_c, const.static_strength(z)
            self.mult = 1.0 + const.c_comp * (1.0 - math.exp(-z / COMPACTION_LENGTH))
        self.z_max = z
        self.top_mult = top_mult

    def top_force(self, const: _Constants) -> float:
        """Force at the top of the unloading line, at the crater bottom [N]."""
        return self.top_mult * self.yield_force(self.z_max, const)

    def unloading_slope(self, const: _Constants) -> float:
        """Slope of the elastic unloading line [N/m].

        ``r_unload F_yield'(z_max)`` (the contract); with :class:`PauseStiffening` times
        ``top_mult^2``, and with :class:`JanssenSaturation` at least ``F_yield / z_max``
        and ``F_yield^2 / (2 W)`` (W: the static work absorbed), so that the bed stores no
        more energy than it absorbed (:mod:`granbayes.testing._effects`).
        """
        slope = const.r_unload * self.yield_slope(self.z_max, const)
        if const.janssen is not None and self.z_max > 0.0:
            force = self.yield_force(self.z_max, const)
            work = self.absorbed_work(self.z_max, const)
            slope = max(slope, force / self.z_max)
            if work > 0.0:
                slope = max(slope, force * force / (2.0 * work))
        return slope * self.top_mult**2

    def unloading_force(self, z: float, const: _Constants) -> float:
        """Force on the elastic unloading line at depth ``z`` (may be negative) [N]."""
        return self.top_force(const) - self.unloading_slope(const) * (self.z_max - z)

    def release_depth(self, const: _Constants) -> float:
        """Depth at which the unloading line reaches zero force [m]."""
        return self.z_max - self.top_force(const) / self.unloading_slope(const)


def _cone_volume(h: float, radius: float) -> float:
    """Volume of the jammed cone of height ``h`` under a foot of radius ``radius`` [m^3]."""
    return math.pi * h * (radius**2 - radius * h / CONE_TAN + h**2 / (3.0 * CONE_TAN**2))


def _library_rhs(
    const: _Constants, bed: _Bed, mode: str, omega: float, coef: float, t_start: float
) -> Rhs:
    """Right-hand side of the library model for one segment and one bed regime.

    The state is ``(x_rod, x_foot, v_rod, v_foot)``; in the segment the actuator follows
    ``alpha(t) = coef cos(omega (t - t_start)) + offset``. One closure per regime with its
    constants bound, the state unpacked to Python floats: the floating-point operations
    are those of the generic ground force (:func:`_ground`), in the same order.
    """
    k_s, c_s = const.k_spring, const.c_spring
    m_motor, m_upper, m_foot = const.m_motor, const.m_upper, const.m_foot
    drive = -coef * omega**2  # alpha'' = drive cos(omega (t - t_start))
    cos = math.cos

    if mode == FREE:

        def free(t: float, y: State) -> list[float]:
            x_r, x_f, v_r, v_f = y.tolist()
            f_spring = k_s * (x_f - x_r) + c_s * (v_f - v_r)
            a_r = (f_spring - m_motor * (drive * cos(omega * (t - t_start)))) / m_upper - G
            return [v_r, v_f, a_r, (0.0 - f_spring) / m_foot - G]

        return free

    if mode == CONTACT:
        top, slope, z_max = bed.top_force(const), bed.unloading_slope(const), bed.z_max

        def contact(t: float, y: State) -> list[float]:
            x_r, x_f, v_r, v_f = y.tolist()
            f_spring = k_s * (x_f - x_r) + c_s * (v_f - v_r)
            a_r = (f_spring - m_motor * (drive * cos(omega * (t - t_start)))) / m_upper - G
            f_ground = top - slope * (z_max - (-x_f))
            return [v_r, v_f, a_r, (f_ground - f_spring) / m_foot - G]

        return contact

    f_c, mult, fs_c = bed.f_c, bed.mult, bed.fs_c
    k, k2, c_d, b = const.k, const.k2, const.c_d, const.b
    rho_c, radius, z_entry = const.cone_density, const.radius, bed.z_entry
    h_full = radius * CONE_TAN
    m_full = rho_c * _cone_volume(h_full, radius)
    rho_pi = rho_c * math.pi

    def advancing(t: float, y: State) -> list[float]:
        x_r, x_f, v_r, v_f = y.tolist()
        f_spring = k_s * (x_f - x_r) + c_s * (v_f - v_r)
        a_r = (f_spring - m_motor * (drive * cos(omega * (t - t_start)))) / m_upper - G
        z, zdot = -x_f, -v_f
        try:
            force = f_c + mult * (k * z + k2 * z * z - fs_c) + c_d * zdot**2 + b * zdot
            if rho_c == 0.0:
                return [v_r, v_f, a_r, (force - f_spring) / m_foot - G]
            h = CONE_MU * (z - z_entry)
            if h >= h_full:  # cone fully formed: constant mass, no accretion
                return [v_r, v_f, a_r, (force - f_spring) / (m_foot + m_full) - G]
            added_mass = rho_c * _cone_volume(h, radius)
            # dV/dh = pi (R - h / tan(theta))^2, dh/dt = mu z', so dm_a/dt = rho_c pi q^2 mu z'
            flux = rho_pi * (radius - h / CONE_TAN) ** 2 * CONE_MU * zdot * zdot
            return [v_r, v_f, a_r, (force + flux - f_spring) / (m_foot + added_mass) - G]
        except OverflowError:  # a wild trial stage (Python floats raise): rejected as NaN
            return [math.nan] * 4

    return advancing


def _ground(
    z: float, zdot: float, s: float, mode: str, bed: _Bed, const: _Constants
) -> tuple[float, float, float]:
    """Ground force, added mass and momentum flux (up positive) at depth ``z``, with effects.

    Parameters
    ----------
    z, zdot : float
        Foot depth [m] and its rate [m/s].
    s : float
        State of the :class:`PauseStiffening` bed [-] (ignored without it).
    mode : str
        Bed regime.
    bed : _Bed
        Bed memory.
    const : _Constants
        Jump constants.

    Returns
    -------
    force : float
        Ground reaction force ``F_g`` [N].
    added_mass : float
        Mass of the jammed cone carried by the foot [kg].
    flux : float
        Momentum flux ``-(dm_a/dt) x_f'`` [N].
    """
    if mode == FREE:
        return 0.0, 0.0, 0.0
    if mode == CONTACT:
        return bed.unloading_force(z, const), 0.0, 0.0
    effects = const.effects if const.effects is not None else _EffectSet()
    strength = bed.yield_force(z, const)
    if effects.pause is not None:
        strength *= effects.pause.multiplier(s)
    if effects.rate is not None:
        strength *= effects.rate.multiplier(zdot)
    c_d = const.c_d
    if effects.drag is not None:
        c_d *= effects.drag.drag_factor(z, const.phi, const.phi_c)
    force = strength + c_d * zdot**2 + const.b * zdot
    if const.cone_density == 0.0:
        return force, 0.0, 0.0
    h_full = const.radius * CONE_TAN
    h = CONE_MU * (z - bed.z_entry)
    if h >= h_full:  # cone fully formed: constant mass, no accretion
        return force, const.cone_density * _cone_volume(h_full, const.radius), 0.0
    added_mass = const.cone_density * _cone_volume(h, const.radius)
    dm_dt = const.cone_density * math.pi * (const.radius - h / CONE_TAN) ** 2 * CONE_MU * zdot
    return force, added_mass, dm_dt * zdot  # -(dm_a/dt) x_f' with x_f' = -z'


def _effects_rhs(
    const: _Constants, bed: _Bed, mode: str, omega: float, coef: float, t_start: float
) -> Rhs:
    """Right-hand side with out-of-library effects (state ``(x_r, x_f, v_r, v_f[, s])``).

    ``s`` is the :class:`PauseStiffening` state, present only with that effect.
    """
    effects = const.effects if const.effects is not None else _EffectSet()
    pause = effects.pause
    advancing = mode == ADVANCING

    def rhs(t: float, y: State) -> list[float]:
        state = y.tolist()
        x_r, x_f, v_r, v_f = state[:4]
        s = state[4] if pause is not None else 0.0
        alpha_ddot = -coef * omega**2 * math.cos(omega * (t - t_start))
        f_spring = const.k_spring * (x_f - x_r) + const.c_spring * (v_f - v_r)
        try:
            f_ground, added_mass, flux = _ground(-x_f, -v_f, s, mode, bed, const)
        except OverflowError:  # a wild trial stage (Python floats raise): rejected as NaN
            return [math.nan] * len(state)
        a_r = (f_spring - const.m_motor * alpha_ddot) / const.m_upper - G
        a_f = (f_ground + flux - f_spring) / (const.m_foot + added_mass) - G
        if pause is None:
            return [v_r, v_f, a_r, a_f]
        return [v_r, v_f, a_r, a_f, pause.rate(s, -v_f, advancing)]

    return rhs


def _rhs_factory(
    const: _Constants, bed: _Bed, mode: str, omega: float, coef: float, t_start: float
) -> Rhs:
    """Right-hand side for one segment and one bed regime (library or with effects)."""
    if const.effects is None:
        return _library_rhs(const, bed, mode, omega, coef, t_start)
    return _effects_rhs(const, bed, mode, omega, coef, t_start)


def _event(
    fun: Callable[[float, State], float], direction: float, terminal: bool
) -> Callable[[float, State], float]:
    """Attach solve_ivp's event attributes to ``fun``."""
    fun.direction = direction  # type: ignore[attr-defined]
    fun.terminal = terminal  # type: ignore[attr-defined]
    return fun


@dataclass(frozen=True)
class _Watch:
    """A regime-ending condition watched by solve_ivp events.

    ``fun`` crosses zero upward when the regime ends; ``peak`` (``-d fun / dt``) crosses
    zero upward where ``fun`` has a local maximum. ``margin`` and ``peak_margin`` are the
    round-off margins used by :func:`_armed` (units of ``fun`` and ``peak``).
    """

    name: str
    fun: Callable[[float, State], float]
    peak: Callable[[float, State], float]
    margin: float
    peak_margin: float


def _watches(mode: str, bed: _Bed, const: _Constants, rhs: Rhs) -> list[_Watch]:
    """Conditions that end the current bed regime (state ``(x_r, x_f, v_r, v_f[, s])``)."""
    if mode == ADVANCING:
        # z' = -v_f crosses zero downward, i.e. v_f crosses zero upward
        return [_Watch("stop", lambda t, y: y[3], lambda t, y: -rhs(t, y)[3], 1e-11, 1e-9)]
    if mode == CONTACT:
        z_max = bed.z_max
        z_release = bed.release_depth(const)  # the unloading force is 0 there
        return [
            _Watch("reach_bottom", lambda t, y: -y[1] - z_max, lambda t, y: y[3], 1e-13, 1e-11),
            _Watch("release", lambda t, y: y[1] + z_release, lambda t, y: -y[3], 1e-13, 1e-11),
        ]
    z_release = bed.release_depth(const)
    return [_Watch("touch", lambda t, y: -y[1] - z_release, lambda t, y: y[3], 1e-13, 1e-11)]


def _armed(
    fun: Callable[[float, State], float],
    margin: float,
    t: float,
    y: State,
    just_fired: bool = False,
) -> Callable[[float, State], float]:
    """A terminal solve_ivp event for ``fun`` crossing zero upward after a restart at ``t``.

    A regime starts exactly where the previous one ended, so its event functions may start
    at zero up to round-off, on either side. solve_ivp only sees sign changes between step
    ends and would miss a crossing from a slightly positive start. A function that starts
    within ``margin`` of zero is therefore offset to start at ``-margin`` (a shift of the
    event by far less than the integration error). The function whose event has just
    stopped the previous run (``just_fired``) is offset to start at ``+margin`` instead, so
    that it does not fire again at once.
    """
    start = fun(t, y)
    offset = 0.0
    if abs(start) < margin:
        offset = start - margin if just_fired else start + margin
    return _event(lambda t, y: fun(t, y) - offset, +1.0, True)


def _first_crossing(fun: Callable[[float, State], float], sol: OptimizeResult) -> float:
    """Time of the upward zero of ``fun`` before the end of a solve_ivp run.

    ``sol`` is a run with dense output that ended at a local maximum of ``fun`` where
    ``fun > 0``; the zero lies after the last step end where ``fun <= 0``.
    """
    times = sol.t
    j = len(times) - 2
    while j > 0 and fun(times[j], sol.sol(times[j])) > 0.0:
        j -= 1
    return brentq(lambda s: fun(s, sol.sol(s)), times[j], times[-1], xtol=1e-15)


def _switch(event: str, y: State, bed: _Bed, const: _Constants) -> str:
    """New bed regime after a regime event at state ``y``; updates the bed memory."""
    if event == "stop":  # the crater bottom is where the foot stopped advancing
        top_mult = 1.0
        if const.effects is not None and const.effects.pause is not None:
            top_mult = float(const.effects.pause.multiplier(float(y[4])))
        bed.end_episode(-float(y[1]), const, top_mult)
        return CONTACT if bed.top_force(const) > 0.0 else FREE
    if event == "release":
        return FREE
    if event == "touch" and bed.top_force(const) > 0.0:
        return CONTACT
    bed.z_entry = bed.z_max  # back at the crater bottom: a new added-mass episode
    return ADVANCING


def _checked_parameters(params: Mapping[str, float]) -> dict[str, float]:
    """All force parameters (absent ones at their defaults), checked against the registry.

    Raises
    ------
    KeyError
        For a parameter this oracle does not implement.
    ValueError
        If ``k`` is missing or a parameter is outside its allowed range (the bounds of
        :mod:`granbayes.forces`, e.g. ``r_unload >= 1``), where the compiled simulator
        returns ``Status.BAD_INPUT``.
    """
    unknown = set(params) - {"k", *PARAMETER_DEFAULTS}
    if unknown:
        raise KeyError(f"unknown force parameter(s): {sorted(unknown)}")
    if "k" not in params:
        raise ValueError("parameter 'k' is required")
    p = {**PARAMETER_DEFAULTS, **{name: float(v) for name, v in params.items()}}
    for parameter in PARAMETERS:
        problem = parameter.check(p[parameter.name])
        if problem:
            raise ValueError(problem)
    return p


def _constants(
    phi: float,
    params: Mapping[str, float],
    experiment: Experiment,
    effects: _EffectSet | None = None,
) -> _Constants:
    """Jump constants from phi, the force parameters, the experiment and the effects.

    Raises
    ------
    KeyError
        For a parameter this oracle does not implement.
    ValueError
        If ``k`` is missing or a parameter is outside its allowed range.
    """
    p = _checked_parameters(params)
    robot = experiment.robot
    return _Constants(
        m_upper=robot.m_motor + robot.m_rod,
        m_motor=robot.m_motor,
        m_foot=robot.m_foot,
        k_spring=robot.k_spring,
        c_spring=robot.c_spring,
        radius=robot.foot_radius,
        k=p["k"],
        c_d=p["c_d"],
        cone_density=p["kappa"] * robot.grain_density * phi,
        r_unload=p["r_unload"],
        k2=p["k2"],
        b=p["b"],
        c_comp=p["c_comp"],
        phi=phi,
        phi_c=experiment.phi_c,
        effects=None if effects is None or effects.empty else effects,
    )


def _settled_depth(const: _Constants, weight: float) -> float:
    """Depth ``z0`` where the fresh bed carries ``weight``: ``F_static(z0) = weight`` [m]."""
    if const.janssen is None:
        # the positive root of k2 z^2 + k z - weight = 0
        if const.k2 > 0.0:
            return (-const.k + math.sqrt(const.k**2 + 4.0 * const.k2 * weight)) / (2.0 * const.k2)
        return weight / const.k
    upper = weight / const.k
    while const.static_strength(upper) < weight:
        if upper > 1e3:
            raise ValueError(
                f"the bed cannot carry the robot (weight {weight:.3g} N): the saturated depth "
                f"force k lambda = {const.k * const.janssen.lambda_m:.3g} N and k2 = 0"
            )
        upper *= 2.0
    return brentq(lambda z: const.static_strength(z) - weight, 0.0, upper, xtol=1e-15)


def _start(program: CommandProgram, const: _Constants) -> tuple[State, _Bed]:
    """Initial state and bed memory (physics-model.md section 4).

    With :class:`PauseStiffening` the state has a fifth component, the bed state, which
    starts at the effect's ``initial``.
    """
    if program.start_state == "settled":
        weight = (const.m_upper + const.m_foot) * G
        z0 = _settled_depth(const, weight)
        x_f = -z0
        x_r = x_f - const.m_upper * G / const.k_spring  # spring carries the upper mass
        bed = _Bed(z_max=z0, z_entry=z0)
        bed.end_episode(z0, const)  # placing the robot is an intrusion to z0 that has ended
        y = np.array([x_r, x_f, 0.0, 0.0])
    else:
        y, bed = np.zeros(4), _Bed(z_max=0.0, z_entry=0.0)
    if const.effects is not None and const.effects.pause is not None:
        y = np.append(y, const.effects.pause.initial)
    return y, bed


def _run_atol(atol: float | Sequence[float], size: int) -> float | np.ndarray:
    """``atol`` for a state of ``size`` components (the bed state appended if needed)."""
    if np.ndim(atol) == 0:
        return atol  # type: ignore[return-value]
    values = np.asarray(atol, dtype=float)
    if values.size < size:
        values = np.append(values, np.full(size - values.size, _STATE_ATOL))
    return values


@dataclass
class _Run:
    """The outcome of one integration of a jump."""

    height: float  # [m]
    #: ``(t_from, t_to, dense output valid on [t_from, t_to])`` of every solve_ivp run
    pieces: list[tuple[float, float, OdeSolution]] = field(default_factory=list)


def _integrate(
    program: CommandProgram,
    const: _Constants,
    *,
    rtol: float,
    atol: float | Sequence[float],
    method: str,
    max_step: float,
    window_after: float,
    track_to: float | None = None,
) -> tuple[_Run, State]:
    """Integrate one jump: its height and, if ``track_to`` is given, its dense output.

    Without ``track_to`` the integration stops as soon as the height is known (the
    touchdown after a flight, or the end of the window). With it, it goes on under the same
    model (landing and whatever follows) until ``track_to`` [s] and the height is known,
    with no height event left once it is; the runs up to the height are the same solve_ivp
    calls in both cases, so the height is the same, bit for bit.

    Returns
    -------
    _Run
        The height [m] and the dense output of every run (if tracking).
    State
        The initial state.
    """
    y, bed = _start(program, const)
    y0 = y.copy()
    omega = program.omega
    tracking = track_to is not None
    run_atol = _run_atol(atol, y.size)

    # initial regime: the foot advances if the net force pushes it into the bed
    mode = ADVANCING
    a_foot = _rhs_factory(const, bed, mode, omega, program.segments[0].coef, 0.0)(0.0, y)[3]
    if a_foot >= 0.0:
        mode = CONTACT if bed.top_force(const) > 0.0 else FREE

    # pieces of constant waveform: the segments, then the hold after the command (and the
    # hold on to the last frame of a trajectory)
    bounds = program.boundaries
    pieces = [(bounds[i], bounds[i + 1], s.coef) for i, s in enumerate(program.segments)]
    hold = len(pieces)
    pieces.append((program.t_end, program.t_end + window_after, 0.0))
    if tracking and track_to > program.t_end + window_after:
        pieces.append((program.t_end + window_after, track_to, 0.0))
    apex = _event(lambda t, y: y[3], -1.0, False)  # x_f' crosses zero downward

    def touchdown(t: float, y: State) -> float:  # x_f crosses zero downward
        return -y[1]

    def flight(t: float, y: State) -> float:  # x_f reaches H_FLIGHT upward
        return y[1] - H_FLIGHT

    out = _Run(height=-math.inf)
    flown = False  # a flight after the command has ended: only then a touchdown ends it
    done = False  # the height is known
    t = 0.0
    last_peak = -1  # index of the watch whose peak stopped the previous run, if any
    for index, (t_start, t_stop, coef) in enumerate(pieces):
        in_window = not done and program.pushoff_index <= index <= hold
        after_command = not done and index == hold
        if in_window:
            out.height = max(out.height, y[1])
        if after_command and y[1] >= H_FLIGHT:
            flown = True
        while True:
            # once the height is known, a trajectory is integrated only up to its last frame
            stop = min(t_stop, track_to) if done and track_to is not None else t_stop
            if t >= stop:
                break
            rhs = _rhs_factory(const, bed, mode, omega, coef, t_start)
            watches = _watches(mode, bed, const, rhs)
            crossings = [_armed(w.fun, w.margin, t, y) for w in watches]
            labels: list[tuple[str, int]] = [("crossing", i) for i in range(len(watches))]
            labels += [("peak", i) for i in range(len(watches))]
            peaks = [
                _armed(w.peak, w.peak_margin, t, y, just_fired=i == last_peak)
                for i, w in enumerate(watches)
            ]
            events = [*crossings, *peaks]
            if in_window:
                labels.append(("apex", -1))
                events.append(apex)
            if after_command and flown:
                labels.append(("touchdown", -1))
                events.append(_armed(touchdown, 1e-13, t, y))
            elif after_command:
                labels.append(("flight", -1))
                events.append(_armed(flight, 1e-13, t, y))

            def run(dense: bool, rhs=rhs, events=events, t=t, y=y, stop=stop) -> OptimizeResult:
                with np.errstate(over="ignore", invalid="ignore"):  # a wild trial stage
                    sol = solve_ivp(
                        rhs,
                        (t, stop),
                        y,
                        method=method,
                        rtol=rtol,
                        atol=run_atol,
                        max_step=max_step,
                        events=events,
                        dense_output=dense,
                    )
                if sol.status < 0:
                    raise RuntimeError(f"solve_ivp failed at t = {t:.6f} s: {sol.message}")
                return sol

            sol = run(tracking)
            t_run, y_run = float(sol.t[-1]), sol.y[:, -1]
            kind, which = "end", -1
            if sol.status == 1:  # a terminal event ended the run: the one at the final time
                # (touchdown first: it can coincide with the foot touching a crater rim)
                fired = [
                    label
                    for label, te in zip(labels, sol.t_events, strict=True)
                    if label[0] != "apex" and len(te) and te[-1] == t_run
                ]
                kind, which = min(fired, key=lambda label: label[0] != "touchdown")
            if kind == "peak":
                crossing = crossings[which]
                if crossing(t_run, y_run) > 0.0:
                    # the regime ended and came back inside one step (a glancing contact):
                    # go back to the first crossing, on the dense output (the same steps)
                    if sol.sol is None:
                        sol = run(True)
                    t_run = _first_crossing(crossing, sol)
                    y_run = sol.sol(t_run)
                    kind = "crossing"
            if in_window:
                apex_states = sol.y_events[labels.index(("apex", -1))]
                apex_times = sol.t_events[labels.index(("apex", -1))]
                out.height = max(
                    out.height,
                    y_run[1],
                    *(ye[1] for te, ye in zip(apex_times, apex_states, strict=True) if te <= t_run),
                )
            if tracking:
                out.pieces.append((t, t_run, sol.sol))
            t, y = t_run, y_run
            last_peak = which if kind == "peak" else -1
            if kind == "end":
                t = stop
            elif kind == "touchdown":
                if not tracking:
                    return out, y0
                done = True
                in_window = after_command = False
            elif kind == "flight":
                flown = True
            elif kind == "crossing":
                mode = _switch(watches[which].name, y, bed, const)
            # kind == "peak" without a crossing: a local maximum short of the regime's end;
            # the run simply restarts from there in the same regime
        if index == hold:
            done = True
    return out, y0


def _setup(
    command: str | CommandProgram,
    phi: float,
    params: Mapping[str, float],
    experiment: Experiment | None,
    effects: Effect | Iterable[Effect] | None,
) -> tuple[CommandProgram, _Constants]:
    """The command's program and the jump's constants."""
    exp = experiment if experiment is not None else Experiment()
    program = (
        command if isinstance(command, CommandProgram) else build_command(command, exp.command)
    )
    return program, _constants(float(phi), params, exp, resolve_effects(effects))


def simulate_height_scipy(
    command: str | CommandProgram,
    phi: float,
    params: Mapping[str, float],
    experiment: Experiment | None = None,
    rtol: float = 1e-9,
    atol: float | Sequence[float] = 1e-12,
    *,
    method: Literal["DOP853", "RK45"] = "DOP853",
    max_step: float = 0.01,
    window_after: float = 0.6,
    effects: Effect | Iterable[Effect] | None = None,
) -> float:
    """Jump height of one jump, integrated with ``scipy.integrate.solve_ivp``.

    Parameters
    ----------
    command : str or CommandProgram
        ``single``, ``preload``, ``stutter``, ``delayed_stutter`` or
        ``delayed_stutter_preload`` (any command of the registry), or a program.
    phi : float
        Volume fraction of the bed [-].
    params : mapping of str to float
        Force-term parameters: ``k`` [N/m] (required), ``c_d`` [kg/m], ``kappa`` [-],
        ``r_unload`` [-] (default 20), ``k2`` [N/m^2], ``b`` [N s/m], ``c_comp`` [-];
        absent terms are off.
    experiment : Experiment, optional
        Robot and command settings (model defaults if omitted); ``phi_c`` is used by
        :class:`~granbayes.testing.DepthDependentDrag`.
    rtol : float
        Relative tolerance of solve_ivp.
    atol : float or sequence of 4 floats
        Absolute tolerance of solve_ivp, for all of ``(x_rod, x_foot, v_rod, v_foot)``
        ([m], [m/s]) or per component (the bed state of
        :class:`~granbayes.testing.PauseStiffening` then gets 1e-12).
    method : str
        solve_ivp method (``"DOP853"`` or ``"RK45"``).
    max_step : float
        Largest step [s]; keeps event detection by sign change reliable.
    window_after : float
        The height window closes this long after the command ends [s].
    effects : effect or sequence of effects, optional
        Out-of-library ground physics (:mod:`granbayes.testing._effects`), at most one of
        each kind; ``None`` or ``()`` is the library model.

    Returns
    -------
    float
        Jump height [mm] (physics-model.md section 5).

    Raises
    ------
    KeyError
        For an unknown force parameter.
    ValueError
        If ``k`` is missing or a parameter is outside its allowed range (e.g. ``r_unload <
        1``; the compiled simulator returns ``Status.BAD_INPUT`` for such a jump), or a
        settled start on a saturating bed that cannot carry the robot.
    RuntimeError
        If solve_ivp fails.

    Examples
    --------
    A perfectly elastic bed, and an unloading line less steep than the loading curve:

    >>> from granbayes.testing import simulate_height_scipy
    >>> round(simulate_height_scipy("single", 0.612, {"k": 3000.0, "r_unload": 1.0}), 1)
    67.7
    >>> simulate_height_scipy("single", 0.612, {"k": 3000.0, "r_unload": 0.5})
    Traceback (most recent call last):
    ...
    ValueError: r_unload must be >= 1 [-], got 0.5
    """
    program, const = _setup(command, phi, params, experiment, effects)
    result, _ = _integrate(
        program,
        const,
        rtol=rtol,
        atol=atol,
        method=method,
        max_step=max_step,
        window_after=window_after,
    )
    return float(1e3 * result.height)


@dataclass(frozen=True)
class OracleTrajectory:
    """The motion of one jump at given frame times, from :func:`simulate_trajectory_scipy`.

    Attributes
    ----------
    t_s : ndarray
        Frame times on the command's clock [s], as given.
    x_foot_mm : ndarray
        Foot height ``x_f`` above the undisturbed surface [mm] (negative: in the bed).
    x_rod_mm : ndarray
        Rod displacement ``x_r(t) - x_r(0)`` [mm].
    v_foot_m_s : ndarray
        Foot velocity [m/s].
    v_rod_m_s : ndarray
        Rod velocity [m/s].
    height_mm : float
        Jump height of the same simulation [mm] (physics-model.md section 5).
    t_end_s : float
        End of the command [s].
    """

    t_s: np.ndarray
    x_foot_mm: np.ndarray
    x_rod_mm: np.ndarray
    v_foot_m_s: np.ndarray
    v_rod_m_s: np.ndarray
    height_mm: float
    t_end_s: float

    def frame(self) -> pd.DataFrame:
        """The frames as a table: ``t_s, x_foot_mm, x_rod_mm`` (``trajectories.csv`` units).

        Returns
        -------
        pandas.DataFrame
        """
        return pd.DataFrame(
            {"t_s": self.t_s, "x_foot_mm": self.x_foot_mm, "x_rod_mm": self.x_rod_mm}
        )


def simulate_trajectory_scipy(
    command: str | CommandProgram,
    phi: float,
    params: Mapping[str, float],
    t_s: Sequence[float] | np.ndarray,
    experiment: Experiment | None = None,
    *,
    effects: Effect | Iterable[Effect] | None = None,
    rtol: float = 1e-9,
    atol: float | Sequence[float] = 1e-12,
    method: Literal["DOP853", "RK45"] = "DOP853",
    max_step: float = 0.01,
    window_after: float = 0.6,
) -> OracleTrajectory:
    """The motion of one jump at the frame times ``t_s``, and its height (section 5b).

    The foot height and the rod's displacement are read from solve_ivp's dense output,
    exact to the integration tolerance at any time (no fixed step, no interpolation
    between recorded points). Semantics:

    * ``t_s`` is on the command's clock: ``t = 0`` at the start of the command's first
      segment (physics-model.md section 4). Frames may be in any order and repeat.
    * For ``t < 0`` the robot rests in its start state (section 4): ``x_foot`` is 0
      (touching) or ``-z0`` (settled), the rod's displacement 0, the velocities 0.
    * The simulation is the one of :func:`simulate_height_scipy` (same solve_ivp runs up
      to the height, so ``height_mm`` equals its value bit for bit). After the command the
      actuator holds its position and the robot moves on under the same model: the hold
      is integrated like the height's, and beyond the end of the height window (the
      touchdown after a flight, or ``window_after`` after the command) the motion
      continues (landing, crater, bouncing, settling) up to the last frame.
    * The last frame may be at most :data:`TRACK_AFTER_END` (5 s) after the command's end.

    Parameters
    ----------
    command : str or CommandProgram
        A registered command, or a program.
    phi : float
        Volume fraction of the bed [-].
    params : mapping of str to float
        Force-term parameters [SI] (as :func:`simulate_height_scipy`).
    t_s : sequence of float
        Frame times [s] (finite; any order).
    experiment : Experiment, optional
        Robot and command settings (model defaults if omitted).
    effects : effect or sequence of effects, optional
        Out-of-library ground physics; ``None`` is the library model.
    rtol : float
        Relative tolerance of solve_ivp.
    atol : float or sequence of 4 floats
        Absolute tolerance of solve_ivp ([m], [m/s]).
    method : str
        solve_ivp method (``"DOP853"`` or ``"RK45"``).
    max_step : float
        Largest step [s].
    window_after : float
        The height window closes this long after the command ends [s].

    Returns
    -------
    OracleTrajectory
        The frames (in the order given) and the height.

    Raises
    ------
    ValueError
        For a frame time that is not finite or later than the command's end plus 5 s, and
        for the parameter problems of :func:`simulate_height_scipy`.
    KeyError
        For an unknown force parameter.

    Examples
    --------
    >>> import numpy as np
    >>> from granbayes.testing import simulate_trajectory_scipy
    >>> traj = simulate_trajectory_scipy("single", 0.612, {"k": 3000.0}, np.arange(-2, 40) * 0.01)
    >>> float(traj.x_foot_mm[0]), bool(traj.x_foot_mm.max() <= traj.height_mm + 1e-9)
    (0.0, True)
    """
    times = np.asarray(t_s, dtype=float)
    if times.ndim != 1:
        raise ValueError(f"t_s must be one-dimensional, got shape {times.shape}")
    if not np.all(np.isfinite(times)):
        raise ValueError("frame times t_s must be finite")
    program, const = _setup(command, phi, params, experiment, effects)
    latest = program.t_end + TRACK_AFTER_END
    if times.size and times.max() > latest:
        raise ValueError(
            f"frame time {times.max():.6g} s is after the command's end + {TRACK_AFTER_END:g} s "
            f"({latest:.6g} s)"
        )
    track_to = max(float(times.max()), 0.0) if times.size else 0.0
    result, y0 = _integrate(
        program,
        const,
        rtol=rtol,
        atol=atol,
        method=method,
        max_step=max_step,
        window_after=window_after,
        track_to=track_to,
    )
    states = np.repeat(y0[:4, None], times.size, axis=1)
    starts = np.array([piece[0] for piece in result.pieces])
    run_of = np.searchsorted(starts, times, side="right") - 1
    for i, (_, _, dense) in enumerate(result.pieces):
        mask = (run_of == i) & (times >= 0.0)
        if mask.any():
            states[:, mask] = dense(times[mask])[:4]
    return OracleTrajectory(
        t_s=times,
        x_foot_mm=1e3 * states[1],
        x_rod_mm=1e3 * (states[0] - y0[0]),
        v_foot_m_s=states[3].copy(),
        v_rod_m_s=states[2].copy(),
        height_mm=float(1e3 * result.height),
        t_end_s=program.t_end,
    )


def _cone_volume_array(h: np.ndarray, radius: float) -> np.ndarray:
    """``V(h) = pi h (R^2 - R h / tan(theta) + h^2 / (3 tan(theta)^2))`` [m^3], vectorised."""
    return np.pi * h * (radius**2 - radius * h / CONE_TAN + h**2 / (3.0 * CONE_TAN**2))


def intrusion_force_scipy(
    phi: float,
    params: Mapping[str, float],
    depth_mm: float | Sequence[float] | np.ndarray,
    speed_mm_s: float,
    experiment: Experiment | None = None,
    *,
    effects: Effect | Iterable[Effect] | None = None,
) -> np.ndarray:
    """Force of a constant-speed intrusion into a fresh bed (physics-model.md section 5b).

    Written from the contract in closed form, vectorised over depths: the foot alone
    advances at ``z' = v`` from the surface into an undisturbed bed (``z_max = z``, no
    compaction history, one added-mass episode from ``z_entry = 0``), and the rig measures

        F(z) = F_adv(z, v) + kappa rho_g phi V'(z) v^2 - m_a(z) g

    with ``F_adv(z, v) = F_static(z) + c_d v^2 + b v`` (``F_static = k z + k2 z^2``),
    ``V'(z) = mu pi (R - h / tan(theta))^2`` for ``h = mu z < R tan(theta)`` and 0 beyond
    (the cone is full), ``m_a = kappa rho_g phi V(min(mu z, R tan(theta)))``. ``c_comp`` and
    ``r_unload`` play no part (nothing unloads). With effects: the static part is
    ``F_static`` with :class:`~granbayes.testing.JanssenSaturation`, times the
    :class:`~granbayes.testing.RateStiffening` factor at ``v`` and the
    :class:`~granbayes.testing.PauseStiffening` factor of the bed state reached at depth
    ``z`` (:meth:`~granbayes.testing.PauseStiffening.state_at`), and ``c_d`` is multiplied by
    the :class:`~granbayes.testing.DepthDependentDrag` factor.

    Parameters
    ----------
    phi : float
        Volume fraction of the bed [-].
    params : mapping of str to float
        Force-term parameters [SI] (as :func:`simulate_height_scipy`).
    depth_mm : float or array_like
        Depths of the foot below the undisturbed surface [mm] (>= 0).
    speed_mm_s : float
        Constant intrusion speed [mm/s] (>= 0; 0 is quasi-static).
    experiment : Experiment, optional
        The robot (its ``foot_radius`` and ``grain_density``) and ``phi_c``.
    effects : effect or sequence of effects, optional
        Out-of-library ground physics; ``None`` is the library model.

    Returns
    -------
    ndarray
        The force [N], one per depth (shape of ``depth_mm``).

    Raises
    ------
    ValueError
        For a negative or non-finite depth or speed, and for the parameter problems of
        :func:`simulate_height_scipy`.
    KeyError
        For an unknown force parameter.

    Examples
    --------
    Quasi-static, the force reads the loading curve ``k z``:

    >>> from granbayes.testing import intrusion_force_scipy
    >>> intrusion_force_scipy(0.612, {"k": 3000.0}, [0.0, 10.0, 20.0], 0.0).tolist()
    [0.0, 30.0, 60.0]
    """
    p = _checked_parameters(params)
    exp = experiment if experiment is not None else Experiment()
    effects_set = resolve_effects(effects)
    z = 1e-3 * np.asarray(depth_mm, dtype=float)
    v = 1e-3 * float(speed_mm_s)
    if not (np.all(np.isfinite(z)) and np.all(z >= 0.0)):
        raise ValueError("depths must be finite and >= 0 mm")
    if not (math.isfinite(v) and v >= 0.0):
        raise ValueError(f"the intrusion speed must be finite and >= 0 mm/s, got {speed_mm_s!r}")
    radius, rho_c = exp.robot.foot_radius, p["kappa"] * exp.robot.grain_density * phi

    janssen = effects_set.janssen if effects_set.janssen is not None else JanssenSaturation()
    static = janssen.depth_force(p["k"], z) + p["k2"] * z**2
    if effects_set.rate is not None:
        static = static * effects_set.rate.multiplier(np.full_like(z, v))
    if effects_set.pause is not None:
        static = static * effects_set.pause.multiplier(effects_set.pause.state_at(z, v))
    c_d = p["c_d"] * (
        1.0 if effects_set.drag is None else effects_set.drag.drag_factor(z, float(phi), exp.phi_c)
    )
    advancing = static + c_d * v**2 + p["b"] * v

    h_full = radius * CONE_TAN
    h = np.minimum(CONE_MU * z, h_full)
    dv_dz = np.where(CONE_MU * z < h_full, CONE_MU * np.pi * (radius - h / CONE_TAN) ** 2, 0.0)
    added_mass = rho_c * _cone_volume_array(h, radius)
    return advancing + rho_c * dv_dz * v**2 - added_mass * G
