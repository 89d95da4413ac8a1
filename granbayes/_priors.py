"""Priors: bounded, physically motivated, one per parameter, overridable from TOML.

The default prior of a force-term parameter, with its reason, is part of the parameter's
entry in the force-term registry (:data:`granbayes.forces.TERMS`); the noise parameter's
is here.

Every prior is proper and bounded. Scale parameters that span decades (stiffnesses, the
unloading ratio, the noise) are log-uniform; coefficients that may vanish (drag, added
mass, viscous, compaction) are uniform from zero. The sampler works in *sampling
coordinates*: ``log(value)`` for log-uniform priors, ``sqrt(value)`` for uniform priors
from zero (coefficients whose effect may be absent), the value itself otherwise, and the
prior density is expressed in those coordinates (the Jacobian is included), so the
sampler never needs to know which is which.

Override in a TOML file passed as ``granbayes fit --priors FILE``::

    [k]
    dist = "loguniform"   # "uniform" | "loguniform" | "normal" | "lognormal"
    lower = 500.0
    upper = 20000.0
    # normal/lognormal also take mu, sigma (lognormal: of log(value)); bounds truncate.
"""

from __future__ import annotations

import math
import tomllib
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np
from scipy.stats import truncnorm

from ._errors import InputError
from .forces import Parameter, parameter, registered_parameters

__all__ = [
    "Prior",
    "calibration_priors",
    "default_priors",
    "load_priors",
    "priors_toml",
    "NOISE_PARAMETERS",
]

_DISTS = ("uniform", "loguniform", "normal", "lognormal")


@dataclass(frozen=True)
class Prior:
    """A bounded prior on one scalar parameter.

    Parameters
    ----------
    dist : {"uniform", "loguniform", "normal", "lognormal"}
        Family; normal and lognormal are truncated to ``[lower, upper]``.
    lower, upper : float
        Bounds in the parameter's units (``lower > 0`` for log families).
    mu, sigma : float, optional
        Location and scale (of ``log(value)`` for lognormal).
    unit : str
        Unit, for reports.
    why : str
        The physical motivation, for reports.
    """

    dist: str
    lower: float
    upper: float
    mu: float | None = None
    sigma: float | None = None
    unit: str = ""
    why: str = ""

    def __post_init__(self) -> None:
        """Check the family and its parameters."""
        if self.dist not in _DISTS:
            raise ValueError(f"prior dist must be one of {_DISTS}, got {self.dist!r}")
        if not (math.isfinite(self.lower) and math.isfinite(self.upper)):
            raise ValueError("prior bounds must be finite")
        if not self.lower < self.upper:
            raise ValueError(f"prior needs lower < upper, got {self.lower} >= {self.upper}")
        if self.log_scale and self.lower <= 0:
            raise ValueError(f"{self.dist} prior needs lower > 0")
        if self.dist in ("normal", "lognormal"):
            if self.mu is None or self.sigma is None:
                raise ValueError(f"{self.dist} prior needs mu and sigma")
            if not (math.isfinite(self.mu) and math.isfinite(self.sigma) and self.sigma > 0):
                raise ValueError(f"{self.dist} prior needs a finite mu and a finite sigma > 0")

    @property
    def log_scale(self) -> bool:
        """Whether the sampling coordinate is ``log(value)``."""
        return self.dist in ("loguniform", "lognormal")

    @property
    def sqrt_scale(self) -> bool:
        """Whether the sampling coordinate is ``sqrt(value)``: a uniform prior from zero.

        A coefficient whose effect may be absent (drag, added mass, ...) has its posterior
        piled against zero when the data hold no such effect; in ``sqrt(value)`` that
        density falls to zero at the wall instead of being cut by it, which the ensemble
        moves mix through several times faster.
        """
        return self.dist == "uniform" and self.lower == 0.0

    @property
    def bounds_u(self) -> tuple[float, float]:
        """Bounds in sampling coordinates."""
        if self.log_scale:
            return math.log(self.lower), math.log(self.upper)
        if self.sqrt_scale:
            return 0.0, math.sqrt(self.upper)
        return self.lower, self.upper

    def to_value(self, u: np.ndarray) -> np.ndarray:
        """Sampling coordinate -> parameter value.

        Parameters
        ----------
        u : ndarray
            Sampling coordinates.

        Returns
        -------
        ndarray
            Values [the parameter's unit].
        """
        u = np.asarray(u, dtype=float)
        if self.log_scale:
            return np.exp(u)
        return u * u if self.sqrt_scale else u

    def to_u(self, value: np.ndarray) -> np.ndarray:
        """Parameter value -> sampling coordinate.

        Parameters
        ----------
        value : ndarray
            Values [the parameter's unit].

        Returns
        -------
        ndarray
        """
        value = np.asarray(value, dtype=float)
        if self.log_scale:
            return np.log(value)
        return np.sqrt(value) if self.sqrt_scale else value

    def log_jacobian(self, u: np.ndarray) -> np.ndarray:
        """``log |d value / d u|`` of the sampling coordinate.

        Parameters
        ----------
        u : ndarray
            Sampling coordinates.

        Returns
        -------
        ndarray
        """
        u = np.asarray(u, dtype=float)
        if self.log_scale:
            return u
        if self.sqrt_scale:  # -inf at u = 0, NaN outside the support (masked by callers)
            with np.errstate(divide="ignore", invalid="ignore"):
                return np.log(2.0 * u)
        return np.zeros_like(u)

    def logpdf_u(self, u: np.ndarray) -> np.ndarray:
        """Log density in sampling coordinates (unnormalised for the truncated families).

        The density of the parameter value times the Jacobian ``|d value / d u|``, so a
        uniform prior stays uniform in the value. Returns ``-inf`` outside the bounds.

        Parameters
        ----------
        u : ndarray
            Sampling coordinates.

        Returns
        -------
        ndarray
        """
        u = np.asarray(u, dtype=float)
        lo, hi = self.bounds_u
        inside = (u >= lo) & (u <= hi)
        if self.dist == "loguniform":
            out = np.full(u.shape, -math.log(hi - lo))
        elif self.dist == "uniform":
            out = -math.log(self.upper - self.lower) + self.log_jacobian(u)
        else:
            z = (u - self.mu) / self.sigma
            out = -0.5 * z * z
        return np.where(inside, out, -np.inf)

    def sample_u(self, rng: np.random.Generator, size: int) -> np.ndarray:
        """Draw in sampling coordinates (rejection for the truncated families).

        Parameters
        ----------
        rng : numpy.random.Generator
            Source of randomness.
        size : int
            Number of draws.

        Returns
        -------
        ndarray, shape (size,)
        """
        lo, hi = self.bounds_u
        if self.dist == "uniform":
            return self.to_u(rng.uniform(self.lower, self.upper, size))
        if self.dist == "loguniform":
            return rng.uniform(lo, hi, size)
        a, b = (lo - self.mu) / self.sigma, (hi - self.mu) / self.sigma
        return truncnorm.rvs(a, b, loc=self.mu, scale=self.sigma, size=size, random_state=rng)

    def describe(self) -> str:
        """One-line description for reports."""
        extra = "" if self.mu is None else f", mu={self.mu:g}, sigma={self.sigma:g}"
        return f"{self.dist}[{self.lower:g}, {self.upper:g}]{extra} {self.unit}".strip()


#: Default priors of the noise-model parameters (those of the force terms are in the
#: force-term registry, :data:`granbayes.forces.TERMS`).
_NOISE_DEFAULTS: dict[str, Prior] = {
    "sigma_mm": Prior(
        "loguniform", 0.3, 30.0, unit="mm", why="trial-to-trial scatter of jump heights"
    ),
}

#: Noise-model parameters (not force terms).
NOISE_PARAMETERS: tuple[str, ...] = tuple(_NOISE_DEFAULTS)


def default_priors() -> dict[str, Prior]:
    """The default prior of every force-term and noise parameter.

    Those of the force-term parameters are read from the registry
    (:data:`granbayes.forces.TERMS`, each :class:`~granbayes.forces.Parameter`'s ``prior``,
    see :func:`_registry_prior`) at each call, in library order; the noise parameters
    follow.

    Returns
    -------
    dict of str to Prior
        Parameter name to prior (bounds in the parameter's unit).
    """
    return {p.name: _registry_prior(p) for p in registered_parameters()} | _NOISE_DEFAULTS


#: Units of the robot parameters a calibration may leave uncertain.
CALIBRATION_UNITS: dict[str, str] = {
    "m_motor": "kg",
    "m_rod": "kg",
    "m_foot": "kg",
    "k_spring": "N/m",
    "c_spring": "N s/m",
    "foot_radius": "m",
    "grain_density": "kg/m^3",
    "amplitude_mm": "mm",
}

#: Half-width of a calibration prior's support, in standard deviations.
CALIBRATION_HALF_WIDTH = 6.0


def calibration_priors(nominal: Mapping[str, float], sd: Mapping[str, float]) -> dict[str, Prior]:
    """The calibration of robot parameters as priors: Normal(nominal, sd).

    Each parameter with a standard deviation > 0 gets a normal prior centred on its
    nominal value, truncated to ``nominal +/- 6 sd`` (and to positive values: every robot
    parameter is); a parameter whose standard deviation is 0 is known exactly and gets
    none.

    Parameters
    ----------
    nominal : mapping of str to float
        The values the robot was built or calibrated to (``experiment.toml``'s
        ``[robot]``, and ``amplitude_mm`` of ``[command]``) [their units].
    sd : mapping of str to float
        One standard deviation of each calibration (``[robot.uncertainty]``), same units.

    Returns
    -------
    dict of str to Prior

    Raises
    ------
    ValueError
        If a parameter has no nominal value or is not one a calibration can leave uncertain
        (:data:`CALIBRATION_UNITS`), or a standard deviation is negative or not finite.
    """
    out: dict[str, Prior] = {}
    for name, s in sd.items():
        if name not in CALIBRATION_UNITS:
            raise ValueError(
                f"{name!r} is not a robot parameter a fit can sample; allowed: "
                f"{', '.join(CALIBRATION_UNITS)}"
            )
        if not (math.isfinite(s) and s >= 0.0):
            raise ValueError(f"the calibration sd of {name!r} must be finite and >= 0, got {s}")
        if s == 0.0:
            continue
        if name not in nominal:
            raise ValueError(f"no nominal value of {name!r}")
        mu = float(nominal[name])
        lower = max(mu - CALIBRATION_HALF_WIDTH * s, 1e-3 * mu)
        out[name] = Prior(
            "normal",
            lower,
            mu + CALIBRATION_HALF_WIDTH * s,
            mu=mu,
            sigma=float(s),
            unit=CALIBRATION_UNITS[name],
            why="the lab's calibration: nominal value +/- its standard deviation",
        )
    return out


def _registry_prior(param: Parameter) -> Prior:
    """The default prior of a force-term parameter, from its registry entry.

    Parameters
    ----------
    param : granbayes.forces.Parameter
        A registered parameter; its ``prior`` gives the family, bounds and reason, its
        ``unit`` the unit.

    Returns
    -------
    Prior
    """
    d = param.prior
    return Prior(d.dist, d.lower, d.upper, mu=d.mu, sigma=d.sigma, unit=param.unit, why=d.why)


def load_priors(path: str | Path, base: Mapping[str, Prior] | None = None) -> dict[str, Prior]:
    """Read prior overrides from a TOML file (one table per parameter; no code executed).

    Parameters
    ----------
    path : str or Path
        TOML file.
    base : mapping, optional
        Priors to override (default: :func:`default_priors`).

    Returns
    -------
    dict of str to Prior
    """
    path = Path(path)
    priors = dict(base if base is not None else default_priors())
    try:
        doc = tomllib.loads(path.read_text(encoding="utf-8"))
    except FileNotFoundError:
        raise InputError("no such file", file=path) from None
    except tomllib.TOMLDecodeError as exc:
        raise InputError(f"malformed TOML: {exc}", file=path) from None
    for name, table in doc.items():
        if name not in priors:
            raise InputError(
                f"unknown parameter; expected one of {', '.join(priors)}", file=path, column=name
            )
        if not isinstance(table, dict):
            raise InputError("expected a table like [k] dist=...", file=path, column=name)
        allowed = {"dist", "lower", "upper", "mu", "sigma"}
        for key, value in table.items():
            if key not in allowed:
                raise InputError(
                    f"unknown key; expected one of {sorted(allowed)}",
                    file=path,
                    column=f"{name}.{key}",
                )
            if key == "dist":
                ok = isinstance(value, str)
            else:
                ok = isinstance(value, int | float) and not isinstance(value, bool)
            if not ok:
                raise InputError(
                    "expected a string" if key == "dist" else "expected a number",
                    file=path,
                    column=f"{name}.{key}",
                )
        try:
            priors[name] = replace(
                priors[name],
                **{k: (v if k == "dist" else float(v)) for k, v in table.items()},
            )
        except ValueError as exc:
            raise InputError(str(exc), file=path, column=name) from None
        problem = _outside_allowed(name, priors[name])
        if problem:
            raise InputError(problem, file=path, column=name)
    return priors


def _outside_allowed(name: str, prior: Prior) -> str | None:
    """Why a prior's support reaches outside the parameter's allowed values, or None."""
    try:
        allowed = parameter(name)
    except KeyError:
        return None  # a noise parameter: positive by its log-scale family
    for end in ("lower", "upper"):
        problem = allowed.check(getattr(prior, end))
        if problem:
            return f"prior {end} bound outside the allowed values: {problem}"
    return None


def priors_toml(
    priors: Mapping[str, Prior] | None = None, names: Sequence[str] | None = None
) -> str:
    """Priors as TOML that :func:`load_priors` reads back, each with its reason as a comment.

    Parameters
    ----------
    priors : mapping of str to Prior, optional
        The priors (default: :func:`default_priors`).
    names : sequence of str, optional
        Parameters to write, in order (default: all of ``priors``).

    Returns
    -------
    str
        One table per parameter (``[k]`` with ``dist``, ``lower``, ``upper`` and, for the
        normal families, ``mu`` and ``sigma``), preceded by a comment with its unit and
        motivation.
    """
    priors = dict(priors if priors is not None else default_priors())
    names = list(priors) if names is None else list(names)
    lines = [
        "# granbayes priors: one table per parameter (granbayes fit --priors FILE).",
        '# dist = "uniform" | "loguniform" | "normal" | "lognormal"; lower and upper are hard',
        "# bounds in the parameter's units; normal and lognormal also take mu and sigma (for",
        "# lognormal: of log(value)). Parameters left out keep their defaults.",
    ]
    for name in names:
        prior = priors[name]
        lines += ["", f"# {name} [{prior.unit or '-'}]: {prior.why}".rstrip(": ")]
        lines += [f"[{name}]", f'dist = "{prior.dist}"']
        lines += [f"lower = {float(prior.lower)!r}", f"upper = {float(prior.upper)!r}"]
        if prior.mu is not None:
            lines += [f"mu = {float(prior.mu)!r}", f"sigma = {float(prior.sigma)!r}"]
    return "\n".join(lines) + "\n"
