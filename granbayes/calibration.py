"""Error rates of ``diagnose``'s verdicts, measured on SYNTHETIC data sets with a known truth.

A verdict such as "the missing physics is drag" is a scientific claim; one data set proves
nothing. This module makes many data sets whose truth is known and records what
:func:`granbayes.diagnose` concludes on each:

``null``
    the truth is the baseline law (``depth`` with a quadratic ``k(phi)``): every verdict
    other than ``baseline_adequate`` is a false discovery;
a library term (``drag``, ``added_mass``, ``stiffening``, ``viscous``, ``compaction``,
``unloading``)
    the truth is the baseline plus that term: the verdict is right when it is ``extended``
    with exactly that term added (power);
``depth_dependent_drag``, ``janssen_saturation``, ``pause_relaxation``,
``rate_dependent_strength`` (physics outside the library)
    ground forces of the oracle's out-of-library physics (:mod:`granbayes.testing._effects`,
    each with its literature): a drag coefficient that grows or fades with depth on either
    side of ``phi_c`` (on top of a drawn ``c_d``), a depth force that saturates, a bed
    that relaxes and stiffens during a pause with its own time constant and is
    rejuvenated by motion, a static resistance that grows with the intrusion rate. The
    right answer is ``misfit_remains``, or an ``extended`` law that predicts a fresh
    replicate of the experiment as well as the truth does (:func:`fresh_deficit`): "no
    misfit cell" alone does not count;
``pause_stiffening``, ``rate_stiffening`` (earlier out-of-library cases, not forces)
    ``k`` rescaled per cell: after a hold (the delayed commands) or with the actuation
    frequency. Each cell on its own is a depth-only law; they are kept so that the
    committed study (which has them) can be summarised, and judged by the same rule.

Every case draws its robot, noise level, design (volume fractions, frequencies, repeated
jumps per cell; :data:`DESIGN_RANGES`) and effect size from documented ranges with its own
seed, so the study measures the rule over a population of plausible experiments, not one.
The true heights come from the independent oracle of the test kit
(:func:`granbayes.testing.simulate_height_scipy`), never from the compiled kernel that the
fits use, so a flaw of the kernel cannot be in both the data and the model; this is the one
import of the test kit by the package (the study is a test of the package).
:func:`diagnose_case` is the campaign task (``granbayes.campaign``); each row records
enough (every candidate's gain and SE, the baseline's misfit statistics) for
:func:`rederive_verdicts` to recompute the round-1 decision under other thresholds without
refitting, which is how the rule's thresholds are chosen.
"""

from __future__ import annotations

import dataclasses
import json
import time
from collections.abc import Callable, Mapping, Sequence
from typing import Any

import numpy as np
import pandas as pd
from scipy import stats

from ._criticism import Candidate, DiagnoseSettings, DiagnosisRecord, diagnose, distinguished
from ._deprecated import renamed_keyword
from ._experiment import Experiment, Robot
from ._measurements import Measurements
from ._priors import default_priors
from ._sampler import ProgressInfo
from .commands import COMMAND_NAMES, COMMANDS, CommandSettings
from .design import candidate_settings, design_jumps, design_parameters
from .forces import TERMS, terms_of
from .kinds import measurements
from .testing import (
    DepthDependentDrag,
    Effect,
    JanssenSaturation,
    LabDesign,
    PauseStiffening,
    RateStiffening,
    simulate_height_scipy,
    synthetic_lab_data,
    write_lab_experiment,
)

__all__ = [
    "CASE_KINDS",
    "DESIGN_RANGES",
    "EFFECT_RANGES",
    "LIBRARY_EFFECTS",
    "OUT_OF_LIBRARY",
    "PHYSICAL_EFFECTS",
    "STEP_BUDGET",
    "Case",
    "OUTCOMES",
    "OverBudget",
    "POWER_DESIGN",
    "POWER_SIZES",
    "POWER_TRACKING",
    "K_FLOOR",
    "StepCounter",
    "MISCALIBRATION",
    "diagnose_case",
    "diagnose_folder",
    "diagnose_miscalibrated",
    "design_parameter_case",
    "design_tie_case",
    "detected",
    "detection_sizes",
    "effect_size",
    "extra_jumps",
    "as_good_as_truth",
    "case_design",
    "clopper_pearson",
    "compare_studies",
    "flip_rates",
    "lack_of_fit_case",
    "fresh_deficit",
    "make_case",
    "tracked_frames",
    "named_terms",
    "outcome",
    "power_case",
    "power_table",
    "primary_rows",
    "rederive_verdicts",
    "summarize",
]

#: Effect sizes drawn (uniformly) for the library terms [SI].
EFFECT_RANGES: dict[str, dict[str, tuple[float, float]]] = {
    "drag": {"c_d": (40.0, 100.0)},
    "added_mass": {"kappa": (1.0, 2.0)},
    "stiffening": {"k2": (1.0e5, 2.0e5)},
    "viscous": {"b": (20.0, 40.0)},
    "compaction": {"c_comp": (0.5, 1.0)},
    "unloading": {"r_unload": (2.0, 4.0)},
}
LIBRARY_EFFECTS = tuple(EFFECT_RANGES)
#: Effects no library term represents, and the range their strength is drawn from
#: (uniformly; the unit is the parameter's, below).
OUT_OF_LIBRARY: dict[str, tuple[float, float]] = {
    "pause_stiffening": (0.25, 0.40),  # k x (1 + a) for the commands with a hold [-]
    "rate_stiffening": (0.30, 0.50),  # k x (1 + a (f - 10 Hz) / 10 Hz) [-]
    "depth_dependent_drag": (50.0, 150.0),  # DepthDependentDrag.depth_rate [1/m]
    "janssen_saturation": (0.03, 0.06),  # JanssenSaturation.lambda_m [m]
    "pause_relaxation": (0.5, 1.0),  # PauseStiffening.gain [-] (tau_s 40 ms)
    "rate_dependent_strength": (0.1, 0.3),  # RateStiffening.gain [-] (v_ref 0.05 m/s)
}
#: The oracle's physics of each out-of-library kind that is a ground force, at a strength.
_PHYSICS: dict[str, Callable[[float], Effect]] = {
    "depth_dependent_drag": lambda s: DepthDependentDrag(depth_rate=s),
    "janssen_saturation": lambda s: JanssenSaturation(lambda_m=s),
    "pause_relaxation": lambda s: PauseStiffening(gain=s),
    "rate_dependent_strength": lambda s: RateStiffening(gain=s),
}
#: The out-of-library kinds that are ground forces of the oracle (the others rescale k).
PHYSICAL_EFFECTS = tuple(_PHYSICS)
#: The drag coefficient [kg/m] under a depth-dependent drag (it multiplies ``c_d``).
_DEPTH_DRAG_C_D = (20.0, 40.0)
CASE_KINDS = ("null", *LIBRARY_EFFECTS, *OUT_OF_LIBRARY)

#: Sampler steps per walker, summed over every fit, rerun and held-out refit of one case,
#: after which the case is stopped and recorded with the verdict ``over_budget``. A step
#: budget, not a wall-clock one, so the outcome does not depend on the machine. Healthy
#: cases need about 4,000-12,000 (``benchmarks/calibrate_verdicts.py`` records every
#: case's count); the cap is reached by a case whose posterior the ensembles cannot mix
#: within ``diagnose``'s per-fit cap, where the rerun at twice the cap and every
#: candidate and held-out refit would each run to the cap as well (tens of CPU-minutes to
#: hours per case). Such a case gives no verdict within the budget; the study counts it
#: as not right and reports how many there were.
STEP_BUDGET = 60_000

_PHI_C = 0.612
_PHIS = (0.592, 0.597, 0.602, 0.607, 0.617, 0.622, 0.627, 0.632)
_FREQS_HZ = (7.0, 8.0, 10.0, 12.0)
_TRIALS = (2, 3, 4)
#: What a case's design and noise are drawn from (part of the study's fingerprint, so a
#: study cannot be resumed with cases drawn otherwise): two volume fractions, two
#: actuation frequencies [Hz], repeated jumps per cell, trial-to-trial scatter [mm].
DESIGN_RANGES: dict[str, Any] = {
    "phis": _PHIS,
    "freqs_hz": _FREQS_HZ,
    "trials": _TRIALS,
    "sigma_mm": (1.5, 3.0),
    "amplitude_mm": (16.0, 20.0),
}
#: The commands with a hold (the pause a pause-stiffened bed relaxes in).
_HELD = tuple(c.name for c in COMMANDS.values() if c.uses)


@dataclasses.dataclass(frozen=True)
class Case:
    """One synthetic data set of the study.

    Attributes
    ----------
    kind : str
        ``null``, a library term or an out-of-library effect (module docstring).
    experiment : Experiment
        The robot and command defaults.
    table : pandas.DataFrame
        The jumps (``load_jumps`` columns plus ``source``).
    truth : dict
        What was drawn: robot, noise, design, k law and effect size.
    true_height_mm : ndarray
        The noise-free heights of the table's rows [mm] (from the oracle).
    trajectories : pandas.DataFrame or None
        The tracked jumps' frames (``load_trajectories`` columns, validated as a user's
        file is), when the case was made with a tracking design (:data:`POWER_TRACKING`);
        else ``None``.
    """

    kind: str
    experiment: Experiment
    table: pd.DataFrame
    truth: dict
    true_height_mm: np.ndarray
    trajectories: pd.DataFrame | None = None

    def measurements(self) -> pd.DataFrame | Measurements:
        """What ``diagnose`` is given: the jumps, with the tracked jumps where there are."""
        if self.trajectories is None:
            return self.table
        return measurements({"heights": self.table, "trajectories": self.trajectories})


#: The smallest true ``k`` [N/m] of a case at any of its volume fractions: twice the lower
#: bound of ``k``'s default prior. The drawn law can dip far lower at the loosest packings
#: (to 106 N/m, and below zero in principle): a truth outside the prior's support, which
#: no fit can reach, so its misfit says nothing about the rule (the study of 2026-11-27
#: found its only false discovery and one miss there).
K_FLOOR = 2.0 * default_priors()["k"].lower


def _k_law(rng: np.random.Generator, phis: Sequence[float]) -> tuple[float, float, float]:
    """Coefficients of ``k(phi) = k0 + k1 x + k2 x^2`` [N/m], ``x = phi - phi_c``.

    ``k0`` is raised where needed so that ``k >= K_FLOOR`` at every one of ``phis`` (the
    draws are unchanged, so every case whose law stays above the floor is as before).
    """
    k0, k1, k2 = (
        float(rng.uniform(2500.0, 5000.0)),
        float(rng.uniform(0.8e5, 1.6e5)),
        float(rng.uniform(0.5e6, 2.0e6)),
    )
    lowest = min(k0 + k1 * (p - _PHI_C) + k2 * (p - _PHI_C) ** 2 for p in phis)
    return k0 + max(0.0, K_FLOOR - lowest), k1, k2


def _true_k(k_law: Sequence[float], phi: float) -> float:
    """A case's true ``k`` [N/m] at ``phi``: ``k0 + k1 x + k2 x^2``, ``x = phi - phi_c``."""
    k0, k1, k2 = k_law
    x = phi - _PHI_C
    return k0 + k1 * x + k2 * x * x


def _draw(
    kind: str,
    seed: int,
    trials: int | None,
    size: float | None = None,
    design: Mapping[str, tuple[int, int] | tuple[float, float]] | None = None,
) -> tuple[dict[str, Any], np.random.Generator]:
    """Everything a case draws before its heights, and the generator its noise continues.

    ``size`` fixes the effect's value (drawn all the same, so the other draws do not
    move); ``design`` draws the design from :data:`POWER_DESIGN`-like ranges instead of
    the study's two volume fractions and two frequencies.
    """
    if kind not in CASE_KINDS:
        raise ValueError(f"unknown case kind {kind!r}; expected one of {', '.join(CASE_KINDS)}")
    if size is not None and kind == "null":
        raise ValueError("a null case has no effect to size")
    rng = np.random.default_rng(seed)
    robot = Robot(
        m_motor=float(rng.uniform(0.8, 1.2)),
        m_rod=float(rng.uniform(0.15, 0.3)),
        m_foot=float(rng.uniform(0.08, 0.14)),
        k_spring=float(rng.uniform(4000.0, 7000.0)),
        c_spring=float(rng.uniform(2.0, 6.0)),
        foot_radius=float(rng.uniform(0.025, 0.04)),
    )
    amplitude_mm = float(rng.uniform(16.0, 20.0))
    if design is None:
        phis = tuple(sorted(float(p) for p in rng.choice(_PHIS, size=2, replace=False)))
        freqs = tuple(sorted(float(f) for f in rng.choice(_FREQS_HZ, size=2, replace=False)))
        sigma_mm = float(rng.uniform(1.5, 3.0))
        if trials is None:
            trials = int(rng.choice(_TRIALS))
    else:
        n_phi = int(rng.integers(design["n_phis"][0], design["n_phis"][1] + 1))
        n_freq = int(rng.integers(design["n_freqs"][0], design["n_freqs"][1] + 1))
        phis = tuple(sorted(float(p) for p in rng.choice(_PHIS, size=n_phi, replace=False)))
        freqs = tuple(sorted(float(f) for f in rng.choice(_FREQS_HZ, size=n_freq, replace=False)))
        sigma_mm = float(rng.uniform(*design["sigma_mm"]))
        if trials is None:
            trials = int(rng.integers(design["trials"][0], design["trials"][1] + 1))
    k0, k1, k2 = _k_law(rng, phis)
    effect: dict[str, float] = {}
    strength = 0.0
    if kind in EFFECT_RANGES:
        effect = {n: float(rng.uniform(*r)) for n, r in EFFECT_RANGES[kind].items()}
        if size is not None:
            ((name, _),) = effect.items()
            effect = {name: float(size)}
    elif kind in OUT_OF_LIBRARY:
        strength = float(rng.uniform(*OUT_OF_LIBRARY[kind]))
        if kind == "depth_dependent_drag":
            effect = {"c_d": float(rng.uniform(*_DEPTH_DRAG_C_D))}
        if size is not None:
            strength = float(size)
    truth = {
        "robot": dataclasses.asdict(robot),
        "amplitude_mm": amplitude_mm,
        "phis": list(phis),
        "freqs_hz": list(freqs),
        "sigma_mm": sigma_mm,
        "trials": trials,
        "k_law": [k0, k1, k2],
        "effect": effect,
        "out_of_library_strength": strength,
    }
    return truth, rng


def case_design(kind: str, seed: int, trials: int | None = None) -> dict[str, Any]:
    """What :func:`make_case` draws from ``seed`` (robot, design, noise level, truth), cheaply.

    The same values as ``make_case(kind, seed, trials).truth``, without simulating a jump.

    Parameters
    ----------
    kind : str
        One of :data:`CASE_KINDS`.
    seed : int
        The case's seed.
    trials : int, optional
        Repeated jumps per cell (drawn if not given).

    Returns
    -------
    dict
    """
    return _draw(kind, seed, trials)[0]


def make_case(
    kind: str,
    seed: int,
    trials: int | None = None,
    replicate: int = 0,
    *,
    size: float | None = None,
    design: Mapping[str, tuple[int, int] | tuple[float, float]] | None = None,
    tracking: Mapping[str, Any] | None = None,
) -> Case:
    """A SYNTHETIC data set of the given kind (module docstring), drawn from ``seed``.

    The true heights come from the independent oracle
    (:func:`granbayes.testing.simulate_height_scipy`, with the kind's out-of-library
    physics where it has some), about 1-2 s per case.

    Parameters
    ----------
    kind : str
        One of :data:`CASE_KINDS`.
    seed : int
        Seed of everything drawn (robot, noise, design, effect, scatter).
    trials : int, optional
        Repeated jumps per cell; drawn from 2, 3 or 4 (after the scatter) if not given.
    replicate : int, default 0
        0: the case itself. ``r > 0``: an independent repetition of the same experiment
        (same robot, design, truth and scatter; new noise from the stream ``(seed, r)``),
        on which a fitted law's predictions are scored out of sample.
    size : float, optional
        The effect's value instead of a draw from its range: the library term's parameter
        (:data:`EFFECT_RANGES`) or the out-of-library strength (:data:`OUT_OF_LIBRARY`);
        the power curves' cases (:data:`POWER_SIZES`).
    design : mapping, optional
        Ranges of the design instead of the study's (two volume fractions, two
        frequencies): ``n_phis``, ``n_freqs`` and ``trials`` (inclusive integer ranges)
        and ``sigma_mm`` (:data:`POWER_DESIGN`).
    tracking : mapping, optional
        Film some jumps as well (:data:`POWER_TRACKING`'s keys): the case then has
        ``trajectories`` (:func:`tracked_frames`). The jump heights are the same as
        without it, bit for bit: the frames draw from a stream of their own.

    Returns
    -------
    Case
    """
    truth, rng = _draw(kind, seed, trials, size, design)
    robot = Robot(**truth["robot"])
    amplitude_mm = truth["amplitude_mm"]
    experiment = Experiment(robot=robot, command=CommandSettings(amplitude_mm=amplitude_mm))
    phis, freqs, trials = truth["phis"], truth["freqs_hz"], truth["trials"]
    sigma_mm = truth["sigma_mm"]
    rows = []
    heights = _cell_heights(kind, truth, experiment)
    for phi in phis:
        for freq in freqs:
            for command in COMMAND_NAMES:
                height = heights[phi, freq, command]
                for trial in range(1, trials + 1):
                    rows.append(
                        {
                            "phi": phi,
                            "command": command,
                            "freq_hz": freq,
                            "amplitude_mm": amplitude_mm,
                            "delay_ms": experiment.command.delay_ms,
                            "settle_periods": experiment.command.settle_periods,
                            "trial": trial,
                            "true_height_mm": height,
                        }
                    )
    table = pd.DataFrame(rows)
    noise = rng if replicate == 0 else np.random.default_rng([seed, replicate])
    table["height_mm"] = table["true_height_mm"] + noise.normal(0.0, sigma_mm, len(table))
    table["source"] = f"synthetic: granbayes.calibration kind={kind} seed={seed}" + (
        f" replicate={replicate}" if replicate else ""
    )
    true_height = table["true_height_mm"].to_numpy(dtype=float)
    frames = None
    if tracking is not None:
        frames = tracked_frames(kind, truth, experiment, tracking, seed=[seed, replicate, 1])
        frames["source"] = table["source"].iloc[0]
        frames = _validated_frames(frames, experiment)
    return Case(kind, experiment, table.drop(columns="true_height_mm"), truth, true_height, frames)


def tracked_frames(
    kind: str,
    truth: Mapping[str, Any],
    experiment: Experiment,
    tracking: Mapping[str, Any],
    *,
    seed: int | Sequence[int],
) -> pd.DataFrame:
    """The frames of a case's filmed jumps, made by the oracle (SYNTHETIC).

    At every volume fraction of ``truth``, trial 1 of each of ``tracking["commands"]`` at
    the first frequency is filmed at ``fps`` frames/s from ``from_s`` [s] to ``after_s``
    [s] past the end of its command (every command's jump has landed by then at the
    study's heights). The frames are the oracle's foot height and rod displacement
    (:func:`granbayes.testing.replicate_measurements`, with the case's out-of-library
    physics) at the robot's times ``t + delta``, ``delta`` a clock offset uniform within
    ``offset_frames`` frames (the window the fit integrates over is this one plus half a
    grid step), plus Ornstein-Uhlenbeck noise of ``frame_sd_mm`` (both coordinates) and
    correlation time ``frame_tau_ms``.

    Parameters
    ----------
    kind : str
        The case's kind (one of :data:`CASE_KINDS` other than the earlier
        ``pause_stiffening``/``rate_stiffening``, which rescale ``k`` per cell and are not
        forces a trajectory could carry).
    truth : mapping
        The case's truth (:attr:`Case.truth`).
    experiment : Experiment
        Its robot and command defaults.
    tracking : mapping
        ``commands``, ``fps`` [1/s], ``from_s`` [s], ``after_s`` [s], ``frame_sd_mm``
        [mm], ``frame_tau_ms`` [ms] and ``offset_frames`` (:data:`POWER_TRACKING`).
    seed : int or sequence of int
        Seed of the clock offsets and the frame noise.

    Returns
    -------
    pandas.DataFrame
        ``trajectories.csv``'s columns (``jump``, ``phi``, ``command``, ``trial``,
        ``freq_hz``, ``amplitude_mm``, ``t_s``, ``x_foot_mm``, ``x_rod_mm``) and the truth
        (``true_offset_s``, ``true_x_foot_mm``, ``true_x_rod_mm``).

    Raises
    ------
    ValueError
        For a kind that rescales ``k`` per cell.
    """
    from .testing import replicate_measurements

    if kind in OUT_OF_LIBRARY and kind not in _PHYSICS:
        raise ValueError(f"{kind!r} rescales k per cell: it is no force a trajectory can carry")
    freq = float(truth["freqs_hz"][0])
    amplitude_mm = float(truth["amplitude_mm"])
    settings = CommandSettings(amplitude_mm=amplitude_mm, freq_hz=freq)
    dt = 1.0 / float(tracking["fps"])
    rows, laws, windows = [], {}, {}
    for phi in truth["phis"]:
        laws[phi] = {
            "k": _true_k(truth["k_law"], phi),
            **truth["effect"],
            "frame_sd_foot_mm": float(tracking["frame_sd_mm"]),
            "frame_sd_rod_mm": float(tracking["frame_sd_mm"]),
            "frame_tau_ms": float(tracking["frame_tau_ms"]),
        }
        for command in tracking["commands"]:
            end = COMMANDS[command].program(settings).t_end
            n = int(np.floor((end + float(tracking["after_s"]) - tracking["from_s"]) / dt)) + 1
            jump = f"phi={phi:g} {command} {freq:g}Hz"
            windows[jump] = float(tracking["offset_frames"]) * dt
            for t in float(tracking["from_s"]) + dt * np.arange(n):
                rows.append(
                    {
                        "jump": jump,
                        "phi": phi,
                        "command": command,
                        "trial": 1,
                        "freq_hz": freq,
                        "amplitude_mm": amplitude_mm,
                        "t_s": round(float(t), 9),
                        "x_foot_mm": np.nan,
                        "x_rod_mm": np.nan,
                    }
                )
    strength = truth["out_of_library_strength"]
    physics = (_PHYSICS[kind](strength),) if kind in _PHYSICS else None
    out = replicate_measurements(
        experiment,
        {"trajectories": pd.DataFrame(rows)},
        laws,
        rng=np.random.default_rng(seed),
        offset_window_s=windows,
        effects=physics,
    )
    return out["trajectories"]


def _validated_frames(frames: pd.DataFrame, experiment: Experiment) -> pd.DataFrame:
    """Frames read back as a user's ``trajectories.csv`` is (the same checks and columns)."""
    import tempfile
    from pathlib import Path

    from ._measurements import load_trajectories

    public = [c for c in frames.columns if not c.startswith("true_")]
    with tempfile.TemporaryDirectory() as folder:
        path = Path(folder) / "trajectories.csv"
        frames[public].to_csv(path, index=False)
        return load_trajectories(path, experiment)


def _cell_heights(
    kind: str, truth: Mapping[str, Any], experiment: Experiment, with_effect: bool = True
) -> dict[tuple[float, float, str], float]:
    """The oracle's noise-free height [mm] of every cell (phi, frequency, command).

    ``with_effect=False``: the same robot, design and ``k(phi)`` without the case's
    effect, for the effect's size in height: the baseline law's truth, except for
    ``depth_dependent_drag``, whose reference keeps its drawn drag ``c_d`` (a library law)
    and loses the depth dependence, the part of the effect the library has no term for and
    the size its power curve varies.
    """
    keep_drag = kind == "depth_dependent_drag"
    effect = truth["effect"] if with_effect or keep_drag else {}
    strength = truth["out_of_library_strength"] if with_effect else 0.0
    physics = (_PHYSICS[kind](strength),) if with_effect and kind in _PHYSICS else None
    amplitude_mm = truth["amplitude_mm"]
    out = {}
    for phi in truth["phis"]:
        k = _true_k(truth["k_law"], phi)
        for freq in truth["freqs_hz"]:
            settings = CommandSettings(amplitude_mm=amplitude_mm, freq_hz=freq)
            cell_exp = dataclasses.replace(experiment, command=settings)
            for command in COMMAND_NAMES:
                scale = 1.0
                if kind == "pause_stiffening" and command in _HELD:
                    scale = 1.0 + strength
                elif kind == "rate_stiffening":
                    scale = 1.0 + strength * (freq - 10.0) / 10.0
                params = {"k": k * scale, **effect}
                out[phi, freq, command] = simulate_height_scipy(
                    command, phi, params, cell_exp, effects=physics
                )
    return out


def effect_size(case: Case) -> dict[str, float]:
    """How large a case's effect is in the heights, before any fit (oracle, no noise).

    Parameters
    ----------
    case : Case
        A case with an effect (not ``null``).

    Returns
    -------
    dict
        ``effect_rms_mm``: the root mean square over cells of the height change the effect
        makes [mm]; ``effect_snr``: the change over every jump in units of the scatter,
        ``sqrt(sum (dh / sigma)^2)`` (twice the log-likelihood ratio of the truth against
        the effect-free law with the same ``k``, in expectation, is its square). Both
        overstate what a fit sees: the baseline law refits ``k`` and absorbs part of it.
        For ``depth_dependent_drag`` the change is against the same drag without its
        depth dependence (:func:`_cell_heights`).
    """
    off = _cell_heights(case.kind, case.truth, case.experiment, with_effect=False)
    cells = zip(case.table["phi"], case.table["freq_hz"], case.table["command"], strict=True)
    # every cell has the same number of trials: over jumps is over cells
    dh = case.true_height_mm - np.array([off[c] for c in cells])
    sigma = case.truth["sigma_mm"]
    return {
        "effect_rms_mm": float(np.sqrt(np.mean(dh**2))),
        "effect_snr": float(np.sqrt(np.sum((dh / sigma) ** 2))),
    }


def fresh_deficit(
    law: Any, table: pd.DataFrame, true_height_mm: np.ndarray, sigma_mm: float
) -> tuple[float, float]:
    """How much worse than the truth a fitted law predicts a fresh replicate [nats].

    ``sum_i [log p_true(y_i) - log p_law(y_i)]`` over the jumps of ``table`` (a replicate
    the fit never saw: :func:`make_case` with ``replicate > 0``, or any new table of the
    same experiment), where the truth's density is its Gaussian noise around the true
    heights and the law's is its posterior predictive density
    (``law.log_predictive_density``), with the SE of the sum of the paired differences.
    Positive: the truth predicts better. A law predicts "as well as the truth" when this is
    within the rule's margin (:func:`as_good_as_truth`).

    Parameters
    ----------
    law : FitResult
        A fitted law (e.g. ``Diagnosis.selected``).
    table : pandas.DataFrame
        The fresh jumps.
    true_height_mm : ndarray
        Their noise-free heights [mm] (``Case.true_height_mm``).
    sigma_mm : float
        The true noise [mm].

    Returns
    -------
    deficit, se : float
    """
    y = table["height_mm"].to_numpy(dtype=float)
    truth = stats.norm.logpdf(y, np.asarray(true_height_mm, dtype=float), sigma_mm)
    return _paired_sum(truth - np.asarray(law.log_predictive_density(table), dtype=float))


def _paired_sum(diff: np.ndarray) -> tuple[float, float]:
    """Sum of paired pointwise differences [nats] and its SE, ``sqrt(n) sd(diff)`` (n - 1)."""
    return float(np.sum(diff)), float(np.sqrt(len(diff)) * np.std(diff, ddof=1))


@renamed_keyword("config")
def as_good_as_truth(deficit: float, se: float, settings: DiagnoseSettings | None = None) -> bool:
    """Whether a law's fresh-replicate deficit is within the rule's margin.

    The rule calls a difference real when it exceeds ``min_gain`` nats *and* ``se_factor``
    SE (:func:`granbayes._criticism.distinguished`, the test a term must pass to be added);
    a deficit that is not real by that rule counts as predicting as well as the truth.

    Parameters
    ----------
    deficit, se : float
        From :func:`fresh_deficit` [nats].
    settings : DiagnoseSettings, optional
        The rule (default settings if omitted).

    Returns
    -------
    bool
    """
    return not distinguished(deficit, se, settings or DiagnoseSettings())


class OverBudget(RuntimeError):
    """A case's diagnosis needed more sampler steps than its budget."""


class StepCounter:
    """``diagnose`` progress callback that counts sampler steps and enforces a budget.

    Every fit run reports its steps per walker after each chunk under its own label; the
    counter sums the increments over all labels (a label whose count falls is a new run).

    Parameters
    ----------
    budget : int, optional
        Steps after which :class:`OverBudget` is raised (None: count only).
    """

    def __init__(self, budget: int | None = None) -> None:
        self.budget = budget
        self.steps = 0
        self._last: dict[str, int] = {}

    def __call__(self, label: str, info: ProgressInfo) -> None:
        """Add the steps of run ``label`` since its last report."""
        last = self._last.get(label, 0)
        self.steps += info.step - last if info.step >= last else info.step
        self._last[label] = info.step
        if self.budget is not None and self.steps > self.budget:
            raise OverBudget(f"{self.steps} sampler steps > the budget of {self.budget}")


@renamed_keyword("config")
def diagnose_case(
    kind: str,
    index: int,
    settings: DiagnoseSettings | None = None,
    *,
    seed: int,
    step_budget: int | None = STEP_BUDGET,
    sampler_replicate: int = 0,
) -> list[dict[str, Any]]:
    """Campaign task: make a case, run ``diagnose`` on it and record the outcome.

    Parameters
    ----------
    kind : str
        Case kind (:data:`CASE_KINDS`).
    index : int
        Replicate number within its kind (recorded).
    settings : DiagnoseSettings, optional
        The rule and sampler settings under study.
    seed : int
        The task's seed: the case is drawn from it, and ``diagnose`` gets a spawned one.
    step_budget : int, optional
        Sampler steps (:data:`STEP_BUDGET`) after which the case is stopped and recorded
        with the verdict ``over_budget`` (None: no budget).
    sampler_replicate : int, default 0
        0: ``diagnose`` with the case's own sampler seed. ``r > 0``: the same case (the
        same data, drawn from ``seed``) diagnosed again with another sampler seed, the
        ``(r + 1)``-th child of ``seed`` after the case's: the Monte Carlo sensitivity of
        the verdict (:func:`flip_rates`).

    Returns
    -------
    list of dict
        One row: the truth summary, the sampler replicate, the verdict, what was added and
        the claim (each round's term with the terms it is not distinguished from), the
        gains, the misfit statistics, the round-1 candidates (JSON text) for
        :func:`rederive_verdicts`, the sampler steps and the wall time [s].
    """
    if sampler_replicate < 0:
        raise ValueError(f"sampler_replicate must be >= 0, got {sampler_replicate}")
    # the children of ``seed`` do not depend on how many are spawned: replicate 0 keeps
    # the sampler seed the study had before replicates existed
    children = np.random.SeedSequence(seed).spawn(2 + sampler_replicate)
    case_seed = int(children[0].generate_state(1)[0])
    diag_seed = int(children[1 + sampler_replicate].generate_state(1)[0])
    return _diagnosed(
        make_case(kind, case_seed),
        index,
        settings,
        case_seed,
        diag_seed,
        step_budget,
        {"sampler_replicate": int(sampler_replicate)},
    )


def lack_of_fit_case(
    kind: str,
    index: int,
    added: Sequence[str],
    settings: DiagnoseSettings | None = None,
    *,
    seed: int,
) -> list[dict[str, Any]]:
    """Campaign task: a study case's selected law refitted, and its omnibus lack of fit.

    The case of :func:`diagnose_case` with the same task ``seed`` (the same data), fitted
    with the baseline plus ``added`` (the terms its diagnosis added) with the
    diagnosis.s sampler settings; :func:`granbayes.stats.lack_of_fit` of the fit
    and its largest cell |z| (:func:`granbayes.stats.residual_table`). Whether the
    omnibus test would have flagged the law a diagnosis selected, read against the study's
    outcome (``benchmarks/lack_of_fit.py``).

    Parameters
    ----------
    kind : str
        Case kind (:data:`CASE_KINDS`).
    index : int
        Replicate number within its kind (recorded).
    added : sequence of str
        Terms the diagnosis added to the baseline (empty: the baseline law).
    settings : DiagnoseSettings, optional
        The rule and sampler settings of the study.
    seed : int
        The study's task seed of the case.

    Returns
    -------
    list of dict
        One row: the law, the omnibus statistic, its degrees of freedom and p-value, the
        largest cell |z|, convergence and wall time [s].
    """
    from . import stats as gstats

    cfg = settings or DiagnoseSettings()
    children = np.random.SeedSequence(seed).spawn(2)
    case_seed, fit_seed = (int(c.generate_state(1)[0]) for c in children)
    case = make_case(kind, case_seed)
    t0 = time.perf_counter()
    result = _fit_case_law(case, case.table, terms_of((*cfg.baseline, *added)), cfg, fit_seed, 1)
    test = gstats.lack_of_fit(result.datatree)
    cells = gstats.residual_table(result.datatree)
    return [
        {
            "kind": kind,
            "index": int(index),
            "law": "+".join(terms_of((*cfg.baseline, *added))),
            "lof_statistic": test["statistic"],
            "lof_dof_lack": test["dof_lack"],
            "lof_dof_pure": test["dof_pure"],
            "lof_p_value": test["p_value"],
            "max_abs_z": float(cells["z"].abs().max()),
            "converged": bool(result.converged),
            "wall_s": time.perf_counter() - t0,
        }
    ]


def _diagnosed(
    case: Case,
    index: int,
    settings: DiagnoseSettings | None,
    case_seed: int,
    diag_seed: int,
    step_budget: int | None,
    extra: Mapping[str, Any],
    size: float | None = None,
    design: Mapping[str, Any] | None = None,
) -> list[dict[str, Any]]:
    """:func:`diagnose_case`'s row: a case diagnosed with ``diag_seed``.

    ``case`` is ``make_case(case.kind, case_seed, size=size, design=design)`` (its fresh
    replicate is made the same way); ``extra`` columns follow the truth's.
    """
    kind = case.kind
    counter = StepCounter(step_budget)
    truth = {
        "kind": kind,
        "index": int(index),
        "truth_effect": "+".join(f"{k}={v:.4g}" for k, v in case.truth["effect"].items()),
        "ool_strength": case.truth["out_of_library_strength"],
        "sigma_mm": case.truth["sigma_mm"],
        "phis": "/".join(f"{p:g}" for p in case.truth["phis"]),
        "freqs_hz": "/".join(f"{f:g}" for f in case.truth["freqs_hz"]),
        "trials": case.truth["trials"],
        **extra,
    }
    t0 = time.perf_counter()
    try:
        d = diagnose(
            case.experiment,
            case.measurements(),
            settings,
            seed=diag_seed,
            log=lambda *a, **k: None,
            progress=counter,
        )
    except OverBudget:
        return [
            {
                **truth,
                "verdict": "over_budget",
                "added": "",
                "all_converged": False,
                "round1": "[]",
                "sampler_steps": counter.steps,
                "wall_time_s": time.perf_counter() - t0,
            }
        ]
    rec = d.record
    misfit = d.residuals_before
    sel = rec.selected
    # the selected law against the baseline on a new run of the same experiment: the gain
    # a user would see on fresh data, free of the selection's optimism
    fresh_case = make_case(kind, case_seed, replicate=1, size=size, design=design)
    fresh = fresh_case.table
    gain_fresh, gain_fresh_se = _paired_sum(
        d.selected.log_predictive_density(fresh) - d.baseline.log_predictive_density(fresh)
    )
    deficit, deficit_se = fresh_deficit(
        d.selected, fresh, fresh_case.true_height_mm, fresh_case.truth["sigma_mm"]
    )
    return [
        {
            **truth,
            "verdict": rec.verdict.value,
            "added": "+".join(sel.added),
            "indistinguishable": "+".join(sorted({t.term for t in sel.indistinguishable})),
            "claim": _claim(rec),
            "elpd_gain": sel.elpd_gain,
            "elpd_gain_se": sel.elpd_gain_se,
            "elpd_gain_cells": sel.elpd_gain_cells,
            "elpd_gain_cells_se": sel.elpd_gain_cells_se,
            "gain_fresh": gain_fresh,
            "gain_fresh_se": gain_fresh_se,
            "deficit_fresh": deficit,
            "deficit_fresh_se": deficit_se,
            "as_good_as_truth": as_good_as_truth(deficit, deficit_se, settings),
            "n_cells": len(misfit),
            "dof_min": float(misfit["dof"].min()) if "dof" in misfit else np.nan,
            "baseline_max_abs_z": float(misfit["z"].abs().max()),
            "n_misfit_baseline": rec.n_misfit_cells,
            "n_residual_misfit": len(rec.residual_misfit),
            "residual_max_abs_z": float(max((abs(c.z_after) for c in sel.per_cell), default=0.0)),
            "z_threshold": rec.rule.z_threshold,
            "family_alpha": rec.rule.family_alpha,
            "lof_p_baseline": rec.lack_of_fit.get("baseline", {}).get("p_value", np.nan),
            "lof_p_selected": rec.lack_of_fit.get("selected", {}).get("p_value", np.nan),
            "lack_of_fit_alpha": rec.rule.lack_of_fit_alpha,
            "all_converged": rec.all_converged,
            "n_fits": len(rec.fits),
            "n_reruns": int(sum(f.reruns for f in rec.fits)),
            "n_screened_out": sum(c.screened_out for c in rec.candidates),
            "round1": _round1_json([c for c in rec.candidates if c.round == 1]),
            "sampler_steps": counter.steps,
            "wall_time_s": time.perf_counter() - t0,
        }
    ]


@renamed_keyword("config")
def diagnose_folder(
    folder: str, *, seed: int, settings: DiagnoseSettings | None = None
) -> list[dict[str, Any]]:
    """Campaign task: diagnose an experiment folder with one seed and summarise the outcome.

    Used to check that a verdict does not depend on the seed (the same data diagnosed with
    several seeds must give the same answer) and that no fitted candidate ends below its
    nested parent (a sampling failure the robust sampler must prevent).

    Parameters
    ----------
    folder : str
        Experiment folder.
    seed : int
        Seed of the diagnosis.
    settings : DiagnoseSettings, optional

    Returns
    -------
    list of dict
        One row: verdict, added terms, ELPD gain, convergence, the number of fits, reruns
        and screened-out candidates, the smallest ELPD gain of a fitted candidate over its
        parent (``min_gain_vs_parent`` [nats] and its SE), every candidate's gain (JSON
        text) and the wall time [s].
    """
    import json

    from ._experiment import load_experiment
    from ._measurements import load_jumps

    experiment = load_experiment(folder)
    table = load_jumps(folder, experiment)
    t0 = time.perf_counter()
    d = diagnose(
        experiment, table, settings, seed=seed, data_source=str(folder), log=lambda *a: None
    )
    rec = d.record
    fitted = [c for c in d.candidates if not c.screened_out]
    worst = min(fitted, key=lambda c: c.gain - 2.0 * c.gain_se, default=None)
    return [
        {
            "seed": int(seed),
            "verdict": rec.verdict.value,
            "added": "+".join(rec.selected.added),
            "indistinguishable": "; ".join(
                f"{t.selected}~{t.term} ({t.elpd_diff:+.1f} ± {t.elpd_diff_se:.1f})"
                for t in rec.selected.indistinguishable
            ),
            "claim": _claim(rec),
            "elpd_gain": rec.selected.elpd_gain,
            "elpd_gain_se": rec.selected.elpd_gain_se,
            "all_converged": rec.all_converged,
            "n_fits": len(rec.fits),
            "n_reruns": int(sum(f.reruns for f in rec.fits)),
            "n_screened_out": len(d.candidates) - len(fitted),
            "min_gain_vs_parent": np.nan if worst is None else worst.gain,
            "min_gain_vs_parent_se": np.nan if worst is None else worst.gain_se,
            "candidates": json.dumps(
                [
                    {
                        "round": c.round,
                        "term": c.term,
                        "gain": None if c.screened_out else round(c.gain, 2),
                        "se": None if c.screened_out else round(c.gain_se, 2),
                        "screen_gain": round(c.screen_gain, 2),
                    }
                    for c in d.candidates
                ]
            ),
            "wall_time_s": time.perf_counter() - t0,
        }
    ]


#: The null study of a robot known only to its calibration (:func:`diagnose_miscalibrated`):
#: one standard deviation of each calibrated parameter of the nominal robot
#: (``Experiment()``), as written to ``[robot.uncertainty]`` [TOML units].
MISCALIBRATION: dict[str, float] = {"k_spring": 172.8, "m_motor": 0.02, "amplitude_mm": 0.4}


@renamed_keyword("config")
def diagnose_miscalibrated(
    calibration: str,
    *,
    seed: int,
    trials: int = 4,
    offsets_sd: Mapping[str, float] | None = None,
    settings: DiagnoseSettings | None = None,
    phi_sd: float = 0.0,
) -> list[dict[str, Any]]:
    """Campaign task: ``diagnose`` on null data from a robot known only to its calibration.

    The SYNTHETIC lab (:func:`granbayes.testing.synthetic_lab_data`, the oracle) draws the
    robot's true spring, motor mass and stroke from their calibration (Normal(nominal,
    :data:`MISCALIBRATION`)), a depth-only law ``k(phi)`` (the verdict study's quadratic
    ranges) and a scatter of 1-2 mm, and measures 5 volume fractions x 2 frequencies x 5
    commands x ``trials`` jumps. The truth is the baseline law: every verdict other than
    ``baseline_adequate`` is a false discovery. ``calibration`` is the diagnosis's
    (``"sample"``: every fit samples the three parameters with their calibration as
    prior; ``"nominal"``: takes them as exact).

    Parameters
    ----------
    calibration : {"sample", "nominal"}
    seed : int
        The data are drawn from it (the same data for both ``calibration`` values), and
        ``diagnose`` gets a spawned one.
    trials : int
        Jumps per cell.
    offsets_sd : mapping of str to float, optional
        Fixed true values instead of draws: each key of :data:`MISCALIBRATION` this far
        from nominal [calibration sds] (the others drawn).
    settings : DiagnoseSettings, optional
        The rule and sampler settings (its ``calibration`` is replaced).
    phi_sd : float
        Each jump's bed's true phi scatters about the written one by this much (one bed
        per jump, ``phi_jitter="jump"``), and ``[bed] phi_sd`` says so (0: exact beds, and
        the data of earlier studies bit for bit).

    Returns
    -------
    list of dict
        One row: the truth (each parameter's offset from nominal in calibration sds, the
        scatter, ``phi_sd``), the verdict, the terms added, the gain and SE, convergence, fits, wall
        time [s].
    """
    import tempfile
    from pathlib import Path

    from ._experiment import load_experiment
    from .kinds import load_measurements

    data_seed, diag_seed = (
        int(s.generate_state(1)[0]) for s in np.random.SeedSequence(seed).spawn(2)
    )
    rng = np.random.default_rng(data_seed)
    phis = (0.592, 0.602, 0.612, 0.622, 0.632)
    k0, k1, k2 = _k_law(rng, phis)
    sigma_mm = float(rng.uniform(1.0, 2.0))
    design = LabDesign(
        phis=phis,
        commands=COMMAND_NAMES,
        freqs_hz=(10.0, 12.0),
        trials=trials,
        sigma_mm=sigma_mm,
        tracked_trials=0,
        intrusion_speeds_mm_s=(),
        robot_sd=MISCALIBRATION,
        robot_true=_offset_robot(offsets_sd or {}),
        phi_sd=phi_sd,
        phi_jitter="jump",
    )
    lab = synthetic_lab_data(
        lambda phi: {"k": k0 + k1 * (phi - _PHI_C) + k2 * (phi - _PHI_C) ** 2},
        seed=data_seed,
        design=design,
    )
    settings = dataclasses.replace(settings or DiagnoseSettings(), calibration=calibration)
    t0 = time.perf_counter()
    with tempfile.TemporaryDirectory() as tmp:
        folder = write_lab_experiment(Path(tmp) / "lab", lab)
        experiment = load_experiment(folder)
        data = load_measurements(folder, experiment)
        d = diagnose(
            experiment, data, settings, seed=diag_seed, data_source=lab.source, log=lambda *a: None
        )
    rec = d.record
    true_robot, nominal = lab.true_experiment.robot_values, lab.experiment.robot_values
    return [
        {
            "seed": int(seed),
            "calibration": calibration,
            **{
                f"{k}_offset_sd": (true_robot[k] - nominal[k]) / sd
                for k, sd in MISCALIBRATION.items()
            },
            "sigma_mm": sigma_mm,
            "phi_sd": phi_sd,
            "verdict": rec.verdict.value,
            "added": "+".join(rec.selected.added),
            "claim": _claim(rec),
            "elpd_gain": rec.selected.elpd_gain,
            "elpd_gain_se": rec.selected.elpd_gain_se,
            "n_misfit_cells": rec.n_misfit_cells,
            "all_converged": rec.all_converged,
            "n_fits": len(rec.fits),
            "wall_s": time.perf_counter() - t0,
        }
    ]


def _offset_robot(offsets_sd: Mapping[str, float]) -> dict[str, float]:
    """True robot values ``nominal + offset x sd`` of :data:`MISCALIBRATION`'s keys."""
    unknown = set(offsets_sd) - set(MISCALIBRATION)
    if unknown:
        raise ValueError(f"offsets of {sorted(unknown)}: only {sorted(MISCALIBRATION)}")
    nominal = Experiment().robot_values
    return {k: nominal[k] + z * MISCALIBRATION[k] for k, z in offsets_sd.items()}


def _claim(rec: DiagnosisRecord) -> str:
    """What a diagnosis claims, independent of which of two tied terms scored higher.

    Per round, the added term together with the terms it is not distinguished from, as a
    sorted set: ``"{compaction} + {drag|viscous}"``.
    """
    ties: dict[int, set[str]] = {}
    for t in rec.selected.indistinguishable:
        ties.setdefault(t.round, set()).add(t.term)
    return " + ".join(
        "{" + "|".join(sorted({term} | ties.get(r, set()))) + "}"
        for r, term in enumerate(rec.selected.added, start=1)
    )


def _round1_json(candidates: Sequence[Candidate]) -> str:
    """The round-1 candidates, as :func:`rederive_verdicts` reads them (JSON text)."""
    import json

    keep = ("term", "elpd_diff_vs_current", "elpd_diff_vs_current_se", "converged", "screen_gain")
    return json.dumps([{k: c.to_json()[k] for k in keep} for c in candidates])


def rederive_verdicts(
    results: pd.DataFrame,
    *,
    min_gain: float,
    se_factor: float,
    strong_gain: float,
    family_alpha: float | None = None,
) -> pd.Series:
    """Round-1 outcome of each case under other thresholds, without refitting.

    The term the rule would add in round 1 (``""``: none) given the recorded candidates
    and baseline misfit. With ``family_alpha`` the misfit threshold is recomputed from the
    recorded number of cells and degrees of freedom; otherwise the recorded one is used.
    Later rounds are not rederived (they need the fits of round 1's choice). Candidates
    screened out (no ELPD) count as not eligible, so thresholds below the screening bar
    the study ran with (its ``min_gain``) are not rederived faithfully: sweep at or above
    it.

    Parameters
    ----------
    results : pandas.DataFrame
        Rows of :func:`diagnose_case`.
    min_gain, se_factor, strong_gain : float
        The rule's thresholds [nats, -, nats].
    family_alpha : float, optional
        Family-wise false-alarm rate of the misfit cells.

    Returns
    -------
    pandas.Series of str
    """
    import json

    from scipy import stats

    out = []
    for r in results.itertuples():
        if r.verdict == "over_budget":  # no decision was reached
            out.append("")
            continue
        if family_alpha is None:
            thr = r.z_threshold
        else:
            q = family_alpha / (2.0 * r.n_cells)
            dof = _dof(r)
            thr = stats.t.isf(q, dof) if dof > 0 else stats.norm.isf(q)
        misfit = r.baseline_max_abs_z > thr
        cands = [
            c
            for c in json.loads(r.round1)
            if c["converged"] and c["elpd_diff_vs_current"] is not None
        ]
        if not cands:
            out.append("")
            continue
        best = max(cands, key=lambda c: c["elpd_diff_vs_current"])
        gain, se = best["elpd_diff_vs_current"], best["elpd_diff_vs_current_se"]
        clear = gain > min_gain and gain > se_factor * se
        out.append(best["term"] if clear and (misfit or gain > strong_gain) else "")
    return pd.Series(out, index=results.index)


def _dof(row) -> float:
    """Pooled degrees of freedom of a case's scatter.

    Rows that lack it (recorded before it was) get it back from their recorded threshold,
    ``t.isf(alpha / (2 n), dof)``.
    """
    from scipy import optimize, stats

    dof = getattr(row, "dof_min", None)
    if dof is not None and np.isfinite(dof):
        return float(dof)
    alpha = getattr(row, "family_alpha", None)
    alpha = 0.05 if alpha is None or not np.isfinite(alpha) else float(alpha)
    q = alpha / (2.0 * row.n_cells)
    if row.z_threshold <= stats.norm.isf(q) * (1 + 1e-9):
        return 0.0
    return float(optimize.brentq(lambda v: stats.t.isf(q, v) - row.z_threshold, 0.5, 1e6))


def clopper_pearson(k: int, n: int, level: float = 0.95) -> tuple[float, float]:
    """Exact two-sided binomial confidence interval for ``k`` successes in ``n`` trials.

    Parameters
    ----------
    k, n : int
        Successes and trials (``0 <= k <= n``, ``n >= 1``).
    level : float, default 0.95
        Confidence level.

    Returns
    -------
    tuple of float
        Lower and upper limit (0 and 1 at the edges).
    """
    a = 1.0 - level
    lo = 0.0 if k == 0 else float(stats.beta.ppf(a / 2, k, n - k + 1))
    hi = 1.0 if k == n else float(stats.beta.ppf(1 - a / 2, k + 1, n - k))
    return lo, hi


#: Outcomes of a case (:func:`outcome`), from right to wrong.
RIGHT = "right"
RIGHT_TIED = "right, with an indistinguishable term"
NOT_DETECTED = "not detected"
WRONG_TERM_TIED = "wrong term, truth reported as indistinguishable"
FALSE_CLAIM = "false claim"
MISFIT_OR_ALARM = "misfit_remains (library truth) / false alarm (null)"
OVER_BUDGET = "over budget"
OUTCOMES = (
    RIGHT,
    RIGHT_TIED,
    NOT_DETECTED,
    WRONG_TERM_TIED,
    FALSE_CLAIM,
    MISFIT_OR_ALARM,
    OVER_BUDGET,
)


def outcome(row: Mapping[str, Any]) -> str:
    """What one case of the study concluded, judged against its truth (:data:`OUTCOMES`).

    Right is ``baseline_adequate`` for ``null``, ``extended`` with exactly the hidden term
    for a library term, and ``misfit_remains`` or an ``extended`` law that predicts a fresh
    replicate as well as the truth (``as_good_as_truth``; in rows made before that check,
    a law leaving no misfit cell) for an out-of-library effect; it is "with an
    indistinguishable term" when a term was reported as tied with an added one. A wrong
    term named is a *false claim* unless the truth was reported as indistinguishable from
    it.

    Parameters
    ----------
    row : mapping
        A row of :func:`diagnose_case` (``kind``, ``verdict``, ``added``,
        ``n_residual_misfit``, optional ``indistinguishable``).

    Returns
    -------
    str
    """
    added = row["added"] if isinstance(row["added"], str) else ""
    ties = row.get("indistinguishable", "")
    ties = ties.split("+") if isinstance(ties, str) and ties else []
    kind, verdict = row["kind"], row["verdict"]
    if verdict == "over_budget":
        return OVER_BUDGET
    if kind == "null":
        if added:
            return FALSE_CLAIM
        return RIGHT if verdict == "baseline_adequate" else MISFIT_OR_ALARM
    if kind in LIBRARY_EFFECTS:
        if added == kind and verdict == "extended":
            return RIGHT_TIED if ties else RIGHT
        if added and added != kind:
            return WRONG_TERM_TIED if kind in ties else FALSE_CLAIM
        return NOT_DETECTED if verdict == "baseline_adequate" else MISFIT_OR_ALARM
    if verdict == "misfit_remains":
        return RIGHT_TIED if ties else RIGHT
    good = row.get("as_good_as_truth")
    if good is None or (isinstance(good, float) and np.isnan(good)):
        # rows of a study made before the fresh-replicate check: no misfit cell left
        good = row["n_residual_misfit"] == 0
    if verdict == "extended" and bool(good):
        return RIGHT_TIED if ties else RIGHT
    return FALSE_CLAIM if verdict == "extended" else NOT_DETECTED


def primary_rows(results: pd.DataFrame) -> pd.DataFrame:
    """The rows of sampler replicate 0: one per case (rows without the column are).

    Parameters
    ----------
    results : pandas.DataFrame
        Rows of :func:`diagnose_case`.

    Returns
    -------
    pandas.DataFrame
    """
    if "sampler_replicate" not in results:
        return results
    return results[results["sampler_replicate"].fillna(0).astype(int) == 0]


def summarize(results: pd.DataFrame) -> pd.DataFrame:
    """Error rates per case kind, with binomial standard errors.

    Columns: ``kind``, ``n``, ``right`` (the fraction of right answers: ``baseline_adequate``
    for ``null``, ``extended`` with exactly the hidden term for a library term,
    ``misfit_remains`` or a law leaving no misfit for an out-of-library effect) and its
    ``right_se`` and its exact (Clopper-Pearson) 95% interval ``right_lo95``,
    ``right_hi95`` (the binomial SE is 0 when every answer is right, the interval is not);
    the fraction of each verdict; ``wrong_term`` (a library term named as
    the cause that is not the truth: for ``null`` any named term, for an out-of-library
    effect ``extended`` although misfit was left, which cannot happen by construction and
    is a check); ``false_claim`` (a wrong term named *and* the truth not reported as
    indistinguishable from it: the claim a user would be misled by) and its one-sided
    95% upper bound ``false_claim_hi95`` (the bound of each kind on its own, not pooled);
    ``right_alone``
    (right, with no other term reported as indistinguishable); ``ambiguous`` (any term
    reported as indistinguishable from an added one); ``over_budget`` (stopped at
    :data:`STEP_BUDGET`, counted as not right); ``all_converged``; the median sampler
    steps and wall time per case.

    Parameters
    ----------
    results : pandas.DataFrame
        Rows of :func:`diagnose_case`. Only sampler replicate 0 of each case counts (the
        other replicates diagnose the same data again: :func:`flip_rates`).

    Returns
    -------
    pandas.DataFrame
        One row per case kind.
    """
    rows = []
    results = primary_rows(results).copy()
    results["added"] = results["added"].fillna("")
    ties = results.get("indistinguishable", pd.Series("", index=results.index))
    results["indistinguishable"] = ties.fillna("")
    for kind, g in results.groupby("kind", sort=False):
        n = len(g)
        tied = g["indistinguishable"] != ""
        label = g.apply(outcome, axis=1)
        right = label.isin((RIGHT, RIGHT_TIED))
        wrong_term = label.isin((WRONG_TERM_TIED, FALSE_CLAIM))
        false_claim = label == FALSE_CLAIM
        p = float(right.mean())
        lo, hi = clopper_pearson(int(right.sum()), n)
        rows.append(
            {
                "kind": kind,
                "n": n,
                "right": p,
                "right_se": float(np.sqrt(p * (1 - p) / n)),
                "right_lo95": lo,
                "right_hi95": hi,
                **{
                    f"verdict_{v}": float((g["verdict"] == v).mean())
                    for v in ("baseline_adequate", "extended", "misfit_remains")
                },
                "right_alone": float((label == RIGHT).mean()),
                "ambiguous": float(tied.mean()),
                "wrong_term": float(wrong_term.mean()),
                "false_claim": float(false_claim.mean()),
                # one-sided 95% upper bound = the upper end of the two-sided 90% interval
                "false_claim_hi95": clopper_pearson(int(false_claim.sum()), n, 0.90)[1],
                "over_budget": float((g["verdict"] == "over_budget").mean()),
                "all_converged": float(g["all_converged"].mean()),
                "median_steps": float(g["sampler_steps"].median())
                if "sampler_steps" in g
                else np.nan,
                "median_time_s": float(g["wall_time_s"].median()),
            }
        )
    order = {k: i for i, k in enumerate(CASE_KINDS)}
    out = pd.DataFrame(rows)
    return out.sort_values("kind", key=lambda k: k.map(order), kind="stable").reset_index(drop=True)


def named_terms(results: pd.DataFrame) -> tuple[pd.DataFrame, pd.DataFrame]:
    """Which library terms the diagnoses named, and which they reported as tied, by truth.

    Parameters
    ----------
    results : pandas.DataFrame
        Rows of :func:`diagnose_case` (each case's first diagnosis counts).

    Returns
    -------
    named : pandas.DataFrame
        One row per case kind (``kind``, ``n``), one column per library term: the number of
        cases whose diagnosis added it (in any round).
    tied : pandas.DataFrame
        The same, counting the cases that reported it as not distinguished from an added
        term (``diagnosis.json``'s ``selected.indistinguishable``).
    """
    results = primary_rows(results)
    tables = []
    for column in ("added", "indistinguishable"):
        terms = results.get(column, pd.Series("", index=results.index)).fillna("")
        sets = terms.map(lambda text: set(str(text).split("+")) - {""})
        rows = []
        for kind, g in sets.groupby(results["kind"], sort=False):
            counts = {t: sum(t in named for named in g) for t in LIBRARY_EFFECTS}
            rows.append({"kind": kind, "n": len(g), **counts})
        order = {k: i for i, k in enumerate(CASE_KINDS)}
        table = pd.DataFrame(rows, columns=["kind", "n", *LIBRARY_EFFECTS])
        tables.append(
            table.sort_values("kind", key=lambda k: k.map(order), kind="stable").reset_index(
                drop=True
            )
        )
    return tables[0], tables[1]


def _claim_of(row: Mapping[str, Any]) -> str:
    """A row's claim (:func:`_claim`); rows made before it was recorded: the added terms."""
    claim = row.get("claim")
    if isinstance(claim, str):
        return claim
    added = row.get("added")
    return added if isinstance(added, str) else ""


def _best_round1(row: Mapping[str, Any]) -> tuple[str, float, float]:
    """The round-1 candidate with the largest ELPD gain: term, gain and its SE [nats]."""
    text = row.get("round1")
    fitted = [
        c
        for c in (json.loads(text) if isinstance(text, str) and text else [])
        if c.get("elpd_diff_vs_current") is not None
        and np.isfinite(float(c["elpd_diff_vs_current"]))
    ]
    if not fitted:
        return "", float("nan"), float("nan")
    best = max(fitted, key=lambda c: float(c["elpd_diff_vs_current"]))
    return best["term"], float(best["elpd_diff_vs_current"]), float(best["elpd_diff_vs_current_se"])


def flip_rates(results: pd.DataFrame, level: float = 0.95) -> tuple[pd.DataFrame, pd.DataFrame]:
    """Monte Carlo sensitivity of the verdicts: each case diagnosed with two sampler seeds.

    Every row of a sampler replicate ``r > 0`` (:func:`diagnose_case`) is paired with the
    row of replicate 0 of the same case (``kind`` and ``index``): the same data, another
    sampler seed. A pair *flips* when a user would read another conclusion: the verdict or
    the claim differs (the terms named, each with the terms reported as not distinguished
    from it, so that two runs naming either of two tied terms do not count as a flip).

    Parameters
    ----------
    results : pandas.DataFrame
        Rows of :func:`diagnose_case`; rows without ``sampler_replicate`` are replicate 0.
    level : float, default 0.95
        Level of the exact (Clopper-Pearson) interval of each rate.

    Returns
    -------
    rates : pandas.DataFrame
        One row per case kind with pairs, then ``all``: ``pairs``, ``verdict_flips`` (the
        verdict differs), ``flips`` (verdict or claim), ``outcome_flips`` (right in one
        run and not in the other, :func:`outcome`), ``flip_rate`` = flips / pairs and its
        interval ``flip_lo``, ``flip_hi``.
    flipped : pandas.DataFrame
        One row per flipped pair, where the rule's margins are to be examined: per run
        (suffixes ``_0`` and ``_r``) the verdict, the claim, the reported gain and its SE,
        the best round-1 candidate's ELPD gain and SE (the rule: > 4 nats and > 2 SE), the
        baseline's largest misfit |z| and what the selected law leaves, against the
        misfit threshold ``z_threshold``.
    """
    results = results.copy()
    if "sampler_replicate" not in results:
        results["sampler_replicate"] = 0
    results["sampler_replicate"] = results["sampler_replicate"].fillna(0).astype(int)
    first = {
        (r["kind"], int(r["index"])): r
        for r in results[results["sampler_replicate"] == 0].to_dict("records")
    }
    pairs = []
    for row in results[results["sampler_replicate"] > 0].to_dict("records"):
        base = first.get((row["kind"], int(row["index"])))
        if base is not None:
            pairs.append((base, row))
    counts: dict[str, dict[str, int]] = {}
    flipped = []
    for base, other in pairs:
        verdict_flip = base["verdict"] != other["verdict"]
        flip = verdict_flip or _claim_of(base) != _claim_of(other)
        right = [outcome(r) in (RIGHT, RIGHT_TIED) for r in (base, other)]
        for key in (base["kind"], "all"):
            c = counts.setdefault(
                key, {"pairs": 0, "verdict_flips": 0, "flips": 0, "outcome_flips": 0}
            )
            c["pairs"] += 1
            c["verdict_flips"] += int(verdict_flip)
            c["flips"] += int(flip)
            c["outcome_flips"] += int(right[0] != right[1])
        if flip:
            entry: dict[str, Any] = {
                "kind": base["kind"],
                "index": int(base["index"]),
                "sampler_replicate": int(other["sampler_replicate"]),
                "z_threshold": base.get("z_threshold", np.nan),
            }
            for suffix, r in (("0", base), ("r", other)):
                term, gain, se = _best_round1(r)
                entry |= {
                    f"verdict_{suffix}": r["verdict"],
                    f"claim_{suffix}": _claim_of(r),
                    f"elpd_gain_{suffix}": r.get("elpd_gain", np.nan),
                    f"elpd_gain_se_{suffix}": r.get("elpd_gain_se", np.nan),
                    f"round1_best_{suffix}": term,
                    f"round1_gain_{suffix}": gain,
                    f"round1_gain_se_{suffix}": se,
                    f"baseline_max_abs_z_{suffix}": r.get("baseline_max_abs_z", np.nan),
                    f"residual_max_abs_z_{suffix}": r.get("residual_max_abs_z", np.nan),
                }
            flipped.append(entry)
    names = ("pairs", "verdict_flips", "flips", "outcome_flips")
    return _rate_table(counts, names, "flips", "pairs", "flip", level), pd.DataFrame(flipped)


def compare_studies(
    earlier: pd.DataFrame, later: pd.DataFrame, level: float = 0.95
) -> tuple[pd.DataFrame, pd.DataFrame]:
    """What changed between two runs of the study on the same cases (another code).

    Each case's first diagnosis (:func:`primary_rows`) in ``later`` is paired with the same
    case (``kind`` and ``index``: the same seed, hence the same drawn truth and design) in
    ``earlier``; cases in one run only are left out. Which terms were named is compared,
    not the claim with its ties: rows made before the claim was recorded hold the
    indistinguishable terms of every round together.

    Parameters
    ----------
    earlier, later : pandas.DataFrame
        Rows of :func:`diagnose_case` from two runs of the study.
    level : float, default 0.95
        Level of the exact (Clopper-Pearson) interval of each change rate.

    Returns
    -------
    rates : pandas.DataFrame
        One row per case kind in both runs, then ``all``: ``cases``, ``verdict_changes``,
        ``changes`` (the verdict or the terms named), ``right_before``, ``right_after``
        (:func:`outcome` right, tied or alone), ``change_rate`` = changes / cases and its
        interval ``change_lo``, ``change_hi``.
    changed : pandas.DataFrame
        One row per changed case: per run (suffixes ``_before``, ``_after``) the verdict,
        the terms named, those reported as indistinguishable, the outcome, the reported
        gain and its SE, and the baseline's largest misfit |z|.
    """
    before = {(r["kind"], int(r["index"])): r for r in primary_rows(earlier).to_dict("records")}
    counts: dict[str, dict[str, int]] = {}
    changed = []
    for row in primary_rows(later).to_dict("records"):
        old = before.get((row["kind"], int(row["index"])))
        if old is None:
            continue
        named = [r.get("added") if isinstance(r.get("added"), str) else "" for r in (old, row)]
        verdict_change = old["verdict"] != row["verdict"]
        change = verdict_change or named[0] != named[1]
        outcomes = [outcome(r) for r in (old, row)]
        for key in (row["kind"], "all"):
            c = counts.setdefault(
                key,
                {
                    "cases": 0,
                    "verdict_changes": 0,
                    "changes": 0,
                    "right_before": 0,
                    "right_after": 0,
                },
            )
            c["cases"] += 1
            c["verdict_changes"] += int(verdict_change)
            c["changes"] += int(change)
            c["right_before"] += int(outcomes[0] in (RIGHT, RIGHT_TIED))
            c["right_after"] += int(outcomes[1] in (RIGHT, RIGHT_TIED))
        if change:
            entry: dict[str, Any] = {"kind": row["kind"], "index": int(row["index"])}
            for suffix, r, terms, out in zip(
                ("before", "after"), (old, row), named, outcomes, strict=True
            ):
                tied = r.get("indistinguishable")
                entry |= {
                    f"verdict_{suffix}": r["verdict"],
                    f"added_{suffix}": terms,
                    f"indistinguishable_{suffix}": tied if isinstance(tied, str) else "",
                    f"outcome_{suffix}": out,
                    f"elpd_gain_{suffix}": r.get("elpd_gain", np.nan),
                    f"elpd_gain_se_{suffix}": r.get("elpd_gain_se", np.nan),
                    f"baseline_max_abs_z_{suffix}": r.get("baseline_max_abs_z", np.nan),
                }
            changed.append(entry)
    names = ("cases", "verdict_changes", "changes", "right_before", "right_after")
    return _rate_table(counts, names, "changes", "cases", "change", level), pd.DataFrame(changed)


def _rate_table(
    counts: Mapping[str, Mapping[str, int]],
    names: Sequence[str],
    events: str,
    total: str,
    prefix: str,
    level: float,
) -> pd.DataFrame:
    """A table of rates: one row per case kind (:data:`CASE_KINDS` order), then ``all``.

    The counts ``names`` and ``events / total`` as ``<prefix>_rate`` with its exact
    interval ``<prefix>_lo``, ``<prefix>_hi`` (:func:`clopper_pearson` at ``level``).
    """
    order = {k: i for i, k in enumerate((*CASE_KINDS, "all"))}
    rows = []
    for kind in sorted(counts, key=lambda k: order.get(k, len(order))):
        c = counts[kind]
        lo, hi = clopper_pearson(c[events], c[total], level)
        rate = {f"{prefix}_rate": c[events] / c[total], f"{prefix}_lo": lo, f"{prefix}_hi": hi}
        rows.append({"kind": kind, **{n: c[n] for n in names}, **rate})
    columns = ["kind", *names, f"{prefix}_rate", f"{prefix}_lo", f"{prefix}_hi"]
    return pd.DataFrame(rows, columns=columns)


# ----------------------------------------------------------------------------------------
# where the tool stops seeing: detection probability against effect size
# ----------------------------------------------------------------------------------------
#: Effect values of the power curves per kind, weakest first (the library term's
#: parameter [SI] or the out-of-library strength; for ``unloading`` a smaller ratio is the
#: stronger effect, 20 being absent, for ``janssen_saturation`` a shorter screening
#: length). Each ladder spans the effect's signal-to-noise ratio in the heights before any
#: refit (:func:`effect_size`) from about 2-3 at the weakest (medians over cases of
#: :data:`POWER_DESIGN`; 1.8 for added mass), near the noise floor, to 11-30 at the
#: strongest (``benchmarks/power_ladders.py``, ``benchmarks/results/power_ladders.md``);
#: stiffening starts at 4.8, since refitting ``k`` absorbs much of a ``k2 z^2``.
POWER_SIZES: dict[str, tuple[float, ...]] = {
    "drag": (5.0, 10.0, 20.0, 40.0),
    "added_mass": (0.25, 0.5, 1.0, 2.0),
    "stiffening": (6.25e3, 1.25e4, 2.5e4, 5.0e4),
    "viscous": (2.5, 5.0, 10.0, 20.0),
    "compaction": (0.0625, 0.125, 0.25, 0.5),
    "unloading": (16.0, 12.0, 8.0, 5.0),
    "depth_dependent_drag": (50.0, 100.0, 200.0, 400.0),
    "janssen_saturation": (0.48, 0.24, 0.12, 0.06),
    "pause_relaxation": (0.125, 0.25, 0.5, 1.0),
    "rate_dependent_strength": (0.0125, 0.025, 0.05, 0.1),
}
#: Designs of the power curves' cases, like a lab's: 2-5 volume fractions, 1-2 actuation
#: frequencies, 2-5 repeated jumps per cell (inclusive) and a scatter of 1.5-5 mm.
POWER_DESIGN: dict[str, tuple[int, int] | tuple[float, float]] = {
    "n_phis": (2, 5),
    "n_freqs": (1, 2),
    "trials": (2, 5),
    "sigma_mm": (1.5, 5.0),
}
#: Filmed jumps of the power curves' cases with tracking (``power_case(tracking=...)``):
#: at every volume fraction, trial 1 of the single jump and of the stutter at the first
#: frequency, at 1000 frames/s from 10 ms before the command to 150 ms after its end (the
#: flight and the landing), with the noise of the shipped reference lab (0.25 mm per
#: coordinate, correlation 0.5 between frames: tau = 1 ms / ln 2) and a clock offset of up
#: to 5 frames.
POWER_TRACKING: dict[str, Any] = {
    "commands": ("single", "stutter"),
    "fps": 1000.0,
    "from_s": -0.01,
    "after_s": 0.15,
    "frame_sd_mm": 0.25,
    "frame_tau_ms": 1.0 / float(np.log(2.0)),
    "offset_frames": 5,
}


def power_case(
    kind: str,
    size: float,
    index: int,
    settings: DiagnoseSettings | None = None,
    *,
    seed: int,
    step_budget: int | None = STEP_BUDGET,
    tracking: Mapping[str, Any] | None = None,
) -> list[dict[str, Any]]:
    """Campaign task of the power curves: a case with its effect at ``size``, diagnosed.

    The case is drawn like the study's (:func:`make_case`) but on a lab-like design
    (:data:`POWER_DESIGN`) and with the effect's value fixed; the row is
    :func:`diagnose_case`'s with ``size`` and the effect's size in the heights
    (:func:`effect_size`). With ``tracking`` (:data:`POWER_TRACKING`) some jumps are
    filmed too and ``diagnose`` fits heights and tracked jumps jointly; the jump heights
    are those of the same case without tracking, so the two curves are paired case by
    case. The fresh replicate that judges an out-of-library case is of the heights.

    Parameters
    ----------
    kind : str
        A library term or an out-of-library effect (:data:`POWER_SIZES`), or ``null``
        (no effect, ``size`` 0: the false-alarm arm of the same designs).
    size : float
        The effect's value (the term's parameter [SI] or the out-of-library strength).
    index : int
        Replicate number at this kind and size (recorded).
    settings : DiagnoseSettings, optional
        The rule and sampler settings.
    seed : int
        The task's seed: the case is drawn from it, ``diagnose`` gets a spawned one.
    step_budget : int, optional
        As :func:`diagnose_case`'s.
    tracking : mapping, optional
        Film some jumps (:func:`tracked_frames`).

    Returns
    -------
    list of dict
        One row (with tracking: ``n_tracked`` and ``n_frames`` as well).
    """
    if kind == "null" and size != 0.0:
        raise ValueError(f"kind 'null' has no effect: its size is 0, got {size!r}")
    case_seed, diag_seed = (
        int(c.generate_state(1)[0]) for c in np.random.SeedSequence(seed).spawn(2)
    )
    null = kind == "null"
    case = make_case(
        kind, case_seed, size=None if null else size, design=POWER_DESIGN, tracking=tracking
    )
    sized = {"effect_rms_mm": 0.0, "effect_snr": 0.0} if null else effect_size(case)
    extra: dict[str, Any] = {"size": float(size), **sized}
    if case.trajectories is not None:
        extra["n_tracked"] = int(case.trajectories["jump"].nunique())
        extra["n_frames"] = len(case.trajectories)
    return _diagnosed(
        case,
        index,
        settings,
        case_seed,
        diag_seed,
        step_budget,
        extra,
        size=None if null else size,
        design=POWER_DESIGN,
    )


def detected(results: pd.DataFrame) -> pd.Series:
    """Whether each case of a power study was detected (its outcome is right).

    For a library term, ``extended`` with exactly that term (a tie reported with it
    counts); for an effect outside the library, ``misfit_remains`` or a law as good as the
    truth on a fresh replicate (:func:`outcome`).

    Parameters
    ----------
    results : pandas.DataFrame
        Rows of :func:`power_case`.

    Returns
    -------
    pandas.Series of bool
        One per row, on the rows' index.
    """
    rows = results.assign(added=results["added"].fillna(""))
    return rows.apply(outcome, axis=1).isin((RIGHT, RIGHT_TIED))


def power_table(results: pd.DataFrame, level: float = 0.95) -> pd.DataFrame:
    """Detection probability per kind and effect size, with exact intervals.

    A case is *detected* when its outcome is right (:func:`outcome`): for a library term,
    ``extended`` with exactly that term (a tie reported with it counts); for an effect
    outside the library, ``misfit_remains`` or a law as good as the truth on a fresh
    replicate, so there "detected" means "not misled", and a ``baseline_adequate`` verdict
    is a miss. ``named`` counts any term named.

    Parameters
    ----------
    results : pandas.DataFrame
        Rows of :func:`power_case`.
    level : float, default 0.95
        Level of the exact (Clopper-Pearson) intervals.

    Returns
    -------
    pandas.DataFrame
        Per kind and size (weakest first, :data:`POWER_SIZES` order): ``n``,
        ``detected``, its fraction ``p`` and interval ``p_lo``, ``p_hi``,
        ``baseline_adequate`` (fraction), ``named`` (fraction naming a term),
        ``over_budget``, and the medians of ``effect_rms_mm`` and ``effect_snr``.
    """
    results = results.assign(added=results["added"].fillna(""), right=detected(results))
    rows = []
    for (kind, size), g in results.groupby(["kind", "size"], sort=False):
        right = g["right"]
        n, k = len(g), int(right.sum())
        lo, hi = clopper_pearson(k, n, level)
        ladder = POWER_SIZES.get(kind, ())
        rows.append(
            {
                "kind": kind,
                "size": float(size),
                "step": ladder.index(size) if size in ladder else len(ladder),
                "n": n,
                "detected": k,
                "p": k / n,
                "p_lo": lo,
                "p_hi": hi,
                "baseline_adequate": float((g["verdict"] == "baseline_adequate").mean()),
                "named": float((g["added"] != "").mean()),
                "over_budget": float((g["verdict"] == "over_budget").mean()),
                "effect_rms_mm": float(g["effect_rms_mm"].median()),
                "effect_snr": float(g["effect_snr"].median()),
            }
        )
    order = {k: i for i, k in enumerate(CASE_KINDS)}
    out = pd.DataFrame(rows)
    if out.empty:
        return out
    out = out.sort_values(["kind", "step"], key=lambda c: c.map(order) if c.name == "kind" else c)
    return out.drop(columns="step").reset_index(drop=True)


def _logistic(x: np.ndarray, y: np.ndarray) -> tuple[float, float, float]:
    """Logistic regression of 0/1 ``y`` on ``x`` about its mean: centre, intercept, slope.

    Maximum likelihood with a weak ridge on the slope (0.01 b1^2 / 2), so that cases
    completely separated by size (every small one missed, every large one detected) give
    a steep finite curve instead of an infinite slope; ``nan`` for fewer than 2 cases.
    """
    from scipy.optimize import minimize

    if len(x) < 2:
        return 0.0, float("nan"), float("nan")
    centre = float(np.mean(x))
    u = x - centre

    def nll(b: np.ndarray) -> float:
        eta = b[0] + b[1] * u
        return float(np.sum(np.logaddexp(0.0, eta) - y * eta) + 0.005 * b[1] ** 2)

    b0, b1 = minimize(nll, np.zeros(2), method="BFGS").x
    return centre, float(b0), float(b1)


def detection_sizes(
    results: pd.DataFrame, column: str = "effect_snr", levels: Sequence[float] = (0.5, 0.9)
) -> pd.DataFrame:
    """Effect sizes at which a kind is detected with the given probabilities.

    Per kind, a logistic regression of detection (:func:`power_table`'s rule) on the
    logarithm of ``column`` over the cases (:func:`_logistic`), read at each level:
    ``size_50``, ``size_90`` (``nan`` where the fit has no positive slope: detection did
    not grow with the size; and where every case was missed, or every case detected: the
    curve lies outside the sizes tried). Read with the per-size rates, whose intervals show
    how much the curve can be trusted.

    Parameters
    ----------
    results : pandas.DataFrame
        Rows of :func:`power_case`.
    column : str, default ``"effect_snr"``
        The size measure: ``effect_snr`` (comparable across kinds), ``effect_rms_mm``
        or ``size`` (the effect's own parameter; for ``unloading`` and
        ``janssen_saturation`` smaller is stronger, so its slope is negative).
    levels : sequence of float
        Detection probabilities to read.

    Returns
    -------
    pandas.DataFrame
        ``kind``, ``n``, the measured range of ``column`` (``range_lo``, ``range_hi``;
        a size outside it is extrapolated), ``slope`` (per unit of log size), then
        ``size_<level>`` per level.
    """
    results = results.assign(right=detected(results))
    rows = []
    for kind, g in results.groupby("kind", sort=False):
        x = np.log(g[column].to_numpy(dtype=float))
        y = g["right"].to_numpy(dtype=float)
        ok = np.isfinite(x)
        x, y = x[ok], y[ok]
        row: dict[str, Any] = {"kind": kind, "n": len(x)}
        row["range_lo"], row["range_hi"] = (
            (float(np.exp(x.min())), float(np.exp(x.max()))) if len(x) else (np.nan, np.nan)
        )
        centre, b0, b1 = _logistic(x, y)
        flip = column == "size" and kind in ("unloading", "janssen_saturation")
        # every case missed (or every case detected): the ridge leaves a slope of ~0 with
        # either sign and an intercept running off; no size can be read from that
        varied = 0.0 < y.sum() < len(y)
        usable = varied and np.isfinite(b1) and (b1 < 0 if flip else b1 > 0)
        row["slope"] = float(b1)
        for level in levels:
            logit = np.log(level / (1.0 - level))
            row[f"size_{round(100 * level)}"] = (
                float(np.exp(centre + (logit - b0) / b1)) if usable else float("nan")
            )
        rows.append(row)
    return pd.DataFrame(rows)


# ----------------------------------------------------------------------------------------
# the experiment that settles a tie (granbayes.design), tested on the study's cases
# ----------------------------------------------------------------------------------------
def extra_jumps(case: Case, plan: pd.DataFrame, rng: np.random.Generator) -> pd.DataFrame:
    """New SYNTHETIC jumps of a library case at the settings of ``plan``, by the oracle.

    Parameters
    ----------
    case : Case
        A case of a library kind (or ``null``): its truth is a law of the library.
    plan : pandas.DataFrame
        ``command``, ``phi``, ``freq_hz``, ``delay_ms`` (NaN: the experiment's) and
        ``trials`` per row.
    rng : numpy.random.Generator
        Source of the scatter (the case's ``sigma_mm``).

    Returns
    -------
    pandas.DataFrame
        Rows as the case's table has them (``trial`` continues after the case's).
    """
    if case.kind not in ("null", *LIBRARY_EFFECTS):
        raise ValueError(f"extra jumps of {case.kind!r}: only library truths are simulated")
    exp = case.experiment
    rows = []
    for r in plan.itertuples():
        delay = exp.command.delay_ms if np.isnan(r.delay_ms) else float(r.delay_ms)
        settings = dataclasses.replace(exp.command, freq_hz=float(r.freq_hz), delay_ms=delay)
        params = {"k": _true_k(case.truth["k_law"], r.phi), **case.truth["effect"]}
        height = simulate_height_scipy(
            r.command, r.phi, params, dataclasses.replace(exp, command=settings)
        )
        for trial in range(int(r.trials)):
            rows.append(
                {
                    "phi": r.phi,
                    "command": r.command,
                    "freq_hz": float(r.freq_hz),
                    "amplitude_mm": exp.command.amplitude_mm,
                    "delay_ms": delay,
                    "settle_periods": exp.command.settle_periods,
                    "trial": case.truth["trials"] + 1 + trial,
                    "height_mm": height + rng.normal(0.0, case.truth["sigma_mm"]),
                }
            )
    out = pd.DataFrame(rows)
    out["source"] = case.table["source"].iloc[0] + " extra jumps"
    return out


def design_parameter_case(
    kind: str,
    index: int,
    settings: DiagnoseSettings | None = None,
    *,
    seed: int,
    sd_ratio: float = 0.5,
    max_jumps: int = 60,
    n_threads: int | None = None,
) -> list[dict[str, Any]]:
    """Campaign task: a parameter narrowed by designed jumps, and by as many random ones.

    A case of ``kind`` (a library term, the truth) is fitted with the baseline plus the
    true term, as ``diagnose`` fits a law. :func:`granbayes.design.design_parameters`
    proposes up to ``max_jumps`` new jumps (every command, the case's volume fractions,
    the study's frequencies :data:`DESIGN_RANGES`) expected to shrink the posterior SD of
    the term's parameter at every volume fraction to ``sd_ratio`` of its present value;
    the same number of jumps at settings drawn uniformly from the same candidates is the
    control. Both sets are simulated from the truth by the oracle and the law refitted on
    the data plus each set.

    Parameters
    ----------
    kind : str
        A library term (:data:`LIBRARY_EFFECTS`).
    index : int
        Replicate number within its kind (recorded).
    settings : DiagnoseSettings, optional
        Rule and sampler settings (default ``DiagnoseSettings()``).
    seed : int
        The task's seed (the case, the fits, the design and the control are spawned
        from it).
    sd_ratio : float
        The design's goal: posterior SD after / before, per target.
    max_jumps : int
        The design's budget of new jumps.
    n_threads : int, optional
        numba threads of the fits.

    Returns
    -------
    list of dict
        One row per arm (``before``, ``designed``, ``random``) and volume fraction: the
        parameter's posterior SD (in the scale of
        :func:`granbayes.design.parameter_contraction`) and contraction, the SD the design
        expected, whether the true value lies in the 90% equal-tailed interval, the new
        jumps, convergence and wall time [s].
    """
    from . import stats as gstats
    from .design import parameter_contraction

    if kind not in LIBRARY_EFFECTS:
        raise ValueError(f"kind {kind!r}: a library term is needed as the truth")
    cfg = settings or DiagnoseSettings()
    case_seed, fit_seed, design_seed, noise_seed, random_seed = (
        int(s.generate_state(1)[0]) for s in np.random.SeedSequence(seed).spawn(5)
    )
    case = make_case(kind, case_seed)
    terms = terms_of((*cfg.baseline, kind))
    (parameter,) = (p.name for p in TERMS[kind].parameters)

    def fit_law(table: pd.DataFrame):
        return _fit_case_law(case, table, terms, cfg, fit_seed, n_threads)

    common = {
        "kind": kind,
        "index": int(index),
        "parameter": parameter,
        "sigma_mm": case.truth["sigma_mm"],
        "freqs_hz": "/".join(f"{f:g}" for f in case.truth["freqs_hz"]),
        "trials": case.truth["trials"],
        "n_jumps": len(case.table),
        "sd_ratio_goal": float(sd_ratio),
    }
    truth = float(case.truth["effect"][parameter])

    def rows_of(arm: str, result, n_new: int, t0: float, expected=None, plan=None) -> list:
        table = parameter_contraction(result, [parameter])
        ci = gstats.posterior_intervals(result.datatree, [parameter], table["phi"], ci_prob=0.9)
        out = []
        for i, r in table.iterrows():
            lo, hi = (float(ci.iloc[i][c]) for c in ("lo", "hi"))
            out.append(
                {
                    **common,
                    "arm": arm,
                    "phi": float(r["phi"]),
                    "truth": truth,
                    "median": float(r["median"]),
                    "posterior_sd": float(r["posterior_sd"]),
                    "contraction": float(r["contraction"]),
                    "covered_90": bool(lo <= truth <= hi),
                    "expected_sd": None if expected is None else float(expected[i]),
                    "n_new": int(n_new),
                    "converged": bool(result.converged),
                    "wall_s": time.perf_counter() - t0,
                    "plan": plan,
                }
            )
        return out

    t0 = time.perf_counter()
    before = fit_law(case.table)
    rows = rows_of("before", before, 0, t0)
    grid = candidate_settings(
        case.table, phis=case.truth["phis"], freqs_hz=_FREQS_HZ, delays_ms=[np.nan]
    )
    design = design_parameters(
        before,
        parameters=[parameter],
        candidates=grid,
        sd_ratio=sd_ratio,
        max_jumps=max_jumps,
        rng=design_seed,
    )
    expected = design.targets["posterior_sd_expected"].to_numpy(float)
    for r in rows:
        r["design_reached"] = design.reached
    n_new = design.n_jumps
    pick = np.random.default_rng(random_seed).integers(len(grid), size=n_new)
    counts = np.bincount(pick, minlength=len(grid))
    arms = {"designed": design.plan, "random": grid.assign(trials=counts)[counts > 0]}
    for arm, plan in arms.items():
        t0 = time.perf_counter()
        new = extra_jumps(case, plan, np.random.default_rng(noise_seed))
        after = fit_law(pd.concat([case.table, new], ignore_index=True))
        rows += rows_of(
            arm,
            after,
            n_new,
            t0,
            expected if arm == "designed" else None,
            json.dumps(plan.to_dict("records")),
        )
    return rows


def _paired_loo(fits: Mapping[str, Any], truth: str, rival: str) -> tuple[float, float, float]:
    """PSIS-LOO difference truth - rival [nats], its SE, and the larger max Pareto k."""
    from . import stats as gstats

    loos = {n: gstats.loo(fits[n].datatree) for n in (truth, rival)}
    strata = gstats.unit_kinds(fits[truth].datatree)
    d, se = gstats.elpd_difference(loos[truth]["elpd_i"], loos[rival]["elpd_i"], strata)
    return d, se, max(float(loos[n]["max_pareto_k"]) for n in loos)


@renamed_keyword("config")
def _fit_case_law(
    case: Case,
    table: pd.DataFrame,
    terms: Sequence[str],
    settings: DiagnoseSettings,
    seed: int,
    n_threads: int | None = None,
) -> Any:
    """A law fitted to a study case's jumps as ``diagnose`` fits one (no prior draws)."""
    from ._fitting import FitSettings, fit

    return fit(
        case.experiment,
        table,
        FitSettings(
            terms=tuple(terms),
            sampler=settings.sampler,
            n_threads=n_threads,
            n_prior_draws=0,
            calibration=settings.calibration,
        ),
        seed=seed,
    )


def design_tie_case(
    kind: str,
    index: int,
    rival: str,
    settings: DiagnoseSettings | None = None,
    *,
    seed: int,
    max_jumps: int = 40,
    n_threads: int | None = None,
) -> list[dict[str, Any]]:
    """Campaign task: a tie broken by designed jumps, and by as many random ones.

    A case of ``kind`` (a library term, the truth) is fitted with the baseline plus the
    true term and with the baseline plus ``rival``, each as ``diagnose`` fits a law. If
    the paired PSIS-LOO difference is short of the rule (a tie),
    :func:`granbayes.design.design_jumps` proposes up to ``max_jumps`` new jumps among
    every command, the case's volume fractions and the study's frequencies
    (:data:`DESIGN_RANGES`); the same number of jumps at settings drawn uniformly from the
    same candidates is the control. Both sets are simulated from the truth by the oracle,
    and both laws refitted on the data plus each set.

    Parameters
    ----------
    kind : str
        A library term (:data:`LIBRARY_EFFECTS`).
    index : int
        Replicate number within its kind (recorded).
    rival : str
        The rival term.
    settings : DiagnoseSettings, optional
        Rule and sampler settings (default ``DiagnoseSettings()``).
    seed : int
        The task's seed (the case, the fits, the design and the control are spawned
        from it).
    max_jumps : int
        The design's budget of new jumps.
    n_threads : int, optional
        numba threads of the fits.

    Returns
    -------
    list of dict
        One row per arm (``before``; for ties also ``designed`` and ``random``): the
        paired difference truth - rival and its SE [nats], whether the rule separates
        them the right way (``settled``) or the wrong way (``wrong_way``), the new jumps,
        the design's expected difference and SE, the larger max Pareto k, convergence
        and wall time [s].
    """
    if kind not in LIBRARY_EFFECTS:
        raise ValueError(f"kind {kind!r}: a library term is needed as the truth")
    cfg = settings or DiagnoseSettings()
    case_seed, fit_seed, design_seed, noise_seed, random_seed = (
        int(s.generate_state(1)[0]) for s in np.random.SeedSequence(seed).spawn(5)
    )
    case = make_case(kind, case_seed)
    base = cfg.baseline
    laws = {kind: (*base, kind), rival: (*base, rival)}

    def fit_both(table: pd.DataFrame) -> dict[str, Any]:
        return {
            name: _fit_case_law(case, table, terms, cfg, fit_seed, n_threads)
            for name, terms in laws.items()
        }

    common = {
        "kind": kind,
        "index": int(index),
        "rival": rival,
        "truth_effect": "+".join(f"{k}={v:.4g}" for k, v in case.truth["effect"].items()),
        "sigma_mm": case.truth["sigma_mm"],
        "phis": "/".join(f"{p:g}" for p in case.truth["phis"]),
        "freqs_hz": "/".join(f"{f:g}" for f in case.truth["freqs_hz"]),
        "trials": case.truth["trials"],
        "n_jumps": len(case.table),
    }

    def row(arm: str, fits: Mapping[str, Any], n_new: int, t0: float, **extra) -> dict:
        d, se, k = _paired_loo(fits, kind, rival)
        return {
            **common,
            "arm": arm,
            "n_new": int(n_new),
            "elpd_diff": d,
            "elpd_diff_se": se,
            "settled": distinguished(d, se, cfg),
            "wrong_way": distinguished(-d, se, cfg),
            "max_pareto_k": k,
            "converged": all(f.converged for f in fits.values()),
            "wall_s": time.perf_counter() - t0,
            **extra,
        }

    t0 = time.perf_counter()
    fits = fit_both(case.table)
    rows = [row("before", fits, 0, t0)]
    if rows[0]["settled"] or rows[0]["wrong_way"]:
        return rows  # not a tie: nothing to design
    grid = candidate_settings(
        case.table, phis=case.truth["phis"], freqs_hz=_FREQS_HZ, delays_ms=[np.nan]
    )
    design = design_jumps(
        fits,
        evidence={(kind, rival): (rows[0]["elpd_diff"], rows[0]["elpd_diff_se"])},
        candidates=grid,
        max_jumps=max_jumps,
        settings=cfg,
        rng=design_seed,
    )
    hyp = design.hypotheses.set_index(["truth", "rival"])
    expected = hyp.loc[(kind, rival)]
    n_new = int(design.plan["trials"].sum())
    pick = np.random.default_rng(random_seed).integers(len(grid), size=n_new)
    counts = np.bincount(pick, minlength=len(grid))
    arms = {
        "designed": (
            design.plan,
            {
                "expected_diff": float(expected["elpd_diff_expected"]),
                "expected_se": float(expected["se_expected"]),
                "design_settled": design.settled,
            },
        ),
        "random": (grid.assign(trials=counts)[counts > 0], {}),
    }
    for arm, (plan, extra) in arms.items():
        t0 = time.perf_counter()
        new = extra_jumps(case, plan, np.random.default_rng(noise_seed))
        fits = fit_both(pd.concat([case.table, new], ignore_index=True))
        rows.append(row(arm, fits, n_new, t0, **extra, plan=json.dumps(plan.to_dict("records"))))
    return rows
