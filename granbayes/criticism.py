"""Model criticism: what the simulation gets wrong, which physics is missing, and the gain.

:func:`diagnose` runs the loop on measured jumps:

1. fit the baseline law (default: the thesis's depth-only law with the bed's default
   unloading), one parameter set per volume fraction shared by all commands;
2. show what it gets wrong: residuals per *cell* (one command at one volume fraction and
   one setting: frequency, amplitude, delay, settle periods), each with a lack-of-fit
   z-score against the trial scatter measured from the repeats (:func:`residual_table`);
   cells beyond :func:`misfit_threshold` are *misfit*;
3. name the cause: every other term of the library is added to the current law, warm-started
   from the current law's posterior (the new parameter at its "off" value), and the
   candidates are compared by PSIS-LOO; where Pareto k exceeds ArviZ's ``good_k`` (0.7
   for the draws of a fit) and the comparison decides the outcome, the flagged jumps are
   moment matched (Paananen et al. 2021), and those still flagged are recomputed by exact
   refits, or by K-fold of their volume fraction where it holds many (``_Pointwise``);
4. extend, forward, by :func:`decide` (the selection rule below), while misfit remains;
5. check what is left: the selected law's own misfit cells (``residual_misfit``). Where
   misfit remains that no library term removes, the verdict is ``misfit_remains``: the
   data hold physics the library does not have, and the report lists what helped and
   where the law still fails instead of naming a cause.

Every fit the decision rests on must have converged (``granbayes.sampler``: autocorrelation,
R-hat across independent ensembles, ESS); a fit that did not is rerun once with twice the
step cap, and a candidate whose fit still did not converge cannot be selected (the report
says so). An extension contains its parent (new parameter "off"), so its ELPD cannot be
far below the parent's: a deficit beyond ``nested_tolerance`` nats plus 2 SE is taken as a
sampling failure and the extension is rerun with another seed.

Selection rule (:func:`decide`; the thresholds are the ones chosen by the calibration study
``benchmarks/calibrate_verdicts.py``, whose measured error rates the README quotes): the
best converged candidate of a round is added when its ELPD gain over the current law
exceeds both ``min_gain`` nats and ``se_factor`` standard errors of the difference, **and**
the current law shows misfit or the gain exceeds ``strong_gain`` nats.

Naming a term is a claim about the physics, so the chosen term must also beat every other
fitted candidate of its round by the same standard (:func:`distinguished`: more than
``min_gain`` nats and ``se_factor`` SE of the paired difference). Those it does not beat
are reported with it as *indistinguishable* on these data (:func:`rivals`;
``selected.indistinguishable`` in ``diagnosis.json``): drag and viscous damping, for one,
differ only in how they scale with the intrusion speed, and a small design often cannot
tell them apart (half of the drag and viscous cases of the calibration study).

The gain is also reported as a leave-one-*cell*-out estimate (PSIS over the summed
log-likelihood of each cell): how much better the selected law predicts a setting it has
not seen. It is computed on the data used for selection, so it is still optimistic about
the choice among candidates; the calibration study (``docs/verdicts/summary.md``) reports
both estimates for every case that added a term, and the false-discovery rate on null data
is what bounds the cost of that optimism at the threshold.
"""

from __future__ import annotations

import contextlib
import math
import time
from collections.abc import Callable, Iterator, Mapping, Sequence
from dataclasses import asdict, dataclass, field, replace

import numpy as np
import pandas as pd
import xarray as xr

from . import stats
from ._deprecated import alias_getattr
from ._provenance import environment
from ._search import drive
from .experiment import Experiment
from .fitting import (
    FitResult,
    FitSettings,
    _run_parts,
    _warm_positions,
    fit,
    part_models,
    screen_many,
)
from .forces import TERMS, terms_of
from .likelihood import Observations, evaluate_models
from .priors import Prior, default_priors
from .sampler import ProgressInfo, SamplerSettings
from .saved import SavedFit

__all__ = [
    "Candidate",
    "DiagnoseSettings",
    "Diagnosis",
    "FitBank",
    "decide",
    "distinguished",
    "diagnose",
    "rivals",
    "verdict",
]

#: Deprecated alias (old name -> new name): importable, with a DeprecationWarning.
__getattr__ = alias_getattr(__name__, {"DiagnoseConfig": "DiagnoseSettings"})

#: Most posterior draws a law's moment matching uses per volume fraction (thinned evenly).
MM_DRAWS = 1000


@dataclass(frozen=True)
class DiagnoseSettings:
    """Settings of the criticism loop (formerly ``DiagnoseConfig``, now a deprecated alias).

    Parameters
    ----------
    baseline : tuple of str
        Terms of the baseline law.
    candidates : tuple of str, optional
        Terms to try (default: every library term not in the baseline).
    sampler : SamplerSettings
        MCMC settings of every fit. The default caps a fit at 10,000 steps (a fit that has
        not converged by then is rerun once with twice the cap and is otherwise recorded as
        unconverged, and no decision rests on it). The cap bounds the cost where the data
        hold physics no law of the library describes and a posterior never mixes (capped at
        ``fit``'s 20,000 steps, and 40,000 on the rerun, such fits cost tens of minutes). It
        cannot be much lower: with hidden ``unloading`` the extended law mixes slowly at the
        densest bed (effective sample size 84 after 3,000 steps and 67 after 6,000, against
        the 400 required), and a cap of 3,000 left that true term unconverged.
    max_added : int
        Most terms added by forward selection.
    min_gain, se_factor, strong_gain : float
        The selection rule (:func:`decide`) [nats, -, nats].
    family_alpha : float
        Misfit threshold: the probability, under a correct law, that any cell of the data
        set is flagged (Bonferroni over cells, Student-t with the pooled degrees of
        freedom of the measured scatter; :func:`misfit_threshold`).
    kfold : int
        Folds of the K-fold fallback.
    max_refits : int
        Where jumps keep a Pareto k above ``good_k`` after moment matching: a volume
        fraction holding at most this many is recomputed by exact leave-one-out refits of
        those jumps, one with more by K-fold cross-validation of that volume fraction
        (``kfold`` refits; the default makes the cheaper choice).
    nested_tolerance : float
        ELPD deficit [nats] (beyond 2 SE) of an extension below its nested parent that is
        taken as a sampling failure and rerun.
    screen : bool
        Screen the candidates before fitting them (:func:`granbayes.fitting.screen`): in
        order of their largest log-likelihood gain, a candidate gets a full posterior
        only if that gain reaches ``min_gain`` and the best ELPD gain of the converged
        candidates fitted before it less ``min_gain + screen_margin``; the others can
        neither win nor be indistinguishable from the winner (:func:`rivals`) and are
        listed as screened out.
    screen_margin : float
        Allowance [nats] for an ELPD gain above the screened log-likelihood gain (a badly
        misspecified parent has a large effective number of parameters, which an
        extension can remove).
    n_threads : int, optional
        numba threads for the simulator.
    """

    baseline: tuple[str, ...] = ("depth",)
    candidates: tuple[str, ...] | None = None
    sampler: SamplerSettings = field(default_factory=lambda: SamplerSettings(max_steps=10_000))
    max_added: int = 2
    min_gain: float = 4.0
    se_factor: float = 2.0
    strong_gain: float = 10.0
    family_alpha: float = 0.05
    kfold: int = 5
    max_refits: int = 5
    nested_tolerance: float = 4.0
    screen: bool = True
    screen_margin: float = 2.0
    n_threads: int | None = None

    def candidate_terms(self, current: Sequence[str]) -> list[str]:
        """Terms that may still be added to ``current``.

        Parameters
        ----------
        current : sequence of str
            Terms of the current law.

        Returns
        -------
        list of str
        """
        pool = self.candidates if self.candidates is not None else tuple(TERMS)
        return [t for t in terms_of(pool) if t not in current and not TERMS[t].required]


# ----------------------------------------------------------------------------------------
# residuals


def _tree(fit: xr.DataTree | FitResult | SavedFit) -> xr.DataTree:
    """The DataTree of a fit given as a DataTree, ``FitResult`` or ``SavedFit``."""
    return fit if isinstance(fit, xr.DataTree) else fit.datatree


# ----------------------------------------------------------------------------------------
# a cached bank of converged fits
@dataclass(frozen=True)
class FitRecord:
    """How one fit of the bank went (``diagnosis.json`` ``fits``)."""

    terms: tuple[str, ...]
    converged: bool
    warnings: tuple[str, ...]
    reruns: int

    def to_json(self) -> dict:
        """JSON-ready record."""
        return {
            "terms": list(self.terms),
            "converged": self.converged,
            "warnings": list(self.warnings),
            "reruns": self.reruns,
        }


class FitBank:
    """Fits of one data set, keyed by their terms; converged, or rerun, and recorded.

    Parameters
    ----------
    experiment : Experiment
    table : pandas.DataFrame
        The jumps.
    config : DiagnoseSettings
    priors : mapping, optional
    seed : int
        Master seed (each law's fits derive their own seeds from it and the law).
    data_source : str
    log : callable
        Progress messages.
    progress : callable, optional
        ``progress(label, info)`` after every sampler chunk of every fit; the label names
        the law and the run (``"depth + drag, phi=0.602"``; reruns and held-out refits
        say so in the law's part).
    """

    def __init__(
        self,
        experiment: Experiment,
        table: pd.DataFrame,
        config: DiagnoseSettings,
        priors: Mapping[str, Prior] | None,
        seed: int,
        data_source: str,
        log: Callable[..., None],
        progress: Callable[[str, ProgressInfo], None] | None = None,
    ) -> None:
        self.experiment, self.table, self.config = experiment, table, config
        self.priors, self.seed, self.data_source, self.log = priors, seed, data_source, log
        self.progress = progress
        self.fits: dict[tuple[str, ...], FitResult] = {}
        self.screens: dict[tuple[str, ...], float] = {}
        #: Wall time [s] spent per kind of work (``diagnosis.json``'s ``timing_s``).
        self.seconds: dict[str, float] = {
            "fits": 0.0,
            "screening": 0.0,
            "moment_matching": 0.0,
            "held_out_refits": 0.0,
        }
        self.loos: dict[tuple[str, ...], dict] = {}
        #: pointwise ELPD of each law after moment matching, and whether each value is
        #: reliable (:meth:`moment_matched`)
        self.matched: dict[tuple[str, ...], tuple[np.ndarray, np.ndarray, int]] = {}
        self.records: dict[tuple[str, ...], FitRecord] = {}

    @property
    def priors_or_default(self) -> dict[str, Prior]:
        """The priors of every fit (the defaults unless overridden)."""
        return dict(self.priors if self.priors is not None else default_priors())

    def _fit_config(self, key: tuple[str, ...], scale: int = 1) -> FitSettings:
        s = self.config.sampler
        return FitSettings(
            terms=key,
            sampler=replace(s, max_steps=s.max_steps * scale),
            n_threads=self.config.n_threads,
            n_prior_draws=0,
        )

    def _law_seed(self, key: tuple[str, ...], attempt: int) -> int:
        code = sum((i + 1) * (list(TERMS).index(t) + 1) for i, t in enumerate(key))
        return int(np.random.SeedSequence([self.seed, code, attempt]).generate_state(1)[0])

    def _progress(self, key: tuple[str, ...], what: str = ""):
        """The fit's ``progress`` callback, its labels prefixed with the law."""
        if self.progress is None:
            return None
        law = " + ".join(key) + what
        return lambda label, info: self.progress(f"{law}, {label}", info)

    def _run(self, key, parent: tuple[str, ...] | None, attempt: int) -> FitResult:
        warm = self.fits[parent].datatree if parent is not None else None
        return fit(
            self.experiment,
            self.table,
            self._fit_config(key, 2**attempt),
            seed=self._law_seed(key, attempt),
            priors=self.priors,
            data_source=self.data_source,
            warm_start=warm,
            progress=self._progress(key, f" (rerun {attempt})" if attempt else ""),
        )

    def get(self, terms: Sequence[str], parent: Sequence[str] | None = None) -> FitResult:
        """The fit of law ``terms`` (warm-started from the fitted ``parent`` law).

        A fit that did not converge is rerun once with twice the step cap; an extension
        whose ELPD lies below its parent's by more than ``nested_tolerance`` + 2 SE is
        rerun once with another seed. Both are recorded.

        Parameters
        ----------
        terms : sequence of str
            The law.
        parent : sequence of str, optional
            A fitted nested law to warm-start from.

        Returns
        -------
        FitResult
        """
        key = terms_of(terms)
        if key in self.fits:
            return self.fits[key]
        parent_key = terms_of(parent) if parent is not None else None
        self.log(f"  fitting {' + '.join(key)} ...")
        with self._timed("fits"):
            return self._get(key, parent_key)

    @contextlib.contextmanager
    def _timed(self, what: str) -> Iterator[None]:
        t0 = time.perf_counter()
        try:
            yield
        finally:
            self.seconds[what] += time.perf_counter() - t0

    def _get(self, key: tuple[str, ...], parent_key: tuple[str, ...] | None) -> FitResult:
        result, notes, reruns = self._run(key, parent_key, 0), [], 0
        if not result.converged:
            notes += result.warnings
            notes.append("not converged: rerun with twice the step cap")
            self.log(f"    {' + '.join(key)} did not converge: rerun")
            result, reruns = self._run(key, parent_key, 1), reruns + 1
        loo = stats.loo(result.datatree)
        if parent_key is not None and reruns == 0:
            diff, se = stats.elpd_difference(loo["elpd_i"], self.loos[parent_key]["elpd_i"])
            if diff < -(self.config.nested_tolerance + 2.0 * se):
                notes.append(
                    f"ELPD {diff:+.1f} ± {se:.1f} below its nested parent "
                    f"({' + '.join(parent_key)}): a sampling failure; rerun with another seed"
                )
                self.log(f"    {' + '.join(key)} below its nested parent: rerun")
                result, reruns = self._run(key, parent_key, 1), reruns + 1
                loo = stats.loo(result.datatree)
        notes += result.warnings
        self.fits[key], self.loos[key] = result, loo
        self.records[key] = FitRecord(key, result.converged, tuple(notes), reruns)
        return result

    def screen(self, terms: Sequence[str], parent: Sequence[str]) -> float:
        """Largest log-likelihood gain [nats] of law ``terms`` over its fitted ``parent``.

        Parameters
        ----------
        terms : sequence of str
            The extended law.
        parent : sequence of str
            The fitted law it extends.

        Returns
        -------
        float
            See :func:`granbayes.fitting.screen`.
        """
        return self.screen_many([terms], parent)[0]

    def screen_many(self, laws: Sequence[Sequence[str]], parent: Sequence[str]) -> list[float]:
        """:meth:`screen` of several extensions of ``parent``, searched side by side.

        Parameters
        ----------
        laws : sequence of sequence of str
            The extended laws.
        parent : sequence of str
            The fitted law they extend.

        Returns
        -------
        list of float
            Their gains [nats] (cached per law; a law's gain does not depend on which
            others are screened with it).
        """
        keys = [terms_of(t) for t in laws]
        todo = list(dict.fromkeys(k for k in keys if k not in self.screens))
        if todo:
            with self._timed("screening"):
                gains = screen_many(
                    self.experiment,
                    self.table,
                    [self._fit_config(k) for k in todo],
                    self.fits[terms_of(parent)].datatree,
                    seeds=[self._law_seed(k, 99) for k in todo],
                    priors=self.priors,
                )
            self.screens.update(zip(todo, gains, strict=True))
        return [self.screens[k] for k in keys]

    def converged(self, key: tuple[str, ...]) -> bool:
        """Whether the (final) fit of law ``key`` converged.

        Parameters
        ----------
        key : tuple of str
            The law's terms (canonical order).

        Returns
        -------
        bool
        """
        return self.records[key].converged

    # fallbacks for bad Pareto k: moment matching, then refits of single volume fractions
    def moment_matched(self, key: tuple[str, ...]) -> tuple[np.ndarray, np.ndarray, int]:
        """Pointwise PSIS-LOO of law ``key`` with its bad-k jumps moment matched.

        See :meth:`moment_matched_many`.

        Parameters
        ----------
        key : tuple of str
            The law's terms (canonical order).

        Returns
        -------
        elpd_i : ndarray, shape (jump,)
            Log predictive density of every jump [nats].
        reliable : ndarray of bool, shape (jump,)
            Whether a jump's value is reliable: its Pareto k, after moment matching where
            it was applied, at most the ``good_k`` of the draws it was computed from.
        n_matched : int
            Jumps moment matching was applied to.
        """
        return self.moment_matched_many([key])[0]

    def moment_matched_many(
        self, keys: Sequence[tuple[str, ...]]
    ) -> list[tuple[np.ndarray, np.ndarray, int]]:
        """Pointwise PSIS-LOO of laws with their bad-k jumps moment matched (cached per law).

        Every jump whose Pareto k exceeds ``good_k`` is moment matched
        (:mod:`granbayes.moment_matching`, Paananen et al. 2021) on the draws of its volume
        fraction's run, in the run's sampling coordinates, thinned evenly to at most
        :data:`MM_DRAWS` draws (each stage simulates every flagged jump's moved draws: its
        cost is proportional to the draws, and PSIS needs nearly independent draws, not
        many; its own ``good_k`` is that of the draws it uses). The flagged jumps of every
        volume fraction of every law go through the stages together, one simulator call
        per round (:func:`granbayes._search.drive`).

        Parameters
        ----------
        keys : sequence of tuple of str
            The laws.

        Returns
        -------
        list of (ndarray, ndarray, int)
            Per law: ``elpd_i`` [nats] and whether it is reliable, for every jump, and the
            number of jumps moment matched (see :meth:`moment_matched`).
        """
        todo = [k for k in dict.fromkeys(keys) if k not in self.matched]
        searches, where = [], []
        for key in todo:
            loo = self.loos[key]
            elpd_i = np.array(loo["elpd_i"], dtype=float)
            reliable = np.asarray(loo["pareto_k"]) <= loo["good_k"]
            bad = np.flatnonzero(~reliable)
            self.matched[key] = (elpd_i, reliable, len(bad))
            for part in self.fits[key].parts:
                local = np.flatnonzero(np.isin(part.jumps, bad))
                if not len(local):
                    continue
                n_chain, n_draw = part.run.samples.shape[:2]
                step = max(1, -(-n_chain * n_draw // MM_DRAWS))
                thin = slice(n_draw - 1 - (n_draw - 1) // step * step, None, step)
                searches.append(
                    stats.moment_match_search(
                        part.run.samples[:, thin],
                        part.run.log_prob[:, thin],
                        part.log_lik[:, thin],
                        local,
                    )
                )
                where.append((key, part))
        if searches:
            with self._timed("moment_matching"):
                models = [part.model for _, part in where]

                def evaluate(requests: list, which: list[int]) -> list:
                    shapes = [u.shape for u, _ in requests]
                    evs = evaluate_models(
                        [models[i] for i in which],
                        [u.reshape(-1, u.shape[-1]) for u, _ in requests],
                    )
                    out = []
                    for ev, (b, n, _), (_, obs) in zip(evs, shapes, requests, strict=True):
                        ll = ev.log_lik.reshape(b, n, -1)[np.arange(b), :, obs]
                        out.append((ev.log_prob.reshape(b, n), ll))
                    return out

                results = drive(searches, evaluate)
            for (key, part), res in zip(where, results, strict=True):
                elpd_i, reliable, _ = self.matched[key]
                elpd_i[part.jumps[res.obs]] = res.elpd_i
                reliable[part.jumps[res.obs]] = res.pareto_k <= res.k_threshold
        return [self.matched[k] for k in keys]

    def held_out(
        self, requests: Sequence[tuple[tuple[str, ...], float, np.ndarray]]
    ) -> list[np.ndarray]:
        """Refits without some jumps, all sampled side by side; their held-out densities.

        A request ``(law, phi, left_out)`` refits law ``law`` on the jumps of volume
        fraction ``phi`` (``per_phi`` laws are independent across volume fractions) without
        the rows ``left_out`` of the jumps table, warm-started from the law's full
        posterior at ``phi``, with lighter settings: two ensembles (one from the full
        posterior, one dispersed) and half the effective sample size, enough for a
        posterior mean of the held-out densities. Every request is one run of
        :func:`granbayes.sampler.run_side_by_side`: one simulator call per round for all.

        Parameters
        ----------
        requests : sequence of (tuple of str, float, ndarray of int)
            Law, volume fraction and the rows to leave out.

        Returns
        -------
        list of ndarray
            Per request, the log predictive density [nats] of each left-out row (in the
            order given), ``log mean_s p(y | theta_s)`` over the refit's draws.
        """
        t = self.table
        specs, configs, seeds, warms, outs = [], [], [], [], []
        for key, phi, left_out in requests:
            config = self._fit_config(key)
            s = config.sampler
            config = replace(config, sampler=replace(s, n_ensembles=2, min_ess=s.min_ess / 2))
            train = t[(t["phi"] == phi) & ~t.index.isin(left_out)]
            ((_, model, jumps),) = part_models(
                self.experiment, train.reset_index(drop=True), config, self.priors_or_default
            )
            what = f" (held out: phi={phi:g}, rows {','.join(map(str, left_out))})"
            specs.append((" + ".join(key) + what, model, jumps))
            configs.append(config)
            code = [int(v) for v in np.asarray(left_out)[:8]]
            seeds.append(self._law_seed(key, 1000 + len(left_out) + 7 * sum(code)))
            warms.append(_warm_positions(model, self.fits[key].datatree, float(phi)))
            outs.append(np.asarray(left_out))
        if not specs:
            return []
        self.log(f"  {len(specs)} held-out refit(s), side by side")
        with self._timed("held_out_refits"):
            parts = _run_parts(specs, configs, seeds, None, False, warms, self.progress)
        out = []
        for part, left_out in zip(parts, outs, strict=True):
            flat = part.run.samples.reshape(-1, part.run.samples.shape[-1])
            obs = Observations.from_table(t.loc[left_out])
            out.append(part.model.log_predictive_density(flat, obs))
        return out

    def folds(self, phi: float) -> np.ndarray:
        """The K-fold assignment of the jumps at ``phi`` (stratified by command), by row.

        Parameters
        ----------
        phi : float
            Volume fraction.

        Returns
        -------
        ndarray of int
            Fold of each jump of the table (-1 at other volume fractions).
        """
        t, k = self.table, self.config.kfold
        rng = np.random.default_rng([self.seed, round(phi * 1e6)])
        folds = np.full(len(t), -1)
        at = t[t["phi"] == phi]
        for _, idx in at.groupby("command").indices.items():
            rows = at.index.to_numpy()[idx]
            folds[rows] = rng.permutation(len(rows)) % k
        return folds


class _Pointwise:
    """Pointwise ELPD of laws compared together, with the fallbacks for bad Pareto k.

    For each law, jumps with Pareto k above ArviZ's ``good_k`` are first moment matched
    (:meth:`FitBank.moment_matched`). Jumps still above ``good_k`` in any of the compared
    laws are recomputed for all of them, per volume fraction: by exact leave-one-out refits
    when the volume fraction holds at most ``max_refits`` such jumps, otherwise by K-fold
    cross-validation of that volume fraction alone (``per_phi`` laws are independent
    across volume fractions). Every refit of every law is sampled side by side in one
    batch (:meth:`FitBank.held_out`). Results are cached per law.

    The paired comparison stays paired: PSIS, moment-matched and exact leave-one-out
    values estimate the same quantity (the density of a jump predicted from all the
    others), so a jump may get them from different methods in the two laws; K-fold values
    estimate a different one (from 1 - 1/K of the data), so a volume fraction computed by
    K-fold is K-fold for every compared law, all its jumps, with the same folds.

    Why not ``arviz_stats.reloo`` / ``loo_kfold`` with a ``SamplingWrapper``: the paired
    ELPD difference of two laws needs the *same* jumps recomputed under both, the union of
    their bad-k sets, while ``reloo`` refits the jumps that one law's own ``ELPDData``
    flags; a refit here is a warm-started, lighter fit of one volume fraction, sampled
    side by side with every other refit, and cached per law for later rounds. The
    arithmetic is the same (the log-mean-exp of the held-out log-likelihood over the
    refit's draws, :meth:`JumpModel.log_predictive_density`). Moment matching is
    ArviZ's algorithm, batched over jumps (:mod:`granbayes.moment_matching`).
    """

    def __init__(self, bank: FitBank) -> None:
        self.bank = bank
        self.exact: dict[tuple[str, ...], dict[int, float]] = {}
        self.kfold: dict[tuple[tuple[str, ...], float], np.ndarray] = {}

    def __call__(self, keys: Sequence[tuple[str, ...]]) -> tuple[list[np.ndarray], str]:
        bank, cfg = self.bank, self.bank.config
        t = bank.table
        matched = dict(zip(keys, bank.moment_matched_many(keys), strict=True))
        bad = sorted(set().union(*(np.flatnonzero(~m[1]).tolist() for m in matched.values())))
        n_matched = max(m[2] for m in matched.values())
        method = "psis-loo" + (" + moment matching" if n_matched else "")
        out = {key: matched[key][0].copy() for key in keys}
        if not bad:
            return [out[k] for k in keys], method
        phi_of = t["phi"].to_numpy(dtype=float)
        exact_rows, kfold_phis = [], []
        for phi in np.unique(phi_of[bad]):
            rows = [j for j in bad if phi_of[j] == phi]
            (exact_rows.extend(rows) if len(rows) <= cfg.max_refits else kfold_phis.append(phi))
        requests, where = [], []
        for key in keys:
            done = self.exact.setdefault(key, {})
            for j in exact_rows:
                if j not in done:
                    requests.append((key, phi_of[j], np.array([j])))
                    where.append(("exact", key, j))
            for phi in kfold_phis:
                if (key, phi) in self.kfold:
                    continue
                folds = bank.folds(phi)
                for f in range(cfg.kfold):
                    rows = np.flatnonzero(folds == f)
                    if len(rows):
                        requests.append((key, phi, rows))
                        where.append(("kfold", key, (phi, rows)))
        if requests:
            bank.log(
                f"  {len(bad)} jump(s) with bad Pareto k after moment matching: "
                f"{len(exact_rows)} exact refit(s) per law"
                + (f", {cfg.kfold}-fold CV of phi = " if kfold_phis else "")
                + ", ".join(f"{p:g}" for p in kfold_phis)
            )
        results = bank.held_out(requests) if requests else []
        for (kind, key, what), lpd in zip(where, results, strict=True):
            if kind == "exact":
                self.exact[key][what] = float(lpd[0])
            else:
                phi, rows = what
                store = self.kfold.setdefault((key, phi), np.full(len(t), np.nan))
                store[rows] = lpd
        for key in keys:
            e = out[key]
            for j in exact_rows:
                e[j] = self.exact[key][j]
            for phi in kfold_phis:
                rows = np.flatnonzero(phi_of == phi)
                e[rows] = self.kfold[(key, phi)][rows]
        if exact_rows:
            method += f" + {len(exact_rows)} exact refit(s)"
        if kfold_phis:
            method += f" + {cfg.kfold}-fold of phi = " + ", ".join(f"{p:g}" for p in kfold_phis)
        return [out[k] for k in keys], method


# ----------------------------------------------------------------------------------------
# candidates and the decision rule
@dataclass(frozen=True)
class Candidate:
    """One candidate extension of the current law, scored against it and the baseline.

    Attributes
    ----------
    term : str
        The term added in this round.
    added : tuple of str
        Every term added to the baseline, this one last.
    round : int
    elpd : float
        ELPD of the extended law [nats].
    gain, gain_se : float
        ELPD difference extended - current law and its SE [nats].
    gain_vs_baseline, gain_vs_baseline_se : float
        ELPD difference extended - baseline law and its SE [nats].
    rmse_mm : float
        Root-mean-square residual of the extended law [mm].
    max_pareto_k : float
    method : str
        How the ELPD was estimated (``psis-loo``, with exact refits or K-fold), or
        ``screened out`` (no full fit: the numbers above are NaN).
    converged : bool
        Whether its fit converged (an unconverged candidate cannot be selected).
    screen_gain : float
        Largest log-likelihood gain over the current law found by the screening search
        [nats] (NaN when screening is off).
    vs_selected, vs_selected_se : float
        ELPD difference (the candidate chosen this round - this one) and its SE [nats],
        paired over the same jumps (NaN for the chosen one, a screened-out candidate, or a
        round where nothing was chosen). :func:`rivals` reads it.
    """

    term: str
    added: tuple[str, ...]
    round: int
    elpd: float
    gain: float
    gain_se: float
    gain_vs_baseline: float
    gain_vs_baseline_se: float
    rmse_mm: float
    max_pareto_k: float
    method: str
    converged: bool
    screen_gain: float = float("nan")
    vs_selected: float = float("nan")
    vs_selected_se: float = float("nan")

    @property
    def screened_out(self) -> bool:
        """Whether the candidate was screened out (never fully fitted)."""
        return self.method.startswith("screened out")

    def to_json(self) -> dict:
        """The ``diagnosis.json`` form (data-format.md names; NaN written as null)."""
        d = {
            k: (None if isinstance(v, float) and not math.isfinite(v) else v)
            for k, v in asdict(self).items()
        }
        d["added"] = list(self.added)
        d["elpd_diff"] = d.pop("gain_vs_baseline")
        d["elpd_diff_se"] = d.pop("gain_vs_baseline_se")
        d["elpd_diff_vs_current"] = d.pop("gain")
        d["elpd_diff_vs_current_se"] = d.pop("gain_se")
        d["elpd_diff_vs_selected"] = d.pop("vs_selected")
        d["elpd_diff_vs_selected_se"] = d.pop("vs_selected_se")
        return d


def decide(
    candidates: Sequence[Candidate], n_misfit: int, config: DiagnoseSettings
) -> Candidate | None:
    """The selection rule: the candidate to add this round, or ``None``.

    The best converged candidate is added when its gain over the current law exceeds both
    ``min_gain`` and ``se_factor`` standard errors, and the current law shows misfit
    (``n_misfit > 0``) or the gain exceeds ``strong_gain``.

    Parameters
    ----------
    candidates : sequence of Candidate
        This round's scored candidates.
    n_misfit : int
        Misfit cells of the current law.
    config : DiagnoseSettings
        The thresholds.

    Returns
    -------
    Candidate or None
    """
    eligible = [c for c in candidates if c.converged and np.isfinite(c.gain)]
    if not eligible:
        return None
    best = max(eligible, key=lambda c: c.gain)
    clear = best.gain > config.min_gain and best.gain > config.se_factor * best.gain_se
    return best if clear and (n_misfit > 0 or best.gain > config.strong_gain) else None


def distinguished(diff: float, se: float, config: DiagnoseSettings) -> bool:
    """Whether an ELPD difference [nats] is clear by the rule's own standard.

    The same standard a term must meet to be added over the current law: more than
    ``min_gain`` nats *and* more than ``se_factor`` standard errors of the paired
    difference. Below 4 nats the normal approximation of the difference's uncertainty is
    unreliable and the two laws predict alike (Sivula, Magnusson & Vehtari 2020,
    "Uncertainty in Bayesian leave-one-out cross-validation based model comparison").

    Parameters
    ----------
    diff, se : float
        The ELPD difference and its standard error [nats].
    config : DiagnoseSettings
        The thresholds.

    Returns
    -------
    bool
    """
    return bool(diff > config.min_gain and diff > config.se_factor * se)


def rivals(candidates: Sequence[Candidate], config: DiagnoseSettings) -> list[Candidate]:
    """Candidates of a round the chosen one is not :func:`distinguished` from.

    A verdict that names a term is a claim about the physics; where the data predict as
    well with another term, naming one alone would overstate it. A rival is a fitted
    candidate whose paired ELPD difference to the chosen one (``vs_selected``) is not
    clear. Unconverged candidates count too: they could not be chosen, nor ruled out.
    Screened-out candidates are not rivals: their largest log-likelihood gain lies more
    than ``min_gain + screen_margin`` below the chosen one's ELPD gain.

    Parameters
    ----------
    candidates : sequence of Candidate
        A round's candidates, compared with its chosen one (``vs_selected`` set).
    config : DiagnoseSettings
        The thresholds.

    Returns
    -------
    list of Candidate
        Closest first.
    """
    out = [
        c
        for c in candidates
        if math.isfinite(c.vs_selected)
        and not distinguished(c.vs_selected, c.vs_selected_se, config)
    ]
    return sorted(out, key=lambda c: c.vs_selected)


def verdict(added: Sequence[str], baseline_misfit: int, residual_misfit: int) -> str:
    """``baseline_adequate``, ``extended`` or ``misfit_remains`` (data-format.md).

    Parameters
    ----------
    added : sequence of str
        Terms the rule added.
    baseline_misfit, residual_misfit : int
        Misfit cells of the baseline and of the selected law.

    Returns
    -------
    str
    """
    if residual_misfit > 0:
        return "misfit_remains"
    if added:
        return "extended"
    return "misfit_remains" if baseline_misfit > 0 else "baseline_adequate"


# ----------------------------------------------------------------------------------------
@dataclass
class Diagnosis:
    """Result of :func:`diagnose` (``to_json`` gives ``diagnosis.json``).

    Attributes
    ----------
    baseline, selected : FitResult
        The fits of the baseline law and of the selected law.
    residuals_before, residuals_after : pandas.DataFrame
        Their cells (:func:`residual_table`).
    candidates : list of Candidate
        Every candidate of every round, screened-out ones included.
    added : list of str
        Terms the rule added, in order.
    record : dict
        The ``diagnosis.json`` document.
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
    record: dict
    fits: dict[tuple[str, ...], FitResult]
    #: Wall time [s] per kind of work (fits, screening, held-out refits); not saved in
    #: ``diagnosis.json``, which a rerun with the same seed reproduces bit for bit.
    timing_s: dict[str, float] = field(default_factory=dict)

    @property
    def verdict(self) -> str:
        """``"baseline_adequate"``, ``"extended"`` or ``"misfit_remains"``."""
        return self.record["verdict"]

    @property
    def converged(self) -> bool:
        """Whether every fit the decision rests on converged."""
        return all(f["converged"] for f in self.record["fits"])

    def to_json(self) -> dict:
        """The ``diagnosis.json`` document (data-format.md)."""
        return self.record


def _score_round(
    bank: FitBank,
    pointwise: _Pointwise,
    current: tuple[str, ...],
    base: tuple[str, ...],
    added: list[str],
    round_no: int,
) -> list[Candidate]:
    """Screen, fit and score the candidates of a round (fallbacks where they decide)."""
    cfg, loos = bank.config, bank.loos
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
                    converged=False,
                    screen_gain=screen_gain[term],
                )
            )
            continue
        res = bank.get(key, parent=current)
        gain, se = stats.elpd_difference(loos[key]["elpd_i"], loos[current]["elpd_i"])
        vs_base, vs_base_se = stats.elpd_difference(loos[key]["elpd_i"], loos[base]["elpd_i"])
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
        if decisive and cand.method != "psis-loo":
            (e_key, e_cur, e_base), method = pointwise((key, current, base))
            gain, se = stats.elpd_difference(e_key, e_cur)
            vs_base, vs_base_se = stats.elpd_difference(e_key, e_base)
            cand = replace(
                cand,
                elpd=float(np.sum(e_key)),
                gain=gain,
                gain_se=se,
                gain_vs_baseline=vs_base,
                gain_vs_baseline_se=vs_base_se,
                method=method,
            )
        out.append(cand)
    return out + screened


def _versus_chosen(
    pointwise: _Pointwise,
    current: tuple[str, ...],
    chosen: Candidate,
    scored: Sequence[Candidate],
) -> list[Candidate]:
    """Every fitted candidate of a round with its paired ELPD difference to the chosen one.

    Where PSIS-LOO does not already separate the two by twice the rule's margin, jumps with
    bad Pareto k in either law are recomputed (``_Pointwise``), as for the decision itself.
    """
    loos, cfg = pointwise.bank.loos, pointwise.bank.config
    key = terms_of((*current, chosen.term))
    out = []
    for c in scored:
        if c.screened_out or c.term == chosen.term or not math.isfinite(c.gain):
            out.append(c)
            continue
        other = terms_of((*current, c.term))
        diff, se = stats.elpd_difference(loos[key]["elpd_i"], loos[other]["elpd_i"])
        far = diff > 2.0 * cfg.min_gain and diff > 2.0 * cfg.se_factor * se
        if not far:
            (e_chosen, e_other), _ = pointwise((key, other))
            diff, se = stats.elpd_difference(e_chosen, e_other)
        out.append(replace(c, vs_selected=diff, vs_selected_se=se))
    return out


def diagnose(
    experiment: Experiment,
    table: pd.DataFrame,
    config: DiagnoseSettings | None = None,
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
    config : DiagnoseSettings, optional
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
        ``progress(label, info)`` (:class:`granbayes.sampler.ProgressInfo`) after every
        sampler chunk of every fit, labelled by law and run (one bar per fit run).

    Returns
    -------
    Diagnosis
    """
    cfg = config or DiagnoseSettings()
    table = table.reset_index(drop=True)
    bank = FitBank(experiment, table, cfg, priors, seed, data_source, log, progress)
    pointwise = _Pointwise(bank)
    base = terms_of(cfg.baseline)
    log(f"Baseline: {' + '.join(base)}")
    baseline = bank.get(base)
    before = stats.residual_table(baseline.datatree)
    z_thr = stats.misfit_threshold(before, cfg.family_alpha)
    current, added, candidates = base, [], []
    misfit = before
    for round_no in range(1, cfg.max_added + 1):
        n_misfit = int((misfit["z"].abs() > z_thr).sum())
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
        misfit = stats.residual_table(bank.fits[current].datatree)
        log(f"  added {chosen.term}")
    selected = bank.fits[current]
    after = stats.residual_table(selected.datatree)
    record = _record(bank, pointwise, base, current, before, after, candidates, added, z_thr)
    return Diagnosis(
        baseline, selected, before, after, candidates, added, record, bank.fits, dict(bank.seconds)
    )


def _interval(values: np.ndarray, ci_prob: float) -> list[float]:
    """``[lo, median, hi]`` of the finite values (the order of ``diagnosis.json``)."""
    med, lo, hi = stats.interval(values, ci_prob)
    return [lo, med, hi]


def _cells_json(residuals: pd.DataFrame, z_thr: float, only_misfit: bool) -> list[dict]:
    rows = residuals[residuals["z"].abs() > z_thr] if only_misfit else residuals
    out = []
    for r in rows.to_dict("records"):
        cell = {k: (r[k] if k == "command" else float(r[k])) for k in stats.CELL_KEYS if k in r}
        cell.update(
            n=int(r["n"]),
            mean_residual_mm=float(r["mean_residual_mm"]),
            z=float(r["z"]),
            p_value=float(r["p_value"]),
            significant=bool(abs(r["z"]) > z_thr),
            description=stats.describe_cell(r),
        )
        out.append(cell)
    return out


def _record(
    bank: FitBank,
    pointwise: _Pointwise,
    base: tuple[str, ...],
    current: tuple[str, ...],
    before: pd.DataFrame,
    after: pd.DataFrame,
    candidates: list[Candidate],
    added: list[str],
    z_thr: float,
) -> dict:
    cfg = bank.config
    baseline, selected = bank.fits[base], bank.fits[current]
    if current == base:
        gain, gain_se, gain_method = 0.0, 0.0, "none added"
        cell_gain, cell_gain_se = 0.0, 0.0
    else:
        (e_cur, e_base), gain_method = pointwise((current, base))
        gain, gain_se = stats.elpd_difference(e_cur, e_base)
        cell_cur, cell_base = stats.cell_loo(selected.datatree), stats.cell_loo(baseline.datatree)
        cell_gain, cell_gain_se = stats.elpd_difference(cell_cur["elpd_i"], cell_base["elpd_i"])
    keys = [k for k in stats.CELL_KEYS if k in before.columns]
    merged = before.merge(after, on=keys, suffixes=("_before", "_after"))
    per_cell = [
        {
            **{k: (r[k] if k == "command" else float(r[k])) for k in keys},
            "residual_before_mm": float(r["mean_residual_mm_before"]),
            "residual_after_mm": float(r["mean_residual_mm_after"]),
            "z_before": float(r["z_before"]),
            "z_after": float(r["z_after"]),
        }
        for r in merged.to_dict("records")
    ]
    post = selected.datatree["posterior"].to_dataset()
    new_params = {
        p.name: {
            f"{float(phi):g}": _interval(post[p.name].sel(phi=phi).values.ravel(), stats.CI_PROB)
            for phi in post["phi"].values
        }
        for term in added
        for p in TERMS[term].parameters
    }
    n_before = int((before["z"].abs() > z_thr).sum())
    residual = _cells_json(after, z_thr, only_misfit=True)
    fits = [bank.records[k].to_json() for k in bank.records]
    indistinguishable = [
        {
            "round": r,
            "selected": term,
            "term": c.term,
            "elpd_diff": c.vs_selected,
            "elpd_diff_se": c.vs_selected_se,
            "converged": c.converged,
        }
        for r, term in enumerate(added, start=1)
        for c in rivals([x for x in candidates if x.round == r], cfg)
    ]
    return {
        "baseline": {
            "terms": list(base),
            "elpd": float(bank.loos[base]["elpd"]),
            "elpd_se": float(bank.loos[base]["se"]),
            "rmse_mm": stats.rmse_mm(baseline.datatree),
        },
        "misfit": _cells_json(before, z_thr, only_misfit=False),
        "n_misfit_cells": n_before,
        "candidates": [c.to_json() for c in candidates],
        "verdict": verdict(added, n_before, len(residual)),
        "selected": {
            "terms": list(current),
            "added": list(added),
            "elpd_gain": gain,
            "elpd_gain_se": gain_se,
            "elpd_method": gain_method,
            "elpd_gain_cells": cell_gain,
            "elpd_gain_cells_se": cell_gain_se,
            "rmse_before_mm": stats.rmse_mm(baseline.datatree),
            "rmse_after_mm": stats.rmse_mm(selected.datatree),
            "indistinguishable": indistinguishable,
            "parameters": new_params,
            "interval": f"{stats.CI_PROB:.0%} equal-tailed (5%, 50%, 95% quantiles)",
            "per_cell": per_cell,
        },
        "residual_misfit": residual,
        "fits": fits,
        "all_converged": all(f["converged"] for f in fits),
        "rule": {
            "min_gain": cfg.min_gain,
            "se_factor": cfg.se_factor,
            "strong_gain": cfg.strong_gain,
            "family_alpha": cfg.family_alpha,
            "z_threshold": z_thr,
            "screen": cfg.screen,
            "screen_margin": cfg.screen_margin,
            "text": (
                f"add the best converged candidate when its ELPD gain > {cfg.min_gain:g} "
                f"nats and > {cfg.se_factor:g} SE, and the current law has a misfit cell "
                f"(|z| > {z_thr:.2f}: family-wise false-alarm rate {cfg.family_alpha:g} "
                f"over {len(before)} cells) or the gain exceeds {cfg.strong_gain:g} nats; "
                f"at most {cfg.max_added} terms; misfit the selected law leaves gives "
                "'misfit_remains'; a fitted candidate the chosen one does not beat by the "
                f"same margin (> {cfg.min_gain:g} nats and > {cfg.se_factor:g} SE of the "
                "paired difference) is reported as indistinguishable from it"
                + (
                    "; a candidate is fitted only if its screened log-likelihood gain reaches "
                    f"{cfg.min_gain:g} nats and the best ELPD gain fitted before it less "
                    f"{cfg.min_gain + cfg.screen_margin:g}"
                    if cfg.screen
                    else ""
                )
            ),
        },
        "seed": int(bank.seed),
        "data_source": bank.data_source,
        # package versions and the machine: what bit-identical results require to match
        **environment(),
    }
