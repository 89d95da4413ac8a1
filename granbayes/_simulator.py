"""Batched simulation of jumps: heights for many parameter sets, trajectories for one.

This is the public face of the compiled integrator (``granbayes._kernel``). Nothing here
raises inside a likelihood: each jump carries a :class:`Status`, and its height is NaN
unless the status is ``OK``.

Besides heights it gives the other measurements of physics-model.md section 5b: the
positions and velocities of tracked jumps at their video frames
(:func:`simulate_frames_rows`, batched, and :func:`simulate_frames` for one jump), from the
same simulation as the height, and
the force of constant-speed intrusion tests (:func:`intrusion_force`,
:func:`intrusion_force_rows`), from the integrator's own ground force.

Examples
--------
>>> from granbayes import simulate
>>> res = simulate("single", 0.612, {"k": 3000.0, "r_unload": 1.0})
>>> round(float(res.height_mm[0]), 1)
67.7

Length: about 1,130 lines, the public face of the kernel for every kind of simulation
(heights, tables, trajectories, frames, intrusion forces): each function checks its
inputs and converts units around one kernel call, and the docstrings carry the semantics
of physics-model.md.
"""

from __future__ import annotations

import contextlib
import dataclasses
import enum
import functools
from collections.abc import Iterator, Mapping, Sequence
from dataclasses import dataclass, field

import numba
import numpy as np
import pandas as pd
from numpy.typing import ArrayLike

from . import _kernel
from ._deprecated import alias_getattr, renamed_keyword
from ._experiment import Experiment, Robot
from .commands import CommandProgram, CommandSettings, build_command
from .forces import PARAMETER_NAMES, PARAMETERS, parameter_term

__all__ = [
    "FRAME_COLUMNS",
    "MAX_FRAME_AFTER_S",
    "ROW_FIELDS",
    "Heights",
    "SolverSettings",
    "Status",
    "TrackedHeights",
    "TrackedJump",
    "Trajectory",
    "build_rows",
    "intrusion_force",
    "intrusion_force_rows",
    "simulate",
    "simulate_frames",
    "simulate_frames_rows",
    "simulate_rows",
    "simulate_table",
    "simulate_trajectory",
]

#: Deprecated alias (old name -> new name): importable, with a DeprecationWarning.
__getattr__ = alias_getattr(__name__, {"SolverOptions": "SolverSettings"})

#: Field order of one input row: robot, phi, then the force-term parameters.
ROW_FIELDS: tuple[str, ...] = _kernel.ROW_FIELDS
#: The robot's columns of an integrator row, in order (the first of :data:`ROW_FIELDS`).
ROBOT_FIELDS: tuple[str, ...] = _kernel.ROBOT_FIELDS

#: The columns of a tracked frame (the last axis of :attr:`TrackedHeights.frames`), in this
#: order: foot height ``x_f`` above the undisturbed surface [mm], rod displacement
#: ``x_r(t) - x_r(0)`` [mm], foot velocity ``x_f'`` [mm/s], rod velocity ``x_r'`` [mm/s].
FRAME_COLUMNS: tuple[str, ...] = ("x_foot_mm", "x_rod_mm", "v_foot_mm_s", "v_rod_mm_s")


class Status(enum.IntEnum):
    """Outcome of one simulated jump."""

    OK = _kernel.STATUS_OK
    NONFINITE = _kernel.STATUS_NONFINITE
    STEP_LIMIT = _kernel.STATUS_STEP_LIMIT
    STEP_UNDERFLOW = _kernel.STATUS_STEP_UNDERFLOW
    BAD_INPUT = _kernel.STATUS_BAD_INPUT

    @property
    def label(self) -> str:
        """``ok`` or ``failed:<reason>`` (as written to CSV files)."""
        return _kernel.STATUS_NAMES[self.value]


@dataclass(frozen=True)
class SolverSettings:
    """Integrator settings (formerly ``SolverOptions``, now a deprecated alias).

    The defaults give heights within 0.05 mm of the converged solution over the realistic
    parameter ranges (see ``benchmarks/bench_simulator.py`` and the README).

    Parameters
    ----------
    rtol : float
        Relative tolerance of the Dormand-Prince error control.
    atol_position : float
        Absolute tolerance on positions [m].
    atol_velocity : float
        Absolute tolerance on velocities [m/s].
    max_step : float
        Largest step [s] of the numerical (Dormand-Prince) integration. The closed form's
        steps in the linear regimes are exact and as long as they provably contain no
        event; they are limited by ``max_step`` only when a trajectory is recorded.
    max_steps : int
        Step budget per jump; exceeding it gives ``Status.STEP_LIMIT``.
    window_after : float
        The height window closes this long after the command ends, if the robot has not
        touched down before [s] (physics-model.md section 5).
    closed_form : bool
        Advance the linear regimes (elastic contact on the unloading line, no ground
        force) by their exact closed form; ``False`` integrates them with Dormand-Prince
        steps too (for checks of the integrator's order).
    """

    rtol: float = 1e-5
    atol_position: float = 1e-7
    atol_velocity: float = 1e-5
    max_step: float = 0.01
    max_steps: int = 200_000
    window_after: float = 0.6
    closed_form: bool = True

    @classmethod
    def converged(cls) -> SolverSettings:
        """Tight settings for reference solutions (about 1e-5 mm)."""
        return cls(rtol=1e-11, atol_position=1e-13, atol_velocity=1e-11)

    def as_array(self) -> np.ndarray:
        """Pack in the integrator's ``OPT_*`` layout."""
        opts = np.empty(_kernel.OPT_SIZE)
        opts[_kernel.OPT_RTOL] = self.rtol
        opts[_kernel.OPT_ATOL_X] = self.atol_position
        opts[_kernel.OPT_ATOL_V] = self.atol_velocity
        opts[_kernel.OPT_HMAX] = self.max_step
        opts[_kernel.OPT_MAX_STEPS] = self.max_steps
        opts[_kernel.OPT_T_AFTER] = self.window_after
        opts[_kernel.OPT_CLOSED] = 1.0 if self.closed_form else 0.0
        return opts


@dataclass(frozen=True)
class Heights:
    """Jump heights of a batch.

    Attributes
    ----------
    height_mm : ndarray of float, shape (n,)
        Jump height [mm] (physics-model.md section 5); NaN where the jump failed.
    status : ndarray of int8, shape (n,)
        :class:`Status` codes.
    n_steps : ndarray of int64, shape (n,)
        Integrator steps per jump.
    """

    height_mm: np.ndarray
    status: np.ndarray
    n_steps: np.ndarray

    @property
    def ok(self) -> np.ndarray:
        """Boolean mask of successful jumps."""
        return self.status == Status.OK

    @property
    def status_labels(self) -> list[str]:
        """Status of each jump as text (``ok``, ``failed:...``)."""
        return _status_labels(self.status).tolist()


@dataclass(frozen=True)
class TrackedHeights(Heights):
    """Jump heights of a batch of tracked jumps, and their motion at the frames.

    Every frame has the four values of :data:`FRAME_COLUMNS`: ``x_foot_mm`` (foot height
    ``x_f`` above the undisturbed surface [mm], negative in the bed), ``x_rod_mm`` (rod
    displacement ``x_r(t) - x_r(0)`` [mm]), ``v_foot_mm_s`` (foot velocity ``x_f'``
    [mm/s], positive upwards) and ``v_rod_mm_s`` (rod velocity ``x_r'`` [mm/s]). A jump
    that failed has NaN in every value of every frame.

    Attributes
    ----------
    height_mm, status, n_steps : ndarray
        As :class:`Heights` (the heights are those of the same jumps untracked, bit for bit).
    frames_flat : ndarray of float, shape (n_frames_total, 4)
        The frames of all jumps, concatenated in the order given; columns
        :data:`FRAME_COLUMNS`.
    frame_offsets : ndarray of int64, shape (n + 1,)
        Jump ``i`` has the rows ``frame_offsets[i]:frame_offsets[i + 1]`` of
        ``frames_flat``.
    frames : ndarray of float, shape (n, n_frames_max, 4)
        The frames by jump: ``frames[i, j]`` is frame ``j`` of jump ``i`` (columns
        :data:`FRAME_COLUMNS`). When every jump has the same number of frames (the usual
        case) this is a view of ``frames_flat``; otherwise the jumps with fewer frames are
        padded with NaN (see ``n_frames``). Computed on first access.
    n_frames : ndarray of int64, shape (n,)
        Number of frames of each jump.
    positions_mm : ndarray of float, shape (n_frames_total, 2)
        ``x_foot_mm`` and ``x_rod_mm`` of ``frames_flat`` (a view).
    velocities_mm_s : ndarray of float, shape (n_frames_total, 2)
        ``v_foot_mm_s`` and ``v_rod_mm_s`` of ``frames_flat`` (a view).
    """

    frames_flat: np.ndarray
    frame_offsets: np.ndarray

    @property
    def n_frames(self) -> np.ndarray:
        """Number of frames of each jump, shape (n,)."""
        return np.diff(self.frame_offsets)

    @functools.cached_property
    def frames(self) -> np.ndarray:
        """The frames by jump, shape (n, n_frames_max, 4) (NaN-padded if ragged)."""
        counts = self.n_frames
        n = counts.size
        width = int(counts.max()) if n else 0
        if n == 0 or np.all(counts == width):
            return self.frames_flat.reshape(n, width, _kernel.FRAME_SIZE)
        out = np.full((n, width, _kernel.FRAME_SIZE), np.nan)
        jump = np.repeat(np.arange(n), counts)
        slot = np.arange(self.frames_flat.shape[0]) - self.frame_offsets[jump]
        out[jump, slot] = self.frames_flat
        return out

    @property
    def positions_mm(self) -> np.ndarray:
        """Foot height and rod displacement [mm] at every frame, shape (n_frames_total, 2)."""
        return self.frames_flat[:, :2]

    @property
    def velocities_mm_s(self) -> np.ndarray:
        """Foot and rod velocity [mm/s] at every frame, shape (n_frames_total, 2)."""
        return self.frames_flat[:, 2:]

    def frames_of(self, i: int) -> np.ndarray:
        """The frames of jump ``i``.

        Parameters
        ----------
        i : int
            Jump index.

        Returns
        -------
        ndarray, shape (n_frames_i, 4)
            Columns :data:`FRAME_COLUMNS`: foot height, rod displacement [mm], foot and rod
            velocity [mm/s] (a view).
        """
        return self.frames_flat[self.frame_offsets[i] : self.frame_offsets[i + 1]]

    def positions(self, i: int) -> np.ndarray:
        """Positions of jump ``i`` at its frames.

        Parameters
        ----------
        i : int
            Jump index.

        Returns
        -------
        ndarray, shape (n_frames_i, 2)
            Foot height and rod displacement [mm] (a view).
        """
        return self.frames_of(i)[:, :2]

    def velocities(self, i: int) -> np.ndarray:
        """Velocities of jump ``i`` at its frames.

        Parameters
        ----------
        i : int
            Jump index.

        Returns
        -------
        ndarray, shape (n_frames_i, 2)
            Foot velocity ``x_f'`` and rod velocity ``x_r'`` [mm/s] (a view).
        """
        return self.frames_of(i)[:, 2:]


@dataclass(frozen=True)
class TrackedJump:
    """One jump as a camera sees it: its motion at the frame times, and its height.

    Attributes
    ----------
    data : pandas.DataFrame
        One row per frame, in the order given: ``t_s`` (frame time on the command's clock
        [s]), ``x_foot_mm`` (foot height above the undisturbed surface [mm]),
        ``x_rod_mm`` (rod displacement ``x_r(t) - x_r(0)`` [mm]), ``v_foot_mm_s`` (foot
        velocity [mm/s]) and ``v_rod_mm_s`` (rod velocity [mm/s]); NaN values if the
        simulation failed.
    height_mm : float
        Jump height [mm] (physics-model.md section 5), NaN if the simulation failed.
    status : Status
        Outcome.
    program : CommandProgram
        The command that was simulated.
    """

    data: pd.DataFrame
    height_mm: float
    status: Status
    program: CommandProgram = field(repr=False)


@dataclass(frozen=True)
class Trajectory:
    """Time series of one jump.

    Attributes
    ----------
    data : pandas.DataFrame
        One row per accepted integrator step and event: ``t_s``, ``x_rod_mm``,
        ``x_foot_mm``, ``v_rod_m_s``, ``v_foot_m_s``, ``depth_mm`` (``z = -x_foot``),
        ``z_max_mm`` (crater depth), ``ground_force_N``, ``added_mass_kg``, ``mode``
        (``advancing``, ``contact``, ``free``), ``alpha_mm`` (actuator position) and
        ``unloading_slope_N_m``: the slope ``r_unload F_yield'(z_max)`` of the bed's elastic
        unloading line from the recorded crater depth (while advancing, the line the bed
        would follow if the foot stopped there, before a ``compaction`` re-anchoring). On
        the unloading line the bed stores the elastic energy ``F_g^2 / (2 slope)``.
    height_mm : float
        Jump height [mm].
    status : Status
        Outcome.
    program : CommandProgram
        The command that was simulated.
    """

    data: pd.DataFrame
    height_mm: float
    status: Status
    program: CommandProgram = field(repr=False)


# ----------------------------------------------------------------------------------------
def _experiment(experiment: Experiment | None) -> Experiment:
    return experiment if experiment is not None else Experiment()


def _program(command: str | CommandProgram, settings: CommandSettings) -> CommandProgram:
    return command if isinstance(command, CommandProgram) else build_command(command, settings)


@contextlib.contextmanager
def _threads(n_threads: int | None) -> Iterator[None]:
    if n_threads is None:
        yield
        return
    previous = numba.get_num_threads()
    numba.set_num_threads(max(1, min(int(n_threads), numba.config.NUMBA_NUM_THREADS)))
    try:
        yield
    finally:
        numba.set_num_threads(previous)


def _robot_row(robot: Robot) -> np.ndarray:
    return np.array([getattr(robot, name) for name in _kernel.ROBOT_FIELDS], dtype=float)


def _check_param_names(params: Mapping[str, object]) -> None:
    """Refuse (``KeyError``) a parameter the compiled kernel has no slot for.

    An unknown name gets the registry's message, naming the valid parameters; a name
    registered after the kernel's row layout was built (a term added at run time, in
    tests) is refused too rather than silently ignored.
    """
    for name in params:
        term = parameter_term(name)  # raises KeyError naming the valid parameters
        if name not in PARAMETER_NAMES:
            raise KeyError(
                f"force parameter {name!r} (term {term!r}) is not in the compiled kernel's "
                "parameter layout: terms need their physics in granbayes/_kernel.py and a "
                "fresh import"
            )


def build_rows(robot: Robot, phi: ArrayLike, params: Mapping[str, ArrayLike]) -> np.ndarray:
    """Integrator input rows for one robot and broadcastable phi and parameters.

    Parameters
    ----------
    robot : Robot
        The robot.
    phi : float or array_like
        Volume fraction(s) [-].
    params : mapping of str to float or array_like
        Force-term parameters [SI]; absent ones take their ``absent`` value (term off,
        ``r_unload`` = 20).

    Returns
    -------
    ndarray, shape (n, len(ROW_FIELDS))
    """
    _check_param_names(params)
    values = [np.asarray(phi, dtype=float)]
    for p in PARAMETERS:
        if p.name in params:
            values.append(np.asarray(params[p.name], dtype=float))
        else:
            values.append(np.asarray(np.nan if p.absent is None else p.absent))
    shape = np.broadcast_shapes(*(v.shape for v in values))
    if len(shape) > 1:
        raise ValueError("phi and parameters must be scalars or 1-d arrays")
    n = shape[0] if shape else 1
    rows = np.empty((n, _kernel.ROW_SIZE))
    rows[:, : _kernel.ROW_PHI] = _robot_row(robot)
    for j, v in enumerate(values):
        rows[:, _kernel.ROW_PHI + j] = np.broadcast_to(v, shape).reshape(n)
    return rows


def _program_tables(
    programs: Sequence[CommandProgram], index: np.ndarray, amplitude_scale: ArrayLike | None
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The kernel's program tables and each row's index into them.

    With ``amplitude_scale`` every row gets its own table: its program's cosine amplitudes
    and offsets (columns 1 and 2 of the segment table) times the row's factor.
    """
    tables = [p.as_table() for p in programs]
    seg = np.stack([t[0] for t in tables])
    meta = np.stack([t[1] for t in tables])
    if amplitude_scale is None:
        return index, np.ascontiguousarray(seg), np.ascontiguousarray(meta)
    scale = np.asarray(amplitude_scale, dtype=float)
    if scale.shape != index.shape:
        raise ValueError(f"amplitude_scale must have shape {index.shape}, got {scale.shape}")
    if not np.all(np.isfinite(scale) & (scale > 0)):
        raise ValueError("amplitude_scale must be finite and > 0")
    seg = seg[index].copy()
    seg[:, :, 1:] *= scale[:, None, None]
    own = np.arange(len(index), dtype=np.int64)
    return own, np.ascontiguousarray(seg), np.ascontiguousarray(meta[index])


@renamed_keyword("options")
def simulate_rows(
    rows: np.ndarray,
    programs: Sequence[CommandProgram],
    command_index: ArrayLike | None = None,
    *,
    settings: SolverSettings | None = None,
    n_threads: int | None = None,
    amplitude_scale: ArrayLike | None = None,
) -> Heights:
    """Simulate jumps given integrator rows (the lowest-level batched entry point).

    Parameters
    ----------
    rows : ndarray, shape (n, len(ROW_FIELDS))
        Robot, phi and force parameters per jump (see :func:`build_rows`).
    programs : sequence of CommandProgram
        The commands used in the batch.
    command_index : array_like of int, shape (n,), optional
        Which program each row uses (default: all the first).
    settings : SolverSettings, optional
        Integrator settings.
    n_threads : int, optional
        numba threads to use (default: numba's current setting).
    amplitude_scale : array_like of float, shape (n,), optional
        Per-row factor on the stroke of the row's program (a robot whose true stroke
        differs from its command's ``amplitude_mm``): every waveform of
        physics-model.md section 4 is proportional to ``A``, so the program of stroke
        ``s A`` is the program of ``A`` with its cosine amplitudes and offsets times ``s``
        (durations unchanged). Default: 1 for every row.

    Returns
    -------
    Heights
    """
    rows = np.ascontiguousarray(rows, dtype=float)
    if rows.ndim != 2 or rows.shape[1] != _kernel.ROW_SIZE:
        raise ValueError(f"rows must have shape (n, {_kernel.ROW_SIZE})")
    n = rows.shape[0]
    index = (
        np.zeros(n, dtype=np.int64)
        if command_index is None
        else np.ascontiguousarray(command_index, dtype=np.int64)
    )
    index, seg, meta = _program_tables(programs, index, amplitude_scale)
    heights = np.empty(n)
    status = np.empty(n, dtype=np.int8)
    n_steps = np.empty(n, dtype=np.int64)
    opts = (settings or SolverSettings()).as_array()
    with _threads(n_threads):
        _kernel.simulate_batch(rows, index, seg, meta, opts, heights, status, n_steps)
    return Heights(height_mm=heights * 1e3, status=status, n_steps=n_steps)


@renamed_keyword("options")
def simulate(
    command: str | CommandProgram,
    phi: ArrayLike,
    params: Mapping[str, ArrayLike],
    *,
    experiment: Experiment | None = None,
    settings: SolverSettings | None = None,
    n_threads: int | None = None,
) -> Heights:
    """Jump heights of one command for many parameter sets (e.g. the walkers of a sampler).

    Parameters
    ----------
    command : str or CommandProgram
        A command name (built with the experiment's command settings) or a program.
    phi : float or array_like
        Volume fraction(s) of the bed [-].
    params : mapping of str to float or array_like
        Force-term parameters (``k`` [N/m], ``c_d`` [kg/m], ``kappa`` [-], ``r_unload``
        [-], ``k2`` [N/m^2], ``b`` [N s/m]); scalars and 1-d arrays broadcast together.
    experiment : Experiment, optional
        Robot and command settings (defaults of the physics model if omitted).
    settings : SolverSettings, optional
        Integrator settings.
    n_threads : int, optional
        numba threads.

    Returns
    -------
    Heights
        Heights [mm] and per-jump status; never raises for a failed integration.
    """
    exp = _experiment(experiment)
    rows = build_rows(exp.robot, phi, params)
    return simulate_rows(
        rows, [_program(command, exp.command)], settings=settings, n_threads=n_threads
    )


#: The command settings a row of a table may give (:class:`CommandSettings` fields).
_TABLE_SETTINGS: tuple[str, ...] = tuple(f.name for f in dataclasses.fields(CommandSettings))

#: Status labels indexed by status code (:attr:`Status.label`).
_STATUS_LABELS = np.array(_kernel.STATUS_NAMES, dtype=object)


def _status_labels(status: ArrayLike) -> np.ndarray:
    """Status codes as their labels (``ok``, ``failed:<reason>``), by array lookup.

    Parameters
    ----------
    status : array_like of int
        :class:`Status` codes.

    Returns
    -------
    numpy.ndarray
        object array of str, the shape of ``status``.

    Raises
    ------
    ValueError
        If a code is not a :class:`Status`.
    """
    codes = np.asarray(status)
    if codes.size and (codes.min() < 0 or codes.max() >= len(_STATUS_LABELS)):
        bad = codes[(codes < 0) | (codes >= len(_STATUS_LABELS))].flat[0]
        raise ValueError(f"{int(bad)} is not a valid Status")
    return _STATUS_LABELS[codes]


def _table_programs(
    table: pd.DataFrame, defaults: CommandSettings
) -> tuple[np.ndarray, list[CommandProgram]]:
    """One command program per distinct command and settings of a table's rows.

    Parameters
    ----------
    table : pandas.DataFrame
        Column ``command``; optional columns of :data:`_TABLE_SETTINGS` (a missing column
        or a NaN or non-numeric cell takes the default).
    defaults : CommandSettings
        The settings rows do not give.

    Returns
    -------
    index : numpy.ndarray
        int64, the program of each row.
    programs : list of CommandProgram
        In the order of their first row.
    """
    n = len(table)
    # a row's command is str() of its cell: group by the cells, name each group once
    codes, cells = pd.factorize(table["command"], use_na_sentinel=False)
    names = [str(cell) for cell in cells]
    keys = [codes]
    for name in _TABLE_SETTINGS:
        default = float(getattr(defaults, name))
        if name in table:
            values = pd.to_numeric(table[name], errors="coerce").to_numpy(dtype=float)
            keys.append(np.where(np.isnan(values), default, values))
        else:
            keys.append(np.full(n, default))
    # group ids: combine the keys' codes (numbered in order of first appearance) as digits
    # of one number, renumbered whenever the next digit could overflow it
    index = np.zeros(n, dtype=np.int64)
    size = 1
    for key in keys:
        codes, uniques = pd.factorize(key)
        if size * len(uniques) >= 2**62:
            index, uniques_so_far = pd.factorize(index)
            size = len(uniques_so_far)
        index = index * len(uniques) + codes
        size *= len(uniques)
    index = pd.factorize(index)[0].astype(np.int64)
    # groups are numbered in order of first appearance: a group's first row is where the
    # group id exceeds every id before it
    first = np.flatnonzero(index > np.maximum.accumulate(np.concatenate(([-1], index[:-1]))))
    programs = [
        build_command(
            names[keys[0][row]],
            CommandSettings(
                **{
                    name: float(key[row])
                    for name, key in zip(_TABLE_SETTINGS, keys[1:], strict=True)
                }
            ),
        )
        for row in first.tolist()
    ]
    return index, programs


@renamed_keyword("options")
def simulate_table(
    table: pd.DataFrame,
    experiment: Experiment | None = None,
    *,
    settings: SolverSettings | None = None,
    n_threads: int | None = None,
) -> pd.DataFrame:
    """Simulate one jump per row of a table (the CLI's batch mode).

    Parameters
    ----------
    table : pandas.DataFrame
        Columns ``command`` and ``phi``; optional force parameters (missing or NaN: term
        off, ``r_unload`` = 20) and optional per-row overrides of the experiment
        (``m_motor`` ... ``grain_density``, ``amplitude_mm``, ``freq_hz``, ``delay_ms``,
        ``settle_periods``).
    experiment : Experiment, optional
        Defaults for the overrides.
    settings : SolverSettings, optional
        Integrator settings.
    n_threads : int, optional
        numba threads.

    Returns
    -------
    pandas.DataFrame
        The input with ``height_mm`` and ``status`` columns set.
    """
    exp = _experiment(experiment)
    n = len(table)
    rows = np.empty((n, _kernel.ROW_SIZE))
    for j, name in enumerate(ROW_FIELDS):
        if name == "phi":
            default = np.nan
        elif j < _kernel.ROW_PHI:
            default = getattr(exp.robot, name)
        else:
            p = PARAMETERS[j - _kernel.ROW_FORCE0]
            default = np.nan if p.absent is None else p.absent
        col = (
            pd.to_numeric(table[name], errors="coerce").to_numpy(dtype=float)
            if name in table
            else np.full(n, default)
        )
        rows[:, j] = np.where(np.isnan(col), default, col)
    index, programs = _table_programs(table, exp.command)
    res = simulate_rows(rows, programs, index, settings=settings, n_threads=n_threads)
    out = table.copy()
    out["height_mm"] = res.height_mm
    out["status"] = _status_labels(res.status)
    return out


@renamed_keyword("options")
def simulate_trajectory(
    command: str | CommandProgram,
    phi: float,
    params: Mapping[str, float],
    *,
    experiment: Experiment | None = None,
    settings: SolverSettings | None = None,
    max_step: float = 5e-4,
) -> Trajectory:
    """Simulate one jump and record its trajectory.

    Parameters
    ----------
    command : str or CommandProgram
        Command name or program.
    phi : float
        Volume fraction [-].
    params : mapping of str to float
        Force-term parameters [SI].
    experiment : Experiment, optional
        Robot and command settings.
    settings : SolverSettings, optional
        Integrator settings; ``max_step`` below overrides its ``max_step``.
    max_step : float
        Largest step [s], so that plots are smooth (the recorded points are exact
        integrator states).

    Returns
    -------
    Trajectory
    """
    exp = _experiment(experiment)
    program = _program(command, exp.command)
    opts = settings or SolverSettings()
    opts = dataclasses.replace(opts, max_step=min(opts.max_step, max_step))
    row = build_rows(exp.robot, phi, params)[0]
    seg, meta = program.as_table()
    capacity = int(4.0 * (program.t_end + opts.window_after) / max_step) + 1000
    while True:  # grow the buffer until the whole trajectory fits
        rec = np.empty((capacity, _kernel.REC_SIZE))
        height, status, _, n = _kernel.simulate_one(row, seg, meta, opts.as_array(), rec, True)
        if n < capacity:
            break
        capacity *= 4
    r = rec[:n]
    data = pd.DataFrame(
        {
            "t_s": r[:, 0],
            "x_rod_mm": r[:, 1] * 1e3,
            "x_foot_mm": r[:, 2] * 1e3,
            "v_rod_m_s": r[:, 3],
            "v_foot_m_s": r[:, 4],
            "depth_mm": -r[:, 2] * 1e3,
            "z_max_mm": r[:, 5] * 1e3,
            "ground_force_N": r[:, 6],
            "added_mass_kg": r[:, 7],
            "mode": np.array(_kernel.MODE_NAMES)[r[:, 8].astype(int)],
            "alpha_mm": r[:, 9] * 1e3,
            "unloading_slope_N_m": r[:, 10],
        }
    )
    return Trajectory(data=data, height_mm=height * 1e3, status=Status(status), program=program)


# ----------------------------------------------------------------------------------------
# measurements beyond jump heights (physics-model.md section 5b)

#: Latest frame a tracked jump may have, after its command has ended [s].
MAX_FRAME_AFTER_S = 5.0


def _checked_frame_order(
    times: np.ndarray, offsets: np.ndarray, t_end: np.ndarray
) -> np.ndarray | None:
    """Refuse bad frames; the permutation that sorts each jump's frames (None if sorted).

    Parameters
    ----------
    times : ndarray
        Frame times [s], concatenated.
    offsets : ndarray
        Jump ``i`` has the frames ``offsets[i]:offsets[i + 1]``.
    t_end : ndarray
        Each jump's command end [s]; its frames may reach :data:`MAX_FRAME_AFTER_S` later.

    Returns
    -------
    ndarray or None
        Indices that sort the frames by jump, then time (stable).

    Raises
    ------
    ValueError
        If a frame time is not finite or too late.
    """
    limits = np.ascontiguousarray(t_end + MAX_FRAME_AFTER_S)
    code, bad = _kernel.check_frames(times, offsets, limits)
    if code == 2:
        raise ValueError(f"frame time {bad} is not finite: {times[bad]!r}")
    if code == 3:
        jump = int(np.searchsorted(offsets, bad, side="right") - 1)
        raise ValueError(
            f"frame {bad} of jump {jump} is at {times[bad]:g} s, more than "
            f"{MAX_FRAME_AFTER_S:g} s after its command ends ({t_end[jump]:g} s)"
        )
    if code == 0:
        return None
    jump = np.repeat(np.arange(offsets.size - 1), np.diff(offsets))
    return np.lexsort((times, jump))


def _frame_layout(
    times: np.ndarray, offsets: ArrayLike | None, n: int
) -> tuple[np.ndarray, np.ndarray]:
    """Frame times concatenated by jump and their offsets, from any accepted layout.

    Parameters
    ----------
    times : ndarray
        Frame times [s]: concatenated (with ``offsets``), one row per jump (shape (n, F)),
        or the same frames for every jump (shape (F,), without ``offsets``).
    offsets : array_like of int or None
        Jump ``i`` has the frames ``offsets[i]:offsets[i + 1]`` of ``times``.
    n : int
        Number of jumps.

    Returns
    -------
    times : ndarray, shape (n_frames_total,)
        Concatenated frame times [s] (contiguous).
    offsets : ndarray of int64, shape (n + 1,)
        Jump ``i`` has the frames ``offsets[i]:offsets[i + 1]``.

    Raises
    ------
    ValueError
        If the shapes or offsets are inconsistent.
    """
    if offsets is None:
        if times.ndim == 1:
            width = times.size
            times = np.tile(times, n)
        elif times.ndim == 2 and times.shape[0] == n:
            width = times.shape[1]
            times = times.ravel()
        else:
            raise ValueError(
                f"without frame_offsets, frame_times_s must have shape (n_frames,) (the same "
                f"frames for every jump) or ({n}, n_frames), got {times.shape}"
            )
        return np.ascontiguousarray(times), np.arange(n + 1, dtype=np.int64) * width
    if times.ndim != 1:
        raise ValueError("with frame_offsets, frame_times_s must be one-dimensional")
    offsets = np.ascontiguousarray(offsets, dtype=np.int64)
    if (
        offsets.shape != (n + 1,)
        or offsets[0] != 0
        or offsets[-1] != times.size
        or np.any(np.diff(offsets) < 0)
    ):
        raise ValueError(
            f"frame_offsets must have shape ({n + 1},), start at 0, not decrease and end at "
            f"the number of frames ({times.size})"
        )
    return times, offsets


@renamed_keyword("options")
def simulate_frames_rows(
    rows: np.ndarray,
    programs: Sequence[CommandProgram],
    program_index: ArrayLike | None,
    frame_times_s: ArrayLike,
    frame_offsets: ArrayLike | None = None,
    settings: SolverSettings | None = None,
    n_threads: int | None = None,
    amplitude_scale: ArrayLike | None = None,
) -> TrackedHeights:
    """Simulate tracked jumps: heights, and positions and velocities at the frames (batched).

    Each jump is simulated once; its motion at the frames comes from the dense output of
    its accepted integrator steps, with no extra steps: exact in the closed-form regimes
    (positions and velocities from the modal solution and its derivative), a quintic
    Hermite interpolant in the Dormand-Prince ones (positions from it, velocities from its
    derivative). Semantics (physics-model.md section 5b): frames are on the command's
    clock; before t = 0 the robot rests in its start state (velocities 0); the height is
    that of :func:`simulate_rows`, bit for bit; if frames remain after the jump's end (the
    touchdown after a flight, or the window's end) the simulation goes on under the same
    model, through the landing and the hold after the command, to the last frame.

    Parameters
    ----------
    rows : ndarray, shape (n, len(ROW_FIELDS))
        Robot, phi and force parameters per jump (see :func:`build_rows`).
    programs : sequence of CommandProgram
        The commands used in the batch.
    program_index : array_like of int, shape (n,), or None
        Which program each row uses (None: all the first).
    frame_times_s : array_like of float
        Frame times on the command's clock [s], at most :data:`MAX_FRAME_AFTER_S` after
        each jump's command ends; within a jump in any order (the frames are returned in
        the order given). Shape (n_frames_total,): all jumps' frames concatenated, with
        ``frame_offsets``. Without ``frame_offsets``: shape (n, n_frames), jump ``i``'s
        frames in row ``i``, or shape (n_frames,), the same frames for every jump.
    frame_offsets : array_like of int, shape (n + 1,), optional
        Jump ``i`` has the frames ``frame_offsets[i]:frame_offsets[i + 1]`` of the
        concatenated ``frame_times_s`` (``frame_offsets[0] = 0``, non-decreasing, last =
        ``n_frames_total``).
    settings : SolverSettings, optional
        Integrator settings.
    n_threads : int, optional
        numba threads to use (default: numba's current setting).
    amplitude_scale : array_like of float, shape (n,), optional
        Per-row factor on the stroke of the row's program (:func:`simulate_rows`).

    Returns
    -------
    TrackedHeights
        Heights [mm], statuses and steps per jump, and the frames: ``frames`` of shape (n,
        n_frames, 4) and ``frames_flat`` of shape (n_frames_total, 4), columns
        :data:`FRAME_COLUMNS` (foot height and rod displacement [mm], foot and rod
        velocity [mm/s]). A failed jump has NaN height and frames and its status (no
        exception).

    Raises
    ------
    ValueError
        If the shapes or offsets are inconsistent, a frame time is not finite, or a frame
        is later than :data:`MAX_FRAME_AFTER_S` after its command's end.

    Examples
    --------
    >>> import numpy as np
    >>> from granbayes import build_command, simulate_frames_rows
    >>> from granbayes._experiment import Robot
    >>> from granbayes._simulator import build_rows
    >>> rows = build_rows(Robot(), [0.6, 0.62], {"k": 3000.0})
    >>> res = simulate_frames_rows(rows, [build_command("single")], None, np.arange(5) * 0.01)
    >>> res.frames.shape  # (jumps, frames, (x_foot_mm, x_rod_mm, v_foot_mm_s, v_rod_mm_s))
    (2, 5, 4)
    """
    # writable C arrays whatever the caller passes (a read-only array, such as a pandas
    # column's values, is another type to numba: one more ~20-s compilation of the kernel)
    rows = np.require(rows, dtype=float, requirements=["C", "W"])
    if rows.ndim != 2 or rows.shape[1] != _kernel.ROW_SIZE:
        raise ValueError(f"rows must have shape (n, {_kernel.ROW_SIZE})")
    n = rows.shape[0]
    index = (
        np.zeros(n, dtype=np.int64)
        if program_index is None
        else np.require(program_index, dtype=np.int64, requirements=["C", "W"])
    )
    if index.shape != (n,):
        raise ValueError(f"program_index must have shape ({n},)")
    if n and (index.min() < 0 or index.max() >= len(programs)):
        raise ValueError(f"program_index must index the {len(programs)} programs")
    times, offsets = _frame_layout(np.asarray(frame_times_s, dtype=float), frame_offsets, n)
    times = np.require(times, dtype=float, requirements=["C", "W"])
    offsets = np.require(offsets, dtype=np.int64, requirements=["C", "W"])
    t_end = np.array([p.t_end for p in programs], dtype=float)
    order = _checked_frame_order(times, offsets, t_end[index])
    if order is not None:
        times = np.ascontiguousarray(times[order])
    index, seg, meta = _program_tables(programs, index, amplitude_scale)
    heights = np.empty(n)
    status = np.empty(n, dtype=np.int8)
    n_steps = np.empty(n, dtype=np.int64)
    out = np.empty((times.size, _kernel.FRAME_SIZE))
    opts = (settings or SolverSettings()).as_array()
    with _threads(n_threads):
        _kernel.simulate_frames_batch(
            rows, index, seg, meta, opts, times, offsets, 1e3, heights, status, n_steps, out
        )
    if order is not None:
        values = np.empty_like(out)
        values[order] = out
        out = values
    return TrackedHeights(
        height_mm=heights * 1e3,
        status=status,
        n_steps=n_steps,
        frames_flat=out,
        frame_offsets=offsets,
    )


@renamed_keyword("options")
def simulate_frames(
    command: str | CommandProgram,
    phi: float,
    params: Mapping[str, float],
    t_s: ArrayLike,
    *,
    experiment: Experiment | None = None,
    settings: SolverSettings | None = None,
) -> TrackedJump:
    """Simulate one tracked jump: positions and velocities at given frame times, and its height.

    Parameters
    ----------
    command : str or CommandProgram
        Command name (built with the experiment's command settings) or program.
    phi : float
        Volume fraction [-].
    params : mapping of str to float
        Force-term parameters [SI].
    t_s : array_like of float
        Frame times on the command's clock [s] (t = 0 at the start of the command), at
        most :data:`MAX_FRAME_AFTER_S` after its end; any order.
    experiment : Experiment, optional
        Robot and command settings.
    settings : SolverSettings, optional
        Integrator settings.

    Returns
    -------
    TrackedJump
        ``data`` with columns ``t_s`` and :data:`FRAME_COLUMNS` (``x_foot_mm``,
        ``x_rod_mm`` [mm], ``v_foot_mm_s``, ``v_rod_mm_s`` [mm/s]; see
        :func:`simulate_frames_rows` for the semantics), the height [mm] and the status.

    Examples
    --------
    >>> from granbayes import simulate_frames
    >>> jump = simulate_frames("single", 0.612, {"k": 3000.0}, [-0.01, 0.0, 0.05])
    >>> jump.data["x_rod_mm"].tolist()[:2], jump.data["v_rod_mm_s"].tolist()[:2]
    ([0.0, 0.0], [0.0, 0.0])
    """
    exp = _experiment(experiment)
    program = _program(command, exp.command)
    times = np.atleast_1d(np.asarray(t_s, dtype=float))
    if times.ndim != 1:
        raise ValueError("t_s must be a scalar or one-dimensional")
    rows = build_rows(exp.robot, phi, params)
    if rows.shape[0] != 1:
        raise ValueError("simulate_frames simulates one jump: phi and parameters are scalars")
    res = simulate_frames_rows(
        rows, [program], None, times, np.array([0, times.size]), settings=settings
    )
    data = pd.DataFrame({"t_s": times})
    for j, column in enumerate(FRAME_COLUMNS):
        data[column] = res.frames_flat[:, j]
    return TrackedJump(
        data=data,
        height_mm=float(res.height_mm[0]),
        status=Status(int(res.status[0])),
        program=program,
    )


def intrusion_force_rows(
    rows: np.ndarray,
    depth_mm: ArrayLike,
    speed_mm_s: ArrayLike,
    row_index: ArrayLike | None = None,
    *,
    n_threads: int | None = None,
) -> np.ndarray:
    """Force of constant-speed intrusions for many (parameter row, depth, speed) (batched).

    The low-level form of :func:`intrusion_force`, for a likelihood that evaluates many
    walkers times many intrusion samples at once: evaluation ``i`` uses the row
    ``rows[row_index[i]]`` (phi, foot radius and grain density are the row's) at depth
    ``depth_mm[i]`` and speed ``speed_mm_s[i]``. No exception: NaN where the row is not
    valid (as a jump's ``Status.BAD_INPUT``) or the depth or speed is negative or not
    finite.

    Parameters
    ----------
    rows : ndarray, shape (n_rows, len(ROW_FIELDS))
        Robot, phi and force parameters (see :func:`build_rows`).
    depth_mm : array_like of float, shape (m,)
        Depth of the foot below the undisturbed surface [mm] (>= 0).
    speed_mm_s : array_like of float, shape (m,)
        Constant intrusion speed [mm/s] (>= 0).
    row_index : array_like of int, shape (m,), optional
        Row of each evaluation; default: row ``i`` for evaluation ``i`` (``n_rows = m``),
        or the one row for all if ``n_rows = 1``.
    n_threads : int, optional
        numba threads.

    Returns
    -------
    ndarray of float, shape (m,)
        Force [N] the rig applies against the bed, less the foot's weight.
    """
    rows = np.ascontiguousarray(rows, dtype=float)
    if rows.ndim != 2 or rows.shape[1] != _kernel.ROW_SIZE:
        raise ValueError(f"rows must have shape (n, {_kernel.ROW_SIZE})")
    depth = np.ascontiguousarray(depth_mm, dtype=float).ravel() * 1e-3
    speed = np.ascontiguousarray(speed_mm_s, dtype=float).ravel() * 1e-3
    m = depth.size
    if speed.size != m:
        raise ValueError("depth_mm and speed_mm_s must have the same size")
    if row_index is None:
        if rows.shape[0] == 1:
            index = np.zeros(m, dtype=np.int64)
        elif rows.shape[0] == m:
            index = np.arange(m, dtype=np.int64)
        else:
            raise ValueError("without row_index, rows must have 1 row or one per evaluation")
    else:
        index = np.ascontiguousarray(row_index, dtype=np.int64).ravel()
        if index.size != m:
            raise ValueError("row_index must have one entry per evaluation")
        if m and (index.min() < 0 or index.max() >= rows.shape[0]):
            raise ValueError(f"row_index must index the {rows.shape[0]} rows")
    out = np.empty(m)
    with _threads(n_threads):
        _kernel.intrusion_batch(rows, index, depth, speed, out)
    return out


def intrusion_force(
    phi: ArrayLike,
    params: Mapping[str, ArrayLike],
    depth_mm: ArrayLike,
    speed_mm_s: ArrayLike,
    *,
    experiment: Experiment | None = None,
) -> np.ndarray:
    """Force of a constant-speed intrusion into a fresh bed (physics-model.md section 5b).

    A rig drives the foot alone at speed ``v`` into an undisturbed bed (one advancing
    episode from the surface, no memory of earlier intrusions). At depth ``z`` it applies,
    less the foot's weight,

        F(z, v) = F_adv(z, v) + kappa rho_g phi V'(z) v^2 - m_a(z) g,

    computed by the integrator's own ground force in the advancing regime, so that every
    term of the force library counts (including any term added to it): the resistance
    ``F_adv``, the added-mass cone's momentum flux (``V'`` falls from ``mu pi R^2`` at the
    surface to 0 once the cone is full at ``z = R tan(theta) / mu``) and the weight of the
    grains it carries. At quasi-static speed it is the loading curve less that weight,
    ``F_static(z) - m_a(z) g``. No ODE is solved.

    Parameters
    ----------
    phi : float or array_like
        Volume fraction of the bed [-].
    params : mapping of str to float or array_like
        Force-term parameters [SI] (absent ones: term off, ``r_unload`` = 20).
    depth_mm : float or array_like
        Depth of the foot below the undisturbed surface [mm] (>= 0).
    speed_mm_s : float or array_like
        Intrusion speed [mm/s] (>= 0).
    experiment : Experiment, optional
        The robot (foot radius, grain density); defaults of the physics model if omitted.

    Returns
    -------
    ndarray of float
        Force [N], of the broadcast shape of ``phi``, the parameters, ``depth_mm`` and
        ``speed_mm_s`` (0-d for scalars); NaN where the parameters are not valid.

    Raises
    ------
    ValueError
        If a depth or speed is negative or not finite.

    Examples
    --------
    >>> from granbayes import intrusion_force
    >>> intrusion_force(0.612, {"k": 3000.0, "c_d": 50.0}, [10.0, 20.0], 100.0).round(3)
    array([30.5, 60.5])
    """
    exp = _experiment(experiment)
    _check_param_names(params)
    depth = np.asarray(depth_mm, dtype=float)
    speed = np.asarray(speed_mm_s, dtype=float)
    for name, v in (("depth_mm", depth), ("speed_mm_s", speed)):
        if not np.all(np.isfinite(v) & (v >= 0.0)):
            raise ValueError(f"{name} must be finite and >= 0")
    law = [np.asarray(phi, dtype=float)] + [np.asarray(v, dtype=float) for v in params.values()]
    shape = np.broadcast_shapes(*(v.shape for v in law), depth.shape, speed.shape)
    if all(v.ndim == 0 for v in law):
        rows = build_rows(exp.robot, phi, params)
    else:
        rows = build_rows(
            exp.robot,
            np.broadcast_to(law[0], shape).ravel(),
            {k: np.broadcast_to(v, shape).ravel() for k, v in zip(params, law[1:], strict=True)},
        )
    force = intrusion_force_rows(
        rows, np.broadcast_to(depth, shape).ravel(), np.broadcast_to(speed, shape).ravel()
    )
    return force.reshape(shape)
