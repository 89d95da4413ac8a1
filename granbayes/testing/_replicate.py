"""A replicate of an experiment's measurements, made by the oracle from a given truth.

:func:`replicate_measurements` keeps an experiment's design (every jump, tracked jump and
intrusion test: volume fraction, command and settings, frame times, depths and speeds)
and replaces every measured value by the oracle's simulation of a given truth plus the
noise of the observation models of ``docs/physics-model.md`` section 11, drawn here:

* a jump height: ``height + sigma_mm * eps``, ``eps`` standard normal (or Student-t with
  ``nu`` degrees of freedom);
* a tracked jump: a clock offset ``delta`` uniform on ``+/- offset_window_s`` (the prior
  the likelihood integrates over), the oracle's foot height and rod displacement at the
  robot's times ``t_s + delta`` (frame ``i`` shows the robot at ``t_i + delta``), and per
  coordinate a stationary Ornstein-Uhlenbeck error of standard deviation
  ``frame_sd_foot_mm`` / ``frame_sd_rod_mm`` and correlation time ``frame_tau_ms``
  (correlation ``exp(-gap / tau)`` between successive frames, whatever their spacing);
* an intrusion test: the oracle's force at every depth plus independent Gaussian noise
  of ``force_sd_N``.

It is what simulation-based calibration of a joint fit needs (``granbayes sbc`` on a
folder with trajectories or intrusions): data drawn from the model's prior predictive by
an implementation that shares no numerical code with the fitting kernel, so that an
error in the kernel's dense output, the offset's integration or the noise's whitening is
not reproduced by the data that test it. Written from the contract: nothing here reads
the likelihood's code.
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Mapping
from typing import Any

import numpy as np
import pandas as pd

from .._experiment import Experiment
from ..commands import SETTINGS, CommandSettings, build_command
from ._effects import Effect, resolve_effects
from ._lab import UNCERTAIN_KEYS, _map, _Task
from ._oracle import intrusion_force_scipy

__all__ = ["replicate_measurements"]

#: Noise parameters a truth may carry (per volume fraction), by measurement kind.
NOISE_KEYS: dict[str, tuple[str, ...]] = {
    "heights": ("sigma_mm",),
    "trajectories": ("frame_sd_foot_mm", "frame_sd_rod_mm", "frame_tau_ms"),
    "intrusions": ("force_sd_N",),
}


def _settings_of(row: Mapping[str, Any], experiment: Experiment) -> CommandSettings:
    """A row's command settings (its columns, else the experiment's)."""
    values = {}
    for name in SETTINGS:
        value = row.get(name, math.nan)
        values[name] = float(getattr(experiment.command, name) if pd.isna(value) else value)
    return CommandSettings(**values)


def _split(truth: Mapping[str, float]) -> tuple[dict[str, float], dict[str, float], dict]:
    """A volume fraction's truth: force law, robot changes, noise parameters."""
    noise_keys = {k for keys in NOISE_KEYS.values() for k in keys}
    law = {k: float(v) for k, v in truth.items() if k not in noise_keys and k not in UNCERTAIN_KEYS}
    robot = {k: float(v) for k, v in truth.items() if k in UNCERTAIN_KEYS}
    noise = {k: float(v) for k, v in truth.items() if k in noise_keys}
    return law, robot, noise


def _true_experiment(nominal: Experiment, robot: Mapping[str, float]) -> tuple[Experiment, float]:
    """The experiment with the truth's robot, and the stroke's factor on every command."""
    changes = {k: v for k, v in robot.items() if k != "amplitude_mm"}
    factor = 1.0
    if "amplitude_mm" in robot:
        factor = robot["amplitude_mm"] / nominal.command.amplitude_mm
    return nominal.replace(**changes), factor


def _ou(rng: np.random.Generator, t_s: np.ndarray, sd: float, tau_s: float) -> np.ndarray:
    """A stationary Ornstein-Uhlenbeck series at times ``t_s`` (increasing) [sd's unit]."""
    z = rng.standard_normal(t_s.size)
    out = np.empty(t_s.size)
    if t_s.size == 0:
        return out
    out[0] = sd * z[0]
    for i in range(1, t_s.size):
        rho = math.exp(-(t_s[i] - t_s[i - 1]) / tau_s)
        out[i] = rho * out[i - 1] + sd * math.sqrt(1.0 - rho * rho) * z[i]
    return out


def replicate_measurements(
    experiment: Experiment,
    tables: Mapping[str, pd.DataFrame],
    truth: Mapping[float, Mapping[str, float]],
    *,
    rng: np.random.Generator,
    offset_window_s: Mapping[Any, float] | None = None,
    noise: str = "normal",
    nu: float = 5.0,
    effects: Effect | Iterable[Effect] | None = None,
    executor: Any = None,
    rtol: float = 1e-9,
    atol: float = 1e-12,
) -> dict[str, pd.DataFrame]:
    """SYNTHETIC measurements of an experiment's design, simulated by the oracle.

    Parameters
    ----------
    experiment : Experiment
        The nominal robot and command defaults (what ``experiment.toml`` says).
    tables : mapping of str to pandas.DataFrame
        The design, per kind (``heights``: rows of ``jumps.csv``; ``trajectories``: frames
        of ``trajectories.csv`` in time order per jump; ``intrusions``: samples of
        ``intrusions.csv``), as loaded and validated; their measured values are replaced.
    truth : mapping of float to mapping of str to float
        Per written volume fraction: the force law (oracle names, SI: ``k`` [N/m],
        ``c_d`` [kg/m], ``kappa`` [-], ...), robot keys that differ from the nominal ones
        (``k_spring`` [N/m], ``amplitude_mm`` [mm], ...), and the noise of every kind in
        ``tables``: ``sigma_mm`` [mm]; ``frame_sd_foot_mm``, ``frame_sd_rod_mm`` [mm] (of
        the position columns the frames have) and ``frame_tau_ms`` [ms];
        ``force_sd_N`` [N].
    rng : numpy.random.Generator
        Source of every draw, in this order: the heights' noise, every tracked jump's clock
        offset (in order of first appearance), every tracked jump's frame noise (foot,
        then rod), the forces' noise.
    offset_window_s : mapping, optional
        Half-width [s] of the uniform prior of each tracked jump's clock offset, by the
        value of its ``jump`` column (required with trajectories).
    noise : {"normal", "student_t"}
        Scatter of the heights.
    nu : float
        Student-t degrees of freedom.
    effects : effect or sequence of effects, optional
        Out-of-library ground physics of the truth (:mod:`granbayes.testing`'s effects),
        in every simulated jump, tracked jump and intrusion test; ``None``: the library
        model.
    executor : optional
        Where the oracle runs (``None``: here; a ``dask.distributed.Client`` or a
        ``map``-like callable, as :func:`~granbayes.testing.synthetic_lab_data`).
    rtol, atol : float
        Tolerances of the oracle [-, m and m/s].

    Returns
    -------
    dict of str to pandas.DataFrame
        The tables of ``tables`` with their values replaced (``height_mm``;
        ``x_foot_mm``/``x_rod_mm``; ``force_N``), each with the truth beside it
        (``true_height_mm``; ``true_offset_s``, ``true_x_foot_mm``, ``true_x_rod_mm``;
        ``true_force_N``).

    Raises
    ------
    KeyError
        If a volume fraction of the design has no truth, or a kind's noise parameter or a
        tracked jump's offset window is missing.
    """
    truth = {float(phi): dict(values) for phi, values in truth.items()}
    physics = tuple(e for e in vars(resolve_effects(effects)).values() if e is not None)

    def at(phi: float) -> tuple[dict[str, float], Experiment, float, dict[str, float]]:
        for key, values in truth.items():
            if math.isclose(key, float(phi), abs_tol=1e-12):
                law, robot, noise_values = _split(values)
                exp, factor = _true_experiment(experiment, robot)
                return law, exp, factor, noise_values
        raise KeyError(f"no truth at phi={phi:g}")

    def need(values: Mapping[str, float], key: str, phi: float) -> float:
        if key not in values:
            raise KeyError(f"the truth at phi={phi:g} has no {key}")
        return float(values[key])

    out: dict[str, pd.DataFrame] = {}
    tasks: list[_Task] = []

    def task(command: str, phi: float, row: Mapping[str, Any], times) -> int:
        law, exp, factor, _ = at(phi)
        cs = _settings_of(row, exp)
        settings = {name: float(getattr(cs, name)) for name in SETTINGS}
        settings["amplitude_mm"] *= factor
        exp = exp.replace(**settings)
        build_command(command, exp.command)  # refuses an unknown command here
        tasks.append(
            _Task(command, phi, tuple(sorted(law.items())), exp, physics, times, rtol, atol)
        )
        return len(tasks) - 1

    heights = tables.get("heights")
    frames = tables.get("trajectories")
    tests = tables.get("intrusions")
    # simulations first (the draws below do not depend on them), then every draw in order
    height_tasks = []
    if heights is not None:
        for _, row in heights.iterrows():
            height_tasks.append(task(str(row["command"]), float(row["phi"]), row, None))
    tracked = []  # (frame rows, clock offset [s], task) per tracked jump
    groups = []
    if frames is not None and len(frames):
        if offset_window_s is None:
            raise KeyError("offset_window_s is required with trajectories")
        for jump, rows in frames.groupby("jump", sort=False):
            if jump not in offset_window_s:
                raise KeyError(f"no clock-offset window for tracked jump {jump!r}")
            groups.append((rows, float(offset_window_s[jump])))
    draws_h = None
    if heights is not None:
        n = len(heights)
        draws_h = rng.standard_normal(n) if noise == "normal" else rng.standard_t(nu, n)
    for rows, window in groups:
        offset = float(rng.uniform(-window, window))
        first = rows.iloc[0]
        times = tuple((rows["t_s"].to_numpy(float) + offset).tolist())
        tracked.append(
            (rows, offset, task(str(first["command"]), float(first["phi"]), first, times))
        )
    results = _map(executor, tasks)

    if heights is not None:
        table = heights.copy()
        sd = np.array([need(at(p)[3], "sigma_mm", p) for p in table["phi"].to_numpy(float)])
        true_h = np.array([results[i][0] for i in height_tasks])
        table["height_mm"] = true_h + sd * draws_h
        table["true_height_mm"] = true_h
        out["heights"] = table
    if frames is not None:
        table = frames.copy()
        for col in ("true_offset_s", "true_x_foot_mm", "true_x_rod_mm"):
            table[col] = np.nan
        for rows, offset, i in tracked:
            phi = float(rows["phi"].iloc[0])
            noise_values = at(phi)[3]
            tau_s = 1e-3 * need(noise_values, "frame_tau_ms", phi)
            t = rows["t_s"].to_numpy(float)
            _, x_foot, x_rod = results[i]
            table.loc[rows.index, "true_offset_s"] = offset
            for col, x in (("x_foot_mm", x_foot), ("x_rod_mm", x_rod)):
                if col not in table.columns:
                    continue
                sd = need(noise_values, col.replace("x_", "frame_sd_"), phi)
                table.loc[rows.index, col] = x + _ou(rng, t, sd, tau_s)
                table.loc[rows.index, "true_" + col] = x
        out["trajectories"] = table
    if tests is not None:
        table = tests.copy()
        true_f = np.full(len(table), np.nan)
        for _, rows in table.groupby("test", sort=False):
            phi = float(rows["phi"].iloc[0])
            law, exp, _, _ = at(phi)
            radius = rows["foot_radius"].iloc[0] if "foot_radius" in rows else math.nan
            if not pd.isna(radius):
                exp = exp.replace(foot_radius=float(radius))
            pos = table.index.get_indexer(rows.index)
            true_f[pos] = intrusion_force_scipy(
                phi,
                law,
                rows["depth_mm"].to_numpy(float),
                float(rows["speed_mm_s"].iloc[0]),
                exp,
                effects=physics,
            )
        sd = np.array([need(at(p)[3], "force_sd_N", p) for p in table["phi"].to_numpy(float)])
        table["force_N"] = true_f + sd * rng.standard_normal(len(table))
        table["true_force_N"] = true_f
        out["intrusions"] = table
    return out
