"""Independent emcee ensembles run until they agree (the sampler knows nothing of the model).

:func:`run_ensembles` takes a vectorised function ``f(positions) -> (log_prob, blobs)``
(arrays of shape ``(n,)`` and ``(n, m)``), one array of starting positions per ensemble and
a seed. The ensembles are advanced together in chunks of ``check_every`` steps. After
each chunk the run is *converged* when all three hold:

1. **autocorrelation**: in every ensemble the chain after burn-in is at least
   ``tau_factor`` times its largest integrated autocorrelation time ``tau`` (emcee's
   estimator). Short chains underestimate ``tau``; criteria 2 and 3 are the guards (a
   multi-chain ESS over every walker and R-hat between ensembles started apart), which is
   why ``tau_factor`` can be 10 rather than emcee's advice of 50 for estimating ``tau``
   itself;
2. **agreement between independent ensembles**: the rank-normalised split R-hat
   (Vehtari et al. 2021, computed with ``arviz_stats``) of every coordinate and of the
   log-probability, with one chain per *ensemble* (its post-burn-in draws in step order),
   is at most ``max_rhat``. R-hat across the walkers of one ensemble cannot see an
   ensemble parked in the wrong mode; R-hat across ensembles started apart can;
3. **enough effective draws for what is reported**: bulk ESS and the tail ESS of the 5%
   and 95% quantiles (the 90% intervals that granbayes reports) of every coordinate, over
   all walkers of all ensembles, are at least ``min_ess``.

When the ensembles disagree (criterion 2 fails although criterion 1 holds) the rule is:
an ensemble whose median log-probability lies more than ``mode_gap`` nats below the best
ensemble's is in a worse-supported mode; it is restarted from the best ensemble's walkers
(at most ``max_restarts`` times per run) and a warning says so. If restarts are exhausted,
the result keeps only the ensembles of the best-supported mode, says so in a warning, and
is not converged. Ensembles that disagree at comparable log-probability are a multimodal
posterior: sampling continues to ``max_steps`` and the warning says so. Nothing is silent.

A single *walker* can be stuck too: an ensemble's moves (stretch, differential evolution,
snooker) propose along lines through, or differences of, the other walkers, so a walker in
a separate, worse-supported mode whose others all sit in the main mode can almost never
reach it (a proposal lands in the valley between). A warm start puts one walker of each
ensemble at the nested parent's solution, which is such a mode whenever the new term's
"off" value is far from the truth; R-hat across ensembles cannot see it (every ensemble
carries one) but the effective sample size stalls. So a walker whose *largest*
log-probability over the post-burn-in window stays more than the ``mode_gap`` rule below
its ensemble's median is stuck: its ensemble gets a fresh chain from its current
positions, the stuck walkers moved onto jittered copies of its other walkers (this counts
as a restart), and a warning says so. A walker that visits the main mode at all in the
window is never flagged, so runs without stuck walkers are unchanged.

**Side by side.** :func:`run_side_by_side` samples several independent runs at once (the
volume fractions of a fit, the held-out refits of a cross-validation): each follows the
rule above on its own, and every round the requests of all ensembles of all runs still
going are evaluated in one call (one simulator call instead of one per run and ensemble).
The steps are emcee's own (its moves, their proposals and its acceptance rule, with each
ensemble's own ``RandomState``), driven by one generator per ensemble instead of
``EnsembleSampler.run_mcmc`` in a thread per ensemble: the chains are those of
``emcee.EnsembleSampler`` with the same random state (tested), and no thread hand-off
costs time at every half-step. :func:`run_ensembles` is one such run.

With a checkpoint folder every ensemble is saved after every chunk (chain, blobs,
acceptance counts, emcee's random state and the step at which its chain began, written to
a temporary file and moved into place, so a checkpoint is always whole). All decisions
depend only on the stored chains, so a resumed run is bit-identical to an uninterrupted
one with the same seed. (emcee's own ``HDFBackend`` reopens the file at every step, which
cost a third of the sampling time here.)

Length: about 1,050 lines for one job (independent ensembles until they agree): the
stopping rule and its statistics, checkpoints and resume, the rescue of walkers stuck in
a worse mode and the side-by-side stepping of many runs; splitting them would put the
stopping rule apart from the loop it stops.
"""

from __future__ import annotations

import os
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Literal

import emcee
import h5py
import numpy as np
from arviz_stats.base import array_stats

__all__ = [
    "Checkpoint",
    "CheckpointMismatchError",
    "ProgressInfo",
    "RunSpec",
    "SamplerRun",
    "SamplerSettings",
    "SnookerMove",
    "load_checkpoint",
    "run_ensembles",
    "run_side_by_side",
    "save_checkpoint",
]

LogProbFn = Callable[[np.ndarray], tuple[np.ndarray, np.ndarray]]

#: Quantiles whose tail ESS the stopping rule needs (those of the reported 90% intervals).
TAIL_PROB = (0.05, 0.95)


class CheckpointMismatchError(ValueError):
    """A checkpoint was written for other data, model or settings than the run resuming it."""


@dataclass(frozen=True)
class SamplerSettings:
    """How to sample and when to stop.

    Parameters
    ----------
    n_walkers : int
        Least walkers per ensemble; raised to four times the dimension (and even) by
        :meth:`walkers_for`.
    n_ensembles : int
        Independent ensembles (each started from its own optimised point).
    max_steps : int
        Hard cap on steps per walker.
    check_every : int
        Steps between convergence checks.
    tau_factor : float
        Autocorrelation criterion: post-burn-in chain length of every ensemble in units of
        its largest autocorrelation time.
    burn_factor : float
        Burn-in discarded, in units of the largest autocorrelation time.
    min_ess : float
        Bulk and tail (5% and 95% quantile) effective sample size required of every
        coordinate, over all ensembles.
    max_rhat : float
        Largest rank-normalised split R-hat across ensembles.
    mode_gap : float
        Median log-probability deficit [nats] beyond which a disagreeing ensemble is in a
        worse-supported mode (and best log-probability deficit below its ensemble's median
        beyond which a walker is stuck).
    max_restarts : int
        Restarts per run of stuck ensembles, or of ensembles with stuck walkers.
    n_draws : int
        Draws kept per walker after burn-in and thinning.
    moves : {"de", "stretch"}
        ``de``: differential evolution (80%) + snooker (20%, :class:`SnookerMove`: emcee
        3.1.6's snooker update samples the wrong distribution), good for the correlated
        valleys of force laws; ``stretch``: emcee's default affine-invariant move.
    start : {"auto", "search", "laplace"}
        Where each ensemble's walkers start (:func:`granbayes.fit`): ``search``, a ball
        about the best point of a random local search from the ensemble's best prior
        draws; ``laplace``, that point climbed to the ensemble's posterior mode (batched
        evolution strategy, Powell, L-BFGS-B; ``granbayes._fitting``) and the walkers
        drawn from the Laplace approximation there (normal, covariance the inverse of the
        finite-difference Hessian of the log-posterior), so that they start
        at the posterior's own scale and orientation; ``auto`` (the default, kept as the
        name saved fits record), ``laplace``. With tracked jumps or intrusion curves, whose
        posteriors are narrow, ensembles started from a ball spent most of their
        1,500-2,550 steps contracting, 6-10x the 250 steps from a Laplace start; with
        heights alone, the runs of the slower laws are shorter too (reference data, seed
        1: depth + drag + compaction 12.2 s instead of 22.3 s, the longest run 300 steps
        instead of 750; depth + drag 9.2 s instead of 10.2 s), and a sampled robot
        calibration 14.3-15.2 s instead of 19.6-25.7 s (``benchmarks/
        bench_calibrated_fit.py``). Until 2026-11-27 ``auto`` chose ``search`` for heights
        alone; the studies of heights made before say so.
    start_climbs : int
        Climbs per ensemble of a Laplace start where the fit has tracked jumps or intrusion
        curves (from its searched point and its next best prior draws; the ensemble starts
        at the highest mode): such a posterior can have separated modes (strong drag or
        added mass) that one climb per ensemble misses by luck
        (``granbayes._fitting._laplace_starts``). With intrusion curves each ensemble
        climbs once more, from the curves' own posterior mode. Fits of heights alone climb
        once per ensemble, from the searched point (``granbayes._fitting._climbs``).
    """

    n_walkers: int = 8
    n_ensembles: int = 4
    max_steps: int = 20_000
    check_every: int = 50
    tau_factor: float = 10.0
    burn_factor: float = 3.0
    min_ess: float = 400.0
    max_rhat: float = 1.01
    mode_gap: float = 5.0
    max_restarts: int = 2
    n_draws: int = 100
    moves: Literal["de", "stretch"] = "de"
    start: Literal["auto", "search", "laplace"] = "auto"
    start_climbs: int = 3

    def __post_init__(self) -> None:
        """Check the choices."""
        if self.start not in ("auto", "search", "laplace"):
            raise ValueError(f"start must be 'auto', 'search' or 'laplace', got {self.start!r}")
        if self.start_climbs < 1:
            raise ValueError(f"start_climbs must be at least 1, got {self.start_climbs}")

    def walkers_for(self, ndim: int) -> int:
        """Walkers per ensemble for a problem of dimension ``ndim`` (even, >= 4 ndim).

        emcee's moves propose along differences of the other half's walkers; with only
        twice the dimension (the least a red-blue move allows) they span few directions,
        and a correlated or curved posterior mixes slowly, by the luck of the start. On
        the reference data (depth + drag, 3 coordinates per volume fraction, seeds 1-3)
        8 walkers needed 250-650 steps (the longest run, tau 35-40 steps, decides the
        fit's time), 12 walkers 200-550 (tau at most 15) for about the same number of
        simulations; 16 walkers cost more simulations without fewer steps. For depth +
        drag + compaction (4 coordinates), 16 walkers instead of 8 halved tau (the
        longest runs 600-950 steps instead of 1,550-1,800) at equal simulations.

        Parameters
        ----------
        ndim : int
            Dimension of the problem.

        Returns
        -------
        int
        """
        n = max(self.n_walkers, 4 * ndim)
        return n + (n % 2)


@dataclass(frozen=True)
class ProgressInfo:
    """What a progress display shows after each chunk.

    Attributes
    ----------
    step, max_steps : int
        Steps per walker done and the cap.
    tau_max : float
        Largest autocorrelation time over ensembles [steps] (NaN before it is known).
    rhat_max, ess_min : float
        Largest R-hat across ensembles and smallest bulk/tail ESS (NaN before known).
    converged : bool
        Whether the stopping rule is met.
    """

    step: int
    max_steps: int
    tau_max: float
    rhat_max: float
    ess_min: float
    converged: bool


@dataclass
class SamplerRun:
    """A finished (or capped) run of several ensembles, pooled.

    Attributes
    ----------
    samples : ndarray, shape (n_chains, n_draws, ndim)
        Kept draws (after burn-in and thinning); one chain per walker, the walkers of
        ensemble 0 first (``ensemble_of_chain``), like ArviZ chains.
    log_prob : ndarray, shape (n_chains, n_draws)
    blobs : ndarray, shape (n_chains, n_draws, m)
        Per-observation log-likelihood of the kept draws.
    ensemble_of_chain : ndarray of int, shape (n_chains,)
        Ensemble each chain belongs to.
    tau : ndarray, shape (n_ensembles, ndim)
        Integrated autocorrelation times [steps] per ensemble (all ensembles run).
    rhat : ndarray, shape (ndim,)
        Rank-normalised split R-hat across the kept ensembles.
    ess_bulk, ess_tail : ndarray, shape (ndim,)
        Effective sample sizes of the pooled kept draws (tail: 5% and 95% quantiles).
    acceptance : ndarray, shape (n_chains,)
        Acceptance fraction per kept walker.
    n_steps : int
        Steps per walker in total.
    burn : ndarray of int, shape (n_ensembles,)
        Burn-in [steps] of each ensemble's current chain.
    thin : int
        Thinning interval of the kept draws.
    converged : bool
        Whether the stopping rule (module docstring) was met.
    warnings : list of str
        Restarts, dropped ensembles and disagreements, in words.
    seed : int
        The seed used.
    """

    samples: np.ndarray
    log_prob: np.ndarray
    blobs: np.ndarray
    ensemble_of_chain: np.ndarray
    tau: np.ndarray
    rhat: np.ndarray
    ess_bulk: np.ndarray
    ess_tail: np.ndarray
    acceptance: np.ndarray
    n_steps: int
    burn: np.ndarray
    thin: int
    converged: bool
    warnings: list[str] = field(default_factory=list)
    seed: int = 0


# ----------------------------------------------------------------------------------------
class SnookerMove(emcee.moves.DESnookerMove):
    """emcee's snooker update as Ter Braak & Vrugt (2008) define it, which emcee 3.1.6 is not.

    The snooker update moves a walker ``x`` along the line through it and another walker
    ``z``, by ``gammas`` times the difference of two more walkers projected on that line,
    and accepts with the extra factor ``(d - 1) log(|x* - z| / |x - z|)``. emcee 3.1.6
    (its latest release; ``requirements.lock``) divides ``x - z`` by the square root of
    its length instead of its length, so the step grows with the walker's distance from
    ``z``, and takes half the factor: the chain's stationary distribution is not the
    target. Measured with emcee's own sampler on a standard normal (4,000 steps;
    ``benchmarks/snooker_move.py``): the snooker move alone gave a standard deviation of
    0.80 in 8 dimensions; granbayes's mixture (80% differential evolution) 0.98 in 3
    dimensions, 0.95 in 8, 0.92 in 13, so every posterior was too narrow by that much and
    its 90% intervals held 89%, 88% and 87% of the target's mass. emcee fixed it after the release
    (dfm/emcee pull request 531, commit 946e664, 2025-01-27); this is that fix. It draws
    the same random numbers as emcee's move. Once a release of emcee carries the fix,
    ``emcee.moves.DESnookerMove`` replaces this class (``tests/test_sampler.py`` checks
    both on a standard normal).

    Parameters
    ----------
    gammas : float
        Mean stretch of the step along the line (1.7, as the reference recommends).
    **kwargs
        emcee's ``RedBlueMove`` options (the ensemble is split in four).
    """

    def get_proposal(
        self, s: np.ndarray, c: Sequence[np.ndarray], random: np.random.RandomState
    ) -> tuple[np.ndarray, np.ndarray]:
        """Proposals for the walkers ``s`` from the complementary sets ``c`` (emcee's API).

        Parameters
        ----------
        s : ndarray, shape (n, ndim)
            The walkers that move.
        c : sequence of ndarray
            The three other quarters of the ensemble (the line's anchor and the two
            walkers whose difference sets the step are drawn one from each).
        random : numpy.random.RandomState
            The ensemble's random state.

        Returns
        -------
        q : ndarray, shape (n, ndim)
            The proposals.
        log_factor : ndarray, shape (n,)
            ``(ndim - 1) log(|q - z| / |s - z|)``, added to the log acceptance ratio.
        """
        ndim = s.shape[1]
        counts = [len(part) for part in c]
        q = np.empty_like(s)
        log_ratio = np.empty(len(s), dtype=np.float64)
        for i in range(len(s)):
            w = np.array([c[j][random.randint(counts[j])] for j in range(3)])
            random.shuffle(w)
            z, z1, z2 = w
            delta = s[i] - z
            norm = np.linalg.norm(delta)
            unit = delta / norm
            q[i] = s[i] + unit * self.gammas * (np.dot(unit, z1) - np.dot(unit, z2))
            log_ratio[i] = np.log(np.linalg.norm(q[i] - z)) - np.log(norm)
        return q, (ndim - 1.0) * log_ratio


def _moves(kind: Literal["de", "stretch"]) -> list:
    if kind == "de":
        return [(emcee.moves.DEMove(), 0.8), (SnookerMove(), 0.2)]
    if kind == "stretch":
        return [(emcee.moves.StretchMove(), 1.0)]
    raise ValueError(f"moves must be 'de' or 'stretch', got {kind!r}")


def _clean(lp: np.ndarray, blobs: np.ndarray, n: int, m: int) -> tuple[np.ndarray, np.ndarray]:
    """Log-probabilities and blobs of ``n`` positions as float arrays ``(n,)``, ``(n, m)``.

    A non-finite log-probability (NaN too) becomes ``-inf`` (the position is never
    accepted) and its blob ``-inf``.
    """
    lp = np.array(lp, dtype=float).reshape(n)
    blobs = np.array(blobs, dtype=float).reshape(n, m)
    bad = ~np.isfinite(lp)
    lp[bad] = -np.inf
    blobs[bad] = -np.inf
    return lp, blobs


@dataclass
class _Ensemble:
    """One emcee ensemble: its chain (an emcee backend), random state and current walkers.

    ``offset`` is the global step at which its current chain began (non-zero after a
    restart); ``log_prob`` is ``None`` until the starting positions ``coords`` have been
    evaluated.
    """

    backend: emcee.backends.Backend
    random: np.random.RandomState
    offset: int
    coords: np.ndarray
    log_prob: np.ndarray | None = None
    blobs: np.ndarray | None = None

    @property
    def iteration(self) -> int:
        """Steps stored in its chain."""
        return int(self.backend.iteration)

    def keep_random_state(self) -> None:
        """Store the current random state in the backend (read by checkpoints)."""
        self.backend.random_state = self.random.get_state()


def _new_ensemble(start: np.ndarray, random_seed: int, offset: int) -> _Ensemble:
    """An ensemble about to start a fresh chain at global step ``offset`` from ``start``."""
    start = np.array(start, dtype=float)
    if not emcee.ensemble.walkers_independent(start):
        raise ValueError(
            "Initial state has a large condition number. Make sure that your walkers are "
            "linearly independent for the best performance"
        )
    backend = emcee.backends.Backend()
    backend.reset(*start.shape)
    random = np.random.RandomState(random_seed)
    return _Ensemble(backend, random, offset, start)


def _resumed_ensemble(backend: emcee.backends.Backend, offset: int) -> _Ensemble:
    """An ensemble continuing the chain stored in ``backend``."""
    random = np.random.RandomState()
    random.set_state(backend.random_state)
    last = backend.get_last_sample()
    blobs = None if last.blobs is None else np.asarray(last.blobs, dtype=float)
    return _Ensemble(backend, random, offset, np.array(last.coords), last.log_prob.copy(), blobs)


def _advance(e: _Ensemble, n: int, moves: Sequence, weights: np.ndarray, m: int):
    """Generator that advances ensemble ``e`` by ``n`` steps of emcee's moves.

    It yields the positions whose log-probability it needs and receives ``(log_prob,
    blobs)`` for them: the driver (:func:`_run_chunk`) evaluates the requests of every
    ensemble of every run in one call. The steps are emcee's own
    (``EnsembleSampler.sample`` and ``RedBlueMove.propose``): the move is chosen, the
    ensemble split and the proposals made with emcee's move objects and the ensemble's own
    ``RandomState``, in the same order, so the chain is the one ``emcee.EnsembleSampler``
    makes with the same random state (tested), without a thread per ensemble.
    """
    if e.log_prob is None:  # a fresh chain: evaluate the starting positions
        lp, blobs = yield e.coords
        e.log_prob, e.blobs = _clean(lp, blobs, len(e.coords), m)
    e.backend.grow(n, e.blobs)
    n_walkers = len(e.coords)
    for _ in range(n):
        move = moves[e.random.choice(len(moves), p=weights)]
        move.setup(e.coords)
        accepted = np.zeros(n_walkers, dtype=bool)
        inds = np.arange(n_walkers) % move.nsplits
        if move.randomize_split:
            e.random.shuffle(inds)
        for split in range(move.nsplits):
            subset = inds == split
            sets = [e.coords[inds == j] for j in range(move.nsplits)]
            q, factors = move.get_proposal(sets[split], sets[:split] + sets[split + 1 :], e.random)
            lp, blobs = yield q
            lp, blobs = _clean(lp, blobs, len(q), m)
            # emcee draws one uniform per walker of the half, in walker order; from a walker
            # at -inf, a proposal at -inf gives NaN, which is not accepted (as in emcee)
            with np.errstate(invalid="ignore"):
                take = factors + lp - e.log_prob[subset] > np.log(e.random.rand(len(q)))
            rows = np.flatnonzero(subset)[take]
            accepted[rows] = True
            e.coords[rows] = q[take]
            e.log_prob[rows] = lp[take]
            e.blobs[rows] = blobs[take]
        e.backend.save_step(emcee.State(e.coords, log_prob=e.log_prob, blobs=e.blobs), accepted)


#: The batched log-probability of several runs: positions per run (only the runs with
#: requests) to ``(log_prob, blobs)`` per run, arrays of shape ``(n,)`` and ``(n, m)``.
EvaluateFn = Callable[[dict[int, np.ndarray]], dict[int, tuple[np.ndarray, np.ndarray]]]


def _run_chunk(
    evaluate: EvaluateFn,
    jobs: Sequence[tuple[int, _Ensemble, int]],
    moves: Mapping[int, tuple[Sequence, np.ndarray]],
    n_blobs: Sequence[int],
) -> None:
    """Advance ensembles side by side: ``jobs`` are ``(run, ensemble, steps)``.

    ``moves[run]`` are the run's emcee moves and their weights, ``n_blobs[run]`` the length
    of its blobs.

    Every ensemble still stepping has one request pending at any time; they are gathered
    per run (in job order), evaluated in one call of ``evaluate`` and handed back.
    ``evaluate`` works row by row, so the values, and the chains, do not depend on how the
    requests are batched.
    """
    gens = [_advance(e, n, *moves[run], n_blobs[run]) for run, e, n in jobs]
    pending: dict[int, np.ndarray] = {}
    for i, g in enumerate(gens):
        try:
            pending[i] = next(g)
        except StopIteration:
            pass
    while pending:
        order = sorted(pending)
        per_run: dict[int, list[int]] = {}
        for i in order:
            per_run.setdefault(jobs[i][0], []).append(i)
        results = evaluate(
            {run: np.concatenate([pending[i] for i in idx]) for run, idx in per_run.items()}
        )
        answers: dict[int, tuple[np.ndarray, np.ndarray]] = {}
        for run, idx in per_run.items():
            lp, blobs = results[run]
            lp = np.asarray(lp, dtype=float).reshape(-1)
            blobs = np.asarray(blobs, dtype=float).reshape(len(lp), n_blobs[run])
            start = 0
            for i in idx:
                stop = start + len(pending[i])
                answers[i] = (lp[start:stop], blobs[start:stop])
                start = stop
        nxt: dict[int, np.ndarray] = {}
        for i in order:
            try:
                nxt[i] = gens[i].send(answers[i])
            except StopIteration:
                pass
        pending = nxt


def _tau(chain: np.ndarray) -> np.ndarray:
    """Integrated autocorrelation time per coordinate (emcee's estimator, no tolerance).

    ``tol=0``: emcee's own length check (a chain shorter than 50 tau) is off, since the
    stopping rule applies its own (``tau_factor``). A coordinate that has not moved over
    the chain (every walker stuck, e.g. all proposals rejected) has a zero-variance
    autocorrelation function, which emcee normalises by dividing by its zero value: the
    time is then NaN, which the stopping rule reads as "not yet known" (it needs finite
    times), so NumPy's divide and invalid-value warnings of that division are silenced
    here. ``np.errstate`` is local to the thread, so it does not hide anything elsewhere.
    """
    with np.errstate(divide="ignore", invalid="ignore"):
        return emcee.autocorr.integrated_time(chain, tol=0)


# ----------------------------------------------------------------------------------------
# checkpoints
def save_checkpoint(
    path: Path,
    backends: Sequence[tuple[emcee.backends.Backend, int]],
    fingerprint: str = "",
    notes: Sequence[str] = (),
) -> None:
    """Write the ensembles of a run to one HDF5 file atomically (temporary file + rename).

    Parameters
    ----------
    path : Path
        Checkpoint file.
    backends : sequence of (emcee.backends.Backend, int)
        Every ensemble's in-memory chain and the global step at which it began (non-zero
        after a restart).
    fingerprint : str
        Identity of the problem; a resume with another one is refused.
    notes : sequence of str
        The run's warnings so far (restarts), so that a resumed run reports them too.
    """
    path = Path(path)
    tmp = path.with_name(path.name + ".tmp")
    with h5py.File(tmp, "w") as f:
        f.attrs.update(fingerprint=fingerprint, n_ensembles=len(backends))
        f.attrs["notes"] = np.array(list(notes), dtype=h5py.string_dtype())
        for i, (backend, offset) in enumerate(backends):
            g = f.create_group(f"ensemble{i}")
            n = backend.iteration
            name, key, pos, has_gauss, cached = backend.random_state
            g.create_dataset("chain", data=backend.chain[:n])
            g.create_dataset("log_prob", data=backend.log_prob[:n])
            if backend.blobs is not None:
                g.create_dataset("blobs", data=np.asarray(backend.blobs[:n], dtype=float))
            g.create_dataset("accepted", data=backend.accepted)
            g.create_dataset("random_state_key", data=np.asarray(key))
            g.attrs.update(
                iteration=n,
                offset=int(offset),
                random_state_name=name,
                random_state_pos=int(pos),
                random_state_has_gauss=int(has_gauss),
                random_state_cached_gaussian=float(cached),
            )
    os.replace(tmp, path)


@dataclass(frozen=True)
class Checkpoint:
    """A run restored from :func:`save_checkpoint`.

    Attributes
    ----------
    backends : list of (emcee.backends.Backend, int)
        Every ensemble's chain and the global step at which it began.
    fingerprint : str
        Identity of the problem the checkpoint was written for.
    notes : list of str
        The run's warnings so far.
    """

    backends: list[tuple[emcee.backends.Backend, int]]
    fingerprint: str
    notes: list[str]


def load_checkpoint(path: Path) -> Checkpoint | None:
    """The ensembles stored in a checkpoint file (``None`` if there is none).

    Parameters
    ----------
    path : Path
        The checkpoint file.

    Returns
    -------
    Checkpoint or None
    """
    path = Path(path)
    if not path.exists():
        return None
    with h5py.File(path, "r") as f:
        backends = []
        for i in range(int(f.attrs["n_ensembles"])):
            g = f[f"ensemble{i}"]
            chain = g["chain"][...]
            backend = emcee.backends.Backend()
            backend.reset(chain.shape[1], chain.shape[2])
            backend.chain = chain
            backend.log_prob = g["log_prob"][...]
            backend.blobs = g["blobs"][...] if "blobs" in g else None
            backend.accepted = g["accepted"][...]
            backend.iteration = int(g.attrs["iteration"])
            backend.random_state = (
                str(g.attrs["random_state_name"]),
                g["random_state_key"][...],
                int(g.attrs["random_state_pos"]),
                int(g.attrs["random_state_has_gauss"]),
                float(g.attrs["random_state_cached_gaussian"]),
            )
            backends.append((backend, int(g.attrs["offset"])))
        notes = [n.decode() if isinstance(n, bytes) else str(n) for n in f.attrs["notes"]]
        return Checkpoint(backends, str(f.attrs["fingerprint"]), notes)


# ----------------------------------------------------------------------------------------
@dataclass(frozen=True)
class _Check:
    """The stopping rule evaluated on the stored chains at one global step."""

    tau: np.ndarray  # (n_ens, ndim)
    burn: np.ndarray  # (n_ens,)
    autocorr_ok: bool
    rhat: np.ndarray  # (ndim,) (NaN until autocorr_ok)
    rhat_lp: float
    ess_bulk: np.ndarray
    ess_tail: np.ndarray
    lp_median: np.ndarray  # (n_ens,)
    lp_spread: float  # robust sd of the best ensemble's log-probability
    walker_lp_max: tuple[np.ndarray, ...] = ()  # per ensemble (n_walkers,), post-burn-in

    def converged(self, s: SamplerSettings) -> bool:
        return bool(
            self.autocorr_ok
            and np.all(self.rhat <= s.max_rhat)
            and self.rhat_lp <= s.max_rhat
            and np.all(self.ess_bulk >= s.min_ess)
            and np.all(self.ess_tail >= s.min_ess)
        )


def _burn(tau: np.ndarray, length: int, s: SamplerSettings) -> int:
    """Burn-in [steps]: ``burn_factor`` autocorrelation times (half the chain if unknown)."""
    if not np.all(np.isfinite(tau)):
        return length // 2
    return min(int(np.ceil(s.burn_factor * np.max(tau))), length // 2)


def _autocorr(chain: np.ndarray, s: SamplerSettings) -> tuple[np.ndarray, int, bool]:
    """Autocorrelation times after burn-in, the burn-in and the length criterion."""
    length = chain.shape[0]
    if length < 4:
        return np.full(chain.shape[-1], np.nan), length // 2, False
    tau = _tau(chain[length // 4 :])
    burn = _burn(tau, length, s)
    tau = _tau(chain[burn:])
    ok = bool(np.all(np.isfinite(tau)) and length - burn >= s.tau_factor * np.max(tau))
    return tau, burn, ok


def _chains(ens: Sequence[_Ensemble], done: int) -> list[tuple[np.ndarray, np.ndarray]]:
    """(chain, log_prob) of every ensemble up to global step ``done``."""
    out = []
    for e in ens:
        n = done - e.offset
        out.append((e.backend.get_chain()[:n], e.backend.get_log_prob()[:n]))
    return out


def _check(ens: Sequence[_Ensemble], done: int, s: SamplerSettings) -> _Check:
    chains = _chains(ens, done)
    taus, burns, oks = zip(*(_autocorr(c, s) for c, _ in chains), strict=True)
    taus, burns = np.array(taus), np.array(burns)
    autocorr_ok = all(oks)
    ndim = taus.shape[1]
    post = [(c[b:], lp[b:]) for (c, lp), b in zip(chains, burns, strict=True)]
    lp_median = np.array([np.median(lp) if lp.size else -np.inf for _, lp in post])
    best = int(np.argmax(lp_median))
    lp_best = post[best][1]
    q25, q75 = np.percentile(lp_best, [25, 75]) if lp_best.size else (0.0, 0.0)
    nan = np.full(ndim, np.nan)
    if not autocorr_ok:
        return _Check(taus, burns, False, nan, np.nan, nan, nan, lp_median, (q75 - q25) / 1.35)
    n = min(len(lp) for _, lp in post)
    # one chain per ensemble for R-hat: post-burn-in draws in step order, walkers inside
    per_ens = np.stack([c[-n:].reshape(-1, ndim) for c, _ in post])  # (n_ens, n*w, ndim)
    lp_ens = np.stack([lp[-n:].reshape(-1) for _, lp in post])
    rhat = np.atleast_1d(array_stats.rhat(per_ens, chain_axis=0, draw_axis=1, method="rank"))
    rhat_lp = float(array_stats.rhat(lp_ens, chain_axis=0, draw_axis=1, method="rank"))
    # ESS with every walker as a chain: (n_ens * w, n, ndim)
    walkers = np.concatenate([np.swapaxes(c[-n:], 0, 1) for c, _ in post])
    ess_bulk = np.atleast_1d(array_stats.ess(walkers, chain_axis=0, draw_axis=1, method="bulk"))
    ess_tail = np.atleast_1d(
        array_stats.ess(walkers, chain_axis=0, draw_axis=1, method="tail", prob=TAIL_PROB)
    )
    spread = (q75 - q25) / 1.35
    walker_lp_max = tuple(lp.max(axis=0) for _, lp in post)
    return _Check(
        taus, burns, True, rhat, rhat_lp, ess_bulk, ess_tail, lp_median, spread, walker_lp_max
    )


def _stuck(check: _Check, s: SamplerSettings) -> list[int]:
    """Ensembles in a worse-supported mode (median log-probability far below the best)."""
    if not check.autocorr_ok or check.converged(s) or len(check.lp_median) < 2:
        return []
    best = float(np.max(check.lp_median))
    gap = max(s.mode_gap, 3.0 * check.lp_spread)
    return [i for i, m in enumerate(check.lp_median) if m < best - gap]


def _stuck_walkers(check: _Check, s: SamplerSettings) -> dict[int, np.ndarray]:
    """Walkers (per ensemble) that never reached their ensemble's typical log-probability.

    A walker is stuck when its largest post-burn-in log-probability lies more than
    ``max(mode_gap, 3 lp_spread)`` below its ensemble's median; only a minority of an
    ensemble can be (a majority elsewhere is the ensemble-level rule's business).
    """
    if not check.autocorr_ok or check.converged(s) or not check.walker_lp_max:
        return {}
    gap = max(s.mode_gap, 3.0 * check.lp_spread)
    out = {}
    for i, (top, med) in enumerate(zip(check.walker_lp_max, check.lp_median, strict=True)):
        idx = np.flatnonzero(top < med - gap)
        if 0 < idx.size < top.size / 2:
            out[i] = idx
    return out


def _spawn(seed: int, n: int) -> list[int]:
    return [int(q.generate_state(1)[0]) for q in np.random.SeedSequence(seed).spawn(n)]


#: How a note on where the ensembles started begins (:attr:`RunSpec.notes`): such a note
#: is not a restart, and does not count against ``max_restarts``.
START_NOTE = "start: "


@dataclass(frozen=True)
class RunSpec:
    """One posterior to sample with independent ensembles (a *run*).

    Parameters
    ----------
    initial : sequence of ndarray, each of shape (n_walkers, ndim)
        Starting positions, one array per ensemble (ignored when resuming).
    n_blobs : int
        Length of each walker's blob (e.g. the pointwise log-likelihood).
    seed : int
        Master seed: every ensemble's random state (and every restart's) is spawned from it.
    checkpoint : str or Path, optional
        HDF5 checkpoint file of this run (all ensembles), written after every chunk.
    resume : bool
        Continue the run stored in ``checkpoint`` (else it is started afresh).
    fingerprint : str
        Identity of the problem (data, model, settings); stored in the checkpoints, and a
        resume from checkpoints with another fingerprint is refused.
    progress : callable, optional
        Called with a :class:`ProgressInfo` after every chunk.
    notes : sequence of str
        What happened before sampling (where the ensembles were started: each begins
        with :data:`START_NOTE`), reported first among the run's warnings.
    """

    initial: Sequence[np.ndarray]
    n_blobs: int
    seed: int
    checkpoint: str | Path | None = None
    resume: bool = False
    fingerprint: str = ""
    progress: Callable[[ProgressInfo], None] | None = None
    notes: Sequence[str] = ()


@dataclass
class _Run:
    """The state of one run while it is sampled (:func:`run_side_by_side`)."""

    spec: RunSpec
    ens: list[_Ensemble]
    moves: list
    weights: np.ndarray
    path: Path | None
    notes: list[str]
    done: int
    restarts: int
    check: _Check | None = None
    finished: bool = False


def _start_run(spec: RunSpec, s: SamplerSettings) -> _Run:
    """The ensembles of a run: fresh from ``spec.initial`` or resumed from its checkpoint."""
    initial = [np.asarray(x, dtype=float) for x in spec.initial]
    n_walkers, ndim = initial[0].shape
    if any(x.shape != (n_walkers, ndim) for x in initial):
        raise ValueError("every ensemble needs initial positions of the same shape")
    if n_walkers < 2 * ndim or n_walkers % 2:
        raise ValueError(f"{n_walkers} walkers: need an even number >= 2 x {ndim} dimensions")
    path = Path(spec.checkpoint) if spec.checkpoint is not None else None
    stored = load_checkpoint(path) if spec.resume and path is not None else None
    notes: list[str] = []
    if stored is not None:
        if stored.fingerprint != spec.fingerprint:
            raise CheckpointMismatchError(
                f"checkpoint {path} was made for other data or settings; start afresh "
                "instead of resuming"
            )
        shapes = {b.shape for b, _ in stored.backends}
        if shapes != {(n_walkers, ndim)} or len(stored.backends) != len(initial):
            raise CheckpointMismatchError(
                f"checkpoint {path} holds {len(stored.backends)} ensemble(s) of shape "
                f"{sorted(shapes)}, not {len(initial)} of {(n_walkers, ndim)}"
            )
        ens = [_resumed_ensemble(backend, offset) for backend, offset in stored.backends]
        notes = list(stored.notes)
    else:
        seeds = _spawn(spec.seed, len(initial))
        ens = [_new_ensemble(x, sub, 0) for x, sub in zip(initial, seeds, strict=True)]
        notes = list(spec.notes)
    # emcee's moves, one set per run (a move keeps per-dimension settings), and their
    # weights normalised as emcee.EnsembleSampler does
    pairs = _moves(s.moves)
    weights = np.atleast_1d([w for _, w in pairs]).astype(float)
    # the global step: every ensemble's chain ends there (offset + its own length)
    done = max(e.offset + e.iteration for e in ens)
    return _Run(
        spec,
        ens,
        [m for m, _ in pairs],
        weights / np.sum(weights),
        path,
        notes,
        done,
        sum(not n.startswith(START_NOTE) for n in notes),  # restarts so far
    )


def _at_check(run: _Run, s: SamplerSettings) -> None:
    """Apply the stopping rule to a run at a check point; restart stuck ensembles/walkers."""
    done, seed = run.done, run.spec.seed
    check = run.check = _check(run.ens, done, s)
    converged = check.converged(s)
    if run.spec.progress is not None:
        run.spec.progress(_progress(check, done, s, converged))
    if converged or done >= s.max_steps:
        run.finished = True
        return
    stuck = _stuck(check, s) if run.restarts < s.max_restarts else []
    if stuck:
        run.restarts += 1
        best = int(np.argmax(check.lp_median))
        run.notes.append(_restart_note(stuck, best, check, done))
        for i in stuck:
            run.ens[i] = _restart(run.ens[best], seed, done, i, run.restarts)
    walkers = _stuck_walkers(check, s) if run.restarts < s.max_restarts and not stuck else {}
    if walkers:
        run.restarts += 1
        run.notes.append(_walker_note(walkers, check, done))
        for i, idx in walkers.items():
            run.ens[i] = _move_walkers(run.ens[i], idx, seed, done, i, run.restarts, check)


def run_side_by_side(
    evaluate: EvaluateFn,
    runs: Sequence[RunSpec],
    settings: SamplerSettings | None = None,
) -> list[SamplerRun]:
    """Sample several independent runs side by side, each until its ensembles agree.

    Every run follows the stopping rule of the module docstring on its own and stops when
    it is met (or at ``max_steps``); the runs still going are stepped together, and the
    requests of all their ensembles are evaluated in one call of ``evaluate`` per round
    (for a simulator, one batched call instead of one per run and ensemble). The chains are
    those of sampling each run alone: ``evaluate`` must work row by row.

    Parameters
    ----------
    evaluate : callable
        ``evaluate({run: positions}) -> {run: (log_prob, blobs)}``: positions of shape
        ``(n, ndim_run)`` for every run that has requests (keys index ``runs``), returning
        arrays of shape ``(n,)`` and ``(n, n_blobs_run)``.
    runs : sequence of RunSpec
        The runs.
    settings : SamplerSettings, optional
        Stopping rule and moves, shared by the runs (``n_ensembles`` is taken from each
        run's ``initial``).

    Returns
    -------
    list of SamplerRun
        In the order of ``runs``.

    Raises
    ------
    CheckpointMismatchError
        When resuming from a checkpoint written for another problem.
    """
    s = settings or SamplerSettings()
    state = [_start_run(spec, s) for spec in runs]
    n_blobs = [spec.n_blobs for spec in runs]
    c = s.check_every
    while True:
        for run in state:
            if not run.finished and (
                run.done >= s.max_steps or (run.done > 0 and run.done % c == 0)
            ):
                _at_check(run, s)
        active = [i for i, run in enumerate(state) if not run.finished]
        if not active:
            break
        n = min(min(c - state[i].done % c, s.max_steps - state[i].done) for i in active)
        jobs = [(i, e, n) for i in active for e in state[i].ens]
        moves = {i: (state[i].moves, state[i].weights) for i in active}
        _run_chunk(evaluate, jobs, moves, n_blobs)
        for i in active:
            run = state[i]
            run.done += n
            if run.path is not None:
                for e in run.ens:
                    e.keep_random_state()
                save_checkpoint(
                    run.path,
                    [(e.backend, e.offset) for e in run.ens],
                    run.spec.fingerprint,
                    run.notes,
                )
    out = []
    for run in state:
        assert run.check is not None
        out.append(
            _pool(run.ens, run.check, run.done, s, run.spec.seed, run.notes, run.spec.n_blobs)
        )
    return out


def run_ensembles(
    log_prob_fn: LogProbFn,
    initial: Sequence[np.ndarray],
    n_blobs: int,
    *,
    seed: int,
    settings: SamplerSettings | None = None,
    checkpoint: str | Path | None = None,
    resume: bool = False,
    fingerprint: str = "",
    progress: Callable[[ProgressInfo], None] | None = None,
) -> SamplerRun:
    """Sample with independent ensembles until they agree (module docstring), or capped.

    One run of :func:`run_side_by_side`.

    Parameters
    ----------
    log_prob_fn : callable
        ``f(x) -> (log_prob, blobs)`` for positions ``x`` of shape ``(n, ndim)``.
    initial : sequence of ndarray, each of shape (n_walkers, ndim)
        Starting positions, one array per ensemble (ignored when resuming).
    n_blobs : int
        Length of each walker's blob (the number of observations).
    seed : int
        Master seed: every ensemble's emcee random state (and every restart's) is spawned
        from it.
    settings : SamplerSettings, optional
        Stopping rule and moves (``n_ensembles`` is taken from ``initial``).
    checkpoint : str or Path, optional
        HDF5 checkpoint file of this run (all ensembles), written after every chunk.
    resume : bool
        Continue the run stored in ``checkpoint`` (else it is started afresh).
    fingerprint : str
        Identity of the problem (data, model, settings); stored in the checkpoints, and a
        resume from checkpoints with another fingerprint is refused.
    progress : callable, optional
        Called with a :class:`ProgressInfo` after every chunk.

    Returns
    -------
    SamplerRun

    Raises
    ------
    CheckpointMismatchError
        When resuming from checkpoints written for another problem.
    """
    spec = RunSpec(initial, n_blobs, seed, checkpoint, resume, fingerprint, progress)
    return run_side_by_side(lambda xs: {0: log_prob_fn(xs[0])}, [spec], settings)[0]


def _progress(check: _Check, done: int, s: SamplerSettings, converged: bool) -> ProgressInfo:
    tau = float(np.nanmax(check.tau)) if np.any(np.isfinite(check.tau)) else np.nan
    rhat = float(np.nanmax([*check.rhat, check.rhat_lp])) if check.autocorr_ok else np.nan
    ess = (
        float(min(np.min(check.ess_bulk), np.min(check.ess_tail))) if check.autocorr_ok else np.nan
    )
    return ProgressInfo(done, s.max_steps, tau, rhat, ess, converged)


def _restart_note(stuck: list[int], best: int, check: _Check, done: int) -> str:
    worst = ", ".join(f"{i} (median log-probability {check.lp_median[i]:.1f})" for i in stuck)
    return (
        f"step {done}: ensemble(s) {worst} stuck in a worse-supported mode than ensemble "
        f"{best} ({check.lp_median[best]:.1f}); restarted from ensemble {best}'s walkers"
    )


def _walker_note(walkers: dict[int, np.ndarray], check: _Check, done: int) -> str:
    parts = []
    for i, idx in walkers.items():
        top = check.walker_lp_max[i][idx]
        parts.append(
            f"ensemble {i}: walker(s) {', '.join(map(str, idx))} (best log-probability "
            f"{', '.join(f'{v:.1f}' for v in top)} vs the ensemble's median "
            f"{check.lp_median[i]:.1f})"
        )
    return (
        f"step {done}: walkers stuck in a worse-supported mode, {'; '.join(parts)}; their "
        "ensembles restarted with them moved onto their other walkers"
    )


def _move_walkers(
    e: _Ensemble,
    stuck: np.ndarray,
    seed: int,
    done: int,
    index: int,
    restart: int,
    check: _Check,
) -> _Ensemble:
    """A fresh chain for ensemble ``e`` with its ``stuck`` walkers moved onto the others.

    Each stuck walker takes the current position of another walker of the ensemble, drawn
    at random, jittered by 1% of the post-burn-in spread of the others. Deterministic in
    (seed, step, ensemble, restart number), so a resumed run repeats it.
    """
    rng = np.random.default_rng([seed, done, index, restart, 1])
    chain = e.backend.get_chain()[: done - e.offset]
    n_walkers, ndim = chain.shape[1:]
    good = np.setdiff1d(np.arange(n_walkers), stuck)
    start = chain[-1].copy()
    post = chain[int(check.burn[index]) :, good].reshape(-1, ndim)
    scale = np.std(post, axis=0)
    donors = rng.choice(good, size=stuck.size)
    start[stuck] = start[donors] + 1e-2 * scale * rng.standard_normal((stuck.size, ndim))
    return _fresh_chain(start, rng, done)


def _restart(best: _Ensemble, seed: int, done: int, index: int, restart: int) -> _Ensemble:
    """A fresh chain for a stuck ensemble, started from the best ensemble's walkers.

    Deterministic in (seed, step, ensemble, restart number), so a resumed run repeats it.
    """
    rng = np.random.default_rng([seed, done, index, restart])
    chain = best.backend.get_chain()
    last = chain[-1]
    scale = np.std(chain[len(chain) // 2 :].reshape(-1, last.shape[-1]), axis=0)
    start = last + 1e-2 * scale * rng.standard_normal(last.shape)
    return _fresh_chain(start, rng, done)


def _fresh_chain(start: np.ndarray, rng: np.random.Generator, done: int) -> _Ensemble:
    """A new ensemble from positions ``start``, its chain beginning at global step ``done``.

    Its random state is drawn from ``rng``.
    """
    return _new_ensemble(start, int(rng.integers(2**32)), done)


def _pool(
    ens: Sequence[_Ensemble],
    check: _Check,
    done: int,
    s: SamplerSettings,
    seed: int,
    notes: list[str],
    n_blobs: int,
) -> SamplerRun:
    """Pool the kept draws of the ensembles of the best-supported mode."""
    converged = check.converged(s)
    keep = list(range(len(ens)))
    if not converged:
        dropped = _stuck(check, s)
        if dropped:
            keep = [i for i in keep if i not in dropped]
            notes.append(
                f"ensemble(s) {', '.join(map(str, dropped))} stayed in a worse-supported mode "
                f"after {s.max_restarts} restart(s): only ensembles {keep} (the best-supported "
                "mode) are kept; the posterior may be incomplete"
            )
        elif check.autocorr_ok and not (
            np.all(check.rhat <= s.max_rhat) and check.rhat_lp <= s.max_rhat
        ):
            notes.append(
                f"independent ensembles disagree at comparable log-probability (R-hat up to "
                f"{np.nanmax([*check.rhat, check.rhat_lp]):.3f}): the posterior may be "
                "multimodal or not yet mixed"
            )
        else:
            notes.append(f"not converged after {done} steps: " + _shortfall(check, s))
    kept_len = min(done - ens[i].offset - int(check.burn[i]) for i in keep)
    kept_len = max(kept_len, 1)
    thin = max(1, kept_len // s.n_draws)
    n_draw = min(s.n_draws, kept_len)
    samples, log_prob, blobs, acc, which = [], [], [], [], []
    for i in keep:
        e = ens[i]
        n = done - e.offset
        sel = slice(n - thin * n_draw, n, thin)
        samples.append(np.swapaxes(e.backend.get_chain()[sel], 0, 1))
        log_prob.append(e.backend.get_log_prob()[sel].T)
        b = np.asarray(e.backend.get_blobs()[sel], dtype=float)
        blobs.append(np.swapaxes(b.reshape(n_draw, -1, n_blobs), 0, 1))
        acc.append(np.asarray(e.backend.accepted / float(e.iteration), dtype=float))
        which.append(np.full(samples[-1].shape[0], i))
    ndim = samples[0].shape[-1]
    nan = np.full(ndim, np.nan)
    return SamplerRun(
        samples=np.concatenate(samples),
        log_prob=np.concatenate(log_prob),
        blobs=np.concatenate(blobs),
        ensemble_of_chain=np.concatenate(which),
        tau=np.asarray(check.tau, dtype=float),
        rhat=check.rhat if check.autocorr_ok else nan,
        ess_bulk=check.ess_bulk if check.autocorr_ok else nan,
        ess_tail=check.ess_tail if check.autocorr_ok else nan,
        acceptance=np.concatenate(acc),
        n_steps=int(done),
        burn=np.asarray(check.burn, dtype=int),
        thin=int(thin),
        converged=converged,
        warnings=notes,
        seed=int(seed),
    )


def _shortfall(check: _Check, s: SamplerSettings) -> str:
    """Which part of the stopping rule is not met, in words."""
    if not check.autocorr_ok:
        return (
            f"chains are shorter than {s.tau_factor:g} autocorrelation times "
            f"(largest tau {np.nanmax(check.tau):.0f} steps) or tau has not settled"
        )
    ess = min(np.min(check.ess_bulk), np.min(check.ess_tail))
    return f"effective sample size {ess:.0f} < {s.min_ess:g}"
