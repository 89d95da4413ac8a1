"""Compiled integrator of the jumping robot on a granular bed with memory (private).

An event-driven, adaptive Dormand-Prince 5(4) integrator (Hairer, Norsett & Wanner,
*Solving ODEs I*, II.5) compiled with numba. The right-hand side is smooth between
events, so every non-smooth point of physics-model.md is an event the integrator stops on:

* actuator segment boundaries (``alpha''`` jumps): steps are clipped to land on them;
* bed regime changes: advancing -> contact (the foot stops advancing, ``z' = 0``),
  contact -> advancing (the foot reaches ``z_max``), contact -> free (the unloading line
  reaches zero force), free -> contact;
* the jump apex (``x_f' = 0`` inside the height window, no restart) and touchdown (the
  first fall through the surface after a flight of ``H_FLIGHT`` once the command has ended).

Where the foot is not advancing (elastic contact on the unloading line, or no ground force)
the robot is a linear 2-DOF system with constant or sinusoidal forcing; there the steps
are its exact closed form (modal decomposition per regime, ``_lin_prepare``), unless
``OPT_CLOSED`` is 0 or the regime has no closed form. Such a step is as long as bounds of
the closed form prove free of events (``_lin_safe``: to the end of the actuator segment or
of the height window if possible; ``max_step`` applies only when a trajectory is
recorded); where no long step can be proved, steps of a fixed fraction of the fastest
period bracket the events as Dormand-Prince steps do. The bounds are per component of the
closed form and joint (the foot's own height, velocity and a bound on its acceleration),
whichever is tighter. The modal decomposition is made once per regime and actuator segment
(the last contact regime and the last free regime are kept for the robot's return, and a
new contact regime's eigenvalues are found by Newton from the last one's); from step to
step the modal amplitudes are carried, and the factors ``exp(lam h)`` of the standard step
are stored with the regime. Once the foot flies freely after the command and cannot rise
above the height already reached (the centre of mass's apex plus the range of the damped
oscillation about it), the height is final and the jump ends there (a recorded trajectory
goes on to the touchdown).

Events are located on the step's cubic Hermite interpolant and then refined with real
Runge-Kutta steps from the step start (safeguarded Newton in a bracket, on the local
quadratic model of the event function; a velocity event's second derivative, the foot's
jerk, is a difference of the right-hand side along the flow), so the state after an event
is a genuine 5th-order solution. The integrator never raises: each jump returns a status
code (``STATUS_*``), and its height is NaN unless the status is ``STATUS_OK``.

Input layout: one float row per jump (``ROW_*`` indices: robot, phi, then the force-term
parameters in ``forces.PARAMETER_NAMES`` order); a command table per command (see
``commands.CommandProgram.as_table``); an options vector (``OPT_*``).

Length: about 1,840 lines of compiled code that must live in one module for numba to
inline across it: the integrator, its events, the closed-form regimes, dense output for
frames and the intrusion force.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit, prange

from .forces import PARAMETER_NAMES

# ----------------------------------------------------------------------------------------
# layouts
ROBOT_FIELDS = (
    "m_motor",
    "m_rod",
    "m_foot",
    "k_spring",
    "c_spring",
    "foot_radius",
    "grain_density",
)
ROW_M_MOTOR, ROW_M_ROD, ROW_M_FOOT, ROW_K_SPRING, ROW_C_SPRING, ROW_RADIUS, ROW_RHO = range(7)
ROW_PHI = 7
ROW_FORCE0 = 8
ROW_SIZE = ROW_FORCE0 + len(PARAMETER_NAMES)
ROW_FIELDS = (*ROBOT_FIELDS, "phi", *PARAMETER_NAMES)

_P_K = ROW_FORCE0 + PARAMETER_NAMES.index("k")
_P_CD = ROW_FORCE0 + PARAMETER_NAMES.index("c_d")
_P_KAPPA = ROW_FORCE0 + PARAMETER_NAMES.index("kappa")
_P_R = ROW_FORCE0 + PARAMETER_NAMES.index("r_unload")
_P_K2 = ROW_FORCE0 + PARAMETER_NAMES.index("k2")
_P_B = ROW_FORCE0 + PARAMETER_NAMES.index("b")
_P_COMP = ROW_FORCE0 + PARAMETER_NAMES.index("c_comp")

OPT_RTOL, OPT_ATOL_X, OPT_ATOL_V, OPT_HMAX, OPT_MAX_STEPS, OPT_T_AFTER, OPT_CLOSED = range(7)
OPT_SIZE = 7

STATUS_OK = 0
STATUS_NONFINITE = 1
STATUS_STEP_LIMIT = 2
STATUS_STEP_UNDERFLOW = 3
STATUS_BAD_INPUT = 4
STATUS_NAMES = ("ok", "failed:non-finite", "failed:step-limit", "failed:step-underflow",
                "failed:bad-input")  # fmt: skip

MODE_ADVANCING = 0
MODE_CONTACT = 1  # not advancing, on the unloading line (F_g > 0)
MODE_FREE = 2  # not advancing, F_g = 0
MODE_NAMES = ("advancing", "contact", "free")

START_TOUCHING = 0
START_SETTLED = 1

# trajectory record columns; ``unloading_slope`` [N/m] is the slope r_unload F_yield'(z_max)
# of the unloading line from the recorded crater depth ``z_max`` (while advancing, the line
# the bed would follow if the foot stopped there, before any compaction re-anchoring), so
# that the bed's stored elastic energy is F^2 / (2 unloading_slope)
REC_FIELDS = ("t", "x_rod", "x_foot", "v_rod", "v_foot", "z_max", "ground_force",
              "added_mass", "mode", "alpha", "unloading_slope")  # fmt: skip
REC_SIZE = len(REC_FIELDS)

G = 9.81
CONE_THETA = math.pi / 3.0  # 60 deg
CONE_TAN = math.tan(CONE_THETA)
CONE_MU = 2.0
_CONE_ITAN = 1.0 / CONE_TAN
_CONE_ITAN2_3 = 1.0 / (3.0 * CONE_TAN**2)

# context vector (per jump, derived from the row)
_C_M, _C_MMOT, _C_MF, _C_KS, _C_CS = 0, 1, 2, 3, 4
_C_K, _C_CD, _C_AM, _C_R, _C_K2, _C_B = 5, 6, 7, 8, 9, 10
_C_RAD, _C_HFULL, _C_OMEGA, _C_SEGCOEF, _C_SEGT0, _C_SEGOFF = 11, 12, 13, 14, 15, 16
_C_ZMAX, _C_ZENTRY, _C_ZFREE, _C_FSMAX = 17, 18, 19, 20
_C_COMP, _C_ZC, _C_FC, _C_MULT, _C_FSC, _C_SUNL = 21, 22, 23, 24, 25, 26
# closed form of the linear regimes (see _lin_prepare): flag, fastest frequency, number of
# oscillatory mode pairs, centre-of-mass forcing, then per mode pair _MODAL_SIZE numbers
_C_LIN, _C_LINW, _C_NMODE, _C_COMK = 27, 28, 29, 30
_C_MODAL = 31
_MODAL_SIZE = 14
# per regime: equilibrium x_f in contact, actuator particular motion (cos, sin coefficients,
# amplitude) of x_f, |lam| of each mode
_C_LINXEQ = _C_MODAL + 2 * _MODAL_SIZE
_C_LINFC, _C_LINFS, _C_LINFA, _C_LINL1, _C_LINL2 = range(_C_LINXEQ + 1, _C_LINXEQ + 6)
# the regime's standard step h_fix = min(theta / fastest frequency, max_step) and
# exp(lam h_fix) of each mode (complex)
_C_LINH = _C_LINXEQ + 6
_C_LINE = _C_LINH + 1
_C_LINEND = _C_LINE + 4
_LIN_BLOCK = _C_LINEND - _C_LIN
# the last contact regime's closed form (the block _C_LIN.._C_LINEND), keyed by unloading
# slope, constant force of the unloading line and actuator coefficient (the robot often
# returns to the same contact after a bounce), then the last free regime's, keyed by the
# actuator coefficient (it does not depend on the bed)
_C_CKEY = _C_LINEND
_C_CBLOCK = _C_CKEY + 4
_C_FKEY = _C_CBLOCK + _LIN_BLOCK
_C_FBLOCK = _C_FKEY + 2
# the last contact regime's eigenvalues and unloading slope: Newton's start for the next
# contact (after an advancing episode the slope has changed a little)
_C_ROOTS = _C_FBLOCK + _LIN_BLOCK
# 1 / (m_motor + m_rod) and 1 / m_foot
_C_MINV = _C_ROOTS + 6
_C_MFINV = _C_MINV + 1
_C_SIZE = _C_MFINV + 1

#: Grain-scale compaction length l_c [m] of the ``compaction`` term: the depth of intrusion
#: over which a loose bed approaches its compacted state (about one poppy-seed diameter;
#: docs/physics-model.md section 8).
COMPACTION_LENGTH = 1e-3

#: Step of the closed form in the linear regimes where no longer step is proved free of
#: events, in radians of the fastest mode (or of the actuator) at rtol = 1e-5: the states
#: are exact, the steps only bracket the events.
LIN_THETA = 0.8
#: Bisections of the longest event-free step between that step and the segment's end.
LIN_BISECT = 5

#: Tolerance of event location relative to the absolute integration tolerances.
EVENT_TOL = 1e-4

#: Flight that makes a touchdown end the jump [m] (physics-model.md section 5): after the
#: command has ended, the foot must have been at least this high above the surface (about a
#: grain) before falling through it; a graze of the surface by micrometres does not end it.
H_FLIGHT = 1e-3

# events (each is g(y) crossing from <= 0 to > 0)
_EV_NONE = -1
_EV_ADV_EXIT = 0  # g = v_f                    (z' from >= 0 to < 0)
_EV_REENTER = 1  # g = z - z_max
_EV_RELEASE = 2  # g = -F_g on the unloading line
_EV_TOUCH = 3  # g = z - z_free
_EV_APEX = 4  # g = -v_f

# Dormand-Prince 5(4) tableau
_A21 = 1.0 / 5.0
_A31, _A32 = 3.0 / 40.0, 9.0 / 40.0
_A41, _A42, _A43 = 44.0 / 45.0, -56.0 / 15.0, 32.0 / 9.0
_A51, _A52, _A53, _A54 = 19372.0 / 6561.0, -25360.0 / 2187.0, 64448.0 / 6561.0, -212.0 / 729.0
_A61, _A62, _A63 = 9017.0 / 3168.0, -355.0 / 33.0, 46732.0 / 5247.0
_A64, _A65 = 49.0 / 176.0, -5103.0 / 18656.0
_B1, _B3, _B4, _B5, _B6 = 35.0 / 384.0, 500.0 / 1113.0, 125.0 / 192.0, -2187.0 / 6784.0, 11.0 / 84.0
_E1, _E3, _E4 = 71.0 / 57600.0, -71.0 / 16695.0, 71.0 / 1920.0
_E5, _E6, _E7 = -17253.0 / 339200.0, 22.0 / 525.0, -1.0 / 40.0
_C2, _C3, _C4, _C5 = 0.2, 0.3, 0.8, 8.0 / 9.0


# ----------------------------------------------------------------------------------------
# GROUND MODEL: the force-term library (physics-model.md section 3). New terms go here.
@njit(cache=True)
def static_strength(z, k, k2):
    """F_static(z) = k z + k2 z^2 [N]: the yield force of the fresh bed at depth z [m]."""
    return k * z + k2 * z * z


@njit(cache=True)
def static_slope(z, k, k2):
    """F_static'(z) = k + 2 k2 z [N/m]: slope of the fresh bed's yield force at depth z [m]."""
    return k + 2.0 * k2 * z


@njit(cache=True)
def compaction_multiplier(z_c, c_comp):
    """Loading-stiffness multiplier ``1 + c_comp (1 - exp(-z_c / l_c))`` [-].

    ``z_c`` [m] is the depth the bed has been intruded to when an advancing episode ends;
    the bed below it has compacted by the fraction ``1 - exp(-z_c / l_c)`` of its full
    compaction ``c_comp`` (``l_c = COMPACTION_LENGTH``).
    """
    return 1.0 + c_comp * -math.expm1(-z_c / COMPACTION_LENGTH)


@njit(cache=True)
def _yield_force(z, c):
    """Yield force F_yield [N] of the bed at depth z >= z_c [m] (below the last anchor).

    ``compaction``: when an advancing episode ends at depth ``z_c`` the loading curve below
    is re-anchored there, ``F_yield(z) = F_c + m (F_static(z) - F_static(z_c))`` with
    ``F_c = F_yield(z_c)`` and ``m = compaction_multiplier(z_c)`` (``m = 1`` before any
    episode has ended, or without the term). The curve is continuous, and since ``m`` never
    decreases its slope only steps up: it stays convex. Only depths at or below the crater
    bottom (``z >= z_c``) can still yield, so only they are asked for.
    """
    base = static_strength(z, c[_C_K], c[_C_K2])
    mult = c[_C_MULT]
    if mult != 1.0:
        return c[_C_FC] + mult * (base - c[_C_FSC])
    return base


@njit(cache=True)
def _yield_slope(z, c):
    """F_yield'(z) [N/m]: slope of the loading curve at depth z >= z_c [m]."""
    return c[_C_MULT] * static_slope(z, c[_C_K], c[_C_K2])


@njit(cache=True)
def _end_of_episode(z, c):
    """Bed memory when an advancing episode ends at depth z [m]: the bed below compacts."""
    if c[_C_COMP] > 0.0:
        c[_C_FC] = _yield_force(z, c)
        c[_C_FSC] = static_strength(z, c[_C_K], c[_C_K2])
        c[_C_ZC] = z
        c[_C_MULT] = compaction_multiplier(z, c[_C_COMP])


@njit(cache=True)
def cone_volume(h, radius):
    """Volume [m^3] of the jammed cone of height h [m] under a foot of given radius."""
    return math.pi * h * (radius * radius - h * (radius * _CONE_ITAN - h * _CONE_ITAN2_3))


@njit(cache=True, inline="always")
def _ground(z, zd, mode, c):
    """Ground force F_g [N], added mass m_a [kg] and momentum flux [N] (up positive)."""
    if mode == MODE_ADVANCING:
        fg = _yield_force(z, c) + c[_C_CD] * zd * zd + c[_C_B] * zd
        am = c[_C_AM]
        if am > 0.0:
            h = CONE_MU * (z - c[_C_ZENTRY])
            radius = c[_C_RAD]
            if h < c[_C_HFULL]:
                q = radius - h * _CONE_ITAN
                return fg, am * cone_volume(h, radius), am * CONE_MU * math.pi * q * q * zd * zd
            return fg, am * cone_volume(c[_C_HFULL], radius), 0.0
        return fg, 0.0, 0.0
    if mode == MODE_CONTACT:
        return c[_C_FSMAX] - c[_C_SUNL] * (c[_C_ZMAX] - z), 0.0, 0.0
    return 0.0, 0.0, 0.0


# ----------------------------------------------------------------------------------------
# equations of motion (physics-model.md section 2); state (x_rod, x_foot, v_rod, v_foot)
@njit(cache=True, inline="always")
def _accel(t, xr, xf, vr, vf, mode, c):
    """Accelerations (rod, foot) [m/s^2]."""
    coef = c[_C_SEGCOEF]
    alpha_dd = 0.0
    if coef != 0.0:  # the actuator is idle (held) for most of a jump
        w = c[_C_OMEGA]
        alpha_dd = -coef * w * w * math.cos(w * (t - c[_C_SEGT0]))
    return _accel_a(alpha_dd, xr, xf, vr, vf, mode, c)


@njit(cache=True, inline="always")
def _accel_a(alpha_dd, xr, xf, vr, vf, mode, c):
    """Accelerations (rod, foot) [m/s^2] with the actuator's acceleration ``alpha_dd``."""
    fs = c[_C_KS] * (xf - xr) + c[_C_CS] * (vf - vr)
    fg, ma, flux = _ground(-xf, -vf, mode, c)
    minv = c[_C_MFINV] if ma == 0.0 else 1.0 / (c[_C_MF] + ma)
    return (fs - c[_C_MMOT] * alpha_dd) * c[_C_MINV] - G, (fg + flux - fs) * minv - G


@njit(cache=True)
def _cos_shift(c0, s0, phi):
    """cos(theta + phi) from c0 = cos(theta), s0 = sin(theta), for |phi| <= 1.

    Taylor series of cos(phi) and sin(phi) to phi^19 (remainder below 1e-18).
    """
    u = phi * phi
    cp = 1.0 + u * (-1.0 / 2 + u * (1.0 / 24 + u * (-1.0 / 720 + u * (1.0 / 40320
         + u * (-1.0 / 3628800 + u * (1.0 / 479001600 + u * (-1.0 / 87178291200
         + u * (1.0 / 20922789888000 + u * (-1.0 / 6402373705728000)))))))))  # fmt: skip
    sp = phi * (1.0 + u * (-1.0 / 6 + u * (1.0 / 120 + u * (-1.0 / 5040 + u * (1.0 / 362880
         + u * (-1.0 / 39916800 + u * (1.0 / 6227020800 + u * (-1.0 / 1307674368000
         + u * (1.0 / 355687428096000 + u * (-1.0 / 121645100408832000))))))))))  # fmt: skip
    return c0 * cp - s0 * sp


@njit(cache=True)
def _dopri_step(t, y, f, h, mode, c, tol):
    """One Dormand-Prince 5(4) step of size ``h`` from state ``y`` with ``f = dy/dt``.

    ``y = (x_rod, x_foot, v_rod, v_foot)``, ``f = (a_rod, a_foot)`` and ``tol = (rtol,
    atol_x, atol_v)``. Returns ``(y_new, f_new, err)`` where ``f_new`` is f at the new state
    (first-same-as-last) and ``err`` the RMS error norm scaled by the tolerances.
    """
    x1, x2, v1, v2 = y
    a1, a2 = f
    # the actuator's acceleration at the stages (stage 6 and the new state share t + h): the
    # cosine of its phase at t shifted by short series (exact to rounding)
    ad2 = ad3 = ad4 = ad5 = ad6 = 0.0
    coef = c[_C_SEGCOEF]
    if coef != 0.0:
        w = c[_C_OMEGA]
        amp = -coef * w * w
        th = w * (t - c[_C_SEGT0])
        wh = w * h
        if abs(wh) <= 1.0:
            c0, s0 = math.cos(th), math.sin(th)
            ad2 = amp * _cos_shift(c0, s0, _C2 * wh)
            ad3 = amp * _cos_shift(c0, s0, _C3 * wh)
            ad4 = amp * _cos_shift(c0, s0, _C4 * wh)
            ad5 = amp * _cos_shift(c0, s0, _C5 * wh)
            ad6 = amp * _cos_shift(c0, s0, wh)
        else:
            ad2 = amp * math.cos(th + _C2 * wh)
            ad3 = amp * math.cos(th + _C3 * wh)
            ad4 = amp * math.cos(th + _C4 * wh)
            ad5 = amp * math.cos(th + _C5 * wh)
            ad6 = amp * math.cos(th + wh)
    # stage 2
    p1 = x1 + h * _A21 * v1
    p2 = x2 + h * _A21 * v2
    q1 = v1 + h * _A21 * a1
    q2 = v2 + h * _A21 * a2
    b1, b2 = _accel_a(ad2, p1, p2, q1, q2, mode, c)
    u1, u2 = q1, q2
    # stage 3
    p1 = x1 + h * (_A31 * v1 + _A32 * u1)
    p2 = x2 + h * (_A31 * v2 + _A32 * u2)
    q1 = v1 + h * (_A31 * a1 + _A32 * b1)
    q2 = v2 + h * (_A31 * a2 + _A32 * b2)
    c1, c2 = _accel_a(ad3, p1, p2, q1, q2, mode, c)
    w1, w2 = q1, q2
    # stage 4
    p1 = x1 + h * (_A41 * v1 + _A42 * u1 + _A43 * w1)
    p2 = x2 + h * (_A41 * v2 + _A42 * u2 + _A43 * w2)
    q1 = v1 + h * (_A41 * a1 + _A42 * b1 + _A43 * c1)
    q2 = v2 + h * (_A41 * a2 + _A42 * b2 + _A43 * c2)
    d1, d2 = _accel_a(ad4, p1, p2, q1, q2, mode, c)
    r1, r2 = q1, q2
    # stage 5
    p1 = x1 + h * (_A51 * v1 + _A52 * u1 + _A53 * w1 + _A54 * r1)
    p2 = x2 + h * (_A51 * v2 + _A52 * u2 + _A53 * w2 + _A54 * r2)
    q1 = v1 + h * (_A51 * a1 + _A52 * b1 + _A53 * c1 + _A54 * d1)
    q2 = v2 + h * (_A51 * a2 + _A52 * b2 + _A53 * c2 + _A54 * d2)
    e1, e2 = _accel_a(ad5, p1, p2, q1, q2, mode, c)
    s1, s2 = q1, q2
    # stage 6
    p1 = x1 + h * (_A61 * v1 + _A62 * u1 + _A63 * w1 + _A64 * r1 + _A65 * s1)
    p2 = x2 + h * (_A61 * v2 + _A62 * u2 + _A63 * w2 + _A64 * r2 + _A65 * s2)
    q1 = v1 + h * (_A61 * a1 + _A62 * b1 + _A63 * c1 + _A64 * d1 + _A65 * e1)
    q2 = v2 + h * (_A61 * a2 + _A62 * b2 + _A63 * c2 + _A64 * d2 + _A65 * e2)
    g1, g2 = _accel_a(ad6, p1, p2, q1, q2, mode, c)
    o1, o2 = q1, q2
    # 5th-order solution and FSAL stage
    nx1 = x1 + h * (_B1 * v1 + _B3 * w1 + _B4 * r1 + _B5 * s1 + _B6 * o1)
    nx2 = x2 + h * (_B1 * v2 + _B3 * w2 + _B4 * r2 + _B5 * s2 + _B6 * o2)
    nv1 = v1 + h * (_B1 * a1 + _B3 * c1 + _B4 * d1 + _B5 * e1 + _B6 * g1)
    nv2 = v2 + h * (_B1 * a2 + _B3 * c2 + _B4 * d2 + _B5 * e2 + _B6 * g2)
    n1, n2 = _accel_a(ad6, nx1, nx2, nv1, nv2, mode, c)
    # embedded error estimate
    ex1 = h * (_E1 * v1 + _E3 * w1 + _E4 * r1 + _E5 * s1 + _E6 * o1 + _E7 * nv1)
    ex2 = h * (_E1 * v2 + _E3 * w2 + _E4 * r2 + _E5 * s2 + _E6 * o2 + _E7 * nv2)
    ev1 = h * (_E1 * a1 + _E3 * c1 + _E4 * d1 + _E5 * e1 + _E6 * g1 + _E7 * n1)
    ev2 = h * (_E1 * a2 + _E3 * c2 + _E4 * d2 + _E5 * e2 + _E6 * g2 + _E7 * n2)
    rtol, atol_x, atol_v = tol
    acc = (ex1 / (atol_x + rtol * max(abs(x1), abs(nx1)))) ** 2
    acc += (ex2 / (atol_x + rtol * max(abs(x2), abs(nx2)))) ** 2
    acc += (ev1 / (atol_v + rtol * max(abs(v1), abs(nv1)))) ** 2
    acc += (ev2 / (atol_v + rtol * max(abs(v2), abs(nv2)))) ** 2
    return (nx1, nx2, nv1, nv2), (n1, n2), math.sqrt(0.25 * acc)


# ----------------------------------------------------------------------------------------
# closed form of the linear regimes. Not advancing (contact on the unloading line, or free)
# the robot is a linear 2-DOF system, mass diag(M, m_f), damping c_s [[1, -1], [-1, 1]],
# stiffness k_s [[1, -1], [-1, 1]] + diag(0, s_b) (s_b = unloading slope in contact, 0
# free), forced by gravity, the constant part of the unloading line and the actuator's
# m_motor coef w^2 cos(w (t - t0)) on the rod. Its motion is a sum of complex modes
# (eigenvalue lam, shape phi, left eigenvector [phi^T (lam M + C), phi^T M]) plus, when
# free, the centre of mass in free fall; the steps are exact and only resolve the events.
@njit(cache=True)
def _abs2(z):
    """|z|^2 of a complex number."""
    return z.real * z.real + z.imag * z.imag


@njit(cache=True)
def _inv(z):
    """1 / z of a complex number (nonzero; no overflow concerns here)."""
    r = 1.0 / _abs2(z)
    return complex(z.real * r, -z.imag * r)


@njit(cache=True)
def _exp_lam(lam, tau):
    """exp(lam tau) of a complex ``lam`` and a real ``tau``."""
    r = math.exp(lam.real * tau)
    th = lam.imag * tau
    return complex(r * math.cos(th), r * math.sin(th))


@njit(cache=True)
def _newton_root(a4, a3, a2, a1, a0, s):
    """Root of the quartic sum a_k s^k by Newton from ``s``; (root, converged)."""
    x, y = s.real, s.imag
    for _ in range(60):
        # Horner in real arithmetic: p(s) and p'(s)
        pr, pi = a4 * x + a3, a4 * y
        dr, di = 4.0 * a4 * x + 3.0 * a3, 4.0 * a4 * y
        pr, pi = pr * x - pi * y + a2, pr * y + pi * x
        dr, di = dr * x - di * y + 2.0 * a2, dr * y + di * x
        pr, pi = pr * x - pi * y + a1, pr * y + pi * x
        dr, di = dr * x - di * y + a1, dr * y + di * x
        pr, pi = pr * x - pi * y + a0, pr * y + pi * x
        d2 = dr * dr + di * di
        if d2 == 0.0:
            return complex(x, y), False
        # ds = p / p'
        dsr = (pr * dr + pi * di) / d2
        dsi = (pi * dr - pr * di) / d2
        x -= dsr
        y -= dsi
        # quadratic convergence: a step of 1e-10 |s| leaves an error of about 1e-20 |s|
        if dsr * dsr + dsi * dsi <= 1e-20 * (x * x + y * y):
            break
    s = complex(x, y)
    r = math.sqrt(_abs2(s))
    scale = (((a4 * r + abs(a3)) * r + a2) * r + a1) * r + a0
    p = (((a4 * s + a3) * s + a2) * s + a1) * s + a0
    return s, _abs2(p) <= (1e-11 * scale) ** 2 and s.imag > 0.0


@njit(cache=True)
def _damped_guess(om2, mu, mf, ks, cs):
    """Eigenvalue estimate of a contact mode of undamped squared frequency ``om2``."""
    den = ks - om2 * mu
    if den == 0.0:
        return complex(0.0, math.sqrt(om2))
    dr = ks / den - 1.0  # rod minus foot displacement of the mode shape (foot 1)
    sig = cs * dr * dr / (2.0 * (mu * (dr + 1.0) ** 2 + mf))
    return complex(-sig, math.sqrt(max(om2 - sig * sig, 0.25 * om2)))


@njit(cache=True)
def _copy_block(c, src, dst):
    """Copy the closed-form block of ``_LIN_BLOCK`` numbers from ``c[src:]`` to ``c[dst:]``."""
    for i in range(_LIN_BLOCK):
        c[dst + i] = c[src + i]


@njit(cache=True)
def _lin_prepare(mode, c, theta, hmax):
    """Modal data of the current regime and actuator segment; ``c[_C_LIN] = 0`` if none.

    No closed form (numerical steps instead) while advancing, for an overdamped mode or
    nearly coincident modes, or near an undamped resonance with the actuator. ``theta``
    [rad] and ``hmax`` [s] set the regime's standard step ``h_fix = min(theta / fastest
    frequency, hmax)``, whose modal factors ``exp(lam h_fix)`` are stored with the data.
    The last contact regime and the last free regime are kept: a robot bouncing on the
    bed returns to them.
    """
    c[_C_LIN] = 0.0
    if mode == MODE_ADVANCING:
        return
    mu, mf, ks, cs = c[_C_M], c[_C_MF], c[_C_KS], c[_C_CS]
    w, coef = c[_C_OMEGA], c[_C_SEGCOEF]
    fmot = c[_C_MMOT] * coef * w * w  # force amplitude of the actuator on the rod
    lam1 = 0j
    lam2 = 0j
    if mode == MODE_FREE:
        if c[_C_FKEY + 1] != 0.0 and c[_C_FKEY] == coef:  # the last free regime's
            _copy_block(c, _C_FBLOCK, _C_LIN)
            return
        nm = 1
        fc = 0.0
        mr = mu * mf / (mu + mf)
        disc = cs * cs - 4.0 * mr * ks
        if disc >= 0.0:
            return
        lam1 = complex(-cs / (2.0 * mr), math.sqrt(-disc) / (2.0 * mr))
        c[_C_COMK] = c[_C_MMOT] * coef / (mu + mf)
    else:
        nm = 2
        sb = c[_C_SUNL]
        fc = c[_C_FSMAX] - sb * c[_C_ZMAX]
        key = c[_C_CKEY] == sb and c[_C_CKEY + 1] == fc and c[_C_CKEY + 2] == coef
        if key and c[_C_CKEY + 3] != 0.0:  # the last contact's closed form
            _copy_block(c, _C_CBLOCK, _C_LIN)
            return
        a4, a3, a2, a1, a0 = mu * mf, cs * (mu + mf), mu * (ks + sb) + mf * ks, cs * sb, ks * sb
        disc = a2 * a2 - 4.0 * a4 * a0
        if disc <= 0.0 or a0 <= 0.0:
            return
        ok1 = ok2 = False
        sb0 = c[_C_ROOTS]
        if c[_C_ROOTS + 1] != 0.0 and abs(sb - sb0) <= 0.1 * sb0:
            # Newton from the last contact's eigenvalues (a nearby unloading slope)
            lam1, ok1 = _newton_root(a4, a3, a2, a1, a0, complex(c[_C_ROOTS + 2], c[_C_ROOTS + 3]))
            lam2, ok2 = _newton_root(a4, a3, a2, a1, a0, complex(c[_C_ROOTS + 4], c[_C_ROOTS + 5]))
        if not (ok1 and ok2) or _abs2(lam1 - lam2) <= 1e-12 * _abs2(lam2):
            om_hi = (a2 + math.sqrt(disc)) / (2.0 * a4)  # undamped squared frequencies
            om_lo = a0 / (a4 * om_hi)
            # Newton from the undamped modes with their first-order damping (the damping
            # matrix projected on the undamped mode shape)
            lam1, ok1 = _newton_root(a4, a3, a2, a1, a0, _damped_guess(om_lo, mu, mf, ks, cs))
            lam2, ok2 = _newton_root(a4, a3, a2, a1, a0, _damped_guess(om_hi, mu, mf, ks, cs))
            if not (ok1 and ok2) or _abs2(lam1 - lam2) <= 1e-12 * _abs2(lam2):
                return
        c[_C_ROOTS] = sb
        c[_C_ROOTS + 1] = 1.0
        c[_C_ROOTS + 2] = lam1.real
        c[_C_ROOTS + 3] = lam1.imag
        c[_C_ROOTS + 4] = lam2.real
        c[_C_ROOTS + 5] = lam2.imag
    wmax = w if coef != 0.0 else 0.0
    xeq = fcs = fsn = 0.0
    for j in range(nm):
        lam = lam1 if j == 0 else lam2
        pr = cs * lam + ks
        pf = mu * lam * lam + cs * lam + ks
        d = pr - pf
        n = 2.0 * lam * (mu * pr * pr + mf * pf * pf) + cs * d * d
        if n == 0.0:
            return
        ninv = _inv(n)
        # free: gravity does not excite the oscillation (phi^T M (1, 1) = 0)
        beta = 0j if mode == MODE_FREE else (pr * (-mu * G) + pf * (fc - mf * G)) * ninv
        pc = 0j
        ps = 0j
        if coef != 0.0:
            den = lam * lam + w * w
            if _abs2(den) < 1e-16 * w**4:
                return
            delta = pr * fmot * ninv * _inv(den)
            pc = -delta * lam
            ps = delta * w
        b = _C_MODAL + j * _MODAL_SIZE
        p0 = -beta * _inv(lam)
        for i, v in enumerate((lam, pr, pf, ninv, p0, pc, ps)):
            c[b + 2 * i] = v.real
            c[b + 2 * i + 1] = v.imag
        lam_abs = math.sqrt(_abs2(lam))
        wmax = max(wmax, lam_abs)
        c[_C_LINL1 + j] = lam_abs
        xeq += 2.0 * (pf * p0).real
        fcs += 2.0 * (pf * pc).real
        fsn += 2.0 * (pf * ps).real
    h_fix = min(theta / wmax, hmax)
    for j in range(nm):
        b = _C_MODAL + j * _MODAL_SIZE
        e = _exp_lam(complex(c[b], c[b + 1]), h_fix)
        c[_C_LINE + 2 * j] = e.real
        c[_C_LINE + 2 * j + 1] = e.imag
    c[_C_LINH] = h_fix
    c[_C_NMODE] = nm
    c[_C_LINW] = wmax
    c[_C_LINXEQ] = xeq
    c[_C_LINFC] = fcs
    c[_C_LINFS] = fsn
    c[_C_LINFA] = (1.0 + 1e-12) * math.sqrt(fcs * fcs + fsn * fsn)
    c[_C_LIN] = 1.0
    if mode == MODE_CONTACT:
        c[_C_CKEY] = c[_C_SUNL]
        c[_C_CKEY + 1] = fc
        c[_C_CKEY + 2] = coef
        c[_C_CKEY + 3] = 1.0
        _copy_block(c, _C_LIN, _C_CBLOCK)
    else:
        c[_C_FKEY] = coef
        c[_C_FKEY + 1] = 1.0
        _copy_block(c, _C_LIN, _C_FBLOCK)


@njit(cache=True)
def _lin_modal(t, y, c):
    """Free modal amplitudes of state ``y`` at ``t`` in a linear regime.

    Returns ``(a1, a2, c0, s0)``: the complex amplitudes ``a_j = q_j - q_p,j(t)`` of the
    (one or two) modes about their particular motion (``a2 = 0`` when free) and the cosine
    and sine of the actuator phase at ``t`` (0 if the actuator is idle).
    """
    xr, xf, vr, vf = y
    mu, mf, cs = c[_C_M], c[_C_MF], c[_C_CS]
    c0 = s0 = 0.0
    forced = c[_C_SEGCOEF] != 0.0
    if forced:
        th0 = c[_C_OMEGA] * (t - c[_C_SEGT0])
        c0, s0 = math.cos(th0), math.sin(th0)
    a1 = a2 = 0j
    for j in range(int(c[_C_NMODE])):
        b = _C_MODAL + j * _MODAL_SIZE
        lam = complex(c[b], c[b + 1])
        pr = complex(c[b + 2], c[b + 3])
        pf = complex(c[b + 4], c[b + 5])
        ninv = complex(c[b + 6], c[b + 7])
        q0 = (pr * ((lam * mu + cs) * xr - cs * xf + mu * vr)
              + pf * ((lam * mf + cs) * xf - cs * xr + mf * vf)) * ninv  # fmt: skip
        qp0 = complex(c[b + 8], c[b + 9])
        if forced:
            qp0 += complex(c[b + 10], c[b + 11]) * c0 + complex(c[b + 12], c[b + 13]) * s0
        if j == 0:
            a1 = q0 - qp0
        else:
            a2 = q0 - qp0
    return a1, a2, c0, s0


@njit(cache=True)
def _lin_advance(t, y, tau, a1, a2, c0, s0, c):
    """Exact state at ``t + tau`` from state ``y`` at ``t`` with modal amplitudes
    ``_lin_modal(t, y, c)``, and the amplitudes and actuator phase there.

    Returns ``(y1, b1, b2, c1, s1)``: the state, the modal amplitudes ``b_j = a_j exp(lam_j
    tau)`` at ``t + tau`` (those of ``_lin_modal(t + tau, y1, c)``, so that a sequence of
    steps in one regime needs the modal decomposition only once) and the cosine and sine of
    the actuator phase there. The regime's standard step ``h_fix`` uses the stored
    ``exp(lam h_fix)``.
    """
    xr, xf, vr, vf = y
    mu, mf = c[_C_M], c[_C_MF]
    w = c[_C_OMEGA]
    forced = c[_C_SEGCOEF] != 0.0
    fixed = tau == c[_C_LINH]
    c1 = s1 = 0.0
    if forced:
        th1 = w * (t + tau - c[_C_SEGT0])
        c1, s1 = math.cos(th1), math.sin(th1)
    nm = int(c[_C_NMODE])
    nxr = nxf = nvr = nvf = 0.0
    if nm == 1:  # free: the centre of mass falls freely, pushed by the actuator
        mt = mu + mf
        x0 = (mu * xr + mf * xf) / mt
        v0 = (mu * vr + mf * vf) / mt
        xc = x0 + v0 * tau - 0.5 * G * tau * tau
        vc = v0 - G * tau
        if forced:
            kap = c[_C_COMK]
            xc += kap * (c0 - c1 - w * s0 * tau)
            vc += kap * w * (s1 - s0)
        nxr = nxf = xc
        nvr = nvf = vc
    b1 = b2 = 0j
    for j in range(nm):
        b = _C_MODAL + j * _MODAL_SIZE
        lam = complex(c[b], c[b + 1])
        pr = complex(c[b + 2], c[b + 3])
        pf = complex(c[b + 4], c[b + 5])
        qp1 = complex(c[b + 8], c[b + 9])
        if forced:
            qp1 += complex(c[b + 10], c[b + 11]) * c1 + complex(c[b + 12], c[b + 13]) * s1
        if fixed:
            e = complex(c[_C_LINE + 2 * j], c[_C_LINE + 2 * j + 1])
        else:
            e = _exp_lam(lam, tau)
        if j == 0:
            b1 = e * a1
            q = b1 + qp1
        else:
            b2 = e * a2
            q = b2 + qp1
        lq = lam * q
        nxr += 2.0 * (pr * q).real
        nxf += 2.0 * (pf * q).real
        nvr += 2.0 * (pr * lq).real
        nvf += 2.0 * (pf * lq).real
    return (nxr, nxf, nvr, nvf), b1, b2, c1, s1


@njit(cache=True)
def _lin_eval(t, y, tau, a1, a2, c0, s0, c):
    """Exact state at ``t + tau`` (``_lin_advance`` without the amplitudes there)."""
    return _lin_advance(t, y, tau, a1, a2, c0, s0, c)[0]


@njit(cache=True)
def _free_ceiling(y, a1, c):
    """Upper bound of the foot height over the rest of a free flight with the actuator idle.

    The centre of mass rises at most to its apex, and the oscillation about it (modal
    amplitude ``a1``, damped) never exceeds its present range ``2 |phi_f a1|``.
    """
    mu, mf = c[_C_M], c[_C_MF]
    mt = mu + mf
    xc = (mu * y[0] + mf * y[1]) / mt
    vc = (mu * y[2] + mf * y[3]) / mt
    if vc > 0.0:
        xc += 0.5 * vc * vc / G
    b = _C_MODAL
    z = complex(c[b + 4], c[b + 5]) * a1
    return xc + 2.0 * (1.0 + 1e-12) * math.sqrt(_abs2(z)) + 1e-12


@njit(cache=True)
def _env_lo(x0, x1, b, r, tau):
    """Lower bound of min over [0, tau] of a component with value x0, slope x1 at 0,
    |second derivative| <= b and |value| <= r throughout.
    """
    return max(-r, min(x0, x0 + tau * (x1 - 0.5 * b * tau)))


@njit(cache=True)
def _env_hi(x0, x1, b, r, tau):
    """Upper bound of max over [0, tau] (see ``_env_lo``)."""
    return min(r, max(x0, x0 + tau * (x1 + 0.5 * b * tau)))


@njit(cache=True)
def _lin_safe(t, y, a1, a2, c0, s0, c, lo, hi, top, tau_fix, tau_max):
    """Longest step in a linear regime that provably contains no event.

    Over a step ``[t, t + tau]`` the foot height must stay inside ``(lo, hi)`` (the regime's
    event thresholds) and, if ``top`` is finite (the height window is open), produce no new
    maximum: either ``x_f <= top`` throughout or ``x_f' > 0`` throughout. The closed form
    (modal amplitudes ``a1, a2`` and actuator phase ``c0, s0`` from ``_lin_modal``) is
    split into an exact part (the centre of mass in free fall, or the equilibrium in
    contact) and components bounded by their value and slope at ``t``, a bound on their
    curvature and a bound on their range: each mode ``2 Re(phi_f a e^(lam s))`` by ``2
    |phi_f a|`` (its modes are damped), the actuator's particular motion by its amplitude,
    its push on the free centre of mass by its curvature. The same curvature bounds give a
    second, joint bound: ``x_f`` itself has value ``y[1]`` and slope ``y[3]`` at ``t`` and
    a curvature within ``p2 -+ r2`` (``p2``: that of the exact part), which is the tighter
    one just after an event, where the foot leaves a threshold while the components move
    apart. Both bounds are monotone in ``tau``. Returns 0 if not even ``tau_fix`` can be
    proved event-free (tried first: the common case near an event), else the largest such
    ``tau`` in ``[tau_fix, tau_max]`` (by bisection, to a few per cent).
    """
    w = c[_C_OMEGA]
    forced = c[_C_SEGCOEF] != 0.0
    nm = int(c[_C_NMODE])
    # exact part p0 + p1 s + p2 s^2 / 2; kb: curvature bound of the actuator's push on the
    # free centre of mass (zero value and slope at s = 0)
    p1 = p2 = kb = 0.0
    if nm == 1:
        mu, mf = c[_C_M], c[_C_MF]
        mt = mu + mf
        p0 = (mu * y[0] + mf * y[1]) / mt
        p1 = (mu * y[2] + mf * y[3]) / mt
        p2 = -G
        if forced:
            kb = abs(c[_C_COMK]) * w * w
    else:
        p0 = c[_C_LINXEQ]
    # the actuator's particular motion Fc cos + Fs sin of its phase
    famp = f0 = f1 = f2 = 0.0
    if forced:
        fc, fs = c[_C_LINFC], c[_C_LINFS]
        famp = c[_C_LINFA]
        f0 = fc * c0 + fs * s0
        f1 = w * (fs * c0 - fc * s0)
        f2 = -w * w * f0
    # the modes: value, slope and second derivative of 2 Re(phi_f a e^(lam s)) at s = 0,
    # its range (inflated against rounding) and |lam|
    b = _C_MODAL
    lam = complex(c[b], c[b + 1])
    z = complex(c[b + 4], c[b + 5]) * a1
    zl = z * lam
    m0, m1, m2 = 2.0 * z.real, 2.0 * zl.real, 2.0 * (zl * lam).real
    ma = 2.0 * (1.0 + 1e-12) * math.sqrt(z.real * z.real + z.imag * z.imag)
    ml = c[_C_LINL1]
    n0 = n1 = n2 = na = nl = 0.0
    if nm == 2:
        b = _C_MODAL + _MODAL_SIZE
        lam = complex(c[b], c[b + 1])
        z = complex(c[b + 4], c[b + 5]) * a2
        zl = z * lam
        n0, n1, n2 = 2.0 * z.real, 2.0 * zl.real, 2.0 * (zl * lam).real
        na = 2.0 * (1.0 + 1e-12) * math.sqrt(z.real * z.real + z.imag * z.imag)
        nl = c[_C_LINL2]
    mb2, mb3 = ma * ml * ml, ma * ml * ml * ml
    nb2, nb3 = na * nl * nl, na * nl * nl * nl
    fb2, fb3 = famp * w * w, famp * w * w * w
    # the joint bound: x_f'' within [alo, ahi] (alo <= 0)
    x0, v0 = y[1], y[3]
    r2 = kb + mb2 + nb2 + fb2
    alo, ahi = p2 - r2, p2 + r2
    apex = top < np.inf
    lo_m = lo + 1e-12
    hi_m = min(hi, top) - 1e-12
    ok_hi = hi - 1e-12
    tau_ok = 0.0
    tau = tau_fix
    lo_t = tau_fix
    hi_t = tau_max
    for it in range(2 + LIN_BISECT):
        # bounds of x_f (and of x_f') over [0, tau]
        if p2 < 0.0:
            xmin = min(p0, p0 + tau * (p1 + 0.5 * p2 * tau))
            sm = min(max(-p1 / p2, 0.0), tau)
            xmax = p0 + sm * (p1 + 0.5 * p2 * sm)
        else:
            xmin = xmax = p0
        xmin += _env_lo(m0, m1, mb2, ma, tau) - 0.5 * kb * tau * tau
        xmax += _env_hi(m0, m1, mb2, ma, tau) + 0.5 * kb * tau * tau
        if nm == 2:
            xmin += _env_lo(n0, n1, nb2, na, tau)
            xmax += _env_hi(n0, n1, nb2, na, tau)
        if forced:
            xmin += _env_lo(f0, f1, fb2, famp, tau)
            xmax += _env_hi(f0, f1, fb2, famp, tau)
        xmin = max(xmin, min(x0, x0 + tau * (v0 + 0.5 * alo * tau)))
        sm = tau if ahi >= 0.0 else min(max(-v0 / ahi, 0.0), tau)
        xmax = min(xmax, max(x0, x0 + sm * (v0 + 0.5 * ahi * sm)))
        good = xmin > lo_m and xmax < ok_hi
        if good and not xmax < hi_m:
            # no new maximum of x_f unless it is the step's end: x_f' > 0 throughout
            vmin = min(p1, p1 + p2 * tau) - kb * tau + _env_lo(m1, m2, mb3, ma * ml, tau)
            if nm == 2:
                vmin += _env_lo(n1, n2, nb3, na * nl, tau)
            if forced:
                vmin += _env_lo(f1, f2, fb3, famp * w, tau)
            vmin = max(vmin, v0 + alo * tau)
            good = apex and vmin > 0.0
        if it == 0:  # tau_fix (most often the bound fails right there)
            if not good:
                return 0.0
            tau_ok = tau_fix
            tau = tau_max
            continue
        if it == 1:  # tau_max
            if good:
                return tau_max
        elif good:
            lo_t = tau
            tau_ok = tau
        else:
            hi_t = tau
        tau = math.sqrt(lo_t * hi_t)
    return tau_ok


# ----------------------------------------------------------------------------------------
# dense output at frame times (trajectories as a camera sees them, physics-model.md 5b):
# positions and velocities of foot and rod. Frames are evaluated inside each accepted
# step, from what the step already has; the steps themselves are those of the height-only
# jump (no small fixed step).
#
# Closed-form steps: the exact solution, the modal amplitudes a_j exp(lam_j tau) plus the
# particular motion (and the free centre of mass); the velocities are its exact
# derivative (each mode's shape times lam_j, as in _lin_advance). Evaluated from scratch
# that costs a complex exponential per mode and the actuator's cosine and sine per frame;
# instead the modal terms and the actuator phase of one frame are carried to the next
# (spacing d) by the factors exp(lam_j d) and a rotation by w d, across the steps of a
# regime (the modal amplitudes of a regime only ever advance by such factors). Camera
# frames are equally spaced, so those factors are computed once per regime and spacing
# (cached): a frame costs a few complex multiplications.
#
# Dormand-Prince steps: a quintic Hermite interpolant of each position through its value,
# velocity and acceleration at both ends of the step; the velocities are its derivative.
# Chosen over the 4th-order continuous extension of DOPRI5 because (i) it is of higher
# order: its interpolation error is at most h^6 max|x^(6)| / 46080, below the step's own
# local error, so the dense output is as accurate as the integrator's states (the
# velocities and accelerations at the ends are the 5th-order states and the right-hand
# side there, the FSAL stage); (ii) it uses only the step's end points, so the
# Dormand-Prince step (shared with event location) need not hand out its stages and the
# hot loop of height-only jumps is untouched. Velocities: the derivative of the quintic
# (error O(h^5 max|x^(6)|), through the states' velocities at both ends) rather than a
# cubic Hermite interpolant of the velocities through their values and the accelerations
# (error h^4 max|x^(5)| / 384): on a 40 Hz damped oscillation the derivative is 20x (w h =
# 1) to 370x (w h = 0.13) more accurate and falls as h^5 against h^4. Measured
# (tests/test_frames.py, tests/test_frames_oracle.py, the report of
# benchmarks/bench_frames.py): with fixed steps the error of the frames falls as h^5 or
# faster, like that of the states; with adaptive steps it follows the tolerance (about
# 1e-6 m at the defaults, 1e-10 m at rtol 1e-9), and the velocities at the frames inside
# the steps are as accurate as the states' velocities at the steps' ends.

#: Columns of a frame (``out`` of ``simulate_one``): foot height x_f [m], rod displacement
#: x_r - x_r(0) [m], foot velocity x_f' [m/s], rod velocity x_r' [m/s].
FRAME_X_FOOT, FRAME_X_ROD, FRAME_V_FOOT, FRAME_V_ROD = 0, 1, 2, 3
FRAME_SIZE = 4

#: Spacings of successive frames [s] that differ by less than this share their cached
#: modal factors (equally spaced frames differ by rounding only, ~1e-15 s).
FRAME_DT_TOL = 1e-14

# frame state (per jump): the spacing of the cached factors, the eigenvalues they belong
# to, exp(lam_j d), cos and sin of w d; then the carried chain: whether it is valid, the
# time of its last frame, the modal terms a_j exp(lam_j (t_frame - t_j)) there and the
# actuator phase's cosine and sine
_FC_D, _FC_L1, _FC_L2, _FC_E1, _FC_E2, _FC_CW, _FC_SW = 0, 1, 3, 5, 7, 9, 10
_FC_CHAIN, _FC_T, _FC_Z1, _FC_Z2, _FC_CS, _FC_SN = 11, 12, 13, 15, 17, 18
_FC_SIZE = 19


@njit(cache=True)
def _frame_factors(d, lam1, lam2, w, fc):
    """exp(lam_j d), cos(w d), sin(w d) for a frame spacing ``d`` [s], cached in ``fc``."""
    if not (abs(d - fc[_FC_D]) <= FRAME_DT_TOL and fc[_FC_L1] == lam1.real
            and fc[_FC_L1 + 1] == lam1.imag and fc[_FC_L2] == lam2.real
            and fc[_FC_L2 + 1] == lam2.imag):  # fmt: skip
        e = _exp_lam(lam1, d)
        fc[_FC_E1], fc[_FC_E1 + 1] = e.real, e.imag
        e = _exp_lam(lam2, d)
        fc[_FC_E2], fc[_FC_E2 + 1] = e.real, e.imag
        fc[_FC_CW], fc[_FC_SW] = math.cos(w * d), math.sin(w * d)
        fc[_FC_D] = d
        fc[_FC_L1], fc[_FC_L1 + 1] = lam1.real, lam1.imag
        fc[_FC_L2], fc[_FC_L2 + 1] = lam2.real, lam2.imag
    return (complex(fc[_FC_E1], fc[_FC_E1 + 1]), complex(fc[_FC_E2], fc[_FC_E2 + 1]),
            fc[_FC_CW], fc[_FC_SW], fc[_FC_D])  # fmt: skip


@njit(cache=True)
def _lin_frames(t, y, a1, a2, c0, s0, c, frames, k, t_new, y1, out, xr0, fc):
    """Positions and velocities at the frames in ``(t, t_new]`` of a closed-form step.

    The state at ``t`` is ``y`` with modal amplitudes ``a1, a2`` and actuator phase ``c0,
    s0`` (``_lin_modal``); ``y1`` is the state at ``t_new``. Writes ``out[i] = (x_f, x_r -
    xr0, x_f', x_r')`` ([m], [m/s]; ``FRAME_*`` columns) for the frames from index ``k`` on
    and returns the index of the first frame after ``t_new``. The velocities are the exact
    derivative of the closed form: ``2 Re(phi lam q)`` per mode (``q`` the modal
    coordinate, free and particular parts, as ``_lin_advance``) plus, when free, the
    centre of mass's velocity. ``fc`` (``_FC_*``) caches the factors of a frame spacing and carries
    the modal terms from frame to frame; its chain must be invalidated (``fc[_FC_CHAIN] =
    0``) whenever the modal amplitudes are computed afresh (a new regime or segment).
    """
    nf = frames.shape[0]
    nm = int(c[_C_NMODE])
    forced = c[_C_SEGCOEF] != 0.0
    w = c[_C_OMEGA]
    b = _C_MODAL
    lam1 = complex(c[b], c[b + 1])
    pr1 = complex(c[b + 2], c[b + 3])
    pf1 = complex(c[b + 4], c[b + 5])
    # the particular motion's constant, cosine and sine parts: positions, then velocities
    # (the mode shapes times lam: (pr, pf, lam pr, lam pf) is the first-order system's
    # eigenvector)
    p0 = complex(c[b + 8], c[b + 9])
    pc = complex(c[b + 10], c[b + 11])
    ps = complex(c[b + 12], c[b + 13])
    vr1 = pr1 * lam1
    vf1 = pf1 * lam1
    rod0 = 2.0 * (pr1 * p0).real
    rodc = 2.0 * (pr1 * pc).real
    rods = 2.0 * (pr1 * ps).real
    vrod0 = 2.0 * (vr1 * p0).real
    vrodc = 2.0 * (vr1 * pc).real
    vrods = 2.0 * (vr1 * ps).real
    vfoot0 = 2.0 * (vf1 * p0).real
    vfootc = 2.0 * (vf1 * pc).real
    vfoots = 2.0 * (vf1 * ps).real
    lam2 = pr2 = pf2 = vr2 = vf2 = 0j
    if nm == 2:
        b = _C_MODAL + _MODAL_SIZE
        lam2 = complex(c[b], c[b + 1])
        pr2 = complex(c[b + 2], c[b + 3])
        pf2 = complex(c[b + 4], c[b + 5])
        p0 = complex(c[b + 8], c[b + 9])
        pc = complex(c[b + 10], c[b + 11])
        ps = complex(c[b + 12], c[b + 13])
        vr2 = pr2 * lam2
        vf2 = pf2 * lam2
        rod0 += 2.0 * (pr2 * p0).real
        rodc += 2.0 * (pr2 * pc).real
        rods += 2.0 * (pr2 * ps).real
        vrod0 += 2.0 * (vr2 * p0).real
        vrodc += 2.0 * (vr2 * pc).real
        vrods += 2.0 * (vr2 * ps).real
        vfoot0 += 2.0 * (vf2 * p0).real
        vfootc += 2.0 * (vf2 * pc).real
        vfoots += 2.0 * (vf2 * ps).real
    foot0, footc, foots = c[_C_LINXEQ], c[_C_LINFC], c[_C_LINFS]
    # free: the centre of mass (value, slope at t) and the actuator's push on it
    x0 = v0 = kap = 0.0
    if nm == 1:
        mu, mf = c[_C_M], c[_C_MF]
        x0 = (mu * y[0] + mf * y[1]) / (mu + mf)
        v0 = (mu * y[2] + mf * y[3]) / (mu + mf)
        if forced:
            kap = c[_C_COMK]
    e1 = e2 = 0j
    cw = sw = 0.0
    d_loc = -1.0  # the spacing of e1, e2, cw, sw
    if fc[_FC_CHAIN] != 0.0:  # carried from the last frame
        t_prev = fc[_FC_T]
        z1 = complex(fc[_FC_Z1], fc[_FC_Z1 + 1])
        z2 = complex(fc[_FC_Z2], fc[_FC_Z2 + 1])
        cs, sn = fc[_FC_CS], fc[_FC_SN]
    else:  # from the step's start
        t_prev = t
        z1, z2 = a1, a2
        cs, sn = c0, s0
        d = frames[k] - t
        z1 = z1 * _exp_lam(lam1, d)
        if nm == 2:
            z2 = z2 * _exp_lam(lam2, d)
        if forced:
            th = w * (frames[k] - c[_C_SEGT0])
            cs, sn = math.cos(th), math.sin(th)
        t_prev = frames[k]
    while k < nf:
        tf = frames[k]
        if tf > t_new:
            break
        d = tf - t_prev
        if d != 0.0:
            if not abs(d - d_loc) <= FRAME_DT_TOL:
                e1, e2, cw, sw, d_loc = _frame_factors(d, lam1, lam2, w, fc)
            z1 = z1 * e1
            if nm == 2:
                z2 = z2 * e2
            if forced:
                cs, sn = cs * cw - sn * sw, sn * cw + cs * sw
            t_prev = tf
        if tf == t_new:  # the step's end: the state itself
            out[k, FRAME_X_FOOT] = y1[1]
            out[k, FRAME_X_ROD] = y1[0] - xr0
            out[k, FRAME_V_FOOT] = y1[3]
            out[k, FRAME_V_ROD] = y1[2]
            k += 1
            continue
        xf = foot0 + 2.0 * (pf1 * z1).real
        xr = rod0 + 2.0 * (pr1 * z1).real
        vf = vfoot0 + 2.0 * (vf1 * z1).real
        vr = vrod0 + 2.0 * (vr1 * z1).real
        if nm == 2:
            xf += 2.0 * (pf2 * z2).real
            xr += 2.0 * (pr2 * z2).real
            vf += 2.0 * (vf2 * z2).real
            vr += 2.0 * (vr2 * z2).real
        if forced:
            xf += footc * cs + foots * sn
            xr += rodc * cs + rods * sn
            vf += vfootc * cs + vfoots * sn
            vr += vrodc * cs + vrods * sn
        if nm == 1:
            tau = tf - t
            xc = x0 + tau * (v0 - 0.5 * G * tau)
            vc = v0 - G * tau
            if forced:
                xc += kap * (c0 - cs - w * s0 * tau)
                vc += kap * w * (sn - s0)
            xf += xc
            xr += xc
            vf += vc
            vr += vc
        out[k, FRAME_X_FOOT] = xf
        out[k, FRAME_X_ROD] = xr - xr0
        out[k, FRAME_V_FOOT] = vf
        out[k, FRAME_V_ROD] = vr
        k += 1
    fc[_FC_CHAIN] = 1.0
    fc[_FC_T] = t_prev
    fc[_FC_Z1], fc[_FC_Z1 + 1] = z1.real, z1.imag
    fc[_FC_Z2], fc[_FC_Z2 + 1] = z2.real, z2.imag
    fc[_FC_CS], fc[_FC_SN] = cs, sn
    return k


@njit(cache=True)
def _hermite_frames(t, y, f, y1, f1, h, frames, k, t_new, out, xr0):
    """Positions and velocities at the frames in ``(t, t_new]`` of a Dormand-Prince step.

    Quintic Hermite interpolant of each position through its value, velocity and
    acceleration at the step's start (``y``, ``f``) and end (``y1``, ``f1``: the left limit
    at an event or a segment boundary), as a polynomial in ``s = (t_frame - t) / h``; the
    velocities are its derivative (a quartic, through the states' velocities at both
    ends). Writes ``out[i] = (x_f, x_r - xr0, x_f', x_r')`` ([m], [m/s]; ``FRAME_*``
    columns) and returns the index of the first frame after ``t_new``.
    """
    nf = frames.shape[0]
    hh = 0.5 * h * h
    # x(s) = p0 + d0 s + q0 s^2 + c3 s^3 + c4 s^4 + c5 s^5 (d: velocity h, q: acceleration
    # h^2 / 2), from the basis of the quintic Hermite interpolant; x'(t) = x'(s) / h
    dp = y1[1] - y[1]
    d0, d1, q0, q1 = h * y[3], h * y1[3], hh * f[1], hh * f1[1]
    f3 = 10.0 * dp - 6.0 * d0 - 4.0 * d1 - 3.0 * q0 + q1
    f4 = -15.0 * dp + 8.0 * d0 + 7.0 * d1 + 3.0 * q0 - 2.0 * q1
    f5 = 6.0 * dp - 3.0 * d0 - 3.0 * d1 - q0 + q1
    ff = (y[1], d0, q0, f3, f4, f5)
    dp = y1[0] - y[0]
    d0, d1, q0, q1 = h * y[2], h * y1[2], hh * f[0], hh * f1[0]
    r3 = 10.0 * dp - 6.0 * d0 - 4.0 * d1 - 3.0 * q0 + q1
    r4 = -15.0 * dp + 8.0 * d0 + 7.0 * d1 + 3.0 * q0 - 2.0 * q1
    r5 = 6.0 * dp - 3.0 * d0 - 3.0 * d1 - q0 + q1
    rr = (y[0] - xr0, d0, q0, r3, r4, r5)
    ih = 1.0 / h
    # the derivative's coefficients, divided by h: [1 / s]
    fv = (ff[1] * ih, 2.0 * ff[2] * ih, 3.0 * ff[3] * ih, 4.0 * ff[4] * ih, 5.0 * ff[5] * ih)
    rv = (rr[1] * ih, 2.0 * rr[2] * ih, 3.0 * rr[3] * ih, 4.0 * rr[4] * ih, 5.0 * rr[5] * ih)
    while k < nf:
        tf = frames[k]
        if tf > t_new:
            break
        if tf == t_new:
            out[k, FRAME_X_FOOT] = y1[1]
            out[k, FRAME_X_ROD] = y1[0] - xr0
            out[k, FRAME_V_FOOT] = y1[3]
            out[k, FRAME_V_ROD] = y1[2]
        else:
            s = min((tf - t) * ih, 1.0)
            out[k, FRAME_X_FOOT] = ff[0] + s * (
                ff[1] + s * (ff[2] + s * (ff[3] + s * (ff[4] + s * ff[5])))
            )
            out[k, FRAME_X_ROD] = rr[0] + s * (
                rr[1] + s * (rr[2] + s * (rr[3] + s * (rr[4] + s * rr[5])))
            )
            out[k, FRAME_V_FOOT] = fv[0] + s * (fv[1] + s * (fv[2] + s * (fv[3] + s * fv[4])))
            out[k, FRAME_V_ROD] = rv[0] + s * (rv[1] + s * (rv[2] + s * (rv[3] + s * rv[4])))
        k += 1
    return k


# ----------------------------------------------------------------------------------------
# events
@njit(cache=True)
def _g(kind, y, c):
    """Event function; the event is g crossing from <= 0 to > 0."""
    if kind == _EV_ADV_EXIT:
        return y[3]
    if kind == _EV_REENTER:
        return -y[1] - c[_C_ZMAX]
    if kind == _EV_RELEASE:
        return -(c[_C_FSMAX] - c[_C_SUNL] * (c[_C_ZMAX] + y[1]))
    if kind == _EV_TOUCH:
        return -y[1] - c[_C_ZFREE]
    return -y[3]  # _EV_APEX


@njit(cache=True)
def _gdot(kind, y, f, c):
    """Time derivative of the event function."""
    if kind == _EV_ADV_EXIT:
        return f[1]
    if kind == _EV_REENTER or kind == _EV_TOUCH:
        return -y[3]
    if kind == _EV_RELEASE:
        return c[_C_SUNL] * y[3]
    return -f[1]


@njit(cache=True)
def _gddot(kind, f, c):
    """Second time derivative of a position event function (0 for velocity events)."""
    if kind == _EV_REENTER or kind == _EV_TOUCH:
        return -f[1]
    if kind == _EV_RELEASE:
        return c[_C_SUNL] * f[1]
    return 0.0


@njit(cache=True)
def _gtol(kind, c, tol):
    """Absolute tolerance on g at an event: ``EVENT_TOL`` times the absolute integration
    tolerance, within 1e-13 to 1e-11 m on positions and 1e-11 to 1e-9 m/s on velocities
    (the lower ends at converged settings, the upper ones at the defaults).
    """
    gx = min(1e-11, max(1e-13, EVENT_TOL * tol[1]))
    if kind == _EV_REENTER or kind == _EV_TOUCH:
        return gx
    if kind == _EV_RELEASE:
        return gx * c[_C_SUNL]
    return min(1e-9, max(1e-11, EVENT_TOL * tol[2]))


@njit(cache=True)
def _hermite(th, g0, g1, d0, d1):
    """Cubic Hermite interpolant on [0, 1] (d0, d1: end slopes times the step)."""
    th2 = th * th
    th3 = th2 * th
    return (
        (2 * th3 - 3 * th2 + 1) * g0
        + (th3 - 2 * th2 + th) * d0
        + (-2 * th3 + 3 * th2) * g1
        + (th3 - th2) * d1
    )


@njit(cache=True, inline="always")
def _glance_possible(kind, y0, f0, y1, f1, h, c, tol):
    """Whether the interpolant of g can rise above zero inside the step (see ``_glance``).

    It never exceeds max(g0, g1) + 4/27 (|d0| + |d1|) (its slope basis functions are
    bounded by 4/27): most steps end here.
    """
    g0 = _g(kind, y0, c)
    g1 = _g(kind, y1, c)
    d0 = h * _gdot(kind, y0, f0, c)
    d1 = h * _gdot(kind, y1, f1, c)
    return max(g0, g1) + (4.0 / 27.0) * (abs(d0) + abs(d1)) > -_gtol(kind, c, tol)


@njit(cache=True)
def _glance(kind, t, y0, f0, y1, f1, h, mode, c, tol, a1, a2, c0, s0):
    """Detect a crossing that comes back within the step (g0 <= 0, g1 <= 0).

    Returns ``(s, y, f, g)`` with ``g > 0`` at ``t + s`` if the interpolant of g rises
    above zero inside the step, else ``s = -1``. In a linear regime ``a1, a2, c0, s0`` are
    the modal amplitudes and actuator phase at ``t`` (``_lin_modal``).
    """
    g0 = _g(kind, y0, c)
    g1 = _g(kind, y1, c)
    d0 = h * _gdot(kind, y0, f0, c)
    d1 = h * _gdot(kind, y1, f1, c)
    gtol = _gtol(kind, c, tol)
    # the interpolant never exceeds max(g0, g1) + 4/27 (|d0| + |d1|) (its slope basis
    # functions are bounded by 4/27): most steps end here
    if max(g0, g1) + (4.0 / 27.0) * (abs(d0) + abs(d1)) <= -gtol:
        return -1.0, y1, f1, g1
    # interior local maximum of the cubic interpolant: p'(th) = qa th^2 + qb th + qc = 0
    # with p''(th) = 2 qa th + qb < 0 (whatever the slopes at the ends of the step)
    qa = 6 * g0 + 3 * d0 - 6 * g1 + 3 * d1
    qb = -6 * g0 - 4 * d0 + 6 * g1 - 2 * d1
    qc = d0
    th = -1.0
    if abs(qa) < 1e-300:
        if qb < 0.0:
            th = -qc / qb
    else:
        disc = qb * qb - 4 * qa * qc
        if disc >= 0.0:
            sq = math.sqrt(disc)
            for r in ((-qb - sq) / (2 * qa), (-qb + sq) / (2 * qa)):
                if 0.0 < r < 1.0 and 2 * qa * r + qb < 0.0:
                    th = r
    if not (0.0 < th < 1.0) or _hermite(th, g0, g1, d0, d1) <= -gtol:
        return -1.0, y1, f1, g1
    s = th * h
    if c[_C_LIN] != 0.0:
        ym = _lin_eval(t, y0, s, a1, a2, c0, s0, c)
        fm = _accel(t + s, ym[0], ym[1], ym[2], ym[3], mode, c)
    else:
        ym, fm, _ = _dopri_step(t, y0, f0, s, mode, c, tol)
    gm = _g(kind, ym, c)
    if gm > 0.0:
        return s, ym, fm, gm
    return -1.0, y1, f1, g1


@njit(cache=True)
def _locate(kind, t, y0, f0, y1, f1, h, mode, c, tol, a1, a2, c0, s0):
    """Locate the first crossing of event ``kind`` in a step of size ``h``.

    Requires ``g(y0) <= 0 < g(y1)``. Returns ``(s, y, f)`` with ``s`` in (0, h] just past
    the root (``g > 0`` there), the state there and its derivative. In a linear regime
    ``a1, a2, c0, s0`` are the modal amplitudes and actuator phase at ``t``.
    """
    g0 = _g(kind, y0, c)
    g1 = _g(kind, y1, c)
    d0 = h * _gdot(kind, y0, f0, c)
    d1 = h * _gdot(kind, y1, f1, c)
    # root of the cubic Hermite interpolant of g (g is affine in y): Illinois method
    a, fa, b, fb = 0.0, g0, 1.0, g1
    side = 0
    th = 1.0
    for _ in range(60):
        th = (a * fb - b * fa) / (fb - fa)
        p = _hermite(th, g0, g1, d0, d1)
        if p > 0.0:
            b, fb = th, p
            if side == -1:
                fa *= 0.5
            side = -1
        else:
            a, fa = th, p
            if side == 1:
                fb *= 0.5
            side = 1
        if b - a < 1e-13 or abs(p) <= 1e-10 * (abs(g0) + abs(g1)):
            break
    # refine with real Runge-Kutta steps from the step start (in a linear regime, exact
    # closed-form states): safeguarded Newton, aimed at half the tolerance past the root
    # so that a trial lands inside (0, gtol) and ends the search
    lo, hi = 0.0, h
    y_hi, f_hi = y1, f1
    s = th * h
    gtol = _gtol(kind, c, tol)
    apex = kind == _EV_APEX
    gxp = _gtol(_EV_TOUCH, c, tol)
    lin = c[_C_LIN] != 0.0
    for _ in range(80):
        if not (lo < s < hi):
            s = 0.5 * (lo + hi)
        if lin:
            ys = _lin_eval(t, y0, s, a1, a2, c0, s0, c)
            fs = _accel(t + s, ys[0], ys[1], ys[2], ys[3], mode, c)
        else:
            ys, fs, _ = _dopri_step(t, y0, f0, s, mode, c, tol)
        gs = _g(kind, ys, c)
        gd = _gdot(kind, ys, fs, c)
        if apex and gs * gs <= 2.0 * abs(gd) * gxp:
            # the height is stationary at the apex: a point within |g|^2 / (2 |g'|) of it
            # (to second order) will do, on either side of the root
            return s, ys, fs
        if gs > 0.0:
            hi, y_hi, f_hi = s, ys, fs
            if gs < gtol or hi - lo < 1e-12:
                break
        else:
            lo = s
            if hi - lo < 1e-12:
                break
        if gd > 0.0:
            # Newton on the local quadratic model: the second derivative of a position
            # event is known; that of a velocity event (the foot's jerk) is a difference of
            # the accelerations along the flow (Dormand-Prince steps only: one evaluation of
            # the right-hand side saves most third trials)
            r = gs - 0.5 * gtol
            gdd = _gddot(kind, fs, c)
            if not lin and (kind == _EV_ADV_EXIT or apex):
                eps = 1e-5 * h
                fe = _accel(t + s + eps, ys[0] + eps * ys[2], ys[1] + eps * ys[3],
                            ys[2] + eps * fs[0], ys[3] + eps * fs[1], mode, c)  # fmt: skip
                gdd = (fe[1] - fs[1]) / eps if kind == _EV_ADV_EXIT else (fs[1] - fe[1]) / eps
            disc = gd * gd - 2.0 * gdd * r
            s = s - (2.0 * r / (gd + math.sqrt(disc)) if disc > 0.0 else r / gd)
        else:
            s = 0.5 * (lo + hi)
    return hi, y_hi, f_hi


# ----------------------------------------------------------------------------------------
# one jump
@njit(cache=True)
def _valid_row(row):
    for i in range(row.shape[0]):
        if not math.isfinite(row[i]):
            return False
    if row[ROW_M_MOTOR] <= 0 or row[ROW_M_ROD] < 0 or row[ROW_M_FOOT] <= 0:
        return False
    if row[ROW_K_SPRING] <= 0 or row[ROW_C_SPRING] < 0 or row[ROW_RADIUS] <= 0:
        return False
    if row[ROW_RHO] < 0 or not (0.0 < row[ROW_PHI] < 1.0):
        return False
    if row[_P_K] <= 0 or row[_P_R] < 1.0:
        return False
    return (
        row[_P_CD] >= 0
        and row[_P_KAPPA] >= 0
        and row[_P_K2] >= 0
        and row[_P_B] >= 0
        and row[_P_COMP] >= 0
    )


@njit(cache=True)
def _set_memory(c, zmax):
    """Set the crater depth z_max [m] and the unloading line derived from it.

    The unloading line starts at ``F_yield(z_max)`` with slope ``r_unload F_yield'(z_max)``
    (physics-model.md section 3) and reaches zero force at depth ``z_free``.
    """
    c[_C_ZMAX] = zmax
    c[_C_FSMAX] = _yield_force(zmax, c)
    c[_C_SUNL] = c[_C_R] * _yield_slope(zmax, c)
    c[_C_ZFREE] = zmax - c[_C_FSMAX] / c[_C_SUNL]


@njit(cache=True)
def _set_segment(c, si, nseg, seg):
    """Point the actuator at segment ``si`` (``si >= nseg``: hold after the command)."""
    if si < nseg:
        c[_C_SEGCOEF] = seg[si, 1]
        c[_C_SEGOFF] = seg[si, 2]
        c[_C_SEGT0] = 0.0 if si == 0 else seg[si - 1, 0]
    else:
        dur = seg[nseg - 1, 0] - (0.0 if nseg == 1 else seg[nseg - 2, 0])
        c[_C_SEGOFF] = seg[nseg - 1, 1] * math.cos(c[_C_OMEGA] * dur) + seg[nseg - 1, 2]
        c[_C_SEGCOEF] = 0.0
        c[_C_SEGT0] = seg[nseg - 1, 0]


@njit(cache=True)
def _record(rec, n, t, y, mode, c):
    """Write one ``REC_FIELDS`` row of state ``y`` at time ``t`` to ``rec[n]``."""
    if n >= rec.shape[0]:
        return n
    z = -y[1]
    fg, ma, _ = _ground(z, -y[3], mode, c)
    rec[n, 0] = t
    rec[n, 1] = y[0]
    rec[n, 2] = y[1]
    rec[n, 3] = y[2]
    rec[n, 4] = y[3]
    advancing = mode == MODE_ADVANCING
    zmax = max(z, c[_C_ZMAX]) if advancing else c[_C_ZMAX]
    rec[n, 5] = zmax
    rec[n, 6] = max(fg, 0.0)
    rec[n, 7] = ma
    rec[n, 8] = mode
    rec[n, 9] = c[_C_SEGCOEF] * math.cos(c[_C_OMEGA] * (t - c[_C_SEGT0])) + c[_C_SEGOFF]
    rec[n, 10] = c[_C_R] * _yield_slope(zmax, c) if advancing else c[_C_SUNL]
    return n + 1


@njit(cache=True)
def _context(row, meta):
    """Per-jump constants (``_C_*`` layout) from an input row and a command's meta."""
    c = np.zeros(_C_SIZE)
    c[_C_M] = row[ROW_M_MOTOR] + row[ROW_M_ROD]
    c[_C_MINV] = 1.0 / c[_C_M]
    c[_C_MFINV] = 1.0 / row[ROW_M_FOOT]
    c[_C_MMOT] = row[ROW_M_MOTOR]
    c[_C_MF] = row[ROW_M_FOOT]
    c[_C_KS] = row[ROW_K_SPRING]
    c[_C_CS] = row[ROW_C_SPRING]
    c[_C_K] = row[_P_K]
    c[_C_CD] = row[_P_CD]
    c[_C_AM] = row[_P_KAPPA] * row[ROW_RHO] * row[ROW_PHI]
    c[_C_R] = row[_P_R]
    c[_C_K2] = row[_P_K2]
    c[_C_B] = row[_P_B]
    c[_C_RAD] = row[ROW_RADIUS]
    c[_C_HFULL] = row[ROW_RADIUS] * CONE_TAN
    c[_C_OMEGA] = meta[0]
    c[_C_COMP] = row[_P_COMP]
    c[_C_MULT] = 1.0
    return c


@njit(cache=True)
def _initial_state(c, start):
    """Start state of physics-model.md section 4; sets the bed memory in ``c``."""
    if start == START_SETTLED:
        m_upper = c[_C_M]
        weight = (m_upper + c[_C_MF]) * G
        k, k2 = c[_C_K], c[_C_K2]
        z0 = 2.0 * weight / (k + math.sqrt(k * k + 4.0 * k2 * weight))  # F_static(z0) = W
        # placing the robot is a quasi-static intrusion to z0 that has ended: it compacts
        _end_of_episode(z0, c)
        _set_memory(c, z0)
        c[_C_ZENTRY] = z0
        return (-z0 - m_upper * G / c[_C_KS], -z0, 0.0, 0.0)
    _set_memory(c, 0.0)
    c[_C_ZENTRY] = 0.0
    return (0.0, 0.0, 0.0, 0.0)


@njit(cache=True)
def _switch(event, y, c):
    """New regime after a regime event at state ``y`` (updates the bed memory in c)."""
    if event == _EV_ADV_EXIT:  # stopped advancing: the crater bottom is here
        _end_of_episode(-y[1], c)
        _set_memory(c, -y[1])
        return MODE_CONTACT if c[_C_FSMAX] > 0.0 else MODE_FREE
    if event == _EV_RELEASE:
        return MODE_FREE
    if event == _EV_TOUCH and c[_C_FSMAX] > 0.0:
        return MODE_CONTACT
    # reached the crater bottom: a new advancing episode (and added-mass cone) starts
    c[_C_ZENTRY] = c[_C_ZMAX]
    return MODE_ADVANCING


@njit(cache=True)
def simulate_one(row, seg, meta, opts, rec, record, frames=None, out=None):
    """Simulate one jump.

    Parameters
    ----------
    row : ndarray, shape (ROW_SIZE,)
        Robot, phi and force parameters (``ROW_*`` layout, SI).
    seg, meta : ndarray
        The command's table (``CommandProgram.as_table``).
    opts : ndarray, shape (OPT_SIZE,)
        Tolerances and limits (``OPT_*``).
    rec : ndarray, shape (capacity, REC_SIZE)
        Trajectory buffer (written only if ``record``).
    record : bool
        Whether to record the trajectory (every accepted step and event).
    frames : ndarray, shape (n_frames,), optional
        Frame times [s] on the command's clock, non-decreasing. If given, the positions and
        velocities at these times are written to ``out`` (dense output of the accepted steps, see
        ``_lin_frames`` and ``_hermite_frames``); the height is determined as without
        frames, but while frames remain after the jump's end (the touchdown after a flight,
        or the window's end) the simulation goes on under the same model (through the hold
        after the command) to the last frame. Before t = 0 the robot rests in its start
        state. Omitted (``None``), the frame code is compiled out.
    out : ndarray, shape (n_frames, FRAME_SIZE), optional
        Written with ``(x_f, x_r - x_r(0), x_f', x_r')`` ([m], [m/s]; the ``FRAME_*``
        columns) at each frame (with ``frames``; left as is unless the status is OK).

    Returns
    -------
    height : float
        Jump height [m] (NaN unless status is OK).
    status : int
    n_steps : int
        Runge-Kutta steps attempted (event refinements excluded).
    n_rec : int
        Rows written to ``rec``.
    """
    if not _valid_row(row):
        return np.nan, STATUS_BAD_INPUT, 0, 0
    tol = (opts[OPT_RTOL], opts[OPT_ATOL_X], opts[OPT_ATOL_V])
    hmax, max_steps = opts[OPT_HMAX], int(opts[OPT_MAX_STEPS])
    c = _context(row, meta)
    nseg = int(meta[1])
    push = int(meta[3])
    t_final = seg[nseg - 1, 0] + opts[OPT_T_AFTER]
    y = _initial_state(c, int(meta[2]))
    si = 0
    _set_segment(c, si, nseg, seg)

    # initial regime: advancing if the foot accelerates into the bed at the yield point
    t = 0.0
    mode = MODE_ADVANCING
    f = _accel(t, y[0], y[1], y[2], y[3], mode, c)
    if f[1] >= 0.0:
        mode = MODE_CONTACT if c[_C_FSMAX] > 0.0 else MODE_FREE
        f = _accel(t, y[0], y[1], y[2], y[3], mode, c)
    closed = opts[OPT_CLOSED] != 0.0
    # steps of the closed form resolve the events: a fraction of the fastest period,
    # shrinking with the tolerance as Dormand-Prince steps would
    lin_theta = LIN_THETA * min(1.0, tol[0] / 1e-5) ** 0.2
    if closed:
        _lin_prepare(mode, c, lin_theta, hmax)
    # the closed form's steps are exact: only a recorded trajectory (plots) needs max_step
    lin_hmax = hmax if record else np.inf

    n_rec = _record(rec, 0, t, y, mode, c) if record else 0
    # frames: the next frame to evaluate, the end of the simulation, and whether the height
    # is final (the jump has ended but frames remain)
    kf = 0
    nf = 0
    t_last = t_final
    done = False
    xr0 = y[0]
    if frames is not None:
        nf = frames.shape[0]
        fcache = np.full(_FC_SIZE, np.nan)
        fcache[_FC_CHAIN] = 0.0
        while kf < nf and frames[kf] <= 0.0:  # at rest in the start state
            out[kf, FRAME_X_FOOT] = y[1]
            out[kf, FRAME_X_ROD] = 0.0
            out[kf, FRAME_V_FOOT] = y[3]
            out[kf, FRAME_V_ROD] = y[2]
            kf += 1
        if nf > 0:
            t_last = max(t_final, frames[nf - 1])
    in_window = push == 0
    height = y[1] if in_window else -np.inf
    # a flight after the command has ended (x_f >= H_FLIGHT): only then does a touchdown
    # end the jump
    flown = False
    h = min(1e-4, hmax)
    n_steps = 0
    f_ok = True
    # in a linear regime: the modal amplitudes and actuator phase of the current state,
    # carried from step to step until the regime or the actuator segment changes
    modal = False
    a1 = a2 = 0j
    c0 = s0 = 0.0
    while True:
        if n_steps >= max_steps:
            return np.nan, STATUS_STEP_LIMIT, n_steps, n_rec
        t_stop = seg[si, 0] if si < nseg else t_final
        if frames is not None:
            if si > nseg:  # the window has closed: on to the last frame
                t_stop = t_last
        remaining = t_stop - t
        lin = c[_C_LIN] != 0.0
        safe = False
        if lin:
            if not modal:
                a1, a2, c0, s0 = _lin_modal(t, y, c)
                modal = True
                if frames is not None:
                    fcache[_FC_CHAIN] = 0.0  # fresh amplitudes: frames start from them
            if mode == MODE_FREE and si >= nseg and flown and not record and not done:
                # the jump ends at touchdown, and until then the foot flies freely, below
                # the centre of mass's highest point plus the range of its (damped)
                # oscillation: once that is below the height, the height is final
                if _free_ceiling(y, a1, c) < height:
                    if frames is None:
                        return height, STATUS_OK, n_steps, n_rec
                    if kf >= nf:
                        return height, STATUS_OK, n_steps, n_rec
                    done = True
                    in_window = False
            h_next = c[_C_LINH]
            tau_max = min(remaining, lin_hmax)
            if tau_max > h_next:
                # the longest step that provably contains no event (0 if none is longer)
                if mode == MODE_CONTACT:
                    lo, hi = -c[_C_ZMAX], -c[_C_ZFREE]
                else:
                    lo, hi = -c[_C_ZFREE], np.inf
                if si >= nseg and flown and y[1] >= 0.0 and not done:
                    lo = max(lo, 0.0)  # touchdown ends the jump
                top = height if in_window else np.inf
                if si >= nseg and not flown and not done:
                    # no flight inside a proved step (x_f stays below H_FLIGHT, or rises
                    # throughout): the step's end tells whether the foot has flown
                    top = min(top, H_FLIGHT)
                tau = _lin_safe(t, y, a1, a2, c0, s0, c, lo, hi, top, h_next, tau_max)
                if tau > h_next:
                    h_next = tau
                    safe = True
        else:
            h_next = h
        landing = h_next >= remaining * (1.0 - 1e-12)
        h_try = remaining if landing else h_next
        if mode == MODE_ADVANCING:
            first, last = _EV_ADV_EXIT, _EV_ADV_EXIT
        elif mode == MODE_CONTACT:
            first, last = _EV_REENTER, _EV_RELEASE
        else:
            first, last = _EV_TOUCH, _EV_TOUCH
        if lin:  # exact closed-form step (error 0)
            y1, b1, b2, c1, s1 = _lin_advance(t, y, h_try, a1, a2, c0, s0, c)
            f1 = f  # after a proved step f is computed when (if) it is needed
            err = 0.0
            if safe:
                for kind in range(first, last + 1):
                    if _g(kind, y1, c) > 0.0:  # only if rounding defeated the bound
                        safe = False
            if not safe:
                if not f_ok:
                    f = _accel(t, y[0], y[1], y[2], y[3], mode, c)
                f1 = _accel(t + h_try, y1[0], y1[1], y1[2], y1[3], mode, c)
        else:
            if not f_ok:
                f = _accel(t, y[0], y[1], y[2], y[3], mode, c)
            y1, f1, err = _dopri_step(t, y, f, h_try, mode, c, tol)
        n_steps += 1
        if not math.isfinite(err):
            h = 0.25 * h_try
            if h < 1e-13:
                return np.nan, STATUS_NONFINITE, n_steps, n_rec
            continue
        if err > 1.0:
            h = h_try * max(0.2, 0.9 * err**-0.2)
            if h < 1e-13:
                return np.nan, STATUS_STEP_UNDERFLOW, n_steps, n_rec
            continue
        # accepted step [t, t + h_try]: the earliest regime event inside it, if any
        event = _EV_NONE
        s_end = h_try
        for kind in range(first, last + 1):
            if safe:
                break  # proved event-free
            g0 = _g(kind, y, c)
            if g0 > 0.0:
                continue
            if _g(kind, y1, c) > 0.0:
                s, ye, fe = _locate(kind, t, y, f, y1, f1, h_try, mode, c, tol, a1, a2, c0, s0)
            elif not _glance_possible(kind, y, f, y1, f1, h_try, c, tol):
                continue
            else:  # a crossing that comes back inside the step (glancing contact)
                sm, ym, fm, _ = _glance(kind, t, y, f, y1, f1, h_try, mode, c, tol, a1, a2, c0, s0)
                if sm < 0.0:
                    continue
                s, ye, fe = _locate(kind, t, y, f, ym, fm, sm, mode, c, tol, a1, a2, c0, s0)
            if s < s_end:
                s_end, event, y1, f1 = s, kind, ye, fe
        # jump height: endpoint and interior maximum of x_f
        step_top = y1[1]
        if in_window:
            if y[3] > 0.0 and y1[3] < 0.0 and not safe:
                _, ya, _ = _locate(_EV_APEX, t, y, f, y1, f1, s_end, mode, c, tol, a1, a2, c0, s0)
                step_top = max(step_top, ya[1])
            height = max(height, step_top)
        if si >= nseg and step_top >= H_FLIGHT:
            flown = True
        touchdown = si >= nseg and flown and y1[1] < 0.0
        if frames is not None:
            if kf < nf:  # the frames inside the accepted step [t, t + s_end]
                t_new = t_stop if (landing and event == _EV_NONE) else t + s_end
                if frames[kf] <= t_new:
                    if lin:
                        kf = _lin_frames(t, y, a1, a2, c0, s0, c, frames, kf, t_new, y1, out,
                                         xr0, fcache)  # fmt: skip
                    else:
                        kf = _hermite_frames(t, y, f, y1, f1, s_end, frames, kf, t_new, out, xr0)
        t = t_stop if (landing and event == _EV_NONE) else t + s_end
        y, f = y1, f1
        f_ok = not safe
        if not (math.isfinite(y[0]) and math.isfinite(y[1]) and math.isfinite(y[2])
                and math.isfinite(y[3])):  # fmt: skip
            return np.nan, STATUS_NONFINITE, n_steps, n_rec
        if event != _EV_NONE:
            mode = _switch(event, y, c)
            f = _accel(t, y[0], y[1], y[2], y[3], mode, c)
            f_ok = True
            modal = False
            if closed:
                _lin_prepare(mode, c, lin_theta, hmax)
        elif landing:
            si += 1
            _set_segment(c, si, nseg, seg)
            if si == push:
                in_window = True
                height = max(height, y[1])
            if si == nseg and y[1] >= H_FLIGHT:
                flown = True
            f = _accel(t, y[0], y[1], y[2], y[3], mode, c)
            f_ok = True
            modal = False
            if closed:
                _lin_prepare(mode, c, lin_theta, hmax)
        elif lin:  # the same regime goes on: its modal amplitudes are at hand
            a1, a2, c0, s0 = b1, b2, c1, s1
        if record:
            n_rec = _record(rec, n_rec, t, y, mode, c)
        if touchdown or si > nseg:
            if frames is None:
                return height, STATUS_OK, n_steps, n_rec
            done = True  # the height is final; frames may remain
            in_window = False
        if frames is not None:
            if done and kf >= nf:
                return height, STATUS_OK, n_steps, n_rec
        if not (lin or landing or event != _EV_NONE):
            h = h_try * (5.0 if err == 0.0 else min(5.0, max(0.2, 0.9 * err**-0.2)))
        h = min(h, hmax)


@njit(cache=True, parallel=True)
def simulate_batch(rows, cmd_index, seg_tables, metas, opts, heights, status, n_steps):
    """Simulate ``rows.shape[0]`` jumps (in parallel over numba threads)."""
    empty = np.empty((0, REC_SIZE))
    for i in prange(rows.shape[0]):
        j = cmd_index[i]
        hgt, st, ns, _ = simulate_one(rows[i], seg_tables[j], metas[j], opts, empty, False)
        heights[i] = hgt
        status[i] = st
        n_steps[i] = ns


@njit(cache=True, parallel=True)
def simulate_frames_batch(
    rows, cmd_index, seg_tables, metas, opts, frames, offsets, scale, heights, status, n_steps,
    out
):  # fmt: skip
    """Simulate jumps with positions at their frame times (in parallel over numba threads).

    Jump ``i`` has the frames ``frames[offsets[i]:offsets[i + 1]]`` (non-decreasing, [s])
    and writes ``out[offsets[i]:offsets[i + 1]]`` = ``scale (x_f, x_r - x_r(0), x_f',
    x_r')`` (the ``FRAME_*`` columns; ``scale = 1e3``: [mm] and [mm/s]): NaN unless its
    status is OK. Heights, statuses and step counts as
    ``simulate_batch`` (the same heights, bit for bit).
    """
    empty = np.empty((0, REC_SIZE))
    for i in prange(rows.shape[0]):
        j = cmd_index[i]
        k0 = offsets[i]
        k1 = offsets[i + 1]
        o = out[k0:k1]
        hgt, st, ns, _ = simulate_one(
            rows[i], seg_tables[j], metas[j], opts, empty, False, frames[k0:k1], o
        )
        if st != STATUS_OK:
            o[:, :] = np.nan
        elif scale != 1.0:
            for k in range(o.shape[0]):
                for col in range(FRAME_SIZE):
                    o[k, col] *= scale
        heights[i] = hgt
        status[i] = st
        n_steps[i] = ns


@njit(cache=True)
def intrusion_batch(rows, row_index, depth, speed, out):
    """Force [N] of constant-speed intrusions into a fresh bed (physics-model.md 5b).

    Evaluation ``i`` drives the foot of row ``rows[row_index[i]]`` at speed ``speed[i]``
    [m/s] (>= 0) through depth ``depth[i]`` [m] (>= 0) and writes the force the rig applies
    against the bed, less the foot's weight: ``F_g + flux - m_a g`` from the integrator's
    own ground force ``_ground`` in the advancing regime, with the bed of the touching start
    state (the undisturbed surface: ``z_entry = 0``, no compaction history; while advancing
    the crater bottom follows the foot), so that every term of the library counts. The foot
    moves at constant speed, so its equation of motion (``_accel_a``: ``(m_f + m_a) x_f'' =
    F_g + flux - F_s - (m_f + m_a) g``) gives the rig's push ``F_s = F_g + flux - (m_f +
    m_a) g``. NaN for a bad row, a negative or non-finite depth or speed.
    """
    n_rows = rows.shape[0]
    ctx = np.zeros((n_rows, _C_SIZE))
    ok = np.zeros(n_rows, dtype=np.bool_)
    meta = np.zeros(4)
    for r in range(n_rows):
        if _valid_row(rows[r]):
            c = _context(rows[r], meta)
            _initial_state(c, START_TOUCHING)
            ctx[r] = c
            ok[r] = True
    for i in range(depth.shape[0]):
        r = row_index[i]
        z = depth[i]
        v = speed[i]
        if not (ok[r] and z >= 0.0 and v >= 0.0 and z < np.inf and v < np.inf):
            out[i] = np.nan
            continue
        fg, ma, flux = _ground(z, v, MODE_ADVANCING, ctx[r])
        out[i] = fg + flux - ma * G


@njit(cache=True)
def check_frames(frames, offsets, limits):
    """One pass over the frames of a batch: ``(code, index)``.

    Jump ``i`` has the frames ``frames[offsets[i]:offsets[i + 1]]`` [s], which must be
    finite and at most ``limits[i]``. ``code`` is 0 if they are and each jump's frames are
    non-decreasing, 1 if they are but some jump's are not, 2 if frame ``index`` is not
    finite, 3 if frame ``index`` is later than its jump's limit (``index`` is -1 unless
    ``code`` >= 2).
    """
    n_bad = 0
    n_down = 0
    for i in range(offsets.shape[0] - 1):  # the common case, without branches
        limit = limits[i]
        prev = -np.inf
        for k in range(offsets[i], offsets[i + 1]):
            t = frames[k]
            n_bad += np.int64(not t <= limit) + np.int64(t == -np.inf)
            n_down += np.int64(t < prev)
            prev = t
    if n_bad == 0:
        return (0 if n_down == 0 else 1), -1
    for i in range(offsets.shape[0] - 1):
        for k in range(offsets[i], offsets[i + 1]):
            t = frames[k]
            if not abs(t) < np.inf:
                return 2, k
            if t > limits[i]:
                return 3, k
    return 0, -1
