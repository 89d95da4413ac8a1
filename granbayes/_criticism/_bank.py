"""The bank of fits of one data set, and how laws are compared on it.

:class:`FitBank` fits each law once (warm-started from the law it extends), reruns a fit
that did not converge or that ends below its nested parent, records how every fit went,
screens candidate terms, and recomputes the pointwise ELPD where PSIS-LOO is unreliable
(moment matching, refits side by side); :class:`Pointwise` gives the paired pointwise ELPD
of laws compared together, with those fallbacks.
"""

from __future__ import annotations

import contextlib
import time
from collections.abc import Callable, Iterator, Mapping, Sequence
from dataclasses import replace

import numpy as np
import pandas as pd

from .. import stats
from .._experiment import Experiment
from .._fitting import (
    FitResult,
    FitSettings,
    _as_measurements,
    _held_out,
    _run_parts,
    _warm_positions,
    fit,
    part_models,
    screen_many,
)
from .._likelihood import evaluate_models
from .._measurements import Measurements
from .._priors import Prior, default_priors
from .._sampler import ProgressInfo
from .._search import drive
from ..forces import TERMS, terms_of
from ._record import FitRecord
from ._rule import DiagnoseSettings

#: Most posterior draws a law's moment matching uses per volume fraction (thinned evenly).
MM_DRAWS = 1000


class FitBank:
    """Fits of one data set, keyed by their terms; converged, or rerun, and recorded.

    Parameters
    ----------
    experiment : Experiment
    table : pandas.DataFrame or Measurements
        The jumps, or measurements of several kinds (every fit is joint over them; units
        of leave-one-out are numbered as in :class:`~granbayes.Measurements`).
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
        table: pd.DataFrame | Measurements,
        settings: DiagnoseSettings,
        priors: Mapping[str, Prior] | None,
        seed: int,
        data_source: str,
        log: Callable[..., None],
        progress: Callable[[str, ProgressInfo], None] | None = None,
    ) -> None:
        self.experiment, self.settings = experiment, settings
        self.data = _as_measurements(table)
        #: One row per unit of leave-one-out: ``kind``, ``unit``, ``phi``, ``command``.
        self.units = self.data.units
        #: The kind of every unit: the strata of every paired ELPD difference's SE
        #: (:func:`granbayes.stats.elpd_difference`), in the order of the fits' units.
        self.strata = self.units["kind"].to_numpy() if len(self.units) else np.array([])
        self.priors, self.seed, self.data_source, self.log = priors, seed, data_source, log
        self.progress = progress
        self.fits: dict[tuple[str, ...], FitResult] = {}
        self.screens: dict[tuple[str, ...], float] = {}
        #: The best point of each screened law's search (``screen_many``'s ``points``).
        self.screen_points: dict[tuple[str, ...], dict[float, dict[str, float]]] = {}
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
        s = self.settings.sampler
        return FitSettings(
            terms=key,
            sampler=replace(s, max_steps=s.max_steps * scale),
            n_threads=self.settings.n_threads,
            n_prior_draws=0,
            calibration=self.settings.calibration,
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
            self.data,
            self._fit_config(key, 2**attempt),
            seed=self._law_seed(key, attempt),
            priors=self.priors,
            data_source=self.data_source,
            warm_start=warm,
            progress=self._progress(key, f" (rerun {attempt})" if attempt else ""),
            # where the candidate was screened, its fit climbs from the screen's best point
            # too: the warm start sits at the new parameters' "off" values, from which the
            # climbs can end in a worse mode (fit's ``start_points``)
            start_points=self.screen_points.get(key),
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
            diff, se = stats.elpd_difference(
                loo["elpd_i"], self.loos[parent_key]["elpd_i"], self.strata
            )
            if diff < -(self.settings.nested_tolerance + 2.0 * se):
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
            See :func:`granbayes._fitting.screen`.
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
            found: list[dict[float, dict[str, float]]] = []
            with self._timed("screening"):
                gains = screen_many(
                    self.experiment,
                    self.data,
                    [self._fit_config(k) for k in todo],
                    self.fits[terms_of(parent)].datatree,
                    seeds=[self._law_seed(k, 99) for k in todo],
                    priors=self.priors,
                    points=found,
                )
            self.screens.update(zip(todo, gains, strict=True))
            self.screen_points.update(zip(todo, found, strict=True))
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

        A request ``(law, phi, left_out)`` refits law ``law`` on the measurements of volume
        fraction ``phi`` (``per_phi`` laws are independent across volume fractions) without
        the units ``left_out`` (jumps, tracked jumps, intrusion tests), warm-started from
        the law's full posterior at ``phi``, with lighter settings: two ensembles (one from the full
        posterior, one dispersed) and half the effective sample size, enough for a
        posterior mean of the held-out densities. Every request is one run of
        :func:`granbayes._sampler.run_side_by_side`: one simulator call per round for all.

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
        unit_phi = self.units["phi"].to_numpy(float)
        specs, configs, seeds, warms, outs = [], [], [], [], []
        for key, phi, left_out in requests:
            config = self._fit_config(key)
            s = config.sampler
            config = replace(config, sampler=replace(s, n_ensembles=2, min_ess=s.min_ess / 2))
            keep = (unit_phi == phi) & ~np.isin(np.arange(len(unit_phi)), left_out)
            ((_, model, jumps),) = part_models(
                self.experiment, self.data.select(keep), config, self.priors_or_default
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
            held_out = _held_out(part.model, self.data.select(left_out))
            out.append(part.model.log_predictive_density(flat, held_out))
        return out

    def folds(self, phi: float) -> np.ndarray:
        """The K-fold assignment of the units at ``phi`` (stratified by kind and command).

        Parameters
        ----------
        phi : float
            Volume fraction.

        Returns
        -------
        ndarray of int
            Fold of each unit (-1 at other volume fractions).
        """
        t, k = self.units, self.settings.kfold
        rng = np.random.default_rng([self.seed, round(phi * 1e6)])
        folds = np.full(len(t), -1)
        at = t[t["phi"] == phi]
        for _, idx in at.groupby(["kind", "command"], dropna=False).indices.items():
            rows = at.index.to_numpy()[idx]
            folds[rows] = rng.permutation(len(rows)) % k
        return folds


class Pointwise:
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
        bank, cfg = self.bank, self.bank.settings
        t = bank.units
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
