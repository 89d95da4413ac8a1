"""The registry of jump commands, and their settings.

A *command* is what the actuator does (physics-model.md section 4): a waveform of
segments, a start state and the segment at whose start the jump-height window opens. Every
fact about a command lives in its :class:`Command` entry of :data:`COMMANDS`: its
description, start state, the settings it uses beyond amplitude and frequency (the delay
of the delayed stutter, the hold of the delayed stutter preload) and its waveform. The rest
of the package reads them from here: the loaders' checks of the ``command`` column, the
simulator's programs, the residual cells and their descriptions, the settings searched by
the optimal-jumping analysis, the figures' labels.

Adding a command: one :class:`Command` entry (``tests/test_registry.py`` registers one at
run time and checks that the consumers pick it up). The integrator needs nothing: a
command is data (cosine segments and holds, :class:`CommandProgram`).

The motor position relative to the rod is ``alpha(t)`` (up positive). Within segment ``i``
(from ``t_i`` to ``t_{i+1}``)

    alpha(t) = coef_i * cos(omega (t - t_i)) + offset_i,

so a hold is ``coef = 0``. After the last segment ``alpha`` is held.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass
from typing import Literal

import numpy as np

__all__ = [
    "COMMANDS",
    "COMMAND_NAMES",
    "MAX_SEGMENTS",
    "SETTINGS",
    "START_STATES",
    "Command",
    "CommandProgram",
    "CommandSettings",
    "Segment",
    "build_command",
    "command_names",
]


@dataclass(frozen=True)
class CommandSettings:
    """Actuator settings shared by the jump commands (units as in ``experiment.toml``).

    Parameters
    ----------
    amplitude_mm : float
        Actuator amplitude ``A`` [mm] (half the stroke).
    freq_hz : float
        Actuator frequency [Hz].
    delay_ms : float
        Hold of the ``delayed_stutter`` command [ms].
    settle_periods : float
        Hold of the ``delayed_stutter_preload`` command [periods].
    """

    amplitude_mm: float = 20.0
    freq_hz: float = 10.0
    delay_ms: float = 50.0
    settle_periods: float = 3.0

    @property
    def amplitude(self) -> float:
        """Amplitude [m]."""
        return self.amplitude_mm * 1e-3

    @property
    def period(self) -> float:
        """Period ``1 / freq`` [s]."""
        return 1.0 / self.freq_hz

    @property
    def delay(self) -> float:
        """Delay [s]."""
        return self.delay_ms * 1e-3


#: The command settings, in the order of data tables (``jumps.csv`` columns, residual
#: cells): the fields of :class:`CommandSettings` [units of ``experiment.toml``].
SETTINGS: tuple[str, ...] = ("freq_hz", "amplitude_mm", "delay_ms", "settle_periods")

#: Start states of physics-model.md section 4, in kernel code order.
START_STATES: tuple[str, ...] = ("touching", "settled")


#: Most segments a command may have (the integrator's fixed table size).
MAX_SEGMENTS = 6


@dataclass(frozen=True)
class Segment:
    """One piece of the actuator waveform.

    Parameters
    ----------
    duration : float
        Length of the segment [s].
    coef : float
        Cosine amplitude [m]; ``alpha = coef cos(omega (t - t_start)) + offset``.
    offset : float
        Constant part of ``alpha`` [m].
    """

    duration: float
    coef: float = 0.0
    offset: float = 0.0


@dataclass(frozen=True)
class CommandProgram:
    """A jump command, ready to simulate.

    Parameters
    ----------
    name : str
        Command name.
    omega : float
        Angular frequency ``2 pi freq`` [rad/s].
    segments : tuple of Segment
        The waveform, starting at ``t = 0``.
    start_state : {"touching", "settled"}
        Initial state of robot and bed.
    pushoff_index : int
        Index of the segment at whose start the jump-height window opens.
    """

    name: str
    omega: float
    segments: tuple[Segment, ...]
    start_state: Literal["touching", "settled"] = "touching"
    pushoff_index: int = 0

    def __post_init__(self) -> None:
        """Check the segments and the push-off index."""
        if not 1 <= len(self.segments) <= MAX_SEGMENTS:
            raise ValueError(f"a command has 1 to {MAX_SEGMENTS} segments")
        if self.start_state not in START_STATES:
            raise ValueError(f"start_state must be one of {START_STATES}")
        if not 0 <= self.pushoff_index < len(self.segments):
            raise ValueError("pushoff_index must index a segment")
        if any(not (s.duration >= 0.0 and math.isfinite(s.duration)) for s in self.segments):
            raise ValueError("segment durations must be finite and >= 0")

    @property
    def boundaries(self) -> np.ndarray:
        """Segment start times followed by the command end time [s]."""
        return np.concatenate([[0.0], np.cumsum([s.duration for s in self.segments])])

    @property
    def t_end(self) -> float:
        """Time at which the command ends [s]."""
        return float(self.boundaries[-1])

    @property
    def t_pushoff(self) -> float:
        """Time at which the jump-height window opens [s]."""
        return float(self.boundaries[self.pushoff_index])

    def alpha(self, t: np.ndarray) -> np.ndarray:
        """Actuator position ``alpha(t)`` [m] (held before 0 and after the end).

        Parameters
        ----------
        t : ndarray
            Times [s].

        Returns
        -------
        ndarray
        """
        return self._evaluate(np.asarray(t, dtype=float), derivative=0)

    def alpha_ddot(self, t: np.ndarray) -> np.ndarray:
        """Actuator acceleration ``alpha''(t)`` [m/s^2] (zero outside the segments).

        Parameters
        ----------
        t : ndarray
            Times [s].

        Returns
        -------
        ndarray
        """
        return self._evaluate(np.asarray(t, dtype=float), derivative=2)

    def _evaluate(self, t: np.ndarray, derivative: int) -> np.ndarray:
        bounds = self.boundaries
        out = np.zeros_like(t)
        for i, seg in enumerate(self.segments):
            inside = (t >= bounds[i]) & (t <= bounds[i + 1])
            phase = self.omega * (t[inside] - bounds[i])
            if derivative == 0:
                out[inside] = seg.coef * np.cos(phase) + seg.offset
            else:
                out[inside] = -seg.coef * self.omega**2 * np.cos(phase)
        if derivative == 0:
            first, last = self.segments[0], self.segments[-1]
            out[t < 0] = first.coef + first.offset
            end_phase = self.omega * last.duration
            out[t > bounds[-1]] = last.coef * math.cos(end_phase) + last.offset
        return out

    def as_table(self) -> tuple[np.ndarray, np.ndarray]:
        """Pack for the integrator (computed once per program; do not modify the arrays).

        Returns
        -------
        segments : ndarray, shape (MAX_SEGMENTS, 3)
            Rows ``(t_end [s], coef [m], offset [m])``; unused rows are zero.
        meta : ndarray, shape (4,)
            ``(omega [rad/s], n_segments, start_state code, pushoff_index)``.
        """
        cached = self.__dict__.get("_table")
        if cached is not None:
            return cached
        table = np.zeros((MAX_SEGMENTS, 3))
        bounds = self.boundaries
        for i, seg in enumerate(self.segments):
            table[i] = (bounds[i + 1], seg.coef, seg.offset)
        meta = np.array(
            [
                self.omega,
                len(self.segments),
                START_STATES.index(self.start_state),
                self.pushoff_index,
            ],
            dtype=float,
        )
        table.flags.writeable = False
        meta.flags.writeable = False
        self.__dict__["_table"] = (table, meta)  # frozen dataclass: cache outside __init__
        return table, meta


@dataclass(frozen=True)
class Command:
    """A jump command and everything the package needs to know about it.

    Parameters
    ----------
    name : str
        Name used in files, on the command line and in figures.
    description : str
        The waveform in one line (physics-model.md section 4).
    start_state : {"touching", "settled"}
        Initial state of robot and bed.
    uses : tuple of str
        Settings it uses besides ``freq_hz`` and ``amplitude_mm`` (``delay_ms``,
        ``settle_periods``): the ones that tell its cells apart.
    waveform : callable
        ``waveform(settings) -> (segments, pushoff_index)`` for a :class:`CommandSettings`.
    """

    name: str
    description: str
    start_state: Literal["touching", "settled"]
    uses: tuple[str, ...]
    waveform: Callable[[CommandSettings], tuple[tuple[Segment, ...], int]]

    @property
    def label(self) -> str:
        """The name in words (``"delayed stutter preload"``)."""
        return self.name.replace("_", " ")

    @property
    def settings(self) -> tuple[str, ...]:
        """Every setting it uses (frequency and amplitude first), in :data:`SETTINGS` order."""
        return tuple(s for s in SETTINGS if s in ("freq_hz", "amplitude_mm") or s in self.uses)

    def program(self, settings: CommandSettings | None = None) -> CommandProgram:
        """The command's program with ``settings`` (the model's defaults if omitted).

        Parameters
        ----------
        settings : CommandSettings, optional

        Returns
        -------
        CommandProgram
        """
        s = settings if settings is not None else CommandSettings()
        omega = 2.0 * math.pi * s.freq_hz
        segments, pushoff = self.waveform(s)
        return CommandProgram(self.name, omega, segments, self.start_state, pushoff)


def _push(s: CommandSettings) -> Segment:
    """``-A cos(w t')`` over one period: the push-off of every command."""
    return Segment(s.period, coef=-s.amplitude)


def _single(s: CommandSettings) -> tuple[tuple[Segment, ...], int]:
    return (_push(s),), 0


def _stutter(s: CommandSettings) -> tuple[tuple[Segment, ...], int]:
    # +A cos(w t) over 1.5 periods: countermovement, hop, push-off. It is split at T/2,
    # where the window opens; A cos(w (T/2 + t')) = -A cos(w t').
    return (Segment(0.5 * s.period, coef=s.amplitude), _push(s)), 1


def _delayed(hold: Callable[[CommandSettings], float]):
    def waveform(s: CommandSettings) -> tuple[tuple[Segment, ...], int]:
        countermovement = Segment(0.5 * s.period, coef=s.amplitude)
        return (countermovement, Segment(hold(s), offset=-s.amplitude), _push(s)), 2

    return waveform


COMMANDS: dict[str, Command] = {
    c.name: c
    for c in (
        Command(
            "single",
            "-A cos(w t), 0 <= t <= T (one period, phase 3 pi/2)",
            "touching",
            (),
            _single,
        ),
        Command("preload", "as single, from the settled state", "settled", (), _single),
        Command(
            "stutter",
            "A cos(w t), 0 <= t <= 1.5 T (countermovement, hop, push-off)",
            "touching",
            (),
            _stutter,
        ),
        Command(
            "delayed_stutter",
            "A cos(w t) for t <= T/2; hold -A for delay_ms; then -A cos(w t') for one period",
            "touching",
            ("delay_ms",),
            _delayed(lambda s: s.delay),
        ),
        Command(
            "delayed_stutter_preload",
            "as delayed_stutter, the hold settle_periods periods",
            "touching",
            ("settle_periods",),
            _delayed(lambda s: s.settle_periods * s.period),
        ),
    )
}

#: The commands registered when the package was imported, in the order used everywhere
#: (tables, figures, arrays). Code that must also see a command registered later, at run
#: time, calls :func:`command_names` instead.
COMMAND_NAMES: tuple[str, ...] = tuple(COMMANDS)


def command_names() -> tuple[str, ...]:
    """Every command in ``COMMANDS`` now, in registry order.

    Returns
    -------
    tuple of str
    """
    return tuple(COMMANDS)


def build_command(name: str, settings: CommandSettings | None = None) -> CommandProgram:
    """The program of a registered command (physics-model.md section 4).

    Parameters
    ----------
    name : str
        A command of :data:`COMMANDS` (``single``, ``preload``, ``stutter``,
        ``delayed_stutter``, ``delayed_stutter_preload``).
    settings : CommandSettings, optional
        Amplitude, frequency, delay and settle periods (defaults of the model if omitted).

    Returns
    -------
    CommandProgram
    """
    if name not in COMMANDS:
        raise ValueError(f"unknown command {name!r}; expected one of {', '.join(COMMANDS)}")
    return COMMANDS[name].program(settings)
