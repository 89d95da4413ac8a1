"""The library of named ground-force terms and force laws built from them.

A *term* is a named piece of physics with its parameters (physics-model.md section 3). A
*force law* is a set of terms with parameter values. Terms that are not in a law take
their ``absent`` value, which switches them off (or, for ``unloading``, sets the bed's
default plasticity).

Adding a term
-------------
1. Add a :class:`ForceTerm` to ``TERMS`` below (its parameters, units, realistic range).
2. Use its parameters in ``granbayes/_kernel.py``, in the block marked
   ``GROUND MODEL`` (the integrator itself is not touched).
The parameter vector, the CLI, the priors and the model-criticism candidates all read
this registry.
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
    "ForceLaw",
    "ForceTerm",
    "Parameter",
    "parameter_term",
    "parameter_vector",
    "terms_of",
    "typical_ranges",
]


@dataclass(frozen=True)
class Parameter:
    """A force-term parameter.

    Parameters
    ----------
    name : str
        Name used in files, on the command line and in posteriors.
    unit : str
        SI unit.
    description : str
        One line of physics.
    absent : float or None
        Value used when the term is not part of a law (``None``: the term is required).
    lower, upper : float
        Hard physical bounds (``lower`` inclusive unless ``lower_open``).
    typical : tuple of float
        Realistic range for poppy seeds and a lab robot (benchmarks, default priors).
    lower_open : bool
        Whether ``lower`` itself is excluded.
    """

    name: str
    unit: str
    description: str
    absent: float | None
    lower: float
    upper: float
    typical: tuple[float, float]
    lower_open: bool = False

    def check(self, value: float) -> str | None:
        """Return a message if ``value`` is not allowed, else ``None``."""
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
            (Parameter("k", "N/m", "depth stiffness", None, 0.0, 1e9, (1e3, 1e4), True),),
            required=True,
        ),
        ForceTerm(
            "drag",
            "c_d z'^2 while advancing (velocity-squared drag)",
            (Parameter("c_d", "kg/m", "quadratic drag coefficient", 0.0, 0.0, 1e6, (0, 100)),),
        ),
        ForceTerm(
            "added_mass",
            "jammed cone kappa rho phi V(d) carried while advancing, with its momentum flux",
            (Parameter("kappa", "-", "fraction of the full cone", 0.0, 0.0, 100.0, (0, 2)),),
        ),
        ForceTerm(
            "stiffening",
            "k2 z^2 while advancing (depth-dependent stiffness)",
            (Parameter("k2", "N/m^2", "quadratic stiffness", 0.0, 0.0, 1e12, (0, 2e5)),),
        ),
        ForceTerm(
            "viscous",
            "b z' while advancing (linear rate dependence)",
            (Parameter("b", "N s/m", "viscous coefficient", 0.0, 0.0, 1e6, (0, 50)),),
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
                    0.0,
                    0.0,
                    100.0,
                    (0, 2),
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
                    20.0,
                    1.0,
                    1e6,
                    (1, 50),
                ),
            ),
        ),
    )
}

#: Every parameter of the library, in the order of the integrator's parameter vector.
PARAMETERS: tuple[Parameter, ...] = tuple(p for t in TERMS.values() for p in t.parameters)
PARAMETER_NAMES: tuple[str, ...] = tuple(p.name for p in PARAMETERS)
_BY_NAME: dict[str, Parameter] = {p.name: p for p in PARAMETERS}
_TERM_OF: dict[str, str] = {p.name: t.name for t in TERMS.values() for p in t.parameters}


def parameter_term(name: str) -> str:
    """Name of the term that owns parameter ``name``."""
    try:
        return _TERM_OF[name]
    except KeyError:
        raise KeyError(
            f"unknown force parameter {name!r}; expected one of {', '.join(PARAMETER_NAMES)}"
        ) from None


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
        ordered = terms_of(self.terms)
        object.__setattr__(self, "terms", ordered)
        for name, value in self.values.items():
            term = parameter_term(name)
            if term not in ordered:
                raise ValueError(f"parameter {name!r} belongs to term {term!r}, not in the law")
            msg = _BY_NAME[name].check(float(value))
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
    """
    wanted = PARAMETER_NAMES if names is None else tuple(names)
    return {n: _BY_NAME[n].typical for n in wanted}


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
