"""The registry of named ground-force terms, and force laws built from them.

A *term* is a named piece of physics with its parameters (physics-model.md section 3). A
*force law* is a set of terms with parameter values. Terms that are not in a law take
their ``absent`` value, which switches them off (or, for ``unloading``, sets the bed's
default plasticity).

Every fact about a term lives in its :class:`ForceTerm` entry of ``TERMS``: for each of
its parameters the unit, the hard bounds, the realistic range, the "off" value, the
default prior with its reason (:class:`DefaultPrior`) and the label of reports and
figures. The rest of the package reads them from here and keeps no table of its own: the
integrator's parameter vector, the CLI, the default priors (``granbayes priors``,
docs/priors.md) and the checks of prior files, the batch-table columns and their allowed
values, the labels of reports and figures, the units of the posterior's variables, the
model-criticism candidates, and the energy-identity box of the tests.

Adding a term
-------------
1. Add a :class:`ForceTerm` to ``TERMS`` below, with a :class:`Parameter` per parameter
   (unit, off value, bounds, realistic range, label, default prior and its reason).
2. Use its parameters in ``granbayes/_kernel.py``, in the block marked
   ``GROUND MODEL`` (the integrator itself is not touched).

Nothing else in the package needs an edit (``tests/test_registry.py`` registers a
throwaway term and checks that every consumer picks it up). The tests then ask for the
term's physics once more, in the independent scipy oracle (``granbayes/testing/_oracle.py``),
against which the kernel block is checked.
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Mapping
from dataclasses import dataclass, field

import numpy as np

__all__ = [
    "PARAMETERS",
    "PARAMETER_NAMES",
    "TERMS",
    "DefaultPrior",
    "ForceLaw",
    "ForceTerm",
    "Parameter",
    "parameter",
    "parameter_term",
    "parameter_vector",
    "registered_parameters",
    "terms_of",
    "typical_ranges",
]


@dataclass(frozen=True)
class DefaultPrior:
    """The default prior of a parameter, with its reason (:class:`granbayes.Prior`).

    Parameters
    ----------
    dist : {"uniform", "loguniform", "normal", "lognormal"}
        Family; normal and lognormal are truncated to ``[lower, upper]``.
    lower, upper : float
        Bounds, in the parameter's unit.
    why : str
        The physical motivation, shown in reports, ``granbayes priors`` and docs/priors.md.
    mu, sigma : float, optional
        Location and scale (of ``log(value)`` for lognormal).
    """

    dist: str
    lower: float
    upper: float
    why: str
    mu: float | None = None
    sigma: float | None = None


@dataclass(frozen=True)
class Parameter:
    """A force-term parameter and everything the package needs to know about it.

    Parameters
    ----------
    name : str
        Name used in files, on the command line and in posteriors.
    unit : str
        SI unit (ASCII, e.g. ``"N/m^2"``; ``"-"`` for a dimensionless parameter).
    description : str
        One line of physics (the ``long_name`` of the posterior variable).
    absent : float or None
        Value used when the term is not part of a law, in ``unit`` (``None``: the term is
        required).
    lower, upper : float
        Hard physical bounds, in ``unit`` (``lower`` inclusive unless ``lower_open``).
    typical : tuple of float
        Realistic range for poppy seeds and a lab robot, in ``unit`` (benchmarks,
        property tests, the energy-identity box).
    lower_open : bool
        Whether ``lower`` itself is excluded.
    label : str
        Axis and table label of reports and figures: symbol and unit, e.g. ``"k2 [N/m²]"``.
    prior : DefaultPrior
        Default prior of fits, with its reason (bounds in ``unit``).
    """

    name: str
    unit: str
    description: str
    absent: float | None
    lower: float
    upper: float
    typical: tuple[float, float]
    lower_open: bool = False
    label: str = field(kw_only=True)
    prior: DefaultPrior = field(kw_only=True)

    def check(self, value: float) -> str | None:
        """Return a message if ``value`` is not allowed, else ``None``.

        Parameters
        ----------
        value : float
            Candidate value [the parameter's unit].

        Returns
        -------
        str or None
        """
        if not math.isfinite(value):
            return f"{self.name} must be finite, got {value!r}"
        if value < self.lower or (self.lower_open and value == self.lower):
            op = ">" if self.lower_open else ">="
            return f"{self.name} must be {op} {self.lower:g} [{self.unit}], got {value:g}"
        if value > self.upper:
            return f"{self.name} must be <= {self.upper:g} [{self.unit}], got {value:g}"
        return None


@dataclass(frozen=True)
class ForceTerm:
    """A named ground-force term.

    Parameters
    ----------
    name : str
        Term name (physics-model.md section 3).
    formula : str
        The force it adds, in words and symbols.
    parameters : tuple of Parameter
        Its parameters.
    required : bool
        Whether every law must contain it.
    """

    name: str
    formula: str
    parameters: tuple[Parameter, ...]
    required: bool = False


TERMS: dict[str, ForceTerm] = {
    t.name: t
    for t in (
        ForceTerm(
            "depth",
            "k z while advancing; sets the bed's static strength F_static = k z + k2 z^2",
            (
                Parameter(
                    "k",
                    "N/m",
                    "depth stiffness",
                    absent=None,
                    lower=0.0,
                    upper=1e9,
                    typical=(1e3, 1e4),
                    lower_open=True,
                    label="k [N/m]",
                    prior=DefaultPrior(
                        "loguniform",
                        200.0,
                        5e4,
                        why="poppy seeds under a 3.5 cm foot: 1e3-1e4 N/m, two decades of room",
                    ),
                ),
            ),
            required=True,
        ),
        ForceTerm(
            "drag",
            "c_d z'^2 while advancing (velocity-squared drag)",
            (
                Parameter(
                    "c_d",
                    "kg/m",
                    "quadratic drag coefficient",
                    absent=0.0,
                    lower=0.0,
                    upper=1e6,
                    typical=(0, 100),
                    label="c_d [kg/m]",
                    prior=DefaultPrior(
                        "uniform",
                        0.0,
                        300.0,
                        why="rho_grain * foot area ~ 4 kg/m per unit drag coefficient; generous",
                    ),
                ),
            ),
        ),
        ForceTerm(
            "added_mass",
            "jammed cone kappa rho phi V(d) carried while advancing, with its momentum flux",
            (
                Parameter(
                    "kappa",
                    "-",
                    "fraction of the full cone",
                    absent=0.0,
                    lower=0.0,
                    upper=100.0,
                    typical=(0, 2),
                    label="κ [-]",
                    prior=DefaultPrior("uniform", 0.0, 3.0, why="0: no cone; 1: full jammed cone"),
                ),
            ),
        ),
        ForceTerm(
            "stiffening",
            "k2 z^2 while advancing (depth-dependent stiffness)",
            (
                Parameter(
                    "k2",
                    "N/m^2",
                    "quadratic stiffness",
                    absent=0.0,
                    lower=0.0,
                    upper=1e12,
                    typical=(0, 2e5),
                    label="k2 [N/m²]",
                    prior=DefaultPrior(
                        "uniform",
                        0.0,
                        1e6,
                        why="stiffening that at most doubles k within ~5 cm of depth",
                    ),
                ),
            ),
        ),
        ForceTerm(
            "viscous",
            "b z' while advancing (linear rate dependence)",
            (
                Parameter(
                    "b",
                    "N s/m",
                    "viscous coefficient",
                    absent=0.0,
                    lower=0.0,
                    upper=1e6,
                    typical=(0, 50),
                    label="b [N s/m]",
                    prior=DefaultPrior(
                        "uniform",
                        0.0,
                        200.0,
                        why="linear damping up to a critically damped foot on the bed",
                    ),
                ),
            ),
        ),
        ForceTerm(
            "compaction",
            "loading stiffness below the crater times 1 + c_comp (1 - exp(-z_c / l_c)) once an "
            "intrusion to depth z_c has ended: a loose bed compacted by intrusion",
            (
                Parameter(
                    "c_comp",
                    "-",
                    "fractional stiffening of a fully compacted bed (intrusion >> l_c = 1 mm)",
                    absent=0.0,
                    lower=0.0,
                    upper=100.0,
                    typical=(0, 2),
                    label="c_comp [-]",
                    prior=DefaultPrior(
                        "uniform",
                        0.0,
                        3.0,
                        why="a fully compacted loose bed is at most 4x stiffer below its crater",
                    ),
                ),
            ),
        ),
        ForceTerm(
            "unloading",
            "elastic unloading line of slope r_unload F_yield'(z_max) from the last yield point",
            (
                Parameter(
                    "r_unload",
                    "-",
                    "unloading/loading stiffness ratio (>= 1: the bed never creates energy)",
                    absent=20.0,
                    lower=1.0,
                    upper=1e6,
                    typical=(1, 50),
                    label="r_unload [-]",
                    prior=DefaultPrior(
                        "loguniform",
                        1.0,
                        200.0,
                        why="1: elastic bed; >>1: plastic bed that keeps its crater",
                    ),
                ),
            ),
        ),
    )
}

#: Every parameter of the library, in the order of the integrator's parameter vector: the
#: terms registered when the package was imported (the compiled kernel's row layout,
#: ``granbayes._kernel.ROW_FIELDS``, is built from it). Code that must also see a term
#: registered later, at run time, calls :func:`registered_parameters` instead.
PARAMETERS: tuple[Parameter, ...] = tuple(p for t in TERMS.values() for p in t.parameters)
PARAMETER_NAMES: tuple[str, ...] = tuple(p.name for p in PARAMETERS)


def registered_parameters() -> tuple[Parameter, ...]:
    """Every parameter of the terms in ``TERMS`` now, in library order.

    Read from the registry at each call, so that a term registered at run time (tests)
    is seen; equal to :data:`PARAMETERS` otherwise.

    Returns
    -------
    tuple of Parameter
    """
    return tuple(p for t in TERMS.values() for p in t.parameters)


def parameter(name: str) -> Parameter:
    """The registered parameter called ``name``.

    Parameters
    ----------
    name : str
        Parameter name, e.g. ``"k"``.

    Returns
    -------
    Parameter

    Raises
    ------
    KeyError
        If no registered term has a parameter of that name.
    """
    return _lookup(name)[1]


def parameter_term(name: str) -> str:
    """Name of the term that owns parameter ``name`` (``KeyError`` if none does).

    Parameters
    ----------
    name : str
        Parameter name.

    Returns
    -------
    str
    """
    return _lookup(name)[0]


def _lookup(name: str) -> tuple[str, Parameter]:
    """The term name and the parameter called ``name``, searched in ``TERMS`` now."""
    for term in TERMS.values():
        for p in term.parameters:
            if p.name == name:
                return term.name, p
    known = ", ".join(p.name for p in registered_parameters())
    raise KeyError(f"unknown force parameter {name!r}; expected one of {known}")


@dataclass(frozen=True)
class ForceLaw:
    """A set of force terms with parameter values.

    Parameters
    ----------
    terms : tuple of str
        Term names; ``depth`` is always included.
    values : mapping of str to float
        Values of the parameters of ``terms`` [SI].

    Examples
    --------
    >>> law = ForceLaw.from_params({"k": 3000.0, "c_d": 50.0})
    >>> law.terms
    ('depth', 'drag')
    >>> law.vector()
    array([3000.,   50.,    0.,    0.,    0.,    0.,   20.])
    """

    terms: tuple[str, ...]
    values: Mapping[str, float] = field(default_factory=dict)

    def __post_init__(self) -> None:
        """Put the terms in canonical order and check the values."""
        ordered = terms_of(self.terms)
        object.__setattr__(self, "terms", ordered)
        for name, value in self.values.items():
            term = parameter_term(name)
            if term not in ordered:
                raise ValueError(f"parameter {name!r} belongs to term {term!r}, not in the law")
            msg = parameter(name).check(float(value))
            if msg:
                raise ValueError(msg)
        missing = [p.name for p in self.parameters if p.name not in self.values]
        if missing:
            raise ValueError(f"missing value(s) for {missing} of terms {list(ordered)}")

    @classmethod
    def from_params(cls, values: Mapping[str, float]) -> ForceLaw:
        """Law whose terms are those owning the given parameters (plus ``depth``)."""
        terms = tuple(dict.fromkeys(parameter_term(n) for n in values))
        return cls(terms, {n: float(v) for n, v in values.items()})

    @property
    def parameters(self) -> tuple[Parameter, ...]:
        """Parameters of the law's terms, in library order."""
        return tuple(p for t in self.terms for p in TERMS[t].parameters)

    def vector(self) -> np.ndarray:
        """Full library parameter vector (absent terms at their ``absent`` value)."""
        return parameter_vector(self.values)


def parameter_vector(values: Mapping[str, float]) -> np.ndarray:
    """Library-ordered parameter vector, absent parameters at their ``absent`` value.

    Parameters
    ----------
    values : mapping of str to float
        Parameter values [SI]; must include every required parameter.

    Returns
    -------
    ndarray, shape (len(PARAMETER_NAMES),)
    """
    out = np.empty(len(PARAMETERS))
    for i, p in enumerate(PARAMETERS):
        if p.name in values:
            out[i] = float(values[p.name])
        elif p.absent is None:
            raise ValueError(f"parameter {p.name!r} ({p.description}) is required")
        else:
            out[i] = p.absent
    return out


def typical_ranges(names: Iterable[str] | None = None) -> dict[str, tuple[float, float]]:
    """Realistic ranges [SI] of parameters (all of the library by default).

    The ranges used by benchmarks and property tests: poppy seeds and a lab robot.

    Parameters
    ----------
    names : iterable of str, optional
        Parameters (default: every one of the library).

    Returns
    -------
    dict of str to (float, float)
        Low and high value [SI] per parameter.
    """
    if names is None:
        return {p.name: p.typical for p in registered_parameters()}
    return {n: parameter(n).typical for n in names}


def terms_of(names: Iterable[str]) -> tuple[str, ...]:
    """Validate term names and return them in library order (``depth`` always included).

    Parameters
    ----------
    names : iterable of str
        Term names, e.g. ``["drag", "depth"]``.

    Returns
    -------
    tuple of str
    """
    names = list(names)
    unknown = [t for t in names if t not in TERMS]
    if unknown:
        raise ValueError(f"unknown force term(s) {unknown}; expected some of {', '.join(TERMS)}")
    return tuple(t for t in TERMS if t in names or TERMS[t].required)
