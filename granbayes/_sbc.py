"""Simulation-based calibration (SBC) of :func:`granbayes.fit` on an experiment's design.

Is the posterior that ``fit`` reports calibrated? Per replicate (Talts et al. 2018):

1. draw every parameter from its prior, per volume fraction (the per-phi parametrisation
   ``fit`` uses by default: at each phi the force-law parameters of the fitted terms and
   that phi's scatter ``sigma_mm`` [mm]); a draw whose jumps do not all finish is drawn
   again (the likelihood gives such laws zero weight, so this is the model's prior);
2. simulate the design of the experiment folder (its robot and settings, and every row
   of its ``jumps.csv``: phi, command, frequency and other settings, as many trials as it
   has) and add Gaussian (or Student-t) scatter of the drawn ``sigma_mm``;
3. fit these SYNTHETIC heights with the same terms, priors and sampler settings;
4. rank each true value among ``n_rank_draws`` posterior draws, thinned to about one per
   autocorrelation time so that they are roughly independent.

A design of several kinds (jump heights with tracked jumps and/or intrusion tests: the
joint fit) is calibrated the same way, with every kind's noise parameters drawn from their
priors too, and its replicates made by the independent oracle
(:func:`draw_measurements`); a design of heights alone keeps the kernel's replicates of
step 2 (:func:`draw_replicate`, fast: the simulator a fit already trusts, checked against
the oracle by the tests). A ``quadratic`` fit (coefficients smooth in ``phi - phi_c``) is
calibrated on replicates of the oracle in which every jump is on its own bed, whose true
phi is ``Normal(written phi, phi_sd)`` (:func:`draw_beds`): the calibration of a fit that
integrates each bed's phi out (``bed_phi="integrate"``) or takes it as written; its ranks
are of the law's values at each written phi.

If the fit is calibrated every rank is uniform on ``0..n_rank_draws``. The replicates run
as tasks of a campaign (:mod:`granbayes.campaign`) on Dask, resumable, each with a seed
spawned from the master seed. Outputs in ``OUT``: ``ranks.csv`` (one row per replicate,
volume fraction and parameter), ``summary.json`` and ``summary.md`` (per parameter and
phi: a chi-square test of uniformity of the binned ranks and ArviZ's ``pot_c`` test,
coverage of the central 50% and 90% posterior intervals with binomial standard errors),
``sbc_ecdf.png`` (ECDF-difference plots with simultaneous 95% bands, ArviZ), plus the
campaign's ``tasks.csv`` and ``tasks/``.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from . import stats
from ._deprecated import renamed_keyword
from ._experiment import Experiment
from ._files import atomic_path, write_json, write_text
from ._fitting import FitPart, FitSettings, _find_starts_many, data_hash, fit, part_models
from ._measurements import Measurements
from ._priors import Prior, default_priors
from ._provenance import machine, package_versions
from .campaign import (
    CampaignResult,
    ClusterSettings,
    Task,
    cluster_settings,
    run_campaign,
    spawn_seeds,
)
from .forces import TERMS

__all__ = [
    "SBCResult",
    "draw_measurements",
    "draw_replicate",
    "rank_draw_indices",
    "replicate_ranks",
    "run_sbc",
]


#: Prior draws tried per volume fraction for a law whose jumps all finish.
_MAX_PRIOR_TRIES = 200


@dataclass
class SBCResult:
    """A finished simulation-based calibration.

    Attributes
    ----------
    folder : Path
        The output folder.
    ranks : pandas.DataFrame
        ``ranks.csv``: one row per replicate, phi and parameter.
    summary : dict
        ``summary.json``.
    campaign : CampaignResult
        Tasks, workers, timings.
    """

    folder: Path
    ranks: pd.DataFrame
    summary: dict[str, Any]
    campaign: CampaignResult


# ----------------------------------------------------------------------------------------
# One replicate (runs on a Dask worker)
# ----------------------------------------------------------------------------------------
def draw_replicate(
    experiment: Experiment,
    design: pd.DataFrame,
    settings: FitSettings,
    priors: Mapping[str, Prior],
    rng: np.random.Generator,
) -> tuple[pd.DataFrame, dict[float, dict[str, float]]]:
    """Draw a force law per volume fraction from the priors and simulate the design.

    The robot parameters ``experiment.toml`` gives an uncertainty are drawn from their
    calibration whatever ``config.calibration`` says (a lab's robot is what it is; the
    setting is how the fit treats it), so SBC with ``calibration="nominal"`` measures the
    coverage of a fit that ignores the calibration's uncertainty. One robot per volume
    fraction, as the per-volume-fraction runs model it (each run's posterior is exact
    given its own jumps whichever robot the others had); with ``calibration="pool"``
    one for all, as that fit models it.

    Parameters
    ----------
    experiment : Experiment
        Robot and command defaults.
    design : pandas.DataFrame
        The jumps table of the experiment (:func:`granbayes.load_jumps`); its heights are
        replaced.
    settings : FitSettings
        Terms, noise family and fixed parameters (``per_phi`` mode).
    priors : mapping of str to Prior
        The priors to draw from.
    rng : numpy.random.Generator
        Source of randomness.

    Returns
    -------
    table : pandas.DataFrame
        ``design`` with SYNTHETIC ``height_mm`` [mm] (simulated + scatter).
    truths : dict
        phi -> parameter name -> true value [SI; ``sigma_mm`` in mm].

    Raises
    ------
    RuntimeError
        If no prior draw in 200 gives jumps that all finish at some volume fraction.
    """
    table = design.reset_index(drop=True).copy()
    heights = np.full(len(table), np.nan)
    truths: dict[float, dict[str, float]] = {}
    # one robot per run: per volume fraction, or one for all with a pooled robot
    drawn = dataclasses.replace(
        settings, calibration="pool" if settings.calibration == "pool" else "sample"
    )
    for _, model, rows in part_models(experiment, table, drawn, priors):
        u, sim = _draw_prior(model, rng)
        values = model.parameter_values(u)
        obs = model.obs
        column = np.searchsorted(model.phis, obs.config_phi[obs.config_of_obs])
        sigma = values["sigma_mm"][0, column]
        n = len(rows)
        eps = (
            rng.standard_normal(n) if settings.noise == "normal" else rng.standard_t(settings.nu, n)
        )
        heights[rows] = sim[0, obs.config_of_obs] + sigma * eps
        for j, phi in enumerate(model.phis):
            truths[float(phi)] = {
                name: float(values[name][0, j])
                for name in (*model.parameters, *model.calibrated, "sigma_mm")
            }
    table["height_mm"] = heights
    return table, truths


def _draw_prior(model, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """A prior draw of one run's coordinates whose jumps all finish, and their heights."""
    for _ in range(_MAX_PRIOR_TRIES):
        u = model.sample_prior(rng, 1)
        sim, ok = model.predict(u)
        if ok[0] and np.all(np.isfinite(sim)):
            return u, sim
    raise RuntimeError(
        f"at phi={float(model.phis[0]):g} none of {_MAX_PRIOR_TRIES} prior draws gave jumps "
        "that all finish; narrow the priors"
    )


def draw_beds(
    experiment: Experiment,
    design: pd.DataFrame,
    settings: FitSettings,
    priors: Mapping[str, Prior],
    rng: np.random.Generator,
) -> tuple[pd.DataFrame, dict[float, dict[str, float]]]:
    """Draw a law smooth in phi and every jump's bed, and simulate by the oracle.

    The replicate of a ``quadratic`` fit: the law's coefficients, the scatter and the
    robot's calibrated parameters are drawn from the priors the fit uses; each jump's bed
    has its own true phi, ``Normal(its written phi, phi_sd)`` (``[bed] phi_sd``; the
    written phi itself without one), drawn whatever ``settings.bed_phi`` says (a lab's
    beds are what they are; the setting is how the fit treats them, so ``bed_phi=
    "measured"`` measures the coverage of a fit that ignores them). The jump is
    simulated at its bed's phi with the law there, by the independent oracle
    (:func:`granbayes.testing.replicate_measurements`), so the integration over the
    beds in the fit's likelihood (a spline over 9 volume fractions and a quadrature) is
    checked against data it did not make. A draw with a jump that does not finish is
    drawn again (law and beds), as in :func:`draw_replicate`.

    Parameters
    ----------
    experiment : Experiment
        Robot, command defaults, ``phi_c`` and ``phi_sd``.
    design : pandas.DataFrame
        The jumps table of the experiment; its heights are replaced.
    settings : FitSettings
        Terms, noise family and fixed parameters (``quadratic`` mode).
    priors : mapping of str to Prior
        The priors to draw from.
    rng : numpy.random.Generator
        Source of randomness (the law, the beds, then the oracle's noise).

    Returns
    -------
    table : pandas.DataFrame
        ``design`` with SYNTHETIC ``height_mm`` [mm]; ``phi`` stays the written one.
    truths : dict
        Written phi -> parameter name -> true value there (the law [SI], the robot's
        calibrated parameters, ``sigma_mm``).

    Raises
    ------
    RuntimeError
        If no draw in 200 gives jumps that all finish.
    """
    from .testing import replicate_measurements  # the oracle makes the data

    table = design.reset_index(drop=True).copy()
    drawn = dataclasses.replace(settings, calibration="sample")
    ((_, model, _),) = part_models(experiment, table, drawn, priors)
    written = table["phi"].to_numpy(float)
    phis = [float(p) for p in model.phis]
    names = (*model.parameters, *model.calibrated, "sigma_mm")
    for _ in range(_MAX_PRIOR_TRIES):
        u, _ = _draw_prior(model, rng)
        beds = written + experiment.phi_sd * rng.standard_normal(len(table))
        law = model.law_values(u, beds)
        values = model.parameter_values(u)
        robot = {name: float(v[0]) for name, v in model.calibration_values(u).items()}
        sigma = {phi: float(values["sigma_mm"][0, i]) for i, phi in enumerate(phis)}
        at_beds = {
            float(bed): {
                **{name: float(v[0, j]) for name, v in law.items()},
                **robot,
                "sigma_mm": sigma[min(phis, key=lambda p, w=written[j]: abs(p - w))],
            }
            for j, bed in enumerate(beds)
        }
        made = replicate_measurements(
            experiment,
            {"heights": table.assign(phi=beds)},
            at_beds,
            rng=rng,
            noise=settings.noise,
            nu=settings.nu,
        )["heights"]
        if np.all(np.isfinite(made["true_height_mm"].to_numpy(float))):
            break
    else:
        raise RuntimeError(
            f"none of {_MAX_PRIOR_TRIES} draws of the law and the beds gave jumps that all "
            "finish; narrow the priors"
        )
    table["height_mm"] = made["height_mm"].to_numpy(float)
    truths = {
        phi: {name: float(values[name][0, i]) for name in names} for i, phi in enumerate(phis)
    }
    return table, truths


def draw_measurements(
    experiment: Experiment,
    design: Measurements,
    settings: FitSettings,
    priors: Mapping[str, Prior],
    rng: np.random.Generator,
) -> tuple[Measurements, dict[float, dict[str, float]]]:
    """Draw every parameter from the priors and simulate a design of several kinds.

    The replicate of a joint fit (jump heights, tracked jumps, intrusion tests): per
    volume fraction, the force law, the robot's calibrated parameters and every noise
    parameter of every kind (``sigma_mm``, ``frame_sd_*_mm``, ``frame_tau_ms``,
    ``force_sd_N``) are drawn from the priors the fit uses (a draw whose jumps do not all
    finish is drawn again, as in :func:`draw_replicate`), and the measurements are
    simulated by the independent oracle
    (:func:`granbayes.testing.replicate_measurements`: its heights, its trajectories at
    every frame time shifted by a clock offset drawn from the likelihood's uniform prior,
    its intrusion forces, with the observation models' noise). Data from an
    implementation that shares no numerical code with the fitting kernel: an error in
    the kernel's dense output, in the offset's integration or in the whitening of the
    frame noise shows up as miscalibration instead of being reproduced by the data.

    Parameters
    ----------
    experiment : Experiment
        Robot and command defaults.
    design : Measurements
        The experiment's measurements (:func:`granbayes.load_measurements`); their values
        are replaced.
    settings : FitSettings
        Terms, noise family and fixed parameters (``per_phi`` mode).
    priors : mapping of str to Prior
        The priors to draw from.
    rng : numpy.random.Generator
        Source of randomness (the parameters, then the oracle's noise).

    Returns
    -------
    measurements : Measurements
        SYNTHETIC measurements of the design.
    truths : dict
        phi -> parameter name -> true value (the sampled parameters: force law [SI], the
        robot's calibrated parameters, then each kind's noise parameters).

    Raises
    ------
    RuntimeError
        If no prior draw in 200 gives jumps that all finish at some volume fraction.
    """
    from .testing import replicate_measurements  # the oracle makes the data

    drawn = dataclasses.replace(settings, calibration="sample")
    truths: dict[float, dict[str, float]] = {}
    oracle_truth: dict[float, dict[str, float]] = {}
    windows: dict[Any, float] = {}
    for _, model, _units in part_models(experiment, design, drawn, priors):
        phi = float(model.phis[0])
        u, _ = _draw_prior(model, rng)
        values = model.parameter_values(u)
        law = model.law_values(u, model.phis)
        names = dict.fromkeys(
            [*model.parameters, *model.calibrated, *(c.parameter for c in model.coordinates)]
        )
        truths[phi] = {name: float(values[name][0, 0]) for name in names}
        oracle_truth[phi] = {
            **{name: float(value) for name, value in model.fixed.items()},
            **{name: float(value[0, 0]) for name, value in law.items()},
            **{name: truths[phi][name] for name in names if name not in law},
        }
        for block in model.blocks:
            if block.kind == "trajectories":
                windows.update(block.offset_windows_s())
    tables = replicate_measurements(
        experiment,
        design.tables,
        oracle_truth,
        rng=rng,
        offset_window_s=windows,
        noise=settings.noise,
        nu=settings.nu,
    )
    kept = {
        kind: table.drop(columns=[c for c in table.columns if c.startswith("true_")])
        for kind, table in tables.items()
    }
    return Measurements(kept, design.unit_columns), truths


def rank_draw_indices(run, n_rank_draws: int) -> tuple[np.ndarray, np.ndarray, bool]:
    """``(chain, draw)`` indices of ``n_rank_draws`` roughly independent draws of one run.

    The kept draws (every ``thin`` steps) are thinned further to one per largest
    autocorrelation time ``tau`` of each walker, then ``n_rank_draws`` are taken evenly
    spaced over all walkers, step after step. If fewer than ``n_rank_draws`` remain (a
    short chain), all kept draws are used instead and ``independent`` is False.

    Parameters
    ----------
    run : SamplerRun
        One ensemble run of a fit (``FitPart.run``).
    n_rank_draws : int
        Number of draws.

    Returns
    -------
    chains, draws : ndarray of int, shape (n_rank_draws,)
        Index the run's ``samples`` and ``log_prob``.
    independent : bool
        Whether the draws are spaced by at least ``tau``.
    """
    n_chain, n_draw, _ = run.samples.shape
    tau = float(np.nanmax(run.tau)) if np.any(np.isfinite(run.tau)) else math.nan
    step = max(1, math.ceil(tau / run.thin)) if math.isfinite(tau) and tau > 0 else 1
    steps = np.arange((n_draw - 1) % step, n_draw, step)  # always keeps the last draw
    independent = len(steps) * n_chain >= n_rank_draws
    if not independent:
        steps = np.arange(n_draw)
    if len(steps) * n_chain < n_rank_draws:
        raise ValueError(
            f"n_rank_draws={n_rank_draws} exceeds the {len(steps) * n_chain} posterior draws "
            "kept (walkers x ensembles x n_draws of the sampler settings)"
        )
    pick = np.round(np.linspace(0, len(steps) * n_chain - 1, n_rank_draws)).astype(int)
    return pick % n_chain, steps[pick // n_chain], independent


def _log_prob_at(model, truths: Mapping[float, Mapping[str, float]]) -> float:
    """The log-posterior of a run's model at true parameter values (per volume fraction).

    NaN if it has coordinates that are not parameters (a polynomial's coefficients).
    """
    coords = model.coordinates
    at = [truths.get(float(model.phis[0]) if c.phi is None else c.phi, {}) for c in coords]
    if any(":" in c.name or c.parameter not in t for c, t in zip(coords, at, strict=True)):
        return math.nan
    u = np.array(
        [[float(c.prior.to_u(np.asarray(t[c.parameter]))) for c, t in zip(coords, at, strict=True)]]
    )
    return float(model(u)[0][0])


def _ranked_columns(parts: Sequence[FitPart]) -> list[tuple[FitPart, int, float]]:
    """Each run with each of its volume fractions (the column of its values there).

    A ``per_phi`` run has one; a ``quadratic`` run all of them, whose values are
    functions of the same draws (ranks of any function of the parameters are uniform
    under a calibrated posterior).
    """
    return [
        (part, column, float(phi)) for part in parts for column, phi in enumerate(part.model.phis)
    ]


def replicate_ranks(
    experiment: Experiment,
    design: pd.DataFrame | Measurements,
    settings: FitSettings,
    priors: Mapping[str, Prior],
    n_rank_draws: int,
    replicate: int,
    *,
    seed: int,
) -> list[dict[str, Any]]:
    """One SBC replicate: draw, simulate, fit, rank (a campaign task).

    Parameters
    ----------
    experiment, design, settings, priors
        As :func:`draw_replicate` (a jumps table) or :func:`draw_measurements`
        (measurements of several kinds).
    n_rank_draws : int
        Posterior draws each true value is ranked among.
    replicate : int
        Index of the replicate (recorded).
    seed : int
        The replicate's seed; the prior draw and the fit get seeds spawned from it.

    Returns
    -------
    list of dict
        One row per volume fraction and parameter: ``replicate``, ``phi``,
        ``parameter``, ``true_value``, ``rank`` (number of draws below the truth),
        ``n_draws``, ``posterior_median``, ``spread_ratio`` (the 16-84% range of the
        ranked draws over that of every kept draw: about 1 if the ranked draws are as
        spread as the run's sample, below 1 if they are correlated), and the run's
        ``converged``, ``tau_max`` [steps], ``n_steps``, ``independent_draws``,
        ``log_prob_truth`` (the log-posterior at the true values), ``log_prob_max`` (the
        highest of the kept draws'): a truth far above every draw means the sampler
        missed its mode, which no convergence check of the run can see; and
        ``log_prob_rank``, the number of ranked draws whose log-posterior is below the
        truth's: the rank of the log-posterior as a test quantity of the whole
        parameter vector (Modrák et al. 2023, Bayesian Analysis), uniform if the fit is
        calibrated, piled at 0 if truths lie in the posterior's tails (too narrow or
        shifted in any direction, which marginal ranks can each show too weakly to test).
    """
    truth_seed, fit_seed = spawn_seeds(seed, 2)
    if isinstance(design, Measurements):
        draw = draw_measurements
    else:
        draw = draw_beds if settings.phi_mode == "quadratic" else draw_replicate
    table, truths = draw(experiment, design, settings, priors, np.random.default_rng(truth_seed))
    result = fit(experiment, table, settings, seed=fit_seed, priors=priors)
    rows = []
    for part, column, phi in _ranked_columns(result.parts):
        chains, steps, independent = rank_draw_indices(part.run, n_rank_draws)
        values = part.model.parameter_values(part.run.samples[chains, steps])
        kept = part.model.parameter_values(part.run.samples.reshape(-1, part.model.ndim))
        lp_truth = _log_prob_at(part.model, truths)  # NaN for a quadratic run
        lp_max = float(np.max(part.run.log_prob))
        lp_draws = part.run.log_prob[chains, steps]
        lp_rank = int(np.sum(lp_draws < lp_truth)) if np.isfinite(lp_truth) else math.nan
        for name in truths[phi]:
            draws = values[name][:, column]
            true = truths[phi][name]
            rows.append(
                {
                    "replicate": int(replicate),
                    "phi": phi,
                    "parameter": name,
                    "true_value": true,
                    "rank": int(np.sum(draws < true)),
                    "n_draws": int(n_rank_draws),
                    "posterior_median": float(np.median(draws)),
                    "spread_ratio": _spread_ratio(draws, kept[name][:, column]),
                    "converged": bool(part.run.converged),
                    "tau_max": float(np.nanmax(part.run.tau)),
                    "n_steps": int(part.run.n_steps),
                    "independent_draws": bool(independent),
                    "log_prob_truth": lp_truth,
                    "log_prob_max": lp_max,
                    "log_prob_rank": lp_rank,
                }
            )
    return rows


def _spread_ratio(draws: np.ndarray, kept: np.ndarray) -> float:
    """The 16-84% range of ``draws`` over that of ``kept`` (NaN if the latter is 0)."""
    width = float(np.subtract(*np.quantile(kept, [0.84, 0.16])))
    return float(np.subtract(*np.quantile(draws, [0.84, 0.16]))) / width if width > 0 else math.nan


def replicate_start_modes(
    experiment: Experiment,
    design: Measurements,
    settings: FitSettings,
    priors: Mapping[str, Prior],
    kinds: tuple[str, ...],
    climbs: int,
    replicate: int,
    *,
    seed: int,
) -> list[dict[str, Any]]:
    """Do the Laplace start's climbs reach the truth's mode? (a campaign task).

    The replicate of :func:`replicate_ranks` for the same seed (the same truth and data,
    drawn from the whole design), restricted to ``kinds``; the start of a fit
    (``start="laplace"``) with ``climbs`` climbs per ensemble, every climb's final
    log-posterior recorded. No sampling: what the ensembles would start from.

    Returns
    -------
    list of dict
        One row per volume fraction: ``replicate``, ``phi``, ``kinds``,
        ``log_prob_truth``, ``climb_ends`` (``;``-separated, ensemble-major, ``climbs``
        per ensemble), ``anchor_ends`` (the climb from the intrusion curves' own mode, one
        per ensemble; empty without intrusion curves) and ``n_ensembles``.
    """
    truth_seed, fit_seed = spawn_seeds(seed, 2)
    data, truths = draw_measurements(
        experiment, design, settings, priors, np.random.default_rng(truth_seed)
    )
    data = Measurements({k: data.tables[k] for k in kinds}, data.unit_columns)
    rows = []
    for _, model, _units in part_models(experiment, data, settings, priors):
        phi = float(model.phis[0])
        ends: dict[tuple[int, int], list[float]] = {}
        s = settings.sampler
        _find_starts_many(
            [model],
            [np.random.default_rng(fit_seed)],
            s.n_ensembles,
            [s.walkers_for(model.ndim)],
            [None],
            "laplace",
            s.mode_gap,
            None,
            climbs,
            ends,
        )
        rows.append(
            {
                "replicate": int(replicate),
                "phi": phi,
                "kinds": ",".join(kinds),
                "log_prob_truth": _log_prob_at(model, truths),
                "climb_ends": ";".join(
                    f"{v:.3f}" for e in range(s.n_ensembles) for v in ends[0, e][:climbs]
                ),
                # the global phase's climb (models with intrusion curves), one per ensemble
                "anchor_ends": ";".join(
                    f"{v:.3f}" for e in range(s.n_ensembles) for v in ends[0, e][climbs:]
                ),
                "n_ensembles": int(s.n_ensembles),
            }
        )
    return rows


# ----------------------------------------------------------------------------------------
# Summary
# ----------------------------------------------------------------------------------------


def _mode_check(ranks: pd.DataFrame, gap: float) -> dict[str, Any]:
    """Runs whose truth lies more than ``gap`` nats above every kept draw (missed modes)."""
    if not len(ranks) or "log_prob_truth" not in ranks:
        return {"n_runs": 0, "n_missed": 0, "missed": [], "gap_nats": gap}
    runs = ranks.drop_duplicates(["replicate", "phi"])
    excess = runs["log_prob_truth"] - runs["log_prob_max"]
    missed = runs[excess > gap]
    return {
        "what": "runs whose truth's log-posterior exceeds every kept draw's by more than "
        "gap_nats (the sampler's mode_gap): the sampler missed the truth's mode",
        "gap_nats": float(gap),
        "n_runs": int(excess.notna().sum()),
        "n_missed": len(missed),
        "missed": [
            {"replicate": int(r.replicate), "phi": float(r.phi), "excess_nats": float(x)}
            for r, x in zip(missed.itertuples(), excess[excess > gap], strict=True)
        ],
        "excess_nats_median": float(excess.median()) if excess.notna().any() else None,
    }


def _log_prob_rank_check(ranks: pd.DataFrame) -> dict[str, Any]:
    """The ranks of the truth's log-posterior among the ranked draws' (``log_prob_rank``).

    A test quantity of the whole parameter vector (Modrák et al. 2023): uniform if the
    fit is calibrated; too many in the lowest tenth of the possible ranks means truths in
    the posterior's tails, which a one-sided exact binomial test measures.
    """
    if not len(ranks) or "log_prob_rank" not in ranks:
        return {"n_runs": 0}
    runs = ranks.drop_duplicates(["replicate", "phi"])
    runs = runs[np.isfinite(runs["log_prob_rank"].astype(float))]
    if not len(runs):
        return {"n_runs": 0}
    frame = runs.assign(parameter="log_posterior", rank=runs["log_prob_rank"].astype(int))
    n_draws = int(frame["n_draws"].iloc[0])
    values = frame["rank"].to_numpy(int)
    below = max(1, round(0.1 * (n_draws + 1)))  # ranks 0..below-1: the lowest tenth
    expected = below / (n_draws + 1)
    low = int(np.sum(values < below))
    from scipy.stats import binomtest

    test = binomtest(low, len(values), expected, alternative="greater")
    return {
        "what": "rank of each run's truth's log-posterior among its ranked draws' (a test "
        "quantity of the whole parameter vector): uniform if calibrated; piled in the "
        "lowest tenth if truths lie in the posterior's tails",
        "n_runs": len(values),
        "n_lowest_tenth": low,
        "expected_fraction": expected,
        "p_lowest_tenth": float(test.pvalue),
        "per_phi": stats.summarize_ranks(
            frame[["parameter", "phi", "replicate", "rank", "n_draws", "converged"]]
        ),
    }


def log_prob_rank_text(lp: Mapping[str, Any]) -> str:
    """The log-posterior rank check (:func:`_log_prob_rank_check`) in a sentence."""
    pot = [row["uniformity"]["pot_c_p_value"] for row in lp["per_phi"]]
    return (
        f"Log-posterior rank (the whole parameter vector): in {lp['n_lowest_tenth']} of "
        f"{lp['n_runs']} runs the truth's log-posterior is in the lowest tenth of the "
        f"ranked draws' (expected {lp['expected_fraction']:.2f}; one-sided exact binomial "
        f"p = {lp['p_lowest_tenth']:.3g}); mean normalised rank "
        + ", ".join(f"{row['mean_normalised_rank']:.2f}" for row in lp["per_phi"])
        + ", uniformity p chi-square "
        + ", ".join(f"{row['uniformity']['p_value']:.3g}" for row in lp["per_phi"])
        + ", pot_c "
        + ", ".join("-" if p is None else f"{p:.3g}" for p in pot)
        + " (per volume fraction)."
    )


def _summary_markdown(summary: Mapping[str, Any]) -> str:
    lines = [
        f"# Simulation-based calibration of `fit` ({', '.join(summary['terms'])})",
        "",
        f"Data: SYNTHETIC replicates of the design of `{summary['data_source']}` "
        f"({', '.join(summary.get('kinds', ['heights']))}; made by "
        f"{summary.get('generator', 'the fitting kernel')}); "
        f"{summary['n_replicates_ok']} of {summary['n_replicates']} replicates finished, "
        f"master seed {summary['seed']}, ranks among {summary['n_rank_draws']} posterior "
        "draws. A calibrated fit gives uniformity p-values that are not small and "
        "coverage near nominal; read the table against that.",
        "",
        "| parameter | phi | n | p chi-square | p pot_c | 50% coverage | 90% coverage |",
        "|---|---|---|---|---|---|---|",
    ]
    for row in summary["parameters"]:
        u, c = row["uniformity"], row["coverage"]
        p_pot = "-" if u["pot_c_p_value"] is None else f"{u['pot_c_p_value']:.3f}"
        cov = [
            f"{c[k]['observed']:.2f} ± {c[k]['se']:.2f} (nominal {c[k]['nominal']:.2f})"
            for k in ("50%", "90%")
        ]
        lines.append(
            f"| {row['parameter']} | {row['phi']:g} | {row['n_replicates']} | "
            f"{u['p_value']:.3f} | {p_pot} | {cov[0]} | {cov[1]} |"
        )
    t = summary["timing"]
    mc = summary.get("mode_check", {})
    if mc.get("n_runs"):
        lines += [
            "",
            f"Missed modes: in {mc['n_missed']} of {mc['n_runs']} runs the truth's "
            f"log-posterior exceeds every kept draw's by more than {mc['gap_nats']:g} nats "
            f"(median excess of the truth over the best draw: {mc['excess_nats_median']:.1f}"
            " nats; a draw from the posterior lies below its mode by about d/2).",
        ]
    lp = summary.get("log_prob_rank", {})
    if lp.get("n_runs"):
        lines += ["", log_prob_rank_text(lp)]
    lines += [
        "",
        f"Compute: {t['task_s_total']:.0f} s of replicate time (median {t['task_s_median']:.1f} "
        f"s per replicate) on {len(summary['workers'])} worker(s); this run's wall time "
        f"{t['wall_s_this_run']:.0f} s.",
        "",
        "![ECDF difference](sbc_ecdf.png)",
        "",
    ]
    return "\n".join(lines)


# ----------------------------------------------------------------------------------------
# The campaign
# ----------------------------------------------------------------------------------------
@renamed_keyword("config")
def run_sbc(
    experiment: Experiment,
    design: pd.DataFrame | Measurements,
    out: str | Path,
    *,
    settings: FitSettings | None = None,
    n_replicates: int = 100,
    seed: int = 0,
    priors: Mapping[str, Prior] | None = None,
    n_rank_draws: int = 99,
    cluster: ClusterSettings | None = None,
    client=None,
    resume: bool = False,
    progress: bool = True,
    data_source: str = "",
    log=None,
    **deprecated: Any,
) -> SBCResult:
    """Simulation-based calibration of :func:`granbayes.fit` on an experiment's design.

    Parameters
    ----------
    experiment : Experiment
        Robot, command defaults and ``phi_c``.
    design : pandas.DataFrame or Measurements
        The experiment's jumps (:func:`granbayes.load_jumps`): which jumps to simulate,
        by the fitting kernel (:func:`draw_replicate`; in ``quadratic`` mode by the
        oracle, each jump on its own bed: :func:`draw_beds`); or its measurements of several
        kinds (:func:`granbayes.load_measurements`): jumps, tracked jumps and intrusion
        tests, simulated by the independent oracle with every kind's noise drawn from its
        prior (:func:`draw_measurements`), for the calibration of a joint fit.
    out : str or Path
        Output folder (built as ``OUT.partial``; replaced only at the end).
    settings : FitSettings, optional
        Terms and sampler settings of the fits (``quadratic`` ``phi_mode`` with jump
        heights only: the ranks are of the law's values at each written phi).
    n_replicates : int
        Number of replicates (each a prior draw, a simulation and a fit).
    seed : int
        Master seed; replicate ``i`` gets the ``i``-th seed spawned from it, so results do
        not depend on the number of workers, and more replicates extend a study.
    priors : mapping of str to Prior, optional
        Priors to draw from and to fit with (default: :func:`default_priors`).
    n_rank_draws : int
        Posterior draws each truth is ranked among (ranks ``0..n_rank_draws``); at most
        ``n_walkers x n_ensembles x n_draws`` of the sampler settings.
    cluster : ClusterSettings, optional
        Where the replicates run (:class:`granbayes.campaign.ClusterSettings`; default: a
        local Dask cluster sized to the machine).
    client : distributed.Client, optional
        An already connected client.
    resume : bool
        Continue a killed run in ``OUT.partial`` (or extend a finished ``OUT``); refused
        for a folder of another study (other data, settings, priors or seed).
    progress : bool
        Show a progress bar.
    data_source : str
        Where the design came from (recorded).
    log : callable, optional
        Receives one-line messages.
    **deprecated
        ``scheduler_address``, ``n_workers``, ``numba_threads``, ``connect_timeout_s``:
        the former loose form of ``cluster`` (``DeprecationWarning``).

    Returns
    -------
    SBCResult

    Raises
    ------
    ValueError
        Bad arguments (``n_replicates < 1``, ``n_rank_draws`` out of range, quadratic
        ``phi_mode`` with measurements of several kinds, empty design).
    granbayes.campaign.CampaignError
        Unreachable scheduler, or resume of another study; nothing is written then.
    """
    settings = settings or FitSettings(terms=("depth", "drag"))
    if isinstance(design, Measurements) and design.kinds == ("heights",):
        design = design.tables["heights"]  # heights alone: the kernel's replicates, as ever
    if settings.phi_mode != "per_phi" and isinstance(design, Measurements):
        raise ValueError(
            "SBC of a quadratic fit takes jump heights alone (a design of several kinds "
            f"needs phi_mode 'per_phi'), got phi_mode {settings.phi_mode!r}"
        )
    if settings.calibration == "pool" and isinstance(design, Measurements):
        raise ValueError(
            "SBC with a pooled robot (calibration 'pool') takes jump heights alone: a "
            "design of several kinds draws one robot per volume fraction"
        )
    if int(n_replicates) < 1:
        raise ValueError(f"n_replicates must be >= 1, got {n_replicates}")
    s = settings.sampler
    kept = s.n_walkers * s.n_ensembles * s.n_draws
    if not 1 <= int(n_rank_draws) <= kept:
        raise ValueError(
            f"n_rank_draws must be in [1, walkers x ensembles x n_draws = {kept}], "
            f"got {n_rank_draws}"
        )
    n_units = design.n_units if isinstance(design, Measurements) else len(design)
    if n_units == 0:
        raise ValueError("design has no jumps")
    # what the workers need; thread counts do not change results
    settings = dataclasses.replace(settings, n_threads=None, n_prior_draws=0)
    priors = dict(priors if priors is not None else default_priors())
    if not isinstance(design, Measurements):
        design = design.reset_index(drop=True)
    used = {*(p.name for t in settings.terms for p in TERMS[t].parameters), "sigma_mm"}
    described = {k: dataclasses.asdict(v) for k, v in sorted(priors.items()) if k in used}
    if isinstance(design, Measurements):  # and every kind's noise parameters, as fitted
        for _, model, _ in part_models(experiment, design, settings, priors):
            for c in model.coordinates:
                described.setdefault(c.parameter, dataclasses.asdict(c.prior))
    description = {
        "kind": "granbayes._sbc",
        "data_sha256": data_hash(experiment, design),
        "config": settings.to_dict(),
        "priors": dict(sorted(described.items())),
        "seed": int(seed),
        "n_rank_draws": int(n_rank_draws),
    }
    if isinstance(design, Measurements):
        description["kinds"] = list(design.kinds)
        description["generator"] = "granbayes.testing.replicate_measurements (the oracle)"
    elif settings.phi_mode == "quadratic":
        description["generator"] = (
            "granbayes.testing.replicate_measurements (the oracle), each jump on its own bed"
        )
        description["phi_sd"] = experiment.phi_sd
    if experiment.uncertainty:  # the robot's calibration the truths are drawn from
        description["calibration_sd"] = dict(sorted(experiment.uncertainty.items()))
    if experiment.phi_sd > 0 and settings.phi_mode == "per_phi" and log is not None:
        log(
            f"[bed] phi_sd = {experiment.phi_sd:g} is not drawn: SBC's laws are drawn per "
            "volume fraction with no slope in phi, so a bed's phi would change only the "
            "added mass (quadratic fits integrate it: run their SBC with phi_mode "
            "'quadratic')"
        )
    seeds = spawn_seeds(seed, int(n_replicates))
    tasks = [
        Task(
            f"replicate-{i:05d}",
            replicate_ranks,
            (experiment, design, settings, priors, int(n_rank_draws), i),
            seed=s,
        )
        for i, s in enumerate(seeds)
    ]
    holder: dict[str, Any] = {}

    def finalize(work: Path, result: CampaignResult) -> None:
        holder["summary"] = _write_outputs(
            work, result, settings, seed, n_replicates, n_rank_draws, description, data_source
        )

    campaign = run_campaign(
        tasks,
        out,
        description=description,
        cluster=cluster_settings(cluster, deprecated, "run_sbc"),
        client=client,
        resume=resume,
        progress=progress,
        results_name="ranks.csv",
        finalize=finalize,
        log=log,
    )
    return SBCResult(Path(out), campaign.results, holder["summary"], campaign)


def _write_outputs(
    work: Path,
    result: CampaignResult,
    settings: FitSettings,
    seed: int,
    n_replicates: int,
    n_rank_draws: int,
    description: Mapping[str, Any],
    data_source: str,
) -> dict[str, Any]:
    """``summary.json``, ``summary.md`` and ``sbc_ecdf.png`` into the work folder."""
    ranks = result.results
    ok = result.tasks[result.tasks["status"] == "ok"]
    elapsed = ok["elapsed_s"].astype(float)
    summary: dict[str, Any] = {
        "what": "simulation-based calibration of granbayes.fit on SYNTHETIC replicates",
        "granbayes_version": package_versions()["granbayes"],
        "data_source": data_source,
        "data_sha256": description["data_sha256"],
        "kinds": description.get("kinds", ["heights"]),
        "generator": description.get(
            "generator", "the fitting kernel (the likelihood's own simulator; heights only)"
        ),
        "terms": list(settings.terms),
        "config": settings.to_dict(),
        "priors": description["priors"],
        "seed": int(seed),
        "n_replicates": int(n_replicates),
        "n_replicates_ok": len(ok),
        "n_replicates_failed": int(result.n_failed),
        "n_rank_draws": int(n_rank_draws),
        "fingerprint": result.fingerprint,
        "workers": result.workers,
        # of the process that wrote this summary; the replicates ran on the workers above
        "versions": package_versions(),
        "machine": machine(),
        "timing": {
            "task_s_total": float(elapsed.sum()),
            "task_s_median": float(elapsed.median()) if len(elapsed) else None,
            "wall_s_this_run": result.wall_time_s,
            "tasks_reused": result.n_reused,
            "tasks_run": result.n_run,
        },
        "uniformity_test": "chi-square of the ranks in equal-probability bins (scipy); "
        "pot_c: ArviZ's uniformity test (arviz-stats)",
        "coverage": "fraction of replicates whose true value lies in the central "
        "interval of the ranked draws; se = sqrt(c (1 - c) / n)",
        "mode_check": _mode_check(ranks, settings.sampler.mode_gap),
        "log_prob_rank": _log_prob_rank_check(ranks),
        "parameters": stats.summarize_ranks(ranks) if len(ranks) else [],
    }
    write_json(work / "summary.json", summary)
    write_text(work / "summary.md", _summary_markdown(summary))
    if len(ranks):
        # Imported here, in the client: the worker processes that run the replicates
        # import this module, and need no plotting (matplotlib: ~1 s per process).
        from matplotlib import pyplot as plt

        from . import figures

        pit, phis = stats.normalised_ranks(ranks)
        if all(len(v) >= 2 for v in pit.values()):
            fig = figures.plot_sbc_ecdf(
                pit,
                phis,
                seed=seed,
                title=f"SBC of fit ({' + '.join(settings.terms)}), {data_source or 'design'}",
            )
            with atomic_path(work / "sbc_ecdf.png") as tmp:
                fig.savefig(tmp, dpi=110, format="png")
            plt.close(fig)
    return summary
