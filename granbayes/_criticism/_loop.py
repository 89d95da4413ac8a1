"""The criticism loop: baseline, misfit, candidates, the rule, the verdict.

:func:`diagnose` fits the baseline law, finds where it fails (residual cells), screens and
fits every candidate term of the library on the bank of fits (:class:`FitBank`), adds
terms by the rule (:func:`decide`) while misfit remains, reports the terms the chosen one
is not told apart from, and returns a :class:`Diagnosis` with its typed record.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field, replace

import numpy as np
import pandas as pd

from .. import stats
from .._deprecated import renamed_keyword
from .._experiment import Experiment
from .._fitting import FitResult
from .._priors import Prior
from .._provenance import environment
from .._sampler import ProgressInfo
from ..forces import TERMS, terms_of
from ._bank import FitBank, Pointwise
from ._cells import cells_of, kind_thresholds, misfit_mask
from ._record import (
    BaselineResult,
    CellChange,
    CellResult,
    DiagnosisRecord,
    RuleRecord,
    SelectedResult,
    Tie,
    interval_of,
)
from ._rule import Candidate, DiagnoseSettings, Estimate, Verdict, decide, rivals, verdict


@dataclass
class Diagnosis:
    """Result of :func:`diagnose` (``to_json`` gives ``diagnosis.json``).

    Attributes
    ----------
    baseline, selected : FitResult
        The fits of the baseline law and of the selected law.
    residuals_before, residuals_after : pandas.DataFrame
        Their cells (:func:`granbayes.stats.residual_table`).
    candidates : list of Candidate
        Every candidate of every round, screened-out ones included.
    added : list of str
        Terms the rule added, in order.
    record : DiagnosisRecord
        What was concluded and why (the content of ``diagnosis.json``).
    fits : dict of tuple of str to FitResult
        Every fit made, by law.
    timing_s : dict of str to float
        Wall time [s] per kind of work (not saved).
    """

    baseline: FitResult
    selected: FitResult
    residuals_before: pd.DataFrame
    residuals_after: pd.DataFrame
    candidates: list[Candidate]
    added: list[str]
    record: DiagnosisRecord
    fits: dict[tuple[str, ...], FitResult]
    #: Wall time [s] per kind of work (fits, screening, held-out refits); not saved in
    #: ``diagnosis.json``, which a rerun with the same seed reproduces bit for bit.
    timing_s: dict[str, float] = field(default_factory=dict)

    @property
    def verdict(self) -> Verdict:
        """The :class:`Verdict`."""
        return self.record.verdict

    @property
    def converged(self) -> bool:
        """Whether every fit the decision rests on converged."""
        return self.record.all_converged

    def to_json(self) -> dict:
        """The ``diagnosis.json`` document (data-format.md)."""
        return self.record.to_json()


def _score_round(
    bank: FitBank,
    pointwise: Pointwise,
    current: tuple[str, ...],
    base: tuple[str, ...],
    added: list[str],
    round_no: int,
) -> list[Candidate]:
    """Screen, fit and score the candidates of a round (fallbacks where they decide)."""
    cfg, loos = bank.settings, bank.loos
    terms = cfg.candidate_terms(current)
    screen_gain = {t: float("nan") for t in terms}
    if cfg.screen:
        gains = bank.screen_many([(*current, t) for t in terms], current)
        screen_gain = dict(zip(terms, gains, strict=True))
        # most promising first; a failed screen (NaN) is fitted in full
        terms = sorted(terms, key=lambda t: -np.nan_to_num(screen_gain[t], nan=np.inf))
    scored: list[tuple[Candidate, tuple[str, ...]]] = []
    screened: list[Candidate] = []
    best_gain = -np.inf
    for term in terms:
        key = terms_of((*current, term))
        # below this bar a candidate can neither win nor be a rival of the winner
        bar = max(cfg.min_gain, best_gain - cfg.min_gain - cfg.screen_margin)
        if cfg.screen and screen_gain[term] < bar:
            nan = float("nan")
            screened.append(
                Candidate(
                    term=term,
                    added=(*added, term),
                    round=round_no,
                    elpd=nan,
                    gain=nan,
                    gain_se=nan,
                    gain_vs_baseline=nan,
                    gain_vs_baseline_se=nan,
                    rmse_mm=nan,
                    max_pareto_k=nan,
                    method=(
                        f"screened out (log-likelihood gain {screen_gain[term]:+.1f} < {bar:.1f})"
                    ),
                    estimate=Estimate.SCREENED_OUT,
                    converged=False,
                    screen_gain=screen_gain[term],
                )
            )
            continue
        res = bank.get(key, parent=current)
        gain, se = stats.elpd_difference(loos[key]["elpd_i"], loos[current]["elpd_i"], bank.strata)
        vs_base, vs_base_se = stats.elpd_difference(
            loos[key]["elpd_i"], loos[base]["elpd_i"], bank.strata
        )
        flagged = bool(loos[key]["n_bad_k"] or loos[current]["n_bad_k"])
        cand = Candidate(
            term=term,
            added=(*added, term),
            round=round_no,
            elpd=float(loos[key]["elpd"]),
            gain=gain,
            gain_se=se,
            gain_vs_baseline=vs_base,
            gain_vs_baseline_se=vs_base_se,
            rmse_mm=stats.rmse_mm(res.datatree),
            max_pareto_k=float(loos[key]["max_pareto_k"]),
            method="psis-loo (bad Pareto k, not decisive)" if flagged else "psis-loo",
            estimate=Estimate.PSIS_FLAGGED if flagged else Estimate.PSIS,
            converged=bank.converged(key),
            screen_gain=screen_gain[term],
        )
        if cand.converged:
            best_gain = max(best_gain, gain)
        scored.append((cand, key))
    scored.sort(key=lambda ck: -ck[0].gain)
    # the decision rests on the best candidate and a runner-up within 2 SE of it: where
    # Pareto k is bad, recompute those comparisons with exact refits or K-fold
    out = []
    for i, (cand, key) in enumerate(scored):
        best = scored[0][0]
        decisive = i == 0 or (
            i == 1 and best.gain - cand.gain < 2.0 * max(best.gain_se, cand.gain_se)
        )
        if decisive and cand.estimate is Estimate.PSIS_FLAGGED:
            (e_key, e_cur, e_base), method = pointwise((key, current, base))
            gain, se = stats.elpd_difference(e_key, e_cur, bank.strata)
            vs_base, vs_base_se = stats.elpd_difference(e_key, e_base, bank.strata)
            cand = replace(
                cand,
                elpd=float(np.sum(e_key)),
                gain=gain,
                gain_se=se,
                gain_vs_baseline=vs_base,
                gain_vs_baseline_se=vs_base_se,
                method=method,
                estimate=Estimate.RECOMPUTED,
            )
        out.append(cand)
    return out + screened


def _versus_chosen(
    pointwise: Pointwise,
    current: tuple[str, ...],
    chosen: Candidate,
    scored: Sequence[Candidate],
) -> list[Candidate]:
    """Every fitted candidate of a round with its paired ELPD difference to the chosen one.

    Where PSIS-LOO does not already separate the two by twice the rule's margin, jumps with
    bad Pareto k in either law are recomputed (``Pointwise``), as for the decision itself.
    """
    loos, cfg = pointwise.bank.loos, pointwise.bank.settings
    key = terms_of((*current, chosen.term))
    out = []
    for c in scored:
        if c.screened_out or c.term == chosen.term or not math.isfinite(c.gain):
            out.append(c)
            continue
        other = terms_of((*current, c.term))
        diff, se = stats.elpd_difference(
            loos[key]["elpd_i"], loos[other]["elpd_i"], pointwise.bank.strata
        )
        far = diff > 2.0 * cfg.min_gain and diff > 2.0 * cfg.se_factor * se
        if not far:
            (e_chosen, e_other), _ = pointwise((key, other))
            diff, se = stats.elpd_difference(e_chosen, e_other, pointwise.bank.strata)
        out.append(replace(c, vs_selected=diff, vs_selected_se=se))
    return out


@renamed_keyword("config")
def diagnose(
    experiment: Experiment,
    table: pd.DataFrame,
    settings: DiagnoseSettings | None = None,
    *,
    seed: int = 0,
    priors: Mapping[str, Prior] | None = None,
    data_source: str = "",
    log: Callable[..., None] = print,
    progress: Callable[[str, ProgressInfo], None] | None = None,
) -> Diagnosis:
    """Run the criticism loop (module docstring) on measured jumps.

    Parameters
    ----------
    experiment : Experiment
        Robot, command defaults and ``phi_c``.
    table : pandas.DataFrame
        Validated jumps (:func:`granbayes.load_jumps`).
    settings : DiagnoseSettings, optional
        Baseline, candidates, MCMC settings and the selection rule.
    seed : int
        Master seed (recorded).
    priors : mapping, optional
        Prior overrides.
    data_source : str
        Where the data came from.
    log : callable
        Progress messages (``print`` by default; pass ``lambda *a: None`` to silence).
    progress : callable, optional
        ``progress(label, info)`` (:class:`granbayes._sampler.ProgressInfo`) after every
        sampler chunk of every fit, labelled by law and run (one bar per fit run).

    Returns
    -------
    Diagnosis
    """
    cfg = settings or DiagnoseSettings()
    if isinstance(table, pd.DataFrame):
        table = table.reset_index(drop=True)
    bank = FitBank(experiment, table, cfg, priors, seed, data_source, log, progress)
    pointwise = Pointwise(bank)
    base = terms_of(cfg.baseline)
    log(f"Baseline: {' + '.join(base)}")
    baseline = bank.get(base)
    before = cells_of(baseline.datatree)
    z_thr = kind_thresholds(before, cfg.family_alpha)
    current, added, candidates = base, [], []
    misfit = before
    tests: dict[tuple[str, ...], dict[str, float]] = {}  # the omnibus test, once per law

    def omnibus(key: tuple[str, ...]) -> dict[str, float]:
        if key not in tests:
            tests[key] = _omnibus(bank.fits[key].datatree)
        return tests[key]

    for round_no in range(1, cfg.max_added + 1):
        n_misfit = int(misfit_mask(misfit, z_thr).sum())
        if cfg.lack_of_fit_alpha is not None:  # the test's rejection is one more signal
            n_misfit += int(_rejects(omnibus(current), cfg.lack_of_fit_alpha))
        if not cfg.candidate_terms(current) or (round_no > 1 and n_misfit == 0):
            break
        log(f"Round {round_no}: trying {', '.join(cfg.candidate_terms(current))}")
        scored = _score_round(bank, pointwise, current, base, added, round_no)
        for c in scored:
            if c.screened_out:
                log(f"    + {c.term:<11} {c.method}")
                continue
            log(
                f"    + {c.term:<11} elpd gain {c.gain:+7.1f} ± {c.gain_se:4.1f}   "
                f"rmse {c.rmse_mm:.2f} mm ({c.method}{'' if c.converged else ', NOT converged'})"
            )
        chosen = decide(scored, n_misfit, cfg)
        if chosen is not None:
            scored = _versus_chosen(pointwise, current, chosen, scored)
        candidates.extend(scored)
        if chosen is None:
            log("  no clear gain")
            break
        close = rivals(scored, cfg)
        if close:
            log(
                f"  {chosen.term} is not distinguished from "
                + ", ".join(
                    f"{c.term} ({c.vs_selected:+.1f} ± {c.vs_selected_se:.1f})" for c in close
                )
            )
        added.append(chosen.term)
        current = terms_of((*current, chosen.term))
        misfit = cells_of(bank.fits[current].datatree)
        log(f"  added {chosen.term}")
    selected = bank.fits[current]
    after = cells_of(selected.datatree)
    tested = {"baseline": omnibus(base), "selected": omnibus(current)}
    record = _record(
        bank, pointwise, base, current, before, after, candidates, added, z_thr, tested
    )
    return Diagnosis(
        baseline, selected, before, after, candidates, added, record, bank.fits, dict(bank.seconds)
    )


def _omnibus(dt) -> dict[str, float]:
    """The omnibus lack-of-fit test of a fit's jump heights (NaN without heights)."""
    if "height_mm" not in dt["observed_data"].to_dataset():
        nan = float("nan")
        return {"statistic": nan, "dof_lack": nan, "dof_pure": nan, "p_value": nan}
    test = stats.lack_of_fit(dt)
    return {k: float(test[k]) for k in ("statistic", "dof_lack", "dof_pure", "p_value")}


def _rejects(test: Mapping[str, float], alpha: float | None) -> bool:
    """Whether the rule counts an omnibus test as misfit (not with ``alpha`` None or NaN)."""
    return alpha is not None and bool(test["p_value"] < alpha)


def _record(
    bank: FitBank,
    pointwise: Pointwise,
    base: tuple[str, ...],
    current: tuple[str, ...],
    before: pd.DataFrame,
    after: pd.DataFrame,
    candidates: list[Candidate],
    added: list[str],
    z_thr: dict[str, float],
    omnibus: dict[str, dict[str, float]],
) -> DiagnosisRecord:
    """The typed record of a finished loop (``omnibus``: the baseline's and selected's test)."""
    cfg = bank.settings
    baseline, selected = bank.fits[base], bank.fits[current]
    if current == base:
        gain, gain_se, gain_method = 0.0, 0.0, "none added"
        cell_gain, cell_gain_se = 0.0, 0.0
    else:
        (e_cur, e_base), gain_method = pointwise((current, base))
        gain, gain_se = stats.elpd_difference(e_cur, e_base, bank.strata)
        cell_cur, cell_base = stats.cell_loo(selected.datatree), stats.cell_loo(baseline.datatree)
        cell_gain, cell_gain_se = stats.elpd_difference(cell_cur["elpd_i"], cell_base["elpd_i"])
    heights_before = before[before["kind"] == "heights"].dropna(axis=1, how="all")
    heights_after = after[after["kind"] == "heights"].dropna(axis=1, how="all")
    keys = [k for k in stats.CELL_KEYS if k in heights_before.columns]
    merged = heights_before.merge(heights_after, on=keys, suffixes=("_before", "_after"))
    per_cell = tuple(
        CellChange(
            key={k: (r[k] if k == "command" else float(r[k])) for k in keys},
            residual_before_mm=float(r["mean_residual_mm_before"]),
            residual_after_mm=float(r["mean_residual_mm_after"]),
            z_before=float(r["z_before"]),
            z_after=float(r["z_after"]),
        )
        for r in merged.to_dict("records")
    )
    post = selected.datatree["posterior"].to_dataset()
    new_params = {
        p.name: {
            f"{float(phi):g}": interval_of(post[p.name].sel(phi=phi).values.ravel(), stats.CI_PROB)
            for phi in post["phi"].values
        }
        for term in added
        for p in TERMS[term].parameters
    }
    n_before = int(misfit_mask(before, z_thr).sum())
    residual = CellResult.from_table(after[misfit_mask(after, z_thr)], z_thr)
    flags = {law: _rejects(test, cfg.lack_of_fit_alpha) for law, test in omnibus.items()}
    ties = tuple(
        Tie(r, term, c.term, c.vs_selected, c.vs_selected_se, c.converged)
        for r, term in enumerate(added, start=1)
        for c in rivals([x for x in candidates if x.round == r], cfg)
    )
    rmse_before, rmse_after = stats.rmse_mm(baseline.datatree), stats.rmse_mm(selected.datatree)
    return DiagnosisRecord(
        baseline=BaselineResult(
            terms=tuple(base),
            elpd=float(bank.loos[base]["elpd"]),
            elpd_se=float(bank.loos[base]["se"]),
            rmse_mm=rmse_before,
        ),
        misfit=CellResult.from_table(before, z_thr),
        n_misfit_cells=n_before,
        candidates=tuple(candidates),
        verdict=verdict(
            added, n_before + int(flags["baseline"]), len(residual) + int(flags["selected"])
        ),
        selected=SelectedResult(
            terms=tuple(current),
            added=tuple(added),
            elpd_gain=gain,
            elpd_gain_se=gain_se,
            elpd_method=gain_method,
            elpd_gain_cells=cell_gain,
            elpd_gain_cells_se=cell_gain_se,
            rmse_before_mm=rmse_before,
            rmse_after_mm=rmse_after,
            indistinguishable=ties,
            parameters=new_params,
            interval=f"{stats.CI_PROB:.0%} equal-tailed (5%, 50%, 95% quantiles)",
            per_cell=per_cell,
        ),
        residual_misfit=residual,
        fits=tuple(bank.records.values()),
        rule=RuleRecord.of(cfg, z_thr, before),
        seed=int(bank.seed),
        data_source=bank.data_source,
        environment=environment(),
        lack_of_fit=omnibus,
    )
