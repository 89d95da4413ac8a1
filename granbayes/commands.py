"""The five jump commands as data: waveform segments, start state and push-off start.

The motor position relative to the rod is ``alpha(t)`` (up positive). A command is a
sequence of segments; within segment ``i`` (from ``t_i`` to ``t_{i+1}``)

    alpha(t) = coef_i * cos(omega (t - t_i)) + offset_i,

so a hold is ``coef = 0``. After the last segment ``alpha`` is held. The jump-height window
starts at the beginning of segment ``pushoff_index`` (physics-model.md, section 5).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Literal

import numpy as np

from .experiment import COMMAND_NAMES, CommandSettings

__all__ = ["MAX_SEGMENTS", "START_STATES", "CommandProgram", "Segment", "build_command"]

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


def build_command(name: str, settings: CommandSettings | None = None) -> CommandProgram:
    """Build one of the five jump commands of physics-model.md section 4.

    Parameters
    ----------
    name : str
        ``single``, ``preload``, ``stutter``, ``delayed_stutter`` or
        ``delayed_stutter_preload``.
    settings : CommandSettings, optional
        Amplitude, frequency, delay and settle periods (defaults of the model if omitted).

    Returns
    -------
    CommandProgram
    """
    s = settings if settings is not None else CommandSettings()
    if name not in COMMAND_NAMES:
        raise ValueError(f"unknown command {name!r}; expected one of {', '.join(COMMAND_NAMES)}")
    a, period = s.amplitude, s.period
    omega = 2.0 * math.pi * s.freq_hz
    push = Segment(period, coef=-a)  # -A cos(w t'): one period of push-off
    if name in ("single", "preload"):
        start = "settled" if name == "preload" else "touching"
        return CommandProgram(name, omega, (push,), start_state=start, pushoff_index=0)
    if name == "stutter":
        # +A cos(w t) over 1.5 periods: countermovement, hop, push-off. It is split at T/2,
        # where the window opens; A cos(w (T/2 + t')) = -A cos(w t').
        return CommandProgram(name, omega, (Segment(0.5 * period, coef=a), push), pushoff_index=1)
    hold = s.delay if name == "delayed_stutter" else s.settle_periods * period
    segments = (Segment(0.5 * period, coef=a), Segment(hold, offset=-a), push)
    return CommandProgram(name, omega, segments, pushoff_index=2)
