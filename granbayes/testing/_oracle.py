"""The independent oracle: a ``scipy.integrate.solve_ivp`` implementation of the model.

:func:`simulate_height_scipy` follows ``docs/physics-model.md`` directly, with a Python
right-hand side and solve_ivp's own event machinery, and it is written for clarity rather
than speed. It shares nothing with the compiled integrator (``granbayes._kernel``) except
the command waveforms (:func:`granbayes.commands.build_command`), the robot/settings
containers (:mod:`granbayes.experiment`) and the parameter bounds and "off" values of the
force-term registry (:mod:`granbayes.forces`); its only numerical dependency is scipy.

How the non-smooth model is integrated
--------------------------------------
--------------------------------------
* The command is integrated segment by segment (``alpha''`` jumps at segment boundaries),
  followed by a hold segment of ``window_after`` seconds after the command ends.
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
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from typing import Literal

import numpy as np
from scipy.integrate import solve_ivp
from scipy.optimize import OptimizeResult, brentq

from ..commands import CommandProgram, build_command
from ..experiment import Experiment
from ..forces import PARAMETERS

G = 9.81
#: Geometry of the jammed cone (Aguilar & Goldman 2016): tan(theta), theta = 60 deg, and mu.
CONE_TAN = math.tan(math.radians(60.0))
CONE_MU = 2.0
#: Grain-scale compaction length l_c [m] of the ``compaction`` term (physics-model.md s. 8).
COMPACTION_LENGTH = 1e-3
#: The flight after which a touchdown ends the jump [m] (physics-model.md section 5).
H_FLIGHT = 1e-3

#: The optional force parameters whose physics this oracle implements. Listed here rather
#: than read from the registry, so that a term added to :mod:`granbayes.forces` but not to
#: this oracle is refused (``KeyError``) instead of silently ignored.
_IMPLEMENTED = ("c_d", "kappa", "k2", "b", "c_comp", "r_unload")

#: Values of the force parameters that are not given (term switched off; default bed): the
#: ``absent`` values of the registry, for the parameters this oracle implements.
PARAMETER_DEFAULTS: dict[str, float] = {
    p.name: p.absent for p in PARAMETERS if p.name in _IMPLEMENTED and p.absent is not None
}

#: Sampler settings for tests of the inference loop on small data: two ensembles of 8


ADVANCING, CONTACT, FREE = "advancing", "contact", "free"


@dataclass(frozen=True)
class _Constants:
    """Robot and bed constants of one jump (SI)."""

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

    def static_strength(self, z: float) -> float:
        """Yield force ``F_static(z) = k z + k2 z^2`` of the fresh bed at depth ``z`` [N]."""
        return self.k * z + self.k2 * z * z


@dataclass
class _Bed:
    """The bed's memory [m, N].

    ``z_max`` is the crater depth and ``z_entry`` the depth where the current advancing
    episode started. The loading curve is anchored at depth ``z_c`` (force ``f_c``, fresh
    strength ``fs_c`` there) with stiffness multiplier ``mult`` below it: every advancing
    episode that ends at depth ``z`` re-anchors it there with ``mult = 1 + c_comp (1 -
    exp(-z / l_c))`` (the ``compaction`` term; ``mult = 1`` without it).
    """

    z_max: float
    z_entry: float
    z_c: float = 0.0
    f_c: float = 0.0
    fs_c: float = 0.0
    mult: float = 1.0

    def yield_force(self, z: float, const: _Constants) -> float:
        """Force needed to advance the foot at depth ``z >= z_c`` (rate terms excluded) [N]."""
        return self.f_c + self.mult * (const.static_strength(z) - self.fs_c)

    def yield_slope(self, z: float, const: _Constants) -> float:
        """Slope ``F_yield'(z)`` of the loading curve at depth ``z >= z_c`` [N/m]."""
        return self.mult * (const.k + 2.0 * const.k2 * z)

    def end_episode(self, z: float, const: _Constants) -> None:
        """The foot stopped advancing at depth ``z``: the crater bottom is there."""
        if const.c_comp > 0.0:
            f_c = self.yield_force(z, const)
            self.z_c, self.f_c, self.fs_c = z, f_c, const.static_strength(z)
            self.mult = 1.0 + const.c_comp * (1.0 - math.exp(-z / COMPACTION_LENGTH))
        self.z_max = z

    def unloading_slope(self, const: _Constants) -> float:
        """Slope ``r_unload F_yield'(z_max)`` of the elastic unloading line [N/m]."""
        return const.r_unload * self.yield_slope(self.z_max, const)

    def unloading_force(self, z: float, const: _Constants) -> float:
        """Force on the elastic unloading line at depth ``z`` (may be negative) [N]."""
        return self.yield_force(self.z_max, const) - self.unloading_slope(const) * (self.z_max - z)

    def release_depth(self, const: _Constants) -> float:
        """Depth at which the unloading line reaches zero force [m]."""
        return self.z_max - self.yield_force(self.z_max, const) / self.unloading_slope(const)


def _cone_volume(h: float, radius: float) -> float:
    """Volume of the jammed cone of height ``h`` under a foot of radius ``radius`` [m^3]."""
    return math.pi * h * (radius**2 - radius * h / CONE_TAN + h**2 / (3.0 * CONE_TAN**2))


def _ground(
    z: float, zdot: float, mode: str, bed: _Bed, const: _Constants
) -> tuple[float, float, float]:
    """Ground force, added mass and momentum flux (up positive) at depth ``z``.

    Parameters
    ----------
    z, zdot : float
        Foot depth [m] and its rate [m/s].
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
    force = bed.yield_force(z, const) + const.c_d * zdot**2 + const.b * zdot
    if const.cone_density == 0.0:
        return force, 0.0, 0.0
    h_full = const.radius * CONE_TAN
    h = CONE_MU * (z - bed.z_entry)
    if h >= h_full:  # cone fully formed: constant mass, no accretion
        return force, const.cone_density * _cone_volume(h_full, const.radius), 0.0
    added_mass = const.cone_density * _cone_volume(h, const.radius)
    # dV/dh = pi (R - h / tan(theta))^2, dh/dt = mu z', so dm_a/dt = rho_c pi q^2 mu z'
    dm_dt = const.cone_density * math.pi * (const.radius - h / CONE_TAN) ** 2 * CONE_MU * zdot
    return force, added_mass, dm_dt * zdot  # -(dm_a/dt) x_f' with x_f' = -z'


def _rhs_factory(
    const: _Constants, bed: _Bed, mode: str, omega: float, coef: float, t_start: float
) -> Callable[[float, np.ndarray], list[float]]:
    """Right-hand side for one segment and one bed regime.

    The state is ``(x_rod, x_foot, v_rod, v_foot)``; in the segment the actuator follows
    ``alpha(t) = coef cos(omega (t - t_start)) + offset``.
    """

    def rhs(t: float, y: np.ndarray) -> list[float]:
        x_r, x_f, v_r, v_f = y
        alpha_ddot = -coef * omega**2 * math.cos(omega * (t - t_start))
        f_spring = const.k_spring * (x_f - x_r) + const.c_spring * (v_f - v_r)
        f_ground, added_mass, flux = _ground(-x_f, -v_f, mode, bed, const)
        a_r = (f_spring - const.m_motor * alpha_ddot) / const.m_upper - G
        a_f = (f_ground + flux - f_spring) / (const.m_foot + added_mass) - G
        return [v_r, v_f, a_r, a_f]

    return rhs


def _event(
    fun: Callable[[float, np.ndarray], float], direction: float, terminal: bool
) -> Callable[[float, np.ndarray], float]:
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
    fun: Callable[[float, np.ndarray], float]
    peak: Callable[[float, np.ndarray], float]
    margin: float
    peak_margin: float


def _watches(
    mode: str, bed: _Bed, const: _Constants, rhs: Callable[[float, np.ndarray], list[float]]
) -> list[_Watch]:
    """Conditions that end the current bed regime (state ``(x_r, x_f, v_r, v_f)``)."""
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
    fun: Callable[[float, np.ndarray], float],
    margin: float,
    t: float,
    y: np.ndarray,
    just_fired: bool = False,
) -> Callable[[float, np.ndarray], float]:
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


def _first_crossing(fun: Callable[[float, np.ndarray], float], sol: OptimizeResult) -> float:
    """Time of the upward zero of ``fun`` before the end of a solve_ivp run.

    ``sol`` is a run with dense output that ended at a local maximum of ``fun`` where
    ``fun > 0``; the zero lies after the last step end where ``fun <= 0``.
    """
    times = sol.t
    j = len(times) - 2
    while j > 0 and fun(times[j], sol.sol(times[j])) > 0.0:
        j -= 1
    return brentq(lambda s: fun(s, sol.sol(s)), times[j], times[-1], xtol=1e-15)


def _switch(event: str, y: np.ndarray, bed: _Bed, const: _Constants) -> str:
    """New bed regime after a regime event at state ``y``; updates the bed memory."""
    if event == "stop":  # the crater bottom is where the foot stopped advancing
        bed.end_episode(-float(y[1]), const)
        return CONTACT if bed.yield_force(bed.z_max, const) > 0.0 else FREE
    if event == "release":
        return FREE
    if event == "touch" and bed.yield_force(bed.z_max, const) > 0.0:
        return CONTACT
    bed.z_entry = bed.z_max  # back at the crater bottom: a new added-mass episode
    return ADVANCING


def _constants(phi: float, params: Mapping[str, float], experiment: Experiment) -> _Constants:
    """Jump constants from phi, the force parameters and the experiment.

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
    )


def _start(program: CommandProgram, const: _Constants) -> tuple[np.ndarray, _Bed]:
    """Initial state and bed memory (physics-model.md section 4)."""
    if program.start_state == "settled":
        weight = (const.m_upper + const.m_foot) * G
        # F_static(z0) = weight, the positive root of k2 z^2 + k z - weight = 0
        if const.k2 > 0.0:
            z0 = (-const.k + math.sqrt(const.k**2 + 4.0 * const.k2 * weight)) / (2.0 * const.k2)
        else:
            z0 = weight / const.k
        x_f = -z0
        x_r = x_f - const.m_upper * G / const.k_spring  # spring carries the upper mass
        bed = _Bed(z_max=z0, z_entry=z0)
        bed.end_episode(z0, const)  # placing the robot is an intrusion to z0 that has ended
        return np.array([x_r, x_f, 0.0, 0.0]), bed
    return np.zeros(4), _Bed(z_max=0.0, z_entry=0.0)


def simulate_height_scipy(
    command: str,
    phi: float,
    params: Mapping[str, float],
    experiment: Experiment | None = None,
    rtol: float = 1e-9,
    atol: float | Sequence[float] = 1e-12,
    *,
    method: Literal["DOP853", "RK45"] = "DOP853",
    max_step: float = 0.01,
    window_after: float = 0.6,
) -> float:
    """Jump height of one jump, integrated with ``scipy.integrate.solve_ivp``.

    Parameters
    ----------
    command : str
        ``single``, ``preload``, ``stutter``, ``delayed_stutter`` or
        ``delayed_stutter_preload``.
    phi : float
        Volume fraction of the bed [-].
    params : mapping of str to float
        Force-term parameters: ``k`` [N/m] (required), ``c_d`` [kg/m], ``kappa`` [-],
        ``r_unload`` [-] (default 20), ``k2`` [N/m^2], ``b`` [N s/m], ``c_comp`` [-];
        absent terms are off.
    experiment : Experiment, optional
        Robot and command settings (model defaults if omitted).
    rtol : float
        Relative tolerance of solve_ivp.
    atol : float or sequence of 4 floats
        Absolute tolerance of solve_ivp, for all of ``(x_rod, x_foot, v_rod, v_foot)``
        ([m], [m/s]) or per component.
    method : str
        solve_ivp method (``"DOP853"`` or ``"RK45"``).
    max_step : float
        Largest step [s]; keeps event detection by sign change reliable.
    window_after : float
        The height window closes this long after the command ends [s].

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
        1``; the compiled simulator returns ``Status.BAD_INPUT`` for such a jump).
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
    exp = experiment if experiment is not None else Experiment()
    program = build_command(command, exp.command)
    const = _constants(float(phi), params, exp)
    y, bed = _start(program, const)
    omega = program.omega

    # initial regime: the foot advances if the net force pushes it into the bed
    mode = ADVANCING
    a_foot = _rhs_factory(const, bed, mode, omega, program.segments[0].coef, 0.0)(0.0, y)[3]
    if a_foot >= 0.0:
        mode = CONTACT if bed.yield_force(bed.z_max, const) > 0.0 else FREE

    # pieces of constant waveform: the segments, then the hold after the command
    bounds = program.boundaries
    pieces = [(bounds[i], bounds[i + 1], s.coef) for i, s in enumerate(program.segments)]
    pieces.append((program.t_end, program.t_end + window_after, 0.0))
    apex = _event(lambda t, y: y[3], -1.0, False)  # x_f' crosses zero downward

    def touchdown(t: float, y: np.ndarray) -> float:  # x_f crosses zero downward
        return -y[1]

    def flight(t: float, y: np.ndarray) -> float:  # x_f reaches H_FLIGHT upward
        return y[1] - H_FLIGHT

    height = -math.inf
    flown = False  # a flight after the command has ended: only then a touchdown ends it
    t = 0.0
    last_peak = -1  # index of the watch whose peak stopped the previous run, if any
    for index, (t_start, t_stop, coef) in enumerate(pieces):
        in_window = index >= program.pushoff_index
        after_command = index == len(pieces) - 1
        if in_window:
            height = max(height, y[1])
        if after_command and y[1] >= H_FLIGHT:
            flown = True
        while t < t_stop:
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
            sol = solve_ivp(
                rhs,
                (t, t_stop),
                y,
                method=method,
                rtol=rtol,
                atol=atol,
                max_step=max_step,
                events=events,
                dense_output=True,
            )
            if sol.status < 0:
                raise RuntimeError(f"solve_ivp failed at t = {t:.6f} s: {sol.message}")
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
                    # go back to the first crossing, using the dense output
                    t_run = _first_crossing(crossing, sol)
                    y_run = sol.sol(t_run)
                    kind = "crossing"
            if in_window:
                apex_states = sol.y_events[labels.index(("apex", -1))]
                apex_times = sol.t_events[labels.index(("apex", -1))]
                height = max(
                    height,
                    y_run[1],
                    *(ye[1] for te, ye in zip(apex_times, apex_states, strict=True) if te <= t_run),
                )
            t, y = t_run, y_run
            last_peak = which if kind == "peak" else -1
            if kind == "end":
                t = t_stop
            elif kind == "touchdown":
                return float(1e3 * height)
            elif kind == "flight":
                flown = True
            elif kind == "crossing":
                mode = _switch(watches[which].name, y, bed, const)
            # kind == "peak" without a crossing: a local maximum short of the regime's end;
            # the run simply restarts from there in the same regime
    return float(1e3 * height)
