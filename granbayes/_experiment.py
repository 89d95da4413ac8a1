"""The experiment: the robot, the command settings and the bed, as loaded from a folder.

An experiment folder (``shared/data-format.md``) holds ``experiment.toml`` (robot, command
settings, bed) and ``jumps.csv`` (one measured jump per row). Every TOML key is optional and
defaults to the representative values of the physics model (``docs/physics-model.md``).

This module is the first step of the data flow: it only reads and validates. It knows
nothing about simulation or inference.
"""

from __future__ import annotations

import dataclasses
import math
import re
import tomllib
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path

from ._errors import InputError
from ._tables import (
    _FRACTION,
    _NON_NEGATIVE,
    _POSITIVE,
    _Range,
    _range_problem,
    _read_text,
    _suggest,
)
from .commands import CommandSettings

__all__ = [
    "Experiment",
    "G",
    "Robot",
    "load_experiment",
]

#: Gravitational acceleration [m/s^2].
G = 9.81


@dataclass(frozen=True)
class Robot:
    """The jumping robot (all SI).

    Parameters
    ----------
    m_motor : float
        Actuator (forcer) mass [kg]; moves along the thrust rod.
    m_rod : float
        Thrust rod and everything rigid above the spring [kg].
    m_foot : float
        Foot plate below the spring [kg].
    k_spring : float
        Leg spring stiffness [N/m].
    c_spring : float
        Leg spring damping [N s/m].
    foot_radius : float
        Radius of the circular foot [m].
    grain_density : float
        Density of one grain [kg/m^3].
    """

    m_motor: float = 1.0
    m_rod: float = 0.2
    m_foot: float = 0.1
    k_spring: float = 5760.0
    c_spring: float = 5.0
    foot_radius: float = 0.035
    grain_density: float = 1100.0

    @property
    def m_upper(self) -> float:
        """Rod plus motor mass ``M`` [kg]."""
        return self.m_motor + self.m_rod

    @property
    def f0_hz(self) -> float:
        """Resonant frequency ``sqrt(k_spring / M) / (2 pi)`` of the leg [Hz]."""
        return math.sqrt(self.k_spring / self.m_upper) / (2.0 * math.pi)


@dataclass(frozen=True)
class Experiment:
    """A robot, its command settings and the bed's critical packing.

    Parameters
    ----------
    robot : Robot
        The robot.
    command : CommandSettings
        Default command settings (``jumps.csv`` rows may override them).
    phi_c : float
        Critical packing fraction of the bed [-].
    source : str, optional
        Where the experiment was loaded from (for messages and provenance).
    calibration_sd : tuple of (str, float)
        ``[robot.uncertainty]``: one standard deviation of the lab's calibration per robot
        or command parameter, in the units of its key (a parameter without one is known
        exactly); as pairs, so that the experiment stays hashable (:attr:`uncertainty`
        gives the mapping).
    phi_sd : float
        ``[bed] phi_sd``: standard deviation of a prepared bed's true volume fraction about
        its measured one [-] (0: exact).
    """

    robot: Robot = field(default_factory=Robot)
    command: CommandSettings = field(default_factory=CommandSettings)
    phi_c: float = 0.612
    source: str | None = None
    calibration_sd: tuple[tuple[str, float], ...] = ()
    phi_sd: float = 0.0

    @property
    def uncertainty(self) -> dict[str, float]:
        """``[robot.uncertainty]`` as a mapping: key to standard deviation."""
        return dict(self.calibration_sd)

    @property
    def robot_values(self) -> dict[str, float]:
        """The robot's parameters and its stroke ``amplitude_mm`` [TOML units].

        The values a calibration may leave uncertain (``[robot.uncertainty]``), by key.
        """
        return {**dataclasses.asdict(self.robot), "amplitude_mm": self.command.amplitude_mm}

    @property
    def uncertain(self) -> bool:
        """Whether the experiment states calibration or packing uncertainties."""
        return bool(self.uncertainty) or self.phi_sd > 0.0

    def replace(self, **changes: float) -> Experiment:
        """Return a copy with robot or command fields replaced by keyword.

        Parameters
        ----------
        **changes
            Field names of :class:`Robot` or :class:`CommandSettings`, or ``phi_c``.

        Returns
        -------
        Experiment
        """
        robot_keys = {f.name for f in dataclasses.fields(Robot)}
        command_keys = {f.name for f in dataclasses.fields(CommandSettings)}
        unknown = set(changes) - robot_keys - command_keys - {"phi_c", "phi_sd"}
        if unknown:
            raise KeyError(f"unknown experiment key(s): {sorted(unknown)}")
        robot = dataclasses.replace(
            self.robot, **{k: v for k, v in changes.items() if k in robot_keys}
        )
        command = dataclasses.replace(
            self.command, **{k: v for k, v in changes.items() if k in command_keys}
        )
        phi_c = changes.get("phi_c", self.phi_c)
        return Experiment(
            robot=robot,
            command=command,
            phi_c=phi_c,
            source=self.source,
            calibration_sd=self.calibration_sd,
            phi_sd=changes.get("phi_sd", self.phi_sd),
        )


# --------------------------------------------------------------------------------------
# Allowed ranges of the numeric inputs
# --------------------------------------------------------------------------------------


#: ``[robot]`` keys and their ranges (same names and order as :class:`Robot`).
_ROBOT_RANGES: dict[str, _Range] = {
    "m_motor": _POSITIVE,
    "m_rod": _POSITIVE,
    "m_foot": _POSITIVE,
    "k_spring": _POSITIVE,
    "c_spring": _NON_NEGATIVE,
    "foot_radius": _POSITIVE,
    "grain_density": _POSITIVE,
}

#: ``[command]`` keys and their ranges (same names and order as :class:`CommandSettings`).
_COMMAND_RANGES: dict[str, _Range] = {
    "amplitude_mm": _POSITIVE,
    "freq_hz": _POSITIVE,
    "delay_ms": _NON_NEGATIVE,
    "settle_periods": _NON_NEGATIVE,
}

#: The sections of ``experiment.toml`` and the keys each one allows.
_TOML_SECTIONS: dict[str, dict[str, _Range]] = {
    "robot": _ROBOT_RANGES,
    "command": _COMMAND_RANGES,
    "bed": {"phi_c": _FRACTION, "phi_sd": _NON_NEGATIVE},
}


# --------------------------------------------------------------------------------------
# Value checks shared by the TOML and CSV loaders
# --------------------------------------------------------------------------------------


# --------------------------------------------------------------------------------------
# The same checks for whole columns: masks of the cells to look at, in bulk
# --------------------------------------------------------------------------------------
#
# The per-cell functions above are the rules. A column is checked in bulk (numpy, and
# iteration in C over builtins such as ``float`` and ``str.strip``: no Python code runs per
# cell), which finds the cells that may break a rule; only those go through the per-cell
# rules, which write the message. A mask may flag more cells than the rules refuse (the
# rules decide), never fewer.


# --------------------------------------------------------------------------------------
# Reading files
# --------------------------------------------------------------------------------------


# --------------------------------------------------------------------------------------
# experiment.toml
# --------------------------------------------------------------------------------------

#: One part of a TOML key: bare, "basic" or 'literal'.
_TOML_KEY_PART = r"""(?:[A-Za-z0-9_-]+|"[^"]*"|'[^']*')"""
_TOML_TABLE_HEADER = re.compile(rf"\[\[?\s*({_TOML_KEY_PART}(?:\s*\.\s*{_TOML_KEY_PART})*)\s*\]")
_TOML_KEY = re.compile(rf"({_TOML_KEY_PART}(?:\s*\.\s*{_TOML_KEY_PART})*)\s*=")


def _toml_key_path(dotted: str) -> list[str]:
    """Split a dotted TOML key (parts possibly quoted) into its parts."""
    return [part.strip("\"'") for part in re.findall(_TOML_KEY_PART, dotted)]


def _toml_line(text: str, section: str, key: str | None) -> int | None:
    """Find the line that defines ``section.key`` (or the section itself), best effort.

    ``tomllib`` does not report where a key was defined; this scan recognises table
    headers (``[robot]``, ``[[robot]]``) and plain and dotted keys (``robot.m_motor = 1``),
    and falls back to the line of the section when the key is in an inline table.

    Parameters
    ----------
    text : str
        The TOML document (already known to be valid).
    section : str
        Top-level table name.
    key : str or None
        Key inside the section, or None for the section itself.

    Returns
    -------
    int or None
        1-based line number, or None if not found.
    """
    current: list[str] = []
    section_line = None
    for number, raw in enumerate(text.splitlines(), start=1):
        line = raw.strip()
        header = _TOML_TABLE_HEADER.match(line)
        if header:
            current = _toml_key_path(header.group(1))
            if current[:1] == [section] and section_line is None:
                section_line = number
            if key is None and current == [section]:
                return number
            continue
        match = _TOML_KEY.match(line)
        if not match:
            continue
        full = current + _toml_key_path(match.group(1))
        if full[:1] == [section] and section_line is None:
            section_line = number
        if key is not None and full[:2] == [section, key]:
            return number
    return section_line


def _toml_type_name(value: object) -> str:
    """Name a TOML value's type for messages."""
    if isinstance(value, bool):
        return "a boolean"
    if isinstance(value, str):
        return "a string"
    if isinstance(value, list):
        return "an array"
    if isinstance(value, dict):
        return "a table"
    return "a date/time"


def _toml_entry(section: str, key: str | None, raw: object) -> tuple[float, str | None]:
    """Check one top-level entry (``key`` None) or one key of a section.

    Returns
    -------
    value : float
        The key's value as a float (NaN for a top-level entry or a bad value).
    problem : str or None
        What is wrong, or None.
    """
    if key is None:
        if section not in _TOML_SECTIONS:
            sections = ", ".join(f"[{name}]" for name in _TOML_SECTIONS)
            hint = _suggest(section, _TOML_SECTIONS)
            return math.nan, (
                f"unknown section or top-level key '{section}'{hint}; allowed sections: {sections}"
            )
        if not isinstance(raw, dict):
            return math.nan, f"expected a table [{section}], got {_toml_type_name(raw)}"
        return math.nan, None
    allowed = _TOML_SECTIONS[section]
    if key not in allowed:
        hint = _suggest(key, allowed)
        return math.nan, (
            f"unknown key '{key}' in [{section}]{hint}; allowed keys: {', '.join(allowed)}"
        )
    if isinstance(raw, bool) or not isinstance(raw, int | float):
        shown = str(raw).lower() if isinstance(raw, bool) else repr(raw)
        return math.nan, f"expected a number, got {_toml_type_name(raw)} ({shown})"
    try:
        value = float(raw)
    except OverflowError:  # an integer beyond the float range
        value = math.inf
    return value, _range_problem(value, allowed[key], repr(raw))


def _toml_values(
    data: Mapping[str, object], text: str, file: Path
) -> tuple[dict[str, float], dict[str, float]]:
    """Validate a parsed ``experiment.toml`` and flatten it to ``Experiment.replace`` keys.

    Parameters
    ----------
    data : Mapping
        Result of :func:`tomllib.loads`.
    text : str
        The document, to locate offending lines.
    file : Path
        The file, for messages.

    Returns
    -------
    values : dict of str to float
        Key (without section) to value, in the document's units.
    uncertainty : dict of str to float
        ``[robot.uncertainty]``: key to standard deviation.

    Raises
    ------
    InputError
        At the first unknown section or key, wrong type or out-of-range value; ``column``
        is ``section.key`` (or the section) and ``row`` its line if it can be found.
    """
    values: dict[str, float] = {}
    uncertainty: dict[str, float] = {}
    for section, table in data.items():
        entries: list[tuple[str | None, object]] = [(None, table)]
        if isinstance(table, dict):
            entries += list(table.items())
        for key, raw in entries:
            if section == "robot" and key == "uncertainty":
                uncertainty.update(_uncertainty(raw, text, file))
                continue
            value, problem = _toml_entry(section, key, raw)
            if problem is not None:
                raise InputError(
                    problem,
                    file=file,
                    row=_toml_line(text, section, key),
                    column=section if key is None else f"{section}.{key}",
                )
            if key is not None:
                values[key] = value
    return values, uncertainty


def _uncertainty(raw: object, text: str, file: Path) -> dict[str, float]:
    """Validate ``[robot.uncertainty]``: robot or command keys, sds finite and >= 0."""
    allowed = {**_ROBOT_RANGES, **_COMMAND_RANGES}
    if not isinstance(raw, dict):
        raise InputError(
            f"expected a table [robot.uncertainty], got {_toml_type_name(raw)}",
            file=file,
            row=_toml_line(text, "robot", "uncertainty"),
            column="robot.uncertainty",
        )
    out = {}
    for key, value in raw.items():
        problem = None
        if key not in allowed:
            problem = (
                f"unknown key '{key}' in [robot.uncertainty]{_suggest(key, allowed)}; allowed "
                f"keys: {', '.join(allowed)}"
            )
        elif isinstance(value, bool) or not isinstance(value, int | float):
            problem = f"expected a number, got {_toml_type_name(value)} ({value!r})"
        elif not (math.isfinite(float(value)) and float(value) >= 0.0):
            problem = f"a standard deviation must be finite and >= 0, got {value!r}"
        if problem is not None:
            raise InputError(
                problem,
                file=file,
                row=_toml_line(text, "robot.uncertainty", key),
                column=f"robot.uncertainty.{key}",
            )
        out[key] = float(value)
    return out


def load_experiment(path: str | Path) -> Experiment:
    """Load and validate an experiment's robot, command settings and bed.

    Parameters
    ----------
    path : str or Path
        An experiment folder (``experiment.toml`` inside it is read; a folder without one
        gives all defaults) or a TOML file. Every key is optional; the allowed ones are
        ``[robot]`` ``m_motor``, ``m_rod``, ``m_foot`` [kg], ``k_spring`` [N/m],
        ``c_spring`` [N s/m], ``foot_radius`` [m], ``grain_density`` [kg/m^3];
        ``[command]`` ``amplitude_mm`` [mm], ``freq_hz`` [Hz], ``delay_ms`` [ms],
        ``settle_periods`` [periods]; ``[bed]`` ``phi_c`` [-] and ``phi_sd`` [-];
        ``[robot.uncertainty]`` a standard deviation per robot or command key.

    Returns
    -------
    Experiment
        With ``source`` set to ``str(path)``.

    Raises
    ------
    InputError
        If the path does not exist, the TOML is malformed (``row`` is the line), or a
        section or key is unknown, not a number (booleans are refused), not finite, or out
        of range: masses, ``k_spring``, ``foot_radius``, ``grain_density``,
        ``amplitude_mm`` and ``freq_hz`` must be > 0; ``c_spring``, ``delay_ms`` and
        ``settle_periods`` >= 0; ``phi_c`` in (0, 1). ``column`` is ``section.key``.
    """
    folder_or_file = Path(path)
    if not folder_or_file.exists():
        raise InputError("no such file or folder", file=folder_or_file)
    if folder_or_file.is_dir():
        file = folder_or_file / "experiment.toml"
        if not file.exists():
            return Experiment(source=str(path))
    else:
        file = folder_or_file
    text = _read_text(file)
    try:
        data = tomllib.loads(text)
    except tomllib.TOMLDecodeError as err:
        line = getattr(err, "lineno", None)
        if line is None:
            found = re.search(r"line (\d+)", str(err))
            line = int(found.group(1)) if found else None
        raise InputError(f"malformed TOML: {err}", file=file, row=line) from err
    values, uncertainty = _toml_values(data, text, file)
    return dataclasses.replace(
        Experiment(source=str(path)).replace(**values),
        calibration_sd=tuple(uncertainty.items()),
    )


# --------------------------------------------------------------------------------------
# CSV tables
# --------------------------------------------------------------------------------------
