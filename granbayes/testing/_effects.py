"""Out-of-library physics: ground forces the force-term library cannot express.

A verdict study needs SYNTHETIC data that hold physics the library of
``docs/physics-model.md`` (section 3: ``depth``, ``drag``, ``added_mass``, ``stiffening``,
``viscous``, ``unloading``, ``compaction``) cannot represent, so that it can check that the
criticism loop answers ``misfit_remains`` instead of naming a library term as the cause.
Each effect here is a documented force law with a literature reference and parameters with
units. The independent oracle (:mod:`granbayes.testing._oracle`) applies them in its ground
force, in jumps, trajectories and intrusion tests, when they are passed as
``effects=(...)``; ``effects=None`` is the library model, unchanged. Nothing else in the
package reads them: they are ground truth for tests, never a model a fit can choose.

Every effect is a frozen dataclass with a *neutral* value at which it vanishes (the
defaults), and acts on the advancing regime of the bed (the foot pushing into undisturbed
grains, physics-model.md section 3) as follows, with ``z`` the depth [m], ``z'`` its rate
[m/s], ``F_yield(z)`` the loading curve (with compaction anchoring, if any):

    F_adv = m_rate(z') * m_pause(s) * F_yield(z) + c_d * f_drag(z, phi) * z'^2 + b z'
            (+ the added-mass cone, unchanged)

* :class:`DepthDependentDrag`: ``f_drag(z, phi) = exp(depth_rate (phi - phi_c) / phi_scale
  * z)``; the drag coefficient grows with depth above ``phi_c`` and fades with depth below
  it (Umbanhowar & Goldman 2010, *PRE* 82, 010301: only near the critical packing is the
  impact force linear in depth plus quadratic in velocity; Brzinski, Mayor & Durian 2013,
  *PRL* 111, 168002: a depth-dependent inertial drag). It multiplies the law's ``c_d`` (a
  law without ``drag`` is unchanged).
* :class:`JanssenSaturation`: the depth term ``k z`` of the static curve saturates,
  ``k lambda (1 - exp(-z / lambda))`` (Janssen 1895, *Z. Ver. Dtsch. Ing.* 39, 1045: wall
  friction screens the pressure in a container over a length ~ its width; Stone et al.
  2004, *Nature* 427, 503: the penetration resistance in a container saturates with depth).
  The ``stiffening`` term ``k2 z^2`` is kept as it is.
* :class:`PauseStiffening`: a bed state ``s`` in [0, 1] (0: just disturbed, 1: fully
  relaxed) that relaxes towards 1 with time constant ``tau_s`` and is erased by the foot's
  plastic advance through the grains over a strain length ``strain_m``:
  ``ds/dt = (1 - s) / tau_s - s z' / strain_m`` while the foot advances, ``ds/dt = (1 -
  s) / tau_s`` otherwise (resting or moving elastically on the unloading line, or in
  flight: the grains rearrange only where the foot flows through them), with ``m_pause =
  1 + gain s`` (Hubicki et al. 2017, SICB: pausing an intrusion for ~40 ms before pushing
  on gave jumps ~40% above prediction; grain motion relaxes over 10-100 ms). It is an
  extra state variable of the equations of motion, starting at ``initial``.
* :class:`RateStiffening`: ``m_rate(z') = 1 + gain ln(1 + z' / v_ref)``, a static
  resistance that grows slowly (logarithmically) with the intrusion rate (Hill, Yeung &
  Koehler 2005, *EPL* 72, 137: a weak rate dependence of the depth force at low speed;
  Roth, Han & Jaeger 2021, *PRL* 126, 218001: depth and velocity dependence are not
  additive).

Energy
------
The rate effects (:class:`DepthDependentDrag`, :class:`RateStiffening`) act only while
advancing and resist the motion (``f_drag > 0``, ``m_rate >= 1`` for ``z' >= 0``), so they
only dissipate; :class:`RateStiffening` is 1 when the foot stops, so the crater's unloading
line starts where the library's does. The other two change the unloading line so that the
bed never returns more work than the foot did on it:

* :class:`PauseStiffening` changes no force at a fixed depth while the foot rests (a state
  that grows under a resting foot would otherwise lift it and create energy). It raises the
  strength the foot meets when it advances again (a force step up at the crater bottom,
  like the library's rate terms) and the unloading line that starts where an advancing
  episode ends: top ``m F_yield(z_max)`` and slope ``m^2 r_unload F_yield'(z_max)`` with
  ``m = 1 + gain s`` at that moment, so the elastic energy it stores, ``F_top^2 / (2
  slope)``, is the library's (which the convex loading curve bounds by the work absorbed).
* :class:`JanssenSaturation` makes the loading curve concave, where the library's slope
  ``r_unload F_yield'(z_max)`` (which falls with depth) no longer bounds the stored energy.
  With it the unloading slope is ``max(r_unload F_yield'(z_max), F_top / z_max, F_top^2 /
  (2 W))``, where ``W`` is the static work absorbed along the loading curve so far: the
  stored energy never exceeds ``W``, and the line never reaches zero force above the
  undisturbed surface. For a convex curve this is the library's slope.

Examples
--------
>>> from granbayes.testing import JanssenSaturation, PauseStiffening, simulate_height_scipy
>>> law = {"k": 3000.0, "r_unload": 5.0}
>>> plain = simulate_height_scipy("single", 0.612, law)
>>> weaker = simulate_height_scipy("single", 0.612, law, effects=(JanssenSaturation(0.01),))
>>> bool(weaker < plain)
True
>>> JanssenSaturation().neutral, PauseStiffening(gain=0.5).neutral
(True, False)
"""

from __future__ import annotations

import math
from collections.abc import Iterable
from dataclasses import dataclass

import numpy as np

__all__ = [
    "DepthDependentDrag",
    "Effect",
    "JanssenSaturation",
    "PauseStiffening",
    "RateStiffening",
]


#: Largest exponent of :meth:`DepthDependentDrag.drag_factor` (exp(700) ~ 1e304).
_MAX_EXPONENT = 700.0


def _check(name: str, value: float, lower: float, *, strict: bool, allow_inf: bool = False):
    """Raise ``ValueError`` unless ``value`` is a number above ``lower``."""
    ok = isinstance(value, int | float) and not isinstance(value, bool)
    ok = ok and not math.isnan(value) and (allow_inf or math.isfinite(value))
    ok = ok and (value > lower if strict else value >= lower)
    if not ok:
        relation = ">" if strict else ">="
        raise ValueError(f"{name} must be a number {relation} {lower}, got {value!r}")


@dataclass(frozen=True)
class DepthDependentDrag:
    """A drag coefficient that changes with depth, in opposite directions about ``phi_c``.

    ``c_d(z, phi) = c_d exp(depth_rate (phi - phi_c) / phi_scale z)``: at ``phi = phi_c +
    phi_scale`` the law's drag coefficient grows e-fold over a depth ``1 / depth_rate``; at
    ``phi = phi_c - phi_scale`` it falls e-fold over the same depth; at ``phi_c`` it is the
    law's ``c_d`` (Umbanhowar & Goldman 2010, *PRE* 82, 010301). It multiplies the law's
    ``drag`` term, in jumps and intrusions, and acts only while the foot advances.

    Parameters
    ----------
    depth_rate : float
        Logarithmic depth rate of the drag coefficient at ``phi - phi_c = phi_scale``
        [1/m]; 0 (the default) is neutral. Negative values swap the trends.
    phi_scale : float
        Volume-fraction scale of the trend [-] (> 0; default 0.01).

    Examples
    --------
    >>> round(float(DepthDependentDrag(50.0).drag_factor(0.02, 0.622, 0.612)), 4)
    2.7183
    """

    depth_rate: float = 0.0
    phi_scale: float = 0.01

    def __post_init__(self) -> None:
        """Check the parameters."""
        _check("depth_rate", self.depth_rate, -math.inf, strict=True)
        _check("phi_scale", self.phi_scale, 0.0, strict=True)

    @property
    def neutral(self) -> bool:
        """Whether the effect vanishes (``depth_rate == 0``)."""
        return self.depth_rate == 0.0

    def drag_factor(self, z: float | np.ndarray, phi: float, phi_c: float) -> float | np.ndarray:
        """Factor ``c_d(z, phi) / c_d`` at depth ``z`` [m] (>= 0) of a bed at ``phi``.

        Parameters
        ----------
        z : float or ndarray
            Depth [m]; negative depths count as 0.
        phi : float
            Volume fraction of the bed [-].
        phi_c : float
            Critical packing fraction [-].

        Returns
        -------
        float or ndarray
            The factor [-] (> 0).
        """
        rate = self.depth_rate * (phi - phi_c) / self.phi_scale
        # (the exponent is capped where exp overflows: a trial stage of the integrator may
        # ask for any depth; the step is then rejected, not the jump)
        if isinstance(z, np.ndarray):
            return np.exp(np.minimum(rate * np.maximum(z, 0.0), _MAX_EXPONENT))
        return math.exp(min(rate * max(z, 0.0), _MAX_EXPONENT))


@dataclass(frozen=True)
class JanssenSaturation:
    """A depth force that saturates over a screening length (the Janssen effect).

    The depth term of the static curve becomes ``k lambda (1 - exp(-z / lambda))``: ``k z``
    near the surface, ``k lambda`` deep down (Janssen 1895; Stone et al. 2004, *Nature* 427,
    503). ``k2 z^2`` is unchanged. The unloading slope is bounded below so that the bed
    stores no more energy than it absorbed (module docstring).

    Parameters
    ----------
    lambda_m : float
        Screening length ``lambda`` [m] (> 0); ``inf`` (the default) is neutral.

    Examples
    --------
    >>> j = JanssenSaturation(0.02)
    >>> round(j.depth_force(3000.0, 0.02), 3), round(j.depth_force(3000.0, 1.0), 3)
    (37.927, 60.0)
    """

    lambda_m: float = math.inf

    def __post_init__(self) -> None:
        """Check the parameter."""
        _check("lambda_m", self.lambda_m, 0.0, strict=True, allow_inf=True)

    @property
    def neutral(self) -> bool:
        """Whether the effect vanishes (``lambda_m == inf``)."""
        return math.isinf(self.lambda_m)

    def depth_force(self, k: float, z: float | np.ndarray) -> float | np.ndarray:
        """The saturated depth term ``k lambda (1 - exp(-z / lambda))`` [N].

        Parameters
        ----------
        k : float
            Depth stiffness of the law [N/m].
        z : float or ndarray
            Depth [m].

        Returns
        -------
        float or ndarray
        """
        lam = self.lambda_m
        if math.isinf(lam):
            return k * z
        if isinstance(z, np.ndarray):
            return -k * lam * np.expm1(-z / lam)
        return -k * lam * math.expm1(-z / lam)

    def depth_slope(self, k: float, z: float) -> float:
        """Slope ``k exp(-z / lambda)`` of the saturated depth term [N/m].

        Parameters
        ----------
        k : float
            Depth stiffness of the law [N/m].
        z : float
            Depth [m].

        Returns
        -------
        float
        """
        return k if math.isinf(self.lambda_m) else k * math.exp(-z / self.lambda_m)

    def depth_work(self, k: float, z: float) -> float:
        """Work ``k lambda (z - lambda (1 - exp(-z / lambda)))`` of the depth term from 0 [J].

        Parameters
        ----------
        k : float
            Depth stiffness of the law [N/m].
        z : float
            Depth [m].

        Returns
        -------
        float
        """
        lam = self.lambda_m
        if math.isinf(lam):
            return 0.5 * k * z * z
        return k * lam * (z + lam * math.expm1(-z / lam))


@dataclass(frozen=True)
class PauseStiffening:
    """A bed that relaxes and stiffens while the foot rests, and is rejuvenated by motion.

    The bed state ``s`` (0: just disturbed, 1: fully relaxed) obeys
    ``ds/dt = (1 - s) / tau_s - s z' / strain_m`` while the foot advances (flows through
    undisturbed grains) and ``ds/dt = (1 - s) / tau_s`` otherwise (resting, on the elastic
    unloading line, in flight); the static resistance of the advancing foot is multiplied
    by ``1 + gain s`` (Hubicki et al. 2017, SICB: a 40 ms pause before the push-off gave
    jumps ~40% above prediction; grain motion relaxes over 10-100 ms). At a constant
    intrusion speed ``v`` the state settles at ``1 / (1 + v tau_s / strain_m)``. Whether a
    pause raises a jump depends on the command and the bed (a bed stiffened at landing
    also stops the foot shallower); a robot that pushes off a relaxed bed (the
    ``preload`` with ``initial = 1``) jumps higher.

    Parameters
    ----------
    gain : float
        Stiffening of a fully relaxed bed [-] (>= 0); 0 (the default) is neutral.
    tau_s : float
        Relaxation time [s] (> 0; default 0.04).
    strain_m : float
        Displacement of the foot through the grains that erases the relaxation [m] (> 0;
        default 1e-3, a poppy seed's diameter).
    initial : float
        State at ``t = 0`` of a jump and at the start of an intrusion [-] (in [0, 1];
        default 0: the bed was just prepared and the robot just placed).

    Examples
    --------
    >>> p = PauseStiffening(gain=1.0)
    >>> round(p.steady_state(0.1), 3), p.state_at(0.0, 0.1), p.state_at(0.01, 0.0)
    (0.2, 0.0, 1.0)
    """

    gain: float = 0.0
    tau_s: float = 0.04
    strain_m: float = 1e-3
    initial: float = 0.0

    def __post_init__(self) -> None:
        """Check the parameters."""
        _check("gain", self.gain, 0.0, strict=False)
        _check("tau_s", self.tau_s, 0.0, strict=True)
        _check("strain_m", self.strain_m, 0.0, strict=True)
        _check("initial", self.initial, 0.0, strict=False)
        if self.initial > 1.0:
            raise ValueError(f"initial must be in [0, 1], got {self.initial!r}")

    @property
    def neutral(self) -> bool:
        """Whether the effect vanishes (``gain == 0``)."""
        return self.gain == 0.0

    def multiplier(self, s: float | np.ndarray) -> float | np.ndarray:
        """Factor ``1 + gain s`` on the static resistance [-].

        Parameters
        ----------
        s : float or ndarray
            Bed state [-].

        Returns
        -------
        float or ndarray
        """
        return 1.0 + self.gain * s

    def rate(self, s: float, speed: float, advancing: bool) -> float:
        """``ds/dt`` [1/s] at state ``s`` and intrusion rate ``speed`` [m/s].

        Parameters
        ----------
        s : float
            Bed state [-].
        speed : float
            Intrusion rate ``z'`` [m/s] (negative values count as 0).
        advancing : bool
            Whether the foot advances into undisturbed grains.

        Returns
        -------
        float
        """
        relax = (1.0 - s) / self.tau_s
        return relax - s * max(speed, 0.0) / self.strain_m if advancing else relax

    def steady_state(self, speed: float) -> float:
        """The state at a constant intrusion speed ``speed`` [m/s] (>= 0), after long.

        Parameters
        ----------
        speed : float
            Intrusion speed [m/s].

        Returns
        -------
        float
        """
        return 1.0 / (1.0 + speed * self.tau_s / self.strain_m)

    def state_at(self, z: float | np.ndarray, speed: float) -> float | np.ndarray:
        """The state of an intrusion at constant speed from ``initial`` at depth ``z``.

        ``s(t) = s_inf + (initial - s_inf) exp(-t (1 / tau_s + speed / strain_m))`` with
        ``t = z / speed``; at ``speed = 0`` (quasi-static) the bed is fully relaxed
        (``s = 1``) below the surface.

        Parameters
        ----------
        z : float or ndarray
            Depth [m] (>= 0).
        speed : float
            Intrusion speed [m/s] (>= 0).

        Returns
        -------
        float or ndarray
        """
        z_arr = np.asarray(z, dtype=float)
        if speed == 0.0:
            out = np.where(z_arr > 0.0, 1.0, self.initial)
        else:
            s_inf = self.steady_state(speed)
            decay = z_arr * (1.0 / (speed * self.tau_s) + 1.0 / self.strain_m)
            out = s_inf + (self.initial - s_inf) * np.exp(-decay)
        return out if isinstance(z, np.ndarray) else float(out)


@dataclass(frozen=True)
class RateStiffening:
    """A static resistance that grows with the intrusion rate.

    The static part of the advancing resistance is multiplied by ``1 + gain ln(1 + z' /
    v_ref)`` (``z' >= 0``): 1 at rest, a slow logarithmic growth with speed (Hill, Yeung &
    Koehler 2005, *EPL* 72, 137; Roth, Han & Jaeger 2021, *PRL* 126, 218001). It is a
    stiffness ``k (1 + gain ln(1 + z'/v_ref))`` that no library term (``viscous``, ``drag``:
    forces independent of depth) can express.

    Parameters
    ----------
    gain : float
        Growth per e-fold of ``1 + z' / v_ref`` [-] (>= 0); 0 (the default) is neutral.
    v_ref : float
        Reference rate [m/s] (> 0; default 0.05).

    Examples
    --------
    >>> round(RateStiffening(gain=0.3, v_ref=0.05).multiplier(0.5), 4)
    1.7194
    """

    gain: float = 0.0
    v_ref: float = 0.05

    def __post_init__(self) -> None:
        """Check the parameters."""
        _check("gain", self.gain, 0.0, strict=False)
        _check("v_ref", self.v_ref, 0.0, strict=True)

    @property
    def neutral(self) -> bool:
        """Whether the effect vanishes (``gain == 0``)."""
        return self.gain == 0.0

    def multiplier(self, zdot: float | np.ndarray) -> float | np.ndarray:
        """Factor ``1 + gain ln(1 + max(z', 0) / v_ref)`` on the static resistance [-].

        Parameters
        ----------
        zdot : float or ndarray
            Intrusion rate ``z'`` [m/s].

        Returns
        -------
        float or ndarray
        """
        if isinstance(zdot, np.ndarray):
            return 1.0 + self.gain * np.log1p(np.maximum(zdot, 0.0) / self.v_ref)
        return 1.0 + self.gain * math.log1p(max(zdot, 0.0) / self.v_ref)


#: Any of the out-of-library effects.
Effect = DepthDependentDrag | JanssenSaturation | PauseStiffening | RateStiffening


@dataclass(frozen=True)
class _EffectSet:
    """At most one effect of each kind, resolved from the ``effects`` argument."""

    drag: DepthDependentDrag | None = None
    janssen: JanssenSaturation | None = None
    pause: PauseStiffening | None = None
    rate: RateStiffening | None = None

    @property
    def empty(self) -> bool:
        """Whether no effect was given (the library model)."""
        return (
            self.drag is None
            and self.janssen is None
            and self.pause is None
            and (self.rate is None)
        )


_SLOTS = {
    DepthDependentDrag: "drag",
    JanssenSaturation: "janssen",
    PauseStiffening: "pause",
    RateStiffening: "rate",
}


def resolve_effects(effects: Effect | Iterable[Effect] | None) -> _EffectSet:
    """Sort ``effects`` into their slots.

    Parameters
    ----------
    effects : effect, iterable of effects, or None
        The effects; ``None`` or an empty sequence is the library model.

    Returns
    -------
    _EffectSet

    Raises
    ------
    TypeError
        For an object that is not one of the effects.
    ValueError
        For two effects of the same kind.
    """
    if effects is None:
        return _EffectSet()
    if isinstance(effects, tuple(_SLOTS)):
        effects = (effects,)
    slots: dict[str, Effect] = {}
    for effect in effects:
        slot = _SLOTS.get(type(effect))
        if slot is None:
            raise TypeError(
                f"not an effect: {effect!r}; expected one of "
                + ", ".join(cls.__name__ for cls in _SLOTS)
            )
        if slot in slots:
            raise ValueError(f"two effects of the same kind: {type(effect).__name__}")
        slots[slot] = effect
    return _EffectSet(**slots)  # type: ignore[arg-type]
