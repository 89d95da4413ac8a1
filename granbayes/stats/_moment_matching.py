"""Importance-weighted moment matching for PSIS-LOO, batched over observations.

PSIS-LOO (Vehtari et al. 2017, 2024) is unreliable for a left-out observation whose Pareto
k exceeds ``good_k``: the posterior draws are then a poor importance-sampling proposal for
the posterior without that observation. Moment matching (Paananen, Piironen, Bürkner &
Vehtari 2021, *Implicitly adaptive importance sampling*, Statistics and Computing 31, 16)
moves the draws by affine maps (mean shift, then marginal scales, then the covariance)
towards the leave-one-out posterior, one observation at a time, keeping a map only if it
lowers k; a final *split* step transforms half of the draws and combines both halves by
multiple importance sampling. Each candidate map needs the full posterior density and the
observation's likelihood at the moved draws: new simulations.

This is the algorithm of ``arviz_stats.loo_moment_match`` (same maps, same acceptance
rule, same split step and PSIS smoothing; ``tests/test_moment_matching.py`` checks that
both give the same ELPD and k on an analytic model). ArviZ's function works through one
observation at a time and asks for the densities of one observation's moved draws per
call; with a simulator behind the density, that is one batch of simulations per
observation and map. Here every flagged observation of a model goes through the same
stage (shift, scale or covariance) together, and the moved draws of all of them are
evaluated in one call of ``evaluate``: one simulator call per stage instead of one per
observation and stage, the same arithmetic.
"""

from __future__ import annotations

from collections.abc import Callable, Generator, Sequence
from dataclasses import dataclass

import numpy as np
from arviz_stats.base import array_stats
from scipy.special import logsumexp

__all__ = ["MomentMatch", "moment_match", "moment_match_search"]

#: ``evaluate(draws, obs)``: for draws of shape (B, S, ndim) and observation indices (B,),
#: the log posterior density (B, S) at the draws (unnormalised, in the draws' coordinates)
#: and the log-likelihood (B, S) of observation ``obs[b]`` at draws ``b``.
EvaluateFn = Callable[[np.ndarray, np.ndarray], tuple[np.ndarray, np.ndarray]]


@dataclass(frozen=True)
class MomentMatch:
    """Moment-matched PSIS-LOO of some observations.

    Attributes
    ----------
    obs : ndarray of int
        The observations.
    elpd_i : ndarray
        Their leave-one-out log predictive density [nats] (the PSIS value where moment
        matching did not lower k).
    pareto_k : ndarray
        Their Pareto k after moment matching (the original where it did not improve).
    original_k : ndarray
        Their Pareto k before.
    k_threshold : float
        The ``good_k`` of the draws used: above it a value is unreliable.
    n_evaluations : int
        Calls of ``evaluate`` made.
    """

    obs: np.ndarray
    elpd_i: np.ndarray
    pareto_k: np.ndarray
    original_k: np.ndarray
    k_threshold: float
    n_evaluations: int


def _psislw(log_ratio: np.ndarray, r_eff: float) -> tuple[np.ndarray, np.ndarray]:
    """Pareto-smoothed normalised log weights and k of log importance ratios (..., S)."""
    lw, k = array_stats.psislw(-log_ratio, r_eff)
    return np.asarray(lw), np.asarray(k, dtype=float)


def _clean(log_ratio: np.ndarray) -> np.ndarray:
    """NaN and +inf log ratios count as -inf (zero weight), as in ArviZ."""
    out = np.array(log_ratio, dtype=float)
    out[np.isnan(out) | np.isposinf(out)] = -np.inf
    return out


def _shift(u: np.ndarray, lw: np.ndarray):
    """Mean shift of draws ``u`` (S, d) to their weighted mean."""
    w = np.exp(lw)
    shift = w @ u - u.mean(axis=0)
    return u + shift, shift, np.ones(u.shape[1]), np.eye(u.shape[1])


def _shift_and_scale(u: np.ndarray, lw: np.ndarray):
    """Shift to the weighted mean and scale to the weighted marginal variances."""
    n = len(u)
    w = np.exp(lw)
    mean = u.mean(axis=0)
    mean_w = w @ u
    mii = (w @ u**2 - mean_w**2) * n / (n - 1)
    var = np.var(u, axis=0, ddof=1)
    scaling = np.ones_like(mean)
    ok = (var > 1e-9) & (mii > 1e-9)
    scaling[ok] = np.sqrt(mii[ok] / var[ok])
    return (u - mean) * scaling + mean_w, mean_w - mean, scaling, np.eye(u.shape[1])


def _shift_and_cov(u: np.ndarray, lw: np.ndarray):
    """Shift to the weighted mean and map the covariance to the weighted covariance."""
    w = np.exp(lw)
    mean = u.mean(axis=0)
    mean_w = w @ u
    cov = np.cov(u, rowvar=False, ddof=1)
    cov_w = np.cov(u, rowvar=False, aweights=w, ddof=1)
    mapping = np.eye(u.shape[1])
    try:
        jitter = 1e-6
        lo, lo_w = np.min(np.linalg.eigvalsh(cov)), np.min(np.linalg.eigvalsh(cov_w))
        if lo <= 0:
            cov = cov + np.eye(len(cov)) * (jitter - lo)
        if lo_w <= 0:
            cov_w = cov_w + np.eye(len(cov_w)) * (jitter - lo_w)
        mapping = np.linalg.cholesky(cov_w) @ np.linalg.inv(np.linalg.cholesky(cov))
    except np.linalg.LinAlgError:
        pass  # the mean shift alone (identity map), as ArviZ does
    return (u - mean) @ mapping.T + mean_w, mean_w - mean, np.ones(u.shape[1]), mapping


_STAGES = (_shift, _shift_and_scale, _shift_and_cov)


def moment_match(
    draws: np.ndarray,
    log_prob: np.ndarray,
    log_lik: np.ndarray,
    obs: Sequence[int],
    evaluate: EvaluateFn,
    *,
    r_eff: float = 1.0,
    k_threshold: float | None = None,
    max_iters: int = 30,
    split: bool = True,
    cov: bool = True,
) -> MomentMatch:
    """Moment-matched PSIS-LOO of the observations ``obs``, all stepped together.

    Parameters
    ----------
    draws : ndarray, shape (chain, draw, ndim)
        Posterior draws in the coordinates the maps act on (unbounded coordinates are best;
        a moved draw outside the support has density zero and gets weight zero).
    log_prob : ndarray, shape (chain, draw)
        Log posterior density at ``draws`` (unnormalised, same coordinates).
    log_lik : ndarray, shape (chain, draw, n_obs)
        Pointwise log-likelihood at ``draws``.
    obs : sequence of int
        Observations to moment-match (those with a bad Pareto k).
    evaluate : callable
        ``evaluate(draws (B, S, ndim), obs (B,)) -> (log_prob (B, S), log_lik (B, S))``.
    r_eff : float
        Relative efficiency of the draws (1 for thinned, nearly independent draws).
    k_threshold : float, optional
        Pareto k above which an observation is moment-matched and iterations continue
        (default: ``min(1 - 1/log10(S), 0.7)``, ArviZ's ``good_k``).
    max_iters : int
        Most accepted maps per observation.
    split : bool
        Finish with the split step (half of the draws moved, multiple importance sampling).
    cov : bool
        Also try matching the covariance (when there are at least 10 draws per coordinate).

    Returns
    -------
    MomentMatch
    """
    search = moment_match_search(
        draws,
        log_prob,
        log_lik,
        obs,
        r_eff=r_eff,
        k_threshold=k_threshold,
        max_iters=max_iters,
        split=split,
        cov=cov,
    )
    try:
        request = next(search)
        while True:
            request = search.send(evaluate(*request))
    except StopIteration as stop:
        return stop.value


def moment_match_search(
    draws: np.ndarray,
    log_prob: np.ndarray,
    log_lik: np.ndarray,
    obs: Sequence[int],
    *,
    r_eff: float = 1.0,
    k_threshold: float | None = None,
    max_iters: int = 30,
    split: bool = True,
    cov: bool = True,
) -> Generator[tuple[np.ndarray, np.ndarray], tuple[np.ndarray, np.ndarray], MomentMatch]:
    """:func:`moment_match` as a generator: it yields ``(draws, obs)`` to evaluate.

    It receives ``(log_prob, log_lik)`` for each request and returns the
    :class:`MomentMatch`; several of them (models) can share calls
    (:func:`granbayes._search.drive`).

    Parameters
    ----------
    draws, log_prob, log_lik : ndarray
        As :func:`moment_match`.
    obs : sequence of int
        Observations to moment-match.
    r_eff, k_threshold, max_iters, split, cov
        As :func:`moment_match`.

    Yields
    ------
    tuple of ndarray
        Moved draws (B, S, ndim) and the observation of each (B,).

    Returns
    -------
    MomentMatch
    """
    n_chain, n_draw, ndim = draws.shape
    n = n_chain * n_draw
    if k_threshold is None:
        k_threshold = min(1.0 - 1.0 / np.log10(n), 0.7) if n > 1 else 0.7
    obs = np.asarray(obs, dtype=int)
    m = len(obs)
    # draw-major order (draw 0 of every chain, then draw 1, ...), as ArviZ's split step
    u0 = np.swapaxes(draws, 0, 1).reshape(n, ndim)
    lp0 = np.swapaxes(log_prob, 0, 1).reshape(n)
    ll0 = np.swapaxes(log_lik, 0, 1).reshape(n, -1)[:, obs].T  # (m, S)
    calls = 0

    lw, k = _psislw(-ll0, r_eff)
    original_k = k.copy()
    lw, k = lw.copy(), k.copy()
    log_liki = ll0.copy()
    u = np.repeat(u0[None], m, axis=0)
    total_shift = np.zeros((m, ndim))
    total_scaling = np.ones((m, ndim))
    total_mapping = np.repeat(np.eye(ndim)[None], m, axis=0)
    applied = np.zeros(m, dtype=bool)
    iters = np.ones(m, dtype=int)
    active = (k > k_threshold) & (iters <= max_iters)
    n_stages = 3 if cov and n >= 10 * ndim else 2
    while np.any(active):
        # each active observation tries the maps in order until one lowers k; one call of
        # ``evaluate`` per stage for all observations at that stage
        todo = active.copy()
        for stage in range(n_stages):
            idx = np.flatnonzero(todo)
            if not len(idx):
                break
            moved = [_STAGES[stage](u[i], lw[i]) for i in idx]
            u_new = np.stack([mv[0] for mv in moved])
            calls += 1
            lp_new, ll_new = yield u_new, obs[idx]
            lp_new, ll_new = np.asarray(lp_new, dtype=float), np.asarray(ll_new, dtype=float)
            with np.errstate(invalid="ignore"):  # -inf - -inf outside the support: NaN -> -inf
                ratio = _clean(-ll_new + lp_new - lp0[None])
            lw_new, k_new = _psislw(ratio, r_eff)
            better = k_new < k[idx]
            for j, i in enumerate(idx):
                if not better[j]:
                    continue
                k[i], lw[i], log_liki[i], u[i] = k_new[j], lw_new[j], ll_new[j], u_new[j]
                _, shift, scaling, mapping = moved[j]
                total_shift[i] += shift
                total_scaling[i] *= scaling
                total_mapping[i] = mapping @ total_mapping[i]
                applied[i] = True
                iters[i] += 1
                todo[i] = False
            # observations no stage improved stop; the others go round again
            if stage == n_stages - 1:
                active[todo] = False
        active &= (k > k_threshold) & (iters <= max_iters)
    final_lw, final_ll = lw, log_liki
    if split and np.any(applied):
        final_lw, final_ll = lw.copy(), log_liki.copy()
        idx = np.flatnonzero(applied)
        half = n // 2
        fwd, inv, jac = [], [], []
        mean = u0.mean(axis=0)
        for i in idx:
            t = (u0 - mean) * total_scaling[i]
            if cov:
                t = t @ total_mapping[i].T
            t = t + total_shift[i] + mean
            ti = u0 - mean
            if cov:
                try:
                    ti = ti @ np.linalg.inv(total_mapping[i].T)
                except np.linalg.LinAlgError:
                    pass
            ti = ti / total_scaling[i] + mean - total_shift[i]
            f = u0.copy()
            f[:half] = t[:half]
            b = u0.copy()
            b[half:] = ti[half:]
            fwd.append(f)
            inv.append(b)
            with np.errstate(divide="ignore"):
                jac.append(
                    -np.sum(np.log(total_scaling[i])) - np.log(np.linalg.det(total_mapping[i]))
                )
        calls += 2
        lp_f, ll_f = yield np.stack(fwd), obs[idx]
        lp_b, _ = yield np.stack(inv), obs[idx]
        lp_f, ll_f, lp_b = (np.asarray(v, dtype=float) for v in (lp_f, ll_f, lp_b))
        with np.errstate(invalid="ignore"):  # moved draws outside the support: -inf
            lp_b = lp_b + np.asarray(jac)[:, None]
            raw = _clean(-ll_f + lp_f - np.logaddexp(lp_f, lp_b))
        lw_half, _ = _psislw(raw, r_eff)
        final_lw[idx] = lw_half
        final_ll[idx] = ll_f
    elpd_orig = logsumexp(_psislw(-ll0, r_eff)[0] + ll0, axis=1)
    with np.errstate(invalid="ignore"):
        elpd_new = logsumexp(final_lw + final_ll, axis=1)
    improved = k < original_k
    return MomentMatch(
        obs=obs,
        elpd_i=np.where(improved, elpd_new, elpd_orig),
        pareto_k=np.where(improved, k, original_k),
        original_k=original_k,
        k_threshold=float(k_threshold),
        n_evaluations=calls,
    )
