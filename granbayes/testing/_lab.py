"""A SYNTHETIC laboratory: experiments as a lab would have them, made by the oracle only.

:func:`synthetic_lab_data` simulates a whole campaign with the independent oracle
(:mod:`granbayes.testing._oracle`; never the compiled kernel, so the data that test the
fitting code are not made by the code under test) and adds a lab's imperfections:

* **jump heights** (``jumps.csv``) with Gaussian trial-to-trial scatter ``sigma_mm``;
* **tracked jumps** (``trajectories.csv``): the first ``tracked_trials`` trials of every
  cell are filmed at ``fps`` frames per second; each coordinate (foot height, rod
  displacement) carries AR(1) frame noise of marginal standard deviation ``frame_sd_mm``
  and correlation ``frame_rho`` between consecutive frames, and each filmed jump a clock
  offset ``~ Normal(0, clock_sd_frames / fps)``: the lab's frame times ``t_s`` run on a
  regular grid, the robot moved at ``t_s - offset`` on the command's clock;
* **intrusion tests** (``intrusions.csv``) at every volume fraction and speed, sampled
  every ``depth_step_mm`` to ``depth_max_mm``, with Gaussian force noise ``force_sd_N``;
* optionally a **robot off its nominal values** (true values given, or drawn from the
  calibration standard deviations written to ``[robot.uncertainty]``), **beds whose true
  phi scatters** around the written phi (``phi_sd``, written to ``[bed]``), and
  **out-of-library physics** (``effects``, :mod:`granbayes.testing._effects`).

The granularity of the phi scatter is a design choice (``phi_jitter``): ``"level"`` (the
default) draws one true phi per written volume fraction, shared by every jump, filmed jump
and intrusion test at that volume fraction (a lab that prepares its beds at a target
packing with a systematic error per target); ``"jump"`` draws one per jump (each trial on a
freshly prepared bed; a filmed jump's height and frames share it) and one per intrusion
test. Every table carries a ``bed`` column naming the bed preparation a row comes from.

Every row carries ``source = "synthetic: <label> seed=<seed>"`` (as
:mod:`granbayes._synthetic` writes it), the tables also hold the noise-free values
(``true_*`` columns, dropped by :func:`write_lab_experiment`), and the truth (robot, beds,
law, effects) stays in the returned :class:`LabData`.

Randomness: one ``numpy.random.SeedSequence(seed)`` spawns an independent generator per
component (robot, beds, heights, clock offsets, frames, forces), each drawn in a fixed
order in the calling process, so a table is fixed by the seed and its own design whatever
else is asked for, and whether or not the simulations run in parallel.

Examples
--------
>>> from granbayes.testing import LabDesign, synthetic_lab_data
>>> design = LabDesign(phis=(0.612,), commands=("single",), trials=2, tracked_trials=0,
...                    intrusion_speeds_mm_s=())
>>> data = synthetic_lab_data({"k": 3000.0}, seed=1, design=design)
>>> data.jumps[["phi", "command", "trial"]].values.tolist()
[[0.612, 'single', 1], [0.612, 'single', 2]]
"""

from __future__ import annotations

import dataclasses
import json
import math
from collections.abc import Callable, Iterable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Literal

import numpy as np
import pandas as pd

from .._experiment import Experiment, Robot
from ..commands import build_command
from ._effects import Effect, resolve_effects
from ._oracle import intrusion_force_scipy, simulate_height_scipy, simulate_trajectory_scipy

__all__ = ["LabData", "LabDesign", "synthetic_lab_data", "write_lab_experiment"]

#: The generator named in the ``source`` column.
LABEL = "granbayes.testing.synthetic_lab_data"

#: Keys that may carry a calibration uncertainty (``[robot.uncertainty]``), in TOML units:
#: the robot's fields [SI] and the actuator amplitude [mm].
UNCERTAIN_KEYS: tuple[str, ...] = (
    *(f.name for f in dataclasses.fields(Robot)),
    "amplitude_mm",
)

Law = Mapping[str, float] | Callable[[float], Mapping[str, float]]


@dataclass(frozen=True)
class LabDesign:
    """What the SYNTHETIC lab measures, and how well (units in the names).

    Parameters
    ----------
    phis : tuple of float
        Written (measured) volume fractions of the beds [-].
    commands : tuple of str
        Jump commands.
    freqs_hz : tuple of float
        Actuator frequencies [Hz] (a ``freq_hz`` column per jump).
    trials : int
        Jumps per cell (volume fraction, frequency, command).
    sigma_mm : float
        Standard deviation of the jump heights' scatter [mm].
    tracked_trials : int
        The first this many trials of every cell are filmed (0: none).
    fps : float
        Camera frame rate [1/s].
    frame_sd_mm : float
        Marginal standard deviation of the frame noise, per coordinate [mm].
    frame_rho : float
        Correlation of the frame noise between consecutive frames (AR(1)) [-], in [0, 1).
    clock_sd_frames : float
        Standard deviation of a filmed jump's clock offset [frames].
    track_from_s : float
        First frame, on the lab's clock, relative to the command's start [s].
    track_after_end_s : float
        Last frame, on the lab's clock, after the command's end [s] (< 4.9).
    intrusion_speeds_mm_s : tuple of float
        Speeds of the intrusion tests at every volume fraction [mm/s] (``()``: none).
    intrusion_repeats : int
        Tests per volume fraction and speed.
    depth_step_mm : float
        Depth between intrusion samples [mm].
    depth_max_mm : float
        Deepest intrusion sample [mm].
    force_sd_N : float
        Standard deviation of the intrusion force noise [N].
    robot_sd : mapping of str to float
        Calibration standard deviation per key of :data:`UNCERTAIN_KEYS` (TOML units: SI,
        ``amplitude_mm`` in mm); the true value of each is drawn ``Normal(nominal, sd)``
        (redrawn until valid), and the sds are written to ``[robot.uncertainty]``.
    robot_true : mapping of str to float
        True values of keys of :data:`UNCERTAIN_KEYS` (TOML units), instead of draws.
    phi_sd : float
        Standard deviation of a bed's true phi about its written phi [-] (0: exact).
    phi_jitter : {"level", "jump"}
        Granularity of the phi scatter: one true phi per written volume fraction, or one
        per jump and per intrusion test (module docstring).
    """

    phis: tuple[float, ...] = (0.592, 0.612, 0.632)
    commands: tuple[str, ...] = ("single", "preload", "stutter")
    freqs_hz: tuple[float, ...] = (10.0,)
    trials: int = 3
    sigma_mm: float = 1.0
    tracked_trials: int = 1
    fps: float = 1000.0
    frame_sd_mm: float = 0.2
    frame_rho: float = 0.5
    clock_sd_frames: float = 2.0
    track_from_s: float = -0.02
    track_after_end_s: float = 0.3
    intrusion_speeds_mm_s: tuple[float, ...] = (1.0, 200.0)
    intrusion_repeats: int = 1
    depth_step_mm: float = 0.5
    depth_max_mm: float = 40.0
    force_sd_N: float = 0.3
    robot_sd: Mapping[str, float] = field(default_factory=dict)
    robot_true: Mapping[str, float] = field(default_factory=dict)
    phi_sd: float = 0.0
    phi_jitter: Literal["level", "jump"] = "level"

    def __post_init__(self) -> None:
        """Check the design."""
        for name in ("sigma_mm", "frame_sd_mm", "clock_sd_frames", "force_sd_N", "phi_sd"):
            value = getattr(self, name)
            if not (math.isfinite(value) and value >= 0.0):
                raise ValueError(f"{name} must be finite and >= 0, got {value!r}")
        for name in ("fps", "depth_step_mm"):
            if not getattr(self, name) > 0.0:
                raise ValueError(f"{name} must be > 0, got {getattr(self, name)!r}")
        if not 0.0 <= self.frame_rho < 1.0:
            raise ValueError(f"frame_rho must be in [0, 1), got {self.frame_rho!r}")
        if self.trials < 1 or not 0 <= self.tracked_trials <= self.trials:
            raise ValueError("need trials >= 1 and 0 <= tracked_trials <= trials")
        if self.intrusion_repeats < 1 or self.depth_max_mm < 0.0:
            raise ValueError("need intrusion_repeats >= 1 and depth_max_mm >= 0")
        if not self.track_after_end_s < 4.9:
            raise ValueError("track_after_end_s must be < 4.9 s (the oracle's reach is 5 s)")
        if self.phi_jitter not in ("level", "jump"):
            raise ValueError(f"phi_jitter must be 'level' or 'jump', got {self.phi_jitter!r}")
        for mapping in (self.robot_sd, self.robot_true):
            unknown = set(mapping) - set(UNCERTAIN_KEYS)
            if unknown:
                raise KeyError(f"unknown robot key(s) {sorted(unknown)}; allowed {UNCERTAIN_KEYS}")
        if any(not (math.isfinite(v) and v >= 0.0) for v in self.robot_sd.values()):
            raise ValueError("robot_sd values must be finite and >= 0")
        for phi in self.phis:
            if not 0.0 < phi < 1.0:
                raise ValueError(f"phi must be in (0, 1), got {phi!r}")
        for command in self.commands:
            build_command(command)  # refuses an unknown command


#: A small SYNTHETIC lab of every kind of measurement: 2 volume fractions, the single jump,
#: 3 trials, one filmed per cell at 1000 frames/s (0.2 mm AR(1) tracking noise, clock off by
#: 1.5 frames sd), intrusion tests at 1 and 200 mm/s to 30 mm (0.3 N force noise). The
#: design of the kinds' tests and of the README's joint fit (``docs/joint_fit_figures.py``).
SMALL_LAB = LabDesign(
    phis=(0.602, 0.622),
    commands=("single",),
    trials=3,
    sigma_mm=1.0,
    tracked_trials=1,
    fps=1000.0,
    frame_sd_mm=0.2,
    frame_rho=0.5,
    clock_sd_frames=1.5,
    track_from_s=-0.005,
    track_after_end_s=0.03,
    intrusion_speeds_mm_s=(1.0, 200.0),
    intrusion_repeats=1,
    depth_step_mm=1.0,
    depth_max_mm=30.0,
    force_sd_N=0.3,
)


@dataclass(frozen=True)
class LabData:
    """A SYNTHETIC experiment: the tables a lab would write, and the truth behind them.

    Attributes
    ----------
    jumps : pandas.DataFrame
        ``jumps.csv``: ``phi, command, height_mm, trial, freq_hz`` (data-format.md), then
        ``jump`` (an id, shared with ``trajectories``), ``bed``, ``source`` and the
        noise-free ``true_height_mm`` [mm].
    trajectories : pandas.DataFrame
        ``trajectories.csv``: ``jump, phi, command, trial, freq_hz, t_s, x_foot_mm,
        x_rod_mm``, then ``bed``, ``source`` and the truth: ``true_t_s`` (the frame's time
        on the command's clock [s]), ``true_x_foot_mm``, ``true_x_rod_mm`` [mm]. Empty
        (with these columns) when no jump is filmed.
    intrusions : pandas.DataFrame
        ``intrusions.csv``: ``test, phi, speed_mm_s, depth_mm, force_N``, then ``bed``,
        ``source`` and ``true_force_N`` [N]. Empty when no test is asked for.
    experiment : Experiment
        The nominal robot and command settings (what ``experiment.toml`` says).
    true_experiment : Experiment
        The robot and settings the data were simulated with.
    beds : pandas.DataFrame
        One row per bed: ``bed``, ``phi`` (written) and ``true_phi`` [-], and the law's
        parameters at ``true_phi`` [SI].
    uncertainty : dict of str to float
        ``[robot.uncertainty]``: the calibration standard deviations (TOML units).
    phi_sd : float
        ``[bed] phi_sd`` [-].
    effects : tuple
        The out-of-library effects in the truth.
    seed : int
        The seed.
    label : str
        The generator named in ``source``.
    """

    jumps: pd.DataFrame
    trajectories: pd.DataFrame
    intrusions: pd.DataFrame
    experiment: Experiment
    true_experiment: Experiment
    beds: pd.DataFrame
    uncertainty: dict[str, float]
    phi_sd: float
    effects: tuple[Effect, ...]
    seed: int
    label: str = LABEL

    @property
    def source(self) -> str:
        """The ``source`` value of every row: ``"synthetic: <label> seed=<seed>"``."""
        return f"synthetic: {self.label} seed={self.seed}"


# ----------------------------------------------------------------------------------------
# simulation tasks (top-level functions and plain data, so that workers can run them)


@dataclass(frozen=True)
class _Task:
    """One oracle call: a jump's height, a filmed jump's frames, and their settings."""

    command: str
    phi: float
    params: tuple[tuple[str, float], ...]
    experiment: Experiment
    effects: tuple[Effect, ...]
    times: tuple[float, ...] | None  # None: the height only
    rtol: float
    atol: float


def _run_task(task: _Task) -> tuple[float, np.ndarray | None, np.ndarray | None]:
    """Height [mm] and, for a filmed jump, foot height and rod displacement [mm]."""
    params = dict(task.params)
    if task.times is None:
        height = simulate_height_scipy(
            task.command,
            task.phi,
            params,
            task.experiment,
            task.rtol,
            task.atol,
            effects=task.effects,
        )
        return height, None, None
    traj = simulate_trajectory_scipy(
        task.command,
        task.phi,
        params,
        np.asarray(task.times),
        task.experiment,
        effects=task.effects,
        rtol=task.rtol,
        atol=task.atol,
    )
    return traj.height_mm, traj.x_foot_mm, traj.x_rod_mm


def _map(executor: Any, tasks: Sequence[_Task]) -> list:
    """Run ``tasks`` serially, with a ``map``-like callable, or on a dask client."""
    if executor is None:
        return [_run_task(task) for task in tasks]
    if hasattr(executor, "gather") and hasattr(executor, "submit"):  # dask.distributed.Client
        return list(executor.gather(executor.map(_run_task, list(tasks), pure=False)))
    if callable(executor):
        return list(executor(_run_task, tasks))
    raise TypeError("executor must be None, a dask.distributed.Client or a map-like callable")


# ----------------------------------------------------------------------------------------
# the lab's randomness


def _ar1(rng: np.random.Generator, n: int, sd: float, rho: float) -> np.ndarray:
    """A stationary AR(1) series of length ``n``: marginal sd ``sd``, lag-1 correlation ``rho``."""
    shocks = rng.standard_normal(n)
    out = np.empty(n)
    if n == 0:
        return out
    scale = math.sqrt(1.0 - rho * rho)
    out[0] = shocks[0]
    for i in range(1, n):
        out[i] = rho * out[i - 1] + scale * shocks[i]
    return sd * out


def _true_robot(
    nominal: Experiment, design: LabDesign, rng: np.random.Generator
) -> tuple[Experiment, dict[str, float]]:
    """The true robot: given values, else draws about the nominal ones (in key order)."""
    values = nominal.robot_values
    changes: dict[str, float] = {}
    for key in UNCERTAIN_KEYS:
        sd = float(design.robot_sd.get(key, 0.0))
        if key in design.robot_true:
            changes[key] = float(design.robot_true[key])
        elif sd > 0.0:
            floor = 0.0 if key == "c_spring" else np.nextafter(0.0, 1.0)
            value = -1.0
            while value < floor:
                value = float(values[key] + sd * rng.standard_normal())
            changes[key] = value
    uncertainty = {k: float(v) for k, v in design.robot_sd.items() if v > 0.0}
    return nominal.replace(**changes), uncertainty


def _law(truth: Law, phi: float) -> dict[str, float]:
    """The force law at the true ``phi``."""
    law = truth(phi) if callable(truth) else truth
    return {name: float(value) for name, value in law.items()}


def synthetic_lab_data(
    truth: Law,
    *,
    seed: int,
    design: LabDesign | None = None,
    experiment: Experiment | None = None,
    effects: Effect | Iterable[Effect] | None = None,
    executor: Any = None,
    rtol: float = 1e-9,
    atol: float = 1e-12,
    label: str = LABEL,
) -> LabData:
    """Simulate a SYNTHETIC lab campaign with the oracle, with the lab's imperfections.

    Parameters
    ----------
    truth : mapping or callable
        The true force law [SI]: one mapping of parameters (``k`` required; see
        :func:`~granbayes.testing.simulate_height_scipy`), or ``truth(phi)`` -> mapping,
        evaluated at each bed's TRUE volume fraction.
    seed : int
        Seed of every random draw (module docstring).
    design : LabDesign, optional
        What is measured and how well (default :class:`LabDesign()`).
    experiment : Experiment, optional
        The nominal robot and command settings (default ``Experiment()``); ``freq_hz`` is
        set per jump by the design.
    effects : effect or sequence of effects, optional
        Out-of-library physics in the truth (:mod:`granbayes.testing._effects`).
    executor : optional
        Where the oracle runs: ``None`` (serially, here), a ``dask.distributed.Client``
        (``client.map``), or a callable with the signature of the builtin ``map`` (e.g.
        ``concurrent.futures.ProcessPoolExecutor().map``). The data do not depend on it.
    rtol : float
        Relative tolerance of the oracle.
    atol : float
        Absolute tolerance of the oracle [m, m/s].
    label : str
        Generator named in the ``source`` column.

    Returns
    -------
    LabData
        The tables (``jumps``, ``trajectories``, ``intrusions``) and the truth.

    Raises
    ------
    ValueError, KeyError
        For a bad design, law or effect (before any simulation).
    """
    design = design if design is not None else LabDesign()
    nominal = experiment if experiment is not None else Experiment()
    effect_tuple = tuple(
        e for e in vars(resolve_effects(effects)).values() if e is not None
    )  # checks them
    streams = [np.random.default_rng(s) for s in np.random.SeedSequence(seed).spawn(6)]
    rng_robot, rng_beds, rng_heights, rng_clock, rng_frames, rng_forces = streams
    true_exp, uncertainty = _true_robot(nominal, design, rng_robot)
    source = f"synthetic: {label} seed={seed}"

    # the jumps, in the order of granbayes.make_jumps: phi, freq, command, trial
    cells = [
        (phi, freq, command)
        for phi in design.phis
        for freq in design.freqs_hz
        for command in design.commands
    ]
    n_jumps = len(cells) * design.trials
    n_tests = len(design.phis) * len(design.intrusion_speeds_mm_s) * design.intrusion_repeats
    per_jump = design.phi_jitter == "jump"
    if per_jump:  # one bed per jump, then one per intrusion test
        level_phi = dict.fromkeys(design.phis, math.nan)
        jump_phi = design.phi_sd * rng_beds.standard_normal(n_jumps)
        test_phi = design.phi_sd * rng_beds.standard_normal(n_tests)
        per_phi_jumps = n_jumps // max(len(design.phis), 1)
        per_phi_tests = n_tests // max(len(design.phis), 1)
        drawn = [
            *(np.repeat(design.phis, per_phi_jumps) + jump_phi),
            *(np.repeat(design.phis, per_phi_tests) + test_phi),
        ]
    else:  # one bed per written volume fraction
        level_phi = {p: p + design.phi_sd * float(rng_beds.standard_normal()) for p in design.phis}
        jump_phi = test_phi = np.zeros(0)
        drawn = list(level_phi.values())
    for phi in drawn:  # before any simulation
        if not 0.0 < phi < 1.0:
            raise ValueError(f"a bed's true phi {phi} is outside (0, 1): phi_sd is too large")

    rows: list[dict[str, Any]] = []
    tasks: list[_Task] = []
    task_index: dict[_Task, int] = {}
    beds: list[dict[str, Any]] = []
    frame_grids: dict[int, tuple[np.ndarray, float]] = {}

    def task_for(task: _Task) -> int:
        if task not in task_index:
            task_index[task] = len(tasks)
            tasks.append(task)
        return task_index[task]

    jump = 0
    for phi, freq, command in cells:
        cell_exp = true_exp.replace(freq_hz=float(freq))
        program = build_command(command, cell_exp.command)
        for trial in range(1, design.trials + 1):
            if per_jump:
                bed, true_phi = jump + 1, phi + float(jump_phi[jump])  # type: ignore[index]
                beds.append({"bed": bed, "phi": phi, "true_phi": true_phi, **_law(truth, true_phi)})
            else:
                bed, true_phi = design.phis.index(phi) + 1, level_phi[phi]
            jump += 1
            law = tuple(sorted(_law(truth, true_phi).items()))
            times = None
            if trial <= design.tracked_trials:
                # the lab's regular frame grid, and the command-clock times it films
                last = program.t_end + design.track_after_end_s
                n_frames = math.floor((last - design.track_from_s) * design.fps + 1e-9) + 1
                lab_t = np.round(design.track_from_s + np.arange(n_frames) / design.fps, 9)
                offset = design.clock_sd_frames / design.fps * float(rng_clock.standard_normal())
                frame_grids[jump] = (lab_t, offset)
                times = tuple((lab_t - offset).tolist())
            task = _Task(command, true_phi, law, cell_exp, effect_tuple, times, rtol, atol)
            rows.append(
                {
                    "phi": phi,
                    "command": command,
                    "trial": trial,
                    "freq_hz": float(freq),
                    "jump": jump,
                    "bed": bed,
                    "source": source,
                    "_task": task_for(task),
                }
            )
    if not per_jump:
        beds = [
            {"bed": i + 1, "phi": p, "true_phi": level_phi[p], **_law(truth, level_phi[p])}
            for i, p in enumerate(level_phi)
        ]

    results = _map(executor, tasks)

    # heights, with scatter in table order
    noise = design.sigma_mm * rng_heights.standard_normal(len(rows))
    true_heights = np.array([results[row["_task"]][0] for row in rows])
    jumps = pd.DataFrame(rows).drop(columns="_task")
    jumps.insert(2, "height_mm", np.round(true_heights + noise, 3))
    jumps["true_height_mm"] = true_heights

    # filmed jumps: AR(1) frame noise per coordinate, foot then rod, in jump order
    frames = []
    for row in rows:
        if row["jump"] not in frame_grids:
            continue
        lab_t, offset = frame_grids[row["jump"]]
        _, x_foot, x_rod = results[row["_task"]]
        n = lab_t.size
        foot_noise = _ar1(rng_frames, n, design.frame_sd_mm, design.frame_rho)
        rod_noise = _ar1(rng_frames, n, design.frame_sd_mm, design.frame_rho)
        frames.append(
            pd.DataFrame(
                {
                    "jump": row["jump"],
                    "phi": row["phi"],
                    "command": row["command"],
                    "trial": row["trial"],
                    "freq_hz": row["freq_hz"],
                    "t_s": lab_t,
                    "x_foot_mm": np.round(x_foot + foot_noise, 4),
                    "x_rod_mm": np.round(x_rod + rod_noise, 4),
                    "bed": row["bed"],
                    "source": source,
                    "true_t_s": lab_t - offset,
                    "true_x_foot_mm": x_foot,
                    "true_x_rod_mm": x_rod,
                }
            )
        )
    columns = ["jump", "phi", "command", "trial", "freq_hz", "t_s", "x_foot_mm", "x_rod_mm"]
    columns += ["bed", "source", "true_t_s", "true_x_foot_mm", "true_x_rod_mm"]
    trajectories = pd.concat(frames, ignore_index=True) if frames else pd.DataFrame(columns=columns)

    # intrusion tests: phi, speed, repeat
    depths = np.round(np.arange(0.0, design.depth_max_mm + 1e-9, design.depth_step_mm), 9)
    tests = []
    test = 0
    for phi in design.phis:
        for speed in design.intrusion_speeds_mm_s:
            for _ in range(design.intrusion_repeats):
                if per_jump:
                    bed, true_phi = n_jumps + test + 1, phi + float(test_phi[test])  # type: ignore[index]
                    beds.append(
                        {"bed": bed, "phi": phi, "true_phi": true_phi, **_law(truth, true_phi)}
                    )
                else:
                    bed, true_phi = design.phis.index(phi) + 1, level_phi[phi]
                test += 1
                force = intrusion_force_scipy(
                    true_phi, _law(truth, true_phi), depths, speed, true_exp, effects=effect_tuple
                )
                measured = force + design.force_sd_N * rng_forces.standard_normal(depths.size)
                tests.append(
                    pd.DataFrame(
                        {
                            "test": test,
                            "phi": phi,
                            "speed_mm_s": float(speed),
                            "depth_mm": depths,
                            "force_N": np.round(measured, 4),
                            "bed": bed,
                            "source": source,
                            "true_force_N": force,
                        }
                    )
                )
    columns = ["test", "phi", "speed_mm_s", "depth_mm", "force_N", "bed", "source", "true_force_N"]
    intrusions = pd.concat(tests, ignore_index=True) if tests else pd.DataFrame(columns=columns)

    return LabData(
        jumps=jumps,
        trajectories=trajectories,
        intrusions=intrusions,
        experiment=nominal,
        true_experiment=true_exp,
        beds=pd.DataFrame(beds),
        uncertainty=uncertainty,
        phi_sd=float(design.phi_sd),
        effects=effect_tuple,
        seed=seed,
        label=label,
    )


def _toml_number(value: float) -> str:
    """A float as TOML writes it."""
    return repr(float(value))


def write_lab_experiment(
    path: str | Path,
    data: LabData,
    *,
    uncertainties: bool = True,
    truth_file: bool = True,
) -> Path:
    """Write a complete experiment folder for :func:`synthetic_lab_data`'s tables.

    ``experiment.toml`` holds the nominal robot and command settings (never the true
    ones), ``[robot.uncertainty]`` and ``[bed] phi_sd`` when the data use them, and a
    comment naming the data SYNTHETIC with the generator and seed; ``jumps.csv``,
    ``trajectories.csv`` and ``intrusions.csv`` (those with rows) hold the tables without
    their ``true_*`` columns, every row with its ``source``. With ``truth_file`` the truth
    goes to ``lab_truth.json`` (true robot, beds with their true phi and law, effects;
    never read by inference).

    Parameters
    ----------
    path : str or Path
        The folder (created; the files written replace those of the same names, and a
        measurement file the data have no rows for is removed).
    data : LabData
        The data.
    uncertainties : bool
        Write ``[robot.uncertainty]`` and ``phi_sd`` (when non-zero). Without them the
        folder reads as an experiment whose robot and beds are known exactly.
    truth_file : bool
        Also write ``lab_truth.json``.

    Returns
    -------
    Path
        The folder.
    """
    folder = Path(path)
    folder.mkdir(parents=True, exist_ok=True)
    exp = data.experiment
    lines = [f"# SYNTHETIC data ({data.label}, seed={data.seed}): made by the scipy oracle"]
    if data.effects:
        lines.append("# with out-of-library physics: " + ", ".join(map(repr, data.effects)))
    lines += ["[robot]"] + [f"{k} = {_toml_number(v)}" for k, v in vars(exp.robot).items()]
    if uncertainties and data.uncertainty:
        lines += ["", "[robot.uncertainty]"]
        lines += [f"{k} = {_toml_number(v)}" for k, v in data.uncertainty.items()]
    lines += ["", "[command]"] + [f"{k} = {_toml_number(v)}" for k, v in vars(exp.command).items()]
    lines += ["", "[bed]", f"phi_c = {_toml_number(exp.phi_c)}"]
    if uncertainties and data.phi_sd > 0.0:
        lines.append(f"phi_sd = {_toml_number(data.phi_sd)}")
    (folder / "experiment.toml").write_text("\n".join(lines) + "\n")

    def public(table: pd.DataFrame) -> pd.DataFrame:
        return table.drop(columns=[c for c in table.columns if c.startswith("true_")])

    for name, table in (
        ("jumps.csv", data.jumps),
        ("trajectories.csv", data.trajectories),
        ("intrusions.csv", data.intrusions),
    ):
        if len(table):
            public(table).to_csv(folder / name, index=False)
        else:  # no stale table of an earlier run beside the new ones
            (folder / name).unlink(missing_ok=True)
    if truth_file:
        truth = {
            "source": data.source,
            "true_robot": vars(data.true_experiment.robot),
            "true_command": vars(data.true_experiment.command),
            "beds": data.beds.to_dict(orient="records"),
            "effects": [
                {"effect": type(e).__name__, **dataclasses.asdict(e)} for e in data.effects
            ],
        }
        (folder / "lab_truth.json").write_text(json.dumps(truth, indent=2, default=float) + "\n")
    return folder
