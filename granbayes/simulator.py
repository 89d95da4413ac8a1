"""Batched simulation of jumps: heights for many parameter sets, trajectories for one.

This is the public face of the compiled integrator (``granbayes._kernel``). Nothing here
raises inside a likelihood: each jump carries a :class:`Status`, and its height is NaN
unless the status is ``OK``.

Examples
--------
>>> from granbayes import simulate
>>> res = simulate("single", 0.612, {"k": 3000.0, "r_unload": 1.0})
>>> round(float(res.height_mm[0]), 1)
67.7
"""

from __future__ import annotations

import contextlib
import dataclasses
import enum
from collections.abc import Iterator, Mapping, Sequence
from dataclasses import dataclass, field

import numba
import numpy as np
import pandas as pd
from numpy.typing import ArrayLike

from . import _kernel
from ._deprecated import alias_getattr
from .commands import CommandProgram, CommandSettings, build_command
from .experiment import Experiment, Robot
from .forces import PARAMETER_NAMES, PARAMETERS, parameter_term

__all__ = [
    "ROW_FIELDS",
    "Heights",
    "SolverSettings",
    "Status",
    "Trajectory",
    "build_rows",
    "simulate",
    "simulate_rows",
    "simulate_table",
    "simulate_trajectory",
]

#: Deprecated alias (old name -> new name): importable, with a DeprecationWarning.
__getattr__ = alias_getattr(__name__, {"SolverOptions": "SolverSettings"})

#: Field order of one input row: robot, phi, then the force-term parameters.
ROW_FIELDS: tuple[str, ...] = _kernel.ROW_FIELDS


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


def simulate_rows(
    rows: np.ndarray,
    programs: Sequence[CommandProgram],
    command_index: ArrayLike | None = None,
    *,
    options: SolverSettings | None = None,
    n_threads: int | None = None,
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
    options : SolverSettings, optional
        Integrator settings.
    n_threads : int, optional
        numba threads to use (default: numba's current setting).

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
    tables = [p.as_table() for p in programs]
    seg = np.ascontiguousarray(np.stack([t[0] for t in tables]))
    meta = np.ascontiguousarray(np.stack([t[1] for t in tables]))
    heights = np.empty(n)
    status = np.empty(n, dtype=np.int8)
    n_steps = np.empty(n, dtype=np.int64)
    opts = (options or SolverSettings()).as_array()
    with _threads(n_threads):
        _kernel.simulate_batch(rows, index, seg, meta, opts, heights, status, n_steps)
    return Heights(height_mm=heights * 1e3, status=status, n_steps=n_steps)


def simulate(
    command: str | CommandProgram,
    phi: ArrayLike,
    params: Mapping[str, ArrayLike],
    *,
    experiment: Experiment | None = None,
    options: SolverSettings | None = None,
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
    options : SolverSettings, optional
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
        rows, [_program(command, exp.command)], options=options, n_threads=n_threads
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


def simulate_table(
    table: pd.DataFrame,
    experiment: Experiment | None = None,
    *,
    options: SolverSettings | None = None,
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
    options : SolverSettings, optional
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
    res = simulate_rows(rows, programs, index, options=options, n_threads=n_threads)
    out = table.copy()
    out["height_mm"] = res.height_mm
    out["status"] = _status_labels(res.status)
    return out


def simulate_trajectory(
    command: str | CommandProgram,
    phi: float,
    params: Mapping[str, float],
    *,
    experiment: Experiment | None = None,
    options: SolverSettings | None = None,
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
    options : SolverSettings, optional
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
    opts = options or SolverSettings()
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
