"""The jumps that identify a parameter: where the data so far leave it to its prior.

A parameter is *unidentified* where its posterior is hardly narrower than its prior: the
contraction ``1 - var_post / var_prior`` (Schad, Betancourt & Vasishth 2021;
:func:`granbayes.stats.identifiability_table`, whose scale this module keeps: ``log`` of
the value for log-scale priors, the value otherwise) below 0.5. :func:`design_parameters`
proposes the jumps (command, volume fraction, frequency, delay) that are expected to
narrow such parameters most, and how many bring each to a goal contraction (0.9 by
default: "well identified").

The criterion is the expected information gain of a linear-Gaussian approximation of the
fit (Bayesian D-optimal design, Chaloner & Verdinelli 1995, *Statistical Science* 10,
273-304), computed on the posterior draws as an ensemble Kalman update does (Evensen 2009):
the targets (the parameters at their volume fractions) and the simulated height of a new
jump at every candidate setting are taken as jointly normal, with their covariance across
the draws; a new jump at setting ``x`` is that height plus the fitted scatter ``sigma^2``.
Conditioning on it lowers the targets' covariance by a rank-one term, and gives

    I_x = -1/2 log(1 - c_x' C_TT^-1 c_x / (C_xx + sigma_x^2))   [nats]

(``C_TT`` the targets' covariance, ``c_x`` their covariance with the height at ``x``):
the expected Kullback-Leibler divergence of the targets' posterior after the jump from
the one before, under the approximation. Jumps are added one at a time to the setting of
largest gain over the targets not yet at the goal, each addition conditioning the
covariance (so a second jump at the same setting is worth less than the first), until
every target reaches the goal or the budget ``max_jumps`` is spent. A ``per_phi`` fit's
volume fractions are separate posteriors: a jump informs the parameters of its own
volume fraction only, and covariances are taken within a run.

What this leaves out, and why it is measured rather than assumed: the linearisation (a
height that depends on a parameter nonlinearly over its posterior informs it differently
than its covariance says; a posterior that is far from normal in the scale used is
summarised by its variance), and the draws' own sampling error in the covariances. How
close the expected posterior SD comes to the one a refit on simulated jumps reaches, and
how the designed jumps compare with as many at random settings, is measured by
``benchmarks/design_parameters.py`` (results in ``benchmarks/results/`` and the README).
"""

from __future__ import annotations

import json
from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np
import pandas as pd

from ._design_draws import candidate_settings, law_draws, plan_of, usable_settings
from ._saved import SavedFit, as_saved_fit
from .stats import IDENTIFIABILITY_LEVELS, identifiability_table

__all__ = ["ParameterDesign", "design_parameters", "parameter_contraction"]

#: Below this contraction a parameter is unidentified (weakly or not identified:
#: :data:`granbayes.stats.IDENTIFIABILITY_LEVELS`), and a target by default.
UNIDENTIFIED = IDENTIFIABILITY_LEVELS[1][0]

#: The default goal: the contraction from which a parameter is "well identified".
WELL_IDENTIFIED = IDENTIFIABILITY_LEVELS[2][0]

_PRIOR_DRAWS = 20_000

#: The columns of :func:`parameter_contraction`.
_COLUMNS = (
    "parameter",
    "phi",
    "unit",
    "scale",
    "median",
    "prior_sd",
    "posterior_sd",
    "contraction",
    "verdict",
    "unidentified",
)


def _log_scale(prior) -> bool:
    return prior.dist in ("loguniform", "lognormal")


def _prior_sd(prior, rng: np.random.Generator) -> float:
    """SD of a prior in the module's scale (log of the value for log-scale priors)."""
    values = prior.to_value(prior.sample_u(rng, _PRIOR_DRAWS))
    return float(np.std(np.log(values) if _log_scale(prior) else values, ddof=1))


def _target_draws(fit: SavedFit, name: str, phi: float, pick: np.ndarray) -> np.ndarray:
    var = fit.datatree["posterior"][name].sel(phi=phi, method="nearest")
    values = var.transpose("chain", "draw").values.reshape(-1).astype(float)[pick]
    return np.log(values) if _log_scale(fit.priors[name]) else values


def parameter_contraction(
    fit: object,
    parameters: Sequence[str] | None = None,
    *,
    rng: np.random.Generator | int = 0,
) -> pd.DataFrame:
    """Posterior-to-prior contraction of a fit's force parameters at each volume fraction.

    As :func:`granbayes.stats.identifiability_table`, but with the prior's variance from
    the parameter's prior itself (20,000 draws), so that fits stored without prior draws
    (those of ``granbayes diagnose``) can be read. For a ``quadratic`` law the prior is
    that of the parameter's value at the critical packing.

    Parameters
    ----------
    fit : FitResult, xarray.DataTree, SavedFit or path
        A fit (``posterior.nc`` or its folder).
    parameters : sequence of str, optional
        Force parameters (default: every one of the law).
    rng : numpy.random.Generator or int
        Seed of the prior draws.

    Returns
    -------
    pandas.DataFrame
        One row per parameter and volume fraction: ``parameter``, ``phi``, ``unit``,
        ``scale`` (``log`` or ``linear``), ``median`` [the parameter's unit], ``prior_sd``
        and ``posterior_sd`` (in the scale), ``contraction``, ``verdict``
        (:data:`granbayes.stats.IDENTIFIABILITY_LEVELS`) and ``unidentified`` (contraction
        below 0.5).

    Raises
    ------
    ValueError
        A parameter the law does not have.
    """
    s = as_saved_fit(fit)
    rng = rng if isinstance(rng, np.random.Generator) else np.random.default_rng(rng)
    names = list(parameters) if parameters is not None else list(s.parameters)
    unknown = [n for n in names if n not in s.parameters]
    if unknown:
        raise ValueError(
            f"parameter(s) {unknown}: the law {'+'.join(s.settings.terms)} has "
            f"{', '.join(s.parameters)}"
        )
    prior_sd = {name: _prior_sd(s.priors[name], rng) for name in names}
    table = identifiability_table(s.datatree, names, prior_sd=prior_sd)
    medians = [
        float(np.nanmedian(s.datatree["posterior"][name].sel(phi=phi).values))
        for name, phi in zip(table["parameter"], table["phi"], strict=True)
    ]
    return table.assign(
        unit=[s.priors[name].unit for name in table["parameter"]],
        median=medians,
        unidentified=table["contraction"] < UNIDENTIFIED,
    )[[*_COLUMNS]]


@dataclass(frozen=True)
class ParameterDesign:
    """A plan of next jumps and how much it is expected to narrow the targeted parameters.

    Attributes
    ----------
    plan : pandas.DataFrame
        The jumps to measure: ``command``, ``phi``, ``freq_hz``, ``delay_ms`` and
        ``trials``, most trials first.
    targets : pandas.DataFrame
        One row per targeted parameter and volume fraction: as
        :func:`parameter_contraction` (``posterior_sd`` and ``contraction`` now), and after
        the plan in expectation ``posterior_sd_expected``, ``contraction_expected``,
        ``information_nats`` (``log(sd now / sd expected)``: the expected information the
        plan gives about that parameter alone) and ``reached`` (the goal: the contraction
        ``goal``, or the SD shrunk to ``sd_ratio`` of the present one).
    candidates : pandas.DataFrame
        Every setting considered: the predictive mean and SD of a new jump [mm]
        (``mean_mm``, ``sd_mm``) and ``information_nats``, the expected information one
        jump there gives about the targets jointly, best first.
    n_jumps : int
        Jumps in the plan.
    information_nats : float
        Expected information of the whole plan about the targets jointly [nats].
    reached : bool
        Whether every target reaches the goal in expectation (if not, ``max_jumps`` was too
        small, or the settings considered cannot inform a target).
    goal : float or None
        The contraction aimed at (None: ``sd_ratio``).
    sd_ratio : float or None
        The share of the present posterior SD aimed at (None: ``goal``).
    law : str
        The fitted law, as ``+``-joined terms.
    notes : tuple of str
        What the design assumed or dropped, in words.
    """

    plan: pd.DataFrame
    targets: pd.DataFrame
    candidates: pd.DataFrame
    n_jumps: int
    information_nats: float
    reached: bool
    goal: float | None
    sd_ratio: float | None
    law: str
    notes: tuple[str, ...] = field(default=())

    def to_json(self) -> dict:
        """JSON-ready summary (``design.json``)."""

        def records(df: pd.DataFrame) -> list[dict]:
            return json.loads(df.to_json(orient="records"))

        return {
            "target": "parameters",
            "law": self.law,
            "goal_contraction": self.goal,
            "goal_sd_ratio": self.sd_ratio,
            "n_jumps": self.n_jumps,
            "information_nats": self.information_nats,
            "reached": self.reached,
            "plan": records(self.plan),
            "parameters": records(self.targets),
            "method": "expected information gain about the targeted parameters (linear-"
            "Gaussian approximation on the posterior draws, as an ensemble Kalman update), "
            "jumps added greedily to the most informative setting until every target "
            "reaches the goal contraction",
            "notes": list(self.notes),
        }


def _gains(cov: np.ndarray, targets: np.ndarray, cols: np.ndarray, noise: np.ndarray):
    """Expected information of one jump at each of ``cols`` about ``targets`` [nats]."""
    c_tt = cov[np.ix_(targets, targets)]
    c_tx = cov[np.ix_(targets, cols)]
    s = cov[cols, cols] + noise
    q = np.sum(c_tx * np.linalg.solve(c_tt, c_tx), axis=0) / s
    return -0.5 * np.log1p(-np.clip(q, 0.0, 1.0 - 1e-12))


def allocate_jumps(
    theta: np.ndarray,
    target_run: np.ndarray,
    mean_mm: np.ndarray,
    noise_mm2: np.ndarray,
    setting_run: np.ndarray,
    var_goal: np.ndarray,
    max_jumps: int,
) -> tuple[np.ndarray, np.ndarray, float, np.ndarray]:
    """Greedy allocation of new jumps by expected information (the module's criterion).

    Parameters
    ----------
    theta : ndarray, shape (n_draws, n_targets)
        The targets' posterior draws, in the scale their variance is judged in.
    target_run : ndarray of int, shape (n_targets,)
        The run (posterior) each target belongs to.
    mean_mm : ndarray, shape (n_draws, n_settings)
        Simulated height of a new jump at each setting, per draw [mm].
    noise_mm2 : ndarray, shape (n_settings,)
        Scatter of a measured jump at each setting [mm^2].
    setting_run : ndarray of int, shape (n_settings,)
        The run each setting's jump informs (-1: none, the setting is not used).
    var_goal : ndarray, shape (n_targets,)
        Each target's variance goal (in the draws' variance): reached targets no longer
        attract jumps.
    max_jumps : int
        Budget.

    Returns
    -------
    counts : ndarray of int, shape (n_settings,)
        Jumps per setting.
    var_after : ndarray, shape (n_targets,)
        Each target's variance after the plan, in expectation.
    information : float
        Expected information of the plan about the targets [nats] (the sum of each jump's
        gain about the targets not yet reached when it was added).
    first : ndarray, shape (n_settings,)
        Expected information of one jump at each setting about every target of its run
        [nats].
    """
    runs = {}
    for r in np.unique(target_run):
        t_idx = np.flatnonzero(target_run == r)
        x_idx = np.flatnonzero(setting_run == r)
        if x_idx.size == 0:
            continue
        z = np.column_stack([theta[:, t_idx], mean_mm[:, x_idx]])
        runs[int(r)] = {"t": t_idx, "x": x_idx, "cov": np.atleast_2d(np.cov(z, rowvar=False))}
    var_after = np.var(theta, axis=0, ddof=1)
    first = np.zeros(mean_mm.shape[1])
    for run in runs.values():
        n_t = len(run["t"])
        cols = n_t + np.arange(len(run["x"]))
        first[run["x"]] = _gains(run["cov"], np.arange(n_t), cols, noise_mm2[run["x"]])
    counts = np.zeros(mean_mm.shape[1], dtype=int)
    information = 0.0
    while counts.sum() < max_jumps:
        best = (0.0, None, None)
        for r, run in runs.items():
            n_t = len(run["t"])
            active = np.flatnonzero(var_after[run["t"]] > var_goal[run["t"]])
            if active.size == 0:
                continue
            cols = n_t + np.arange(len(run["x"]))
            g = _gains(run["cov"], active, cols, noise_mm2[run["x"]])
            j = int(np.argmax(g))
            if g[j] > best[0]:
                best = (float(g[j]), r, j)
        gain, r, j = best
        if r is None:
            break  # every target reached (or no setting informs one)
        run = runs[r]
        n_t, x, cov = len(run["t"]), run["x"][j], run["cov"]
        c = cov[:, n_t + j].copy()
        cov -= np.outer(c, c) / (c[n_t + j] + noise_mm2[x])
        var_after[run["t"]] = np.diag(cov)[:n_t]
        counts[x] += 1
        information += gain
    return counts, var_after, information, first


def design_parameters(
    fit: object,
    *,
    parameters: Sequence[str] | None = None,
    candidates: pd.DataFrame | None = None,
    goal: float = WELL_IDENTIFIED,
    sd_ratio: float | None = None,
    max_jumps: int = 60,
    n_draws: int = 800,
    rng: np.random.Generator | int = 0,
) -> ParameterDesign:
    """Propose the next jumps that best identify a fit's unidentified parameters.

    See the module's description for the criterion and what it leaves out.

    Parameters
    ----------
    fit : FitResult, xarray.DataTree, SavedFit or path
        A fit with jump heights (``posterior.nc`` or its folder).
    parameters : sequence of str, optional
        Force parameters to target at every fitted volume fraction (default: those whose
        contraction is below 0.5 somewhere, :func:`parameter_contraction`, at the volume
        fractions where it is).
    candidates : pandas.DataFrame, optional
        Settings a next jump may have (:func:`granbayes.design.candidate_settings`;
        default: within the fit's measured jumps).
    goal : float
        Contraction each target should reach, in (0, 1) (default 0.9).
    sd_ratio : float, optional
        Instead of ``goal``: each target's posterior SD should shrink to this share of
        its present one, in (0, 1) (to narrow an identified parameter further).
    max_jumps : int
        Budget.
    n_draws : int
        Posterior draws used.
    rng : numpy.random.Generator or int
        Seed of the draws' selection and of the prior draws.

    Returns
    -------
    ParameterDesign

    Raises
    ------
    ValueError
        No target (every parameter identified, and none named), a parameter the law does
        not have, a goal outside (0, 1), or no setting the law predicts.
    """
    if not 0.0 < goal < 1.0:
        raise ValueError(f"goal = {goal}: a contraction in (0, 1)")
    if sd_ratio is not None and not 0.0 < sd_ratio < 1.0:
        raise ValueError(f"sd_ratio = {sd_ratio}: a share of the present SD, in (0, 1)")
    if max_jumps < 1:
        raise ValueError(f"max_jumps = {max_jumps}: must be >= 1")
    rng = rng if isinstance(rng, np.random.Generator) else np.random.default_rng(rng)
    s = as_saved_fit(fit)
    law = "+".join(s.settings.terms)
    table = parameter_contraction(s, parameters, rng=rng)
    if parameters is None:
        table = table[table["unidentified"]]
        if table.empty:
            raise ValueError(
                f"every force parameter of {law} is identified (contraction >= "
                f"{UNIDENTIFIED:g} at every volume fraction): nothing to design; name "
                "parameters to narrow them further"
            )
    table = table.reset_index(drop=True)
    if candidates is None:
        candidates = candidate_settings(s.observed())
    candidates = candidates.reset_index(drop=True)
    post = s.datatree["posterior"]
    n_total = post.sizes["chain"] * post.sizes["draw"]
    pick = np.sort(rng.choice(n_total, size=min(n_draws, n_total), replace=False))
    draws, failed = law_draws(s, candidates, pick)
    usable, notes = usable_settings(failed, "the law's", "the law")
    labels = list(s.models())
    target_run = np.array([labels.index(r) for r in s.runs_of(table["phi"].to_numpy(float))])
    pairs = zip(table["parameter"], table["phi"], strict=True)
    theta = np.column_stack([_target_draws(s, p, phi, pick) for p, phi in pairs])
    mean_mm, noise = draws.mean_mm, draws.var_mm2.mean(axis=0)
    # the plan shrinks the variance of the draws used by var_after / var_draws; applied to
    # the variance of every draw (that of the table), so "now" is parameter_contraction's
    var_draws = theta.var(axis=0, ddof=1)
    var_now = table["posterior_sd"].to_numpy(float) ** 2
    var_prior = table["prior_sd"].to_numpy(float) ** 2
    if sd_ratio is not None:
        var_goal = sd_ratio**2 * var_draws
    else:
        var_goal = (1.0 - goal) * var_prior * var_draws / var_now
    setting_run = np.where(usable, draws.setting_run, -1)
    counts, var_after, information, first = allocate_jumps(
        theta, target_run, mean_mm, noise, setting_run, var_goal, max_jumps
    )
    reached = var_after <= var_goal
    if any(not (setting_run == target_run[i]).any() for i in np.flatnonzero(~reached)):
        notes.append("a target's volume fraction has no candidate setting: widen the candidates")
    expected_var = var_now * var_after / var_draws
    targets = table.assign(
        posterior_sd_expected=np.sqrt(expected_var),
        contraction_expected=1.0 - expected_var / var_prior,
        information_nats=0.5 * np.log(var_draws / var_after),
        reached=reached,
    )
    grid = candidates.assign(
        mean_mm=mean_mm.mean(axis=0),
        sd_mm=np.sqrt(np.maximum(mean_mm.var(axis=0) + noise, 0.0)),
        information_nats=first,
    )[usable]
    plan = plan_of(candidates, counts)
    return ParameterDesign(
        plan=plan,
        targets=targets,
        candidates=grid.sort_values("information_nats", ascending=False, kind="stable").reset_index(
            drop=True
        ),
        n_jumps=int(counts.sum()),
        information_nats=float(information),
        reached=bool(reached.all()),
        goal=float(goal) if sd_ratio is None else None,
        sd_ratio=None if sd_ratio is None else float(sd_ratio),
        law=law,
        notes=tuple(notes),
    )
