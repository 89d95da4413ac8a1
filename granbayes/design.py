"""Which jumps to measure next: to separate rival laws, or to identify a parameter.

Where ``diagnose`` reports laws it cannot tell apart (``selected.indistinguishable``: the
paired ELPD difference is short of the rule's margin, more than ``min_gain`` nats *and*
``se_factor`` standard errors), :func:`design_jumps` proposes the jumps (command, volume
fraction, frequency, delay) that are expected to separate them, and how many.

The criterion starts from Box & Hill (1967, "Discrimination among mechanistic models",
*Technometrics* 9, 57-71): a new jump at setting ``x`` adds to the ELPD difference of the
true law T over its rival R, in expectation, the Kullback-Leibler divergence of their
posterior predictive distributions at ``x``, and the variance of that log ratio adds to
the variance of the paired sum. As the truth is not known, every ordered pair of the laws
is a hypothesis ("T is true, R its rival"), whose new jumps come from T's present
predictive distribution of a new measured jump (posterior draws of the law plus the
fitted scatter, taken as normal).

Jumps added one by one to the best setting by that criterion alone pile up at one setting,
and a rival with free parameters then fits that setting by moving them: the separation
it promised does not come (the first run of ``benchmarks/design_ties.py`` showed it).
So the plan is judged after the posteriors have moved: each law's posterior draws are
reweighted by their expected log-likelihood of the planned jumps (importance weights,
per run: a per-phi law moves only at the volume fraction of the jumps), and the expected
difference after the plan is

    d_TR + [fit of the measured jumps, T moved - T now] - [the same for R]
         + sum_x n_x E_{y ~ p_T(x)} [log p_T'(y | x) - log p_R'(y | x)],

with the moved laws T', R' (normal approximations of their reweighted predictive
distributions) and the variance ``se_TR^2 + sum_x n_x Var[...]``; ``d_TR`` and ``se_TR``
are the paired difference and its SE on the data so far. A plan *settles* the tie in
expectation when under every hypothesis that difference passes the rule (``min_gain``
nats and ``se_factor`` SE). Jumps are added one at a time to the setting that most raises
the worst hypothesis's ratio to the rule (a greedy maximin allocation), until the plan
settles or the budget ``max_jumps`` is spent; a returns-diminishing setting (the rival
catches up there) yields to another.

What this leaves out, and why it is measured rather than assumed: the reweighting is an
expected update (the planned jumps at their predicted mean, not a drawn data set), with
the present draws only (a plan that moves a posterior far from them is flagged by
``ess_share``), and ELPD on the measured jumps in-sample rather than leave-one-out; a
fit that integrates each bed's volume fraction is designed at the written one. So the
expected separation is an estimate of the gain, not a promise. How often designed jumps,
simulated from the truth and fitted, break real ties, against the same number of jumps
at settings drawn at random, is measured by ``benchmarks/design_ties.py`` (results in
``benchmarks/results/`` and the README). Only jump heights are designed (tracked jumps
and intrusion tests are not proposed).

Where a parameter rather than a law is in doubt (its posterior hardly narrower than its
prior), :func:`design_parameters` proposes the jumps that narrow it most (expected
information gain of a linear-Gaussian approximation on the posterior draws; its
description is in ``granbayes/_identify.py``).
"""

from __future__ import annotations

import itertools
import json
import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import pandas as pd
from scipy.special import logsumexp

from ._criticism import DiagnoseSettings
from ._deprecated import renamed_keyword
from ._design_draws import (
    LawDraws,
    candidate_settings,
    law_draws,
    plan_of,
    usable_settings,
)
from ._identify import ParameterDesign, design_parameters, parameter_contraction
from ._saved import SavedFit, as_saved_fit, load_fit
from .forces import terms_of

__all__ = [
    "Design",
    "LawDraws",
    "ParameterDesign",
    "candidate_settings",
    "design_from_diagnosis",
    "design_jumps",
    "design_parameters",
    "law_draws",
    "load_tie",
    "normal_separation",
    "parameter_contraction",
    "plan_jumps",
    "save_tie_laws",
    "ties_of",
]


def _expected_log_density(a, big_a, b, big_b):
    """E log N(y; b, B) for y ~ N(a, A) [nats]."""
    return -0.5 * np.log(2.0 * np.pi * big_b) - ((a - b) ** 2 + big_a) / (2.0 * big_b)


def _log_ratio_variance(a, big_a, b1, big_b1, b2, big_b2):
    """Var[log N(y; b1, B1) - log N(y; b2, B2)] for y ~ N(a, A) [nats^2]."""
    lin = (a - b2) / big_b2 - (a - b1) / big_b1
    quad = 0.5 / big_b2 - 0.5 / big_b1
    return lin**2 * big_a + 2.0 * quad**2 * big_a**2


def normal_separation(
    mean_t: np.ndarray, sd_t: np.ndarray, mean_r: np.ndarray, sd_r: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Mean and variance of log p_T(y) - log p_R(y) for y ~ p_T, both normal [nats].

    The mean is the Kullback-Leibler divergence KL(p_T || p_R).

    Parameters
    ----------
    mean_t, sd_t : ndarray
        Mean and standard deviation of the true law's predictive distribution [mm].
    mean_r, sd_r : ndarray
        The same for the rival [mm].

    Returns
    -------
    kl, var : ndarray
        Expected log ratio per jump and its variance [nats, nats^2] (broadcast shape).

    Examples
    --------
    >>> kl, var = normal_separation(0.0, 1.0, 2.0, 1.0)  # equal widths: delta^2 / 2
    >>> float(kl), float(var)
    (2.0, 4.0)
    """
    st2, sr2 = np.square(sd_t), np.square(sd_r)
    kl = _expected_log_density(mean_t, st2, mean_t, st2) - _expected_log_density(
        mean_t, st2, mean_r, sr2
    )
    return kl, _log_ratio_variance(mean_t, st2, mean_t, st2, mean_r, sr2)


@dataclass(frozen=True)
class Design:
    """A plan of next jumps and the separation it is expected to give.

    Attributes
    ----------
    plan : pandas.DataFrame
        The jumps to measure: the settings (``command``, ``phi``, ``freq_hz``,
        ``delay_ms``) and ``trials``, most trials first.
    hypotheses : pandas.DataFrame
        One row per ordered pair of laws (``truth``, ``rival``): the paired ELPD
        difference truth - rival on the data so far (``elpd_diff_now``, ``se_now``), and
        expected after the plan (``elpd_diff_expected``, ``se_expected``) [nats],
        ``ess_share`` (the smallest effective sample size of a reweighted posterior, as a
        share of its draws) and ``settled`` (the rule passed in expectation).
    candidates : pandas.DataFrame
        Every setting considered: per law the predictive mean and SD of a new jump
        [mm] (``mean_mm[<law>]``, ``sd_mm[<law>]``), per hypothesis the expected
        separation per jump ``kl[<truth> vs <rival>]`` [nats] and its variance, and
        ``worst_kl`` (the smallest over the hypotheses), best first.
    n_jumps : int
        Jumps in the plan.
    settled : bool
        Whether the plan passes the rule under every hypothesis in expectation (if not,
        ``max_jumps`` was too small, or the settings considered cannot separate the
        laws).
    laws : tuple of str
        The laws, as ``+``-joined terms.
    rule : dict
        ``min_gain`` [nats] and ``se_factor``.
    notes : tuple of str
        What the design assumed or dropped, in words.
    """

    plan: pd.DataFrame
    hypotheses: pd.DataFrame
    candidates: pd.DataFrame
    n_jumps: int
    settled: bool
    laws: tuple[str, ...]
    rule: dict = field(default_factory=dict)
    notes: tuple[str, ...] = ()

    def to_json(self) -> dict:
        """JSON-ready summary (``design.json``)."""

        def records(df: pd.DataFrame) -> list[dict]:
            return json.loads(df.to_json(orient="records"))

        return {
            "laws": list(self.laws),
            "n_jumps": self.n_jumps,
            "settled": self.settled,
            "rule": self.rule,
            "plan": records(self.plan),
            "hypotheses": records(self.hypotheses),
            "method": "expected paired ELPD difference after the plan (Box & Hill 1967 "
            "Kullback-Leibler separation of the laws' posterior predictive distributions, "
            "normal approximation, with both posteriors reweighted by the planned jumps), "
            "greedy maximin allocation of jumps over the hypotheses",
            "notes": list(self.notes),
        }


def _law_name(fit: SavedFit) -> str:
    return "+".join(fit.settings.terms)


class _LawState:
    """One law's draws under a plan: log-weights per run and what they give, cached.

    A planned jump reweights the draws of its run only, so trying a jump recomputes that
    run's settings and measured jumps alone.
    """

    def __init__(self, d: LawDraws, gain: np.ndarray):
        self.d, self.gain = d, gain  # gain: expected log-likelihood of one jump, (S, X)
        n_draws = d.mean_mm.shape[0]
        self.now = logsumexp(d.log_lik, axis=0) - math.log(n_draws)
        self.second = d.var_mm2 + d.mean_mm**2
        self.cols = [np.flatnonzero(d.setting_run == r) for r in range(d.n_runs)]
        self.jumps = [np.flatnonzero(d.jump_run == r) for r in range(d.n_runs)]
        self.logw = np.zeros((d.n_runs, n_draws))
        self.mean = np.zeros(d.mean_mm.shape[1])
        self.var = np.zeros(d.mean_mm.shape[1])
        self.fit = np.zeros(d.n_runs)
        self.ess = np.ones(d.n_runs)
        for r in range(d.n_runs):
            self.commit(r, self.logw[r])

    def _run(self, r: int, logw: np.ndarray) -> tuple[np.ndarray, np.ndarray, float, float]:
        """Moments at run ``r``'s settings, its measured jumps' fit change, its ESS share."""
        w = np.exp(logw - logw.max())
        w /= w.sum()
        cols, jumps = self.cols[r], self.jumps[r]
        mean = w @ self.d.mean_mm[:, cols]
        var = np.maximum(w @ self.second[:, cols] - mean**2, 1e-12)
        with np.errstate(divide="ignore"):
            fit = logsumexp(np.log(w)[:, None] + self.d.log_lik[:, jumps], axis=0)
        return mean, var, float(np.sum(fit - self.now[jumps])), float(1.0 / np.sum(w**2) / w.size)

    def commit(self, r: int, logw: np.ndarray) -> None:
        """Make ``logw`` run ``r``'s log-weights."""
        self.logw[r] = logw
        self.mean[self.cols[r]], self.var[self.cols[r]], self.fit[r], self.ess[r] = self._run(
            r, logw
        )

    def current(self) -> tuple[np.ndarray, np.ndarray, float, float]:
        """Moments at every setting, the fit change of all measured jumps, the least ESS."""
        return self.mean, self.var, float(self.fit.sum()), float(self.ess.min())

    def trial(self, x: int) -> tuple[tuple, tuple[int, np.ndarray]]:
        """One more jump at setting ``x``: what it gives (as :meth:`current`), and its change."""
        r = int(self.d.setting_run[x])
        logw = self.logw[r] + self.gain[:, x]
        mean_r, var_r, fit_r, ess_r = self._run(r, logw)
        mean, var = self.mean.copy(), self.var.copy()
        mean[self.cols[r]], var[self.cols[r]] = mean_r, var_r
        ess = min(ess_r, float(np.delete(self.ess, r).min(initial=1.0)))
        return (mean, var, float(self.fit.sum() - self.fit[r] + fit_r), ess), (r, logw)


class _Hypothesis:
    """One law true, its rival fitted: the expected paired difference of a plan.

    The data of the hypothesis come from the true law's present predictive distribution
    (mean ``a``, variance ``A`` per setting). Planned jumps reweight the draws of both laws
    by their expected log-likelihood of such jumps (each law's posterior after the jumps,
    by importance weighting): the rival moves towards the data where it can, which the
    separation of its moved predictive distribution, and its fit of the jumps measured so
    far, then show.
    """

    def __init__(self, truth: LawDraws, rival: LawDraws, diff_now: float, se_now: float):
        self.a, self.big_a = truth.moments()
        self.diff_now, self.var_now = float(diff_now), float(se_now) ** 2
        self.states = [
            _LawState(d, _expected_log_density(self.a, self.big_a, d.mean_mm, d.var_mm2))
            for d in (truth, rival)
        ]

    def evaluate(self, counts: np.ndarray, truth: tuple, rival: tuple) -> tuple[float, ...]:
        """Expected difference truth - rival, its variance, and the smallest ESS share."""
        (m_t, v_t, fit_t, ess_t), (m_r, v_r, fit_r, ess_r) = truth, rival
        per_jump = _expected_log_density(self.a, self.big_a, m_t, v_t) - _expected_log_density(
            self.a, self.big_a, m_r, v_r
        )
        var = _log_ratio_variance(self.a, self.big_a, m_t, v_t, m_r, v_r)
        diff = self.diff_now + fit_t - fit_r + float(counts @ per_jump)
        return diff, self.var_now + float(counts @ var), min(ess_t, ess_r)

    def now(self, counts: np.ndarray) -> tuple[float, ...]:
        """:meth:`evaluate` of the plan so far."""
        return self.evaluate(counts, *(s.current() for s in self.states))

    def trial(self, x: int, counts: np.ndarray) -> tuple[tuple[float, ...], list]:
        """:meth:`evaluate` with one more jump at ``x`` (in ``counts``), and its changes."""
        tried = [s.trial(x) for s in self.states]
        return self.evaluate(counts, *(t for t, _ in tried)), [c for _, c in tried]

    def commit(self, changes: list) -> None:
        """Make the changes of a :meth:`trial` the plan's."""
        for state, (r, logw) in zip(self.states, changes, strict=True):
            state.commit(r, logw)

    def fit_changes(self) -> tuple[float, float]:
        """Truth's and rival's change of fit of the measured jumps under the plan [nats]."""
        return self.states[0].current()[2], self.states[1].current()[2]


def plan_jumps(
    draws: Mapping[str, LawDraws],
    evidence: Mapping[tuple[str, str], tuple[float, float]],
    *,
    max_jumps: int,
    min_gain: float = 4.0,
    se_factor: float = 2.0,
) -> tuple[np.ndarray, pd.DataFrame, bool, float]:
    """Greedy maximin allocation of new jumps over settings (module docstring).

    Jumps are added one at a time, each to the setting that most raises the worst
    hypothesis's ratio to the rule, ``min(d / min_gain, d / (se_factor * se))`` with the
    expected difference ``d`` and its SE after the planned jumps (both laws' posteriors
    reweighted by the planned jumps), until the ratio exceeds 1 under every hypothesis or
    ``max_jumps`` are spent.

    Parameters
    ----------
    draws : mapping of str to LawDraws
        The laws, on the same settings and measured jumps.
    evidence : mapping
        ``{(truth, rival): (diff, se)}``, one entry per hypothesis (usually every ordered
        pair of the laws): the paired ELPD difference on the data so far and its SE
        [nats].
    max_jumps : int
        Budget.
    min_gain, se_factor : float
        The rule.

    Returns
    -------
    counts : ndarray of int, shape (n_settings,)
        Jumps per setting.
    hypotheses : pandas.DataFrame
        Per ordered pair: ``truth``, ``rival``, ``elpd_diff_now``, ``se_now``,
        ``elpd_diff_expected``, ``se_expected`` [nats], ``settled``, and ``ess_share``
        (the smallest effective sample size of a reweighted posterior, as a share of the
        draws: small values mean the plan asks more than the draws can represent) and
        ``refuted_now`` (the data so far already reject the hypothesis by the rule: its
        rival beats its truth; it is not designed for), ``fit_change_truth`` and
        ``fit_change_rival`` [nats] (each law's change of in-sample log predictive
        density of the jumps measured so far once the plan reweights its draws: part of
        ``elpd_diff_expected``, whose rest is the planned jumps' own separation; a rival
        pulled towards the truth's predictions at the new settings can lose fit of the
        old jumps).
    settled : bool
        Whether every hypothesis not refuted passes the rule in expectation.
    first_jump : float
        The worst hypothesis's ratio to the rule before any jump (> 1: already settled).

    Raises
    ------
    ValueError
        If every hypothesis is refuted.
    """
    pairs = list(evidence)
    hyps = [_Hypothesis(draws[t], draws[r], *evidence[(t, r)]) for t, r in pairs]
    n_settings = next(iter(draws.values())).mean_mm.shape[1]
    counts = np.zeros(n_settings)

    def ratio(diff: float, var: float) -> float:
        by_se = diff / (se_factor * math.sqrt(var)) if var > 0 else math.copysign(np.inf, diff)
        return min(diff / min_gain, by_se)

    state = [h.now(counts) for h in hyps]
    now = {p: ratio(d, v) for p, (d, v, _) in zip(pairs, state, strict=True)}
    # a hypothesis the data already reject by the rule (its rival beats its truth) is not
    # designed for
    refuted = [now.get((r, t), -np.inf) > 1.0 for t, r in pairs]
    active = [i for i, out in enumerate(refuted) if not out]
    if not active:
        raise ValueError("every hypothesis is refuted by the data so far: no tie to settle")
    first = min(now[pairs[i]] for i in active)
    settled = first > 1.0
    while not settled and counts.sum() < max_jumps:
        best, best_score, best_state = -1, -np.inf, None
        for x in range(n_settings):
            trial = counts.copy()
            trial[x] += 1
            cand = [h.trial(x, trial) for h in hyps]
            score = min(ratio(*cand[i][0][:2]) for i in active)
            if score > best_score:
                best, best_score, best_state = x, score, cand
        counts[best] += 1
        for h, (_, changes) in zip(hyps, best_state, strict=True):
            h.commit(changes)
        state = [ev for ev, _ in best_state]
        settled = best_score > 1.0
    fit_changes = [h.fit_changes() for h in hyps]
    table = pd.DataFrame(
        {
            "truth": [t for t, _ in pairs],
            "rival": [r for _, r in pairs],
            "elpd_diff_now": [evidence[p][0] for p in pairs],
            "se_now": [evidence[p][1] for p in pairs],
            "elpd_diff_expected": [d for d, _, _ in state],
            "se_expected": [math.sqrt(v) for _, v, _ in state],
            "ess_share": [e for _, _, e in state],
            "fit_change_truth": [truth for truth, _ in fit_changes],
            "fit_change_rival": [rival for _, rival in fit_changes],
            "refuted_now": refuted,
        }
    )
    table["settled"] = [ratio(d, v) > 1.0 for d, v, _ in state]
    return counts.astype(int), table, bool(settled), float(first)


@renamed_keyword("config")
def design_jumps(
    fits: Mapping[str, object] | Sequence[object],
    *,
    evidence: Mapping[tuple[str, str], tuple[float, float]] | None = None,
    candidates: pd.DataFrame | None = None,
    max_jumps: int = 60,
    n_draws: int = 800,
    settings: DiagnoseSettings | None = None,
    rng: np.random.Generator | int = 0,
) -> Design:
    """Propose the next jumps that best separate rival laws fitted to the same data.

    Parameters
    ----------
    fits : mapping of str to fit, or sequence of fits
        Two or more fits of the same measurements (``granbayes.fit`` results, DataTrees,
        or ``posterior.nc`` paths), by law name (a sequence: named by their terms).
    evidence : mapping, optional
        ``{(truth, rival): (elpd_diff, se)}``, the paired ELPD difference truth - rival on
        the data so far and its SE [nats], for the ordered pairs given (the reverse pair
        is implied). Default: PSIS-LOO of the fits, paired over the same units
        (:func:`granbayes.stats.loo` and :func:`granbayes.stats.elpd_difference`).
    candidates : pandas.DataFrame, optional
        Settings a next jump may have (:func:`candidate_settings`; default: that of the
        first fit's measured jumps).
    max_jumps : int
        Budget: jumps added until the plan settles the tie, at most this many.
    n_draws : int
        Posterior draws per law (the same (chain, draw) indices in every run).
    settings : DiagnoseSettings, optional
        The rule's thresholds (``min_gain``, ``se_factor``; default ``DiagnoseSettings()``).
    rng : numpy.random.Generator or int
        Seed of the draws' selection.

    Returns
    -------
    Design

    Raises
    ------
    ValueError
        Fewer than two laws, fits of different data, or no setting every law predicts.
    """
    cfg = settings or DiagnoseSettings()
    if max_jumps < 1:
        raise ValueError(f"max_jumps = {max_jumps}: must be >= 1")
    rng = rng if isinstance(rng, np.random.Generator) else np.random.default_rng(rng)
    items = fits.items() if isinstance(fits, Mapping) else [(None, f) for f in fits]
    saved = {}
    for name, f in items:
        s = as_saved_fit(f)
        saved[name or _law_name(s)] = s
    laws = tuple(saved)
    if len(laws) < 2:
        raise ValueError(f"design_jumps needs two or more laws, got {list(laws)}")
    shas = {n: s.datatree.attrs.get("data_sha256") for n, s in saved.items()}
    if len(set(shas.values())) > 1:
        raise ValueError(f"the fits are of different data (sha256 by law: {shas})")
    first = saved[laws[0]]
    if candidates is None:
        candidates = candidate_settings(first.observed())
    candidates = candidates.reset_index(drop=True)
    n_total = min(
        s.datatree["posterior"].sizes["draw"] * s.datatree["posterior"].sizes["chain"]
        for s in saved.values()
    )
    pick = np.sort(rng.choice(n_total, size=min(n_draws, n_total), replace=False))
    draws, failed = {}, np.zeros(len(candidates))
    for law, s in saved.items():
        draws[law], f = law_draws(s, candidates, pick)
        failed = np.maximum(failed, f)
    usable, notes = usable_settings(failed, "a law's", "every law")
    draws = {
        law: LawDraws(
            d.mean_mm[:, usable],
            d.var_mm2[:, usable],
            d.log_lik,
            d.setting_run[usable],
            d.jump_run,
        )
        for law, d in draws.items()
    }
    table = candidates[usable].reset_index(drop=True)
    evidence = dict(evidence) if evidence is not None else _loo_evidence(saved)
    pairs = list(itertools.permutations(laws, 2))
    full = {}
    for t, r in pairs:
        if (t, r) in evidence:
            full[(t, r)] = tuple(map(float, evidence[(t, r)]))
        elif (r, t) in evidence:
            d, s = evidence[(r, t)]
            full[(t, r)] = (-float(d), float(s))
        else:
            raise ValueError(f"no evidence for the pair ({t}, {r})")
    moments = {law: d.moments() for law, d in draws.items()}
    for law, (mean, var) in moments.items():
        table[f"mean_mm[{law}]"] = mean
        table[f"sd_mm[{law}]"] = np.sqrt(var)
    for t, r in pairs:
        k, v = normal_separation(
            moments[t][0], np.sqrt(moments[t][1]), moments[r][0], np.sqrt(moments[r][1])
        )
        table[f"kl[{t} vs {r}]"], table[f"kl_var[{t} vs {r}]"] = k, v
    table["worst_kl"] = table[[f"kl[{t} vs {r}]" for t, r in pairs]].min(axis=1)
    counts, hyp, settled, first_ratio = plan_jumps(
        draws, full, max_jumps=max_jumps, min_gain=cfg.min_gain, se_factor=cfg.se_factor
    )
    plan = plan_of(table, counts)
    if first_ratio > 1.0:
        notes.append("the data already separate the laws: no jump needed")
    if (hyp["ess_share"] < 0.05).any():
        notes.append(
            "the plan reweights a posterior to fewer than 5% of its draws: its expected "
            "difference is uncertain; measure part of it, refit and design again"
        )
    return Design(
        plan=plan,
        hypotheses=hyp,
        candidates=table.sort_values("worst_kl", ascending=False, kind="stable").reset_index(
            drop=True
        ),
        n_jumps=int(counts.sum()),
        settled=settled,
        laws=laws,
        rule={"min_gain": cfg.min_gain, "se_factor": cfg.se_factor},
        notes=tuple(notes),
    )


def _loo_evidence(saved: Mapping[str, SavedFit]) -> dict[tuple[str, str], tuple[float, float]]:
    """Paired PSIS-LOO difference of every pair of laws on their common units [nats]."""
    from . import stats

    loos = {law: stats.loo(s.datatree)["elpd_i"] for law, s in saved.items()}
    strata = stats.unit_kinds(next(iter(saved.values())).datatree)
    out = {}
    for t, r in itertools.combinations(saved, 2):
        d, se = stats.elpd_difference(loos[t], loos[r], strata)
        out[(t, r)] = (float(d), float(se))
    return out


# ----------------------------------------------------------------------------------------
# from a saved diagnosis
# ----------------------------------------------------------------------------------------
def ties_of(record: Mapping) -> list[dict]:
    """The ties of a ``diagnosis.json`` document, with the two laws each compares.

    In round ``r`` the law with the first ``r`` added terms was compared with the law of
    round ``r - 1`` plus the rival term, on the same jumps.

    Parameters
    ----------
    record : mapping
        The ``diagnosis.json`` document.

    Returns
    -------
    list of dict
        Per tie: ``round``, ``selected``/``term`` (the terms), ``laws`` (the two laws'
        terms, selected first), ``elpd_diff`` and ``elpd_diff_se`` [nats].
    """
    base = tuple(record["baseline"]["terms"])
    added = tuple(record["selected"]["added"])
    out = []
    for tie in record["selected"]["indistinguishable"]:
        r = int(tie["round"])
        winner = terms_of(base + added[:r])
        rival = terms_of(base + added[: r - 1] + (tie["term"],))
        out.append({**tie, "laws": (winner, rival)})
    return out


def law_files(laws: Sequence[Sequence[str]]) -> dict[str, str]:
    """File names (under a diagnosis folder) of the posteriors of tied laws.

    Parameters
    ----------
    laws : sequence of sequence of str
        The laws, as their terms.

    Returns
    -------
    dict
        ``{"depth+drag": "laws/depth+drag.nc", ...}``.
    """
    return {"+".join(t): f"laws/{'+'.join(t)}.nc" for t in laws}


def load_tie(folder: str | Path, index: int = 0) -> tuple[dict, dict[str, SavedFit]]:
    """A diagnosis folder's tie and the saved posteriors of its two laws.

    Parameters
    ----------
    folder : str or Path
        Output folder of ``granbayes diagnose`` (``diagnosis.json``, ``laws/``).
    index : int
        Which tie (in the order of ``selected.indistinguishable``).

    Returns
    -------
    tie : dict
        As :func:`ties_of` gives it.
    fits : dict of str to SavedFit
        The two laws' fits, the selected law first.

    Raises
    ------
    ValueError
        If the diagnosis reports no tie, or the index is out of range.
    FileNotFoundError
        If a law's posterior is missing (diagnoses written before ``laws/`` existed).
    """
    folder = Path(folder)
    record = json.loads((folder / "diagnosis.json").read_text())
    ties = ties_of(record)
    if not ties:
        raise ValueError(
            f"{folder / 'diagnosis.json'}: no indistinguishable laws (the diagnosis "
            f"separated every candidate it fitted): nothing to design"
        )
    if not 0 <= index < len(ties):
        raise ValueError(f"tie {index}: the diagnosis has {len(ties)} (0..{len(ties) - 1})")
    tie = ties[index]
    fits = {}
    for law, name in law_files(tie["laws"]).items():
        path = folder / name
        if not path.exists():
            raise FileNotFoundError(
                f"{path}: the posterior of {law} is missing (rerun granbayes diagnose: "
                "diagnoses write the laws of every tie under laws/)"
            )
        fits[law] = load_fit(path)
    return tie, fits


def save_tie_laws(diagnosis: object, folder: str | Path) -> list[Path]:
    """Write the posteriors of the laws of every tie of a diagnosis under ``folder/laws/``.

    ``granbayes diagnose`` calls it, so that ``granbayes design`` can read them back
    (:func:`load_tie`).

    Parameters
    ----------
    diagnosis : granbayes.Diagnosis
        An in-memory diagnosis (its ``record`` and ``fits``).
    folder : str or Path
        The diagnosis folder.

    Returns
    -------
    list of Path
        Files written (none when the diagnosis has no tie).
    """
    from . import _datatree as gdt

    folder = Path(folder)
    written = []
    for tie in ties_of(diagnosis.record.to_json()):
        for law, name in law_files(tie["laws"]).items():
            path = folder / name
            if path.exists():
                continue
            path.parent.mkdir(parents=True, exist_ok=True)
            gdt.write_datatree(diagnosis.fits[terms_of(law.split("+"))].datatree, path)
            written.append(path)
    return written


def design_from_diagnosis(
    folder: str | Path,
    *,
    tie: int = 0,
    candidates: pd.DataFrame | None = None,
    max_jumps: int = 60,
    n_draws: int = 800,
    rng: np.random.Generator | int = 0,
    data_sha256: str | None = None,
) -> tuple[dict, Design]:
    """:func:`design_jumps` for a tie of a saved diagnosis (``granbayes design``).

    The evidence so far is the diagnosis's own paired difference of the two laws (the
    estimate its rule used: PSIS-LOO, moment matched, refits or K-fold) and its rule.

    Parameters
    ----------
    folder : str or Path
        Output folder of ``granbayes diagnose``.
    tie : int
        Which tie of ``selected.indistinguishable``.
    candidates : pandas.DataFrame, optional
        Settings a next jump may have (default: :func:`candidate_settings` of the
        measured jumps).
    max_jumps, n_draws, rng
        As :func:`design_jumps`.
    data_sha256 : str, optional
        The measurements' hash (:func:`granbayes.data_hash`): checked against
        the diagnosed data's before anything is computed.

    Returns
    -------
    tie : dict
        The tie (:func:`ties_of`).
    design : Design

    Raises
    ------
    ValueError
        No tie, or (with ``data_sha256``) a diagnosis of other data.
    """
    record = json.loads((Path(folder) / "diagnosis.json").read_text())
    chosen, fits = load_tie(folder, tie)
    diagnosed = {f.datatree.attrs.get("data_sha256") for f in fits.values()}
    if data_sha256 is not None and diagnosed != {data_sha256}:
        raise ValueError(
            f"{folder} diagnosed other data (sha256 "
            f"{', '.join(str(h)[:12] for h in sorted(map(str, diagnosed)))}... against "
            f"{data_sha256[:12]}...): pass the diagnosed folder, with the same kinds of "
            "measurement"
        )
    winner, rival = ("+".join(t) for t in chosen["laws"])
    rule = record["rule"]
    cfg = DiagnoseSettings(min_gain=float(rule["min_gain"]), se_factor=float(rule["se_factor"]))
    design = design_jumps(
        fits,
        evidence={(winner, rival): (chosen["elpd_diff"], chosen["elpd_diff_se"])},
        candidates=candidates,
        max_jumps=max_jumps,
        n_draws=n_draws,
        settings=cfg,
        rng=rng,
    )
    return chosen, design
