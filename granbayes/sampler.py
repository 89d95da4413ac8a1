"""Run an emcee ensemble until it has converged (the sampler knows nothing of the model).

:func:`run_ensemble` takes a vectorised function ``f(positions) -> (log_prob, blobs)``
(arrays of shape ``(n,)`` and ``(n, m)``), starting positions and a seed. It samples in
chunks; after each chunk it estimates the integrated autocorrelation time ``tau`` of every
coordinate (emcee's estimator) and stops once the chain after burn-in is at least
``tau_factor`` (default 50) times the largest ``tau`` and ``tau`` has stabilised, or at
``max_steps``. With an HDF5 checkpoint file the run is saved after every chunk (chain,
blobs, acceptance counts and emcee's random state, written to a temporary file and moved
into place, so a checkpoint is always whole). An interrupted run resumes from the last
checkpoint, losing at most one chunk of work, and a resumed run is bit-identical to an
uninterrupted one with the same seed. (emcee's own ``HDFBackend`` reopens the file at every
step, which cost a third of the sampling time here.)
"""

from __future__ import annotations

import os
import warnings
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import emcee
import h5py
import numpy as np

__all__ = [
    "SamplerSettings",
    "SamplerRun",
    "run_ensemble",
    "save_checkpoint",
    "load_checkpoint",
]

LogProbFn = Callable[[np.ndarray], tuple[np.ndarray, np.ndarray]]


@dataclass(frozen=True)
class SamplerSettings:
    """How long and how to sample.

    Parameters
    ----------
    n_walkers : int
        Ensemble size (at least twice the dimension, and even).
    max_steps : int
        Hard cap on steps per walker.
    check_every : int
        Steps between convergence checks.
    tau_factor : float
        Required post-burn-in chain length in units of the largest autocorrelation time.
    burn_factor : float
        Burn-in discarded, in units of the largest autocorrelation time.
    n_draws : int
        Draws kept per walker after burn-in and thinning.
    moves : {"de", "stretch"}
        ``de``: differential evolution (80%) + snooker (20%), good for the correlated
        valleys of force laws; ``stretch``: emcee's default affine-invariant move.
    progress : bool
        Show a tqdm progress bar.
    """

    n_walkers: int = 32
    max_steps: int = 20_000
    check_every: int = 250
    tau_factor: float = 50.0
    burn_factor: float = 3.0
    n_draws: int = 250
    moves: str = "de"
    progress: bool = False


@dataclass
class SamplerRun:
    """A finished (or capped) ensemble run.

    Attributes
    ----------
    samples : ndarray, shape (n_walkers, n_draws, ndim)
        Kept draws (after burn-in and thinning), walker-major like ArviZ chains.
    log_prob : ndarray, shape (n_walkers, n_draws)
    blobs : ndarray, shape (n_walkers, n_draws, m)
        Per-observation log-likelihood of the kept draws.
    tau : ndarray, shape (ndim,)
        Integrated autocorrelation times [steps].
    acceptance : ndarray, shape (n_walkers,)
        Acceptance fraction per walker.
    n_steps : int
        Steps per walker in total.
    burn : int
        Burn-in [steps] (``burn_factor`` autocorrelation times).
    first, thin : int
        First kept step and thinning interval.
    converged : bool
        Whether the chain reached ``tau_factor * tau`` after burn-in.
    seed : int
        The seed used.
    """

    samples: np.ndarray
    log_prob: np.ndarray
    blobs: np.ndarray
    tau: np.ndarray
    acceptance: np.ndarray
    n_steps: int
    burn: int
    first: int
    thin: int
    converged: bool
    seed: int


def _moves(kind: str) -> list:
    if kind == "de":
        return [(emcee.moves.DEMove(), 0.8), (emcee.moves.DESnookerMove(), 0.2)]
    if kind == "stretch":
        return [(emcee.moves.StretchMove(), 1.0)]
    raise ValueError(f"moves must be 'de' or 'stretch', got {kind!r}")


def _adapt(fn: LogProbFn, m: int) -> Callable[[np.ndarray], list]:
    """emcee's vectorised-with-blobs protocol: a list of per-walker (lp, blob) tuples."""

    def wrapped(x: np.ndarray) -> list:
        lp, blobs = fn(x)
        lp = np.asarray(lp, dtype=float)
        blobs = np.asarray(blobs, dtype=float).reshape(len(lp), m)
        bad = ~np.isfinite(lp)
        lp = np.where(bad, -np.inf, lp)
        blobs[bad] = -np.inf
        return [(lp[i], blobs[i]) for i in range(len(lp))]

    return wrapped


def _tau(chain: np.ndarray) -> np.ndarray:
    """Integrated autocorrelation time per coordinate (emcee's estimator, no tolerance)."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return emcee.autocorr.integrated_time(chain, tol=0)


def save_checkpoint(backend: emcee.backends.Backend, path: Path, fingerprint: str = "") -> None:
    """Write an in-memory emcee backend to ``path`` atomically (temporary file + rename)."""
    path = Path(path)
    tmp = path.with_name(path.name + ".tmp")
    n = backend.iteration
    name, key, pos, has_gauss, cached = backend.random_state
    with h5py.File(tmp, "w") as f:
        f.create_dataset("chain", data=backend.chain[:n])
        f.create_dataset("log_prob", data=backend.log_prob[:n])
        if backend.blobs is not None:
            f.create_dataset("blobs", data=np.asarray(backend.blobs[:n], dtype=float))
        f.create_dataset("accepted", data=backend.accepted)
        f.create_dataset("random_state_key", data=np.asarray(key))
        f.attrs.update(
            iteration=n,
            random_state_name=name,
            random_state_pos=int(pos),
            random_state_has_gauss=int(has_gauss),
            random_state_cached_gaussian=float(cached),
            fingerprint=fingerprint,
        )
    os.replace(tmp, path)


def checkpoint_fingerprint(path: Path) -> str | None:
    """The fingerprint stored in a checkpoint (``None`` if there is no checkpoint)."""
    path = Path(path)
    if not path.exists():
        return None
    with h5py.File(path, "r") as f:
        return str(f.attrs.get("fingerprint", ""))


def load_checkpoint(path: Path) -> emcee.backends.Backend | None:
    """An in-memory emcee backend restored from a checkpoint (``None`` if there is none)."""
    path = Path(path)
    if not path.exists():
        return None
    with h5py.File(path, "r") as f:
        n = int(f.attrs["iteration"])
        chain = f["chain"][...]
        backend = emcee.backends.Backend()
        backend.reset(chain.shape[1], chain.shape[2])
        backend.chain = chain
        backend.log_prob = f["log_prob"][...]
        backend.blobs = f["blobs"][...] if "blobs" in f else None
        backend.accepted = f["accepted"][...]
        backend.iteration = n
        backend.random_state = (
            str(f.attrs["random_state_name"]),
            f["random_state_key"][...],
            int(f.attrs["random_state_pos"]),
            int(f.attrs["random_state_has_gauss"]),
            float(f.attrs["random_state_cached_gaussian"]),
        )
    return backend if n > 0 else None


def _burn(tau: np.ndarray, done: int, s: SamplerSettings) -> int:
    """Burn-in [steps]: ``burn_factor`` autocorrelation times (half the chain if unknown)."""
    if not np.all(np.isfinite(tau)):
        return done // 2
    return min(int(np.ceil(s.burn_factor * np.max(tau))), done // 2)


def _assess(chain: np.ndarray, s: SamplerSettings) -> tuple[np.ndarray, bool]:
    """Autocorrelation times after burn-in and whether the chain is long enough."""
    done = chain.shape[0]
    tau = _tau(chain[done // 4 :])
    burn = _burn(tau, done, s)
    tau = _tau(chain[burn:])
    ok = bool(np.all(np.isfinite(tau)) and done - burn >= s.tau_factor * np.max(tau))
    return tau, ok


def run_ensemble(
    log_prob_fn: LogProbFn,
    initial: np.ndarray,
    n_blobs: int,
    *,
    seed: int,
    settings: SamplerSettings | None = None,
    checkpoint: str | Path | None = None,
    resume: bool = False,
    fingerprint: str = "",
) -> SamplerRun:
    """Sample until converged or capped.

    Parameters
    ----------
    log_prob_fn : callable
        ``f(x) -> (log_prob, blobs)`` for positions ``x`` of shape ``(n, ndim)``.
    initial : ndarray, shape (n_walkers, ndim)
        Starting positions (ignored when resuming a non-empty backend).
    n_blobs : int
        Length of each walker's blob (the number of observations).
    seed : int
        Seed of emcee's random state (used for fresh runs; resumed runs continue the
        stored state).
    settings : SamplerSettings, optional
        Chain length and moves.
    checkpoint : str or Path, optional
        HDF5 checkpoint file of this run (written after every chunk).
    resume : bool
        Continue the run stored in ``checkpoint`` (else it is started afresh).
    fingerprint : str
        Identity of the problem (data, model, settings); stored in the checkpoint, and a
        resume from a checkpoint with another fingerprint is refused.

    Returns
    -------
    SamplerRun
    """
    s = settings or SamplerSettings()
    initial = np.asarray(initial, dtype=float)
    n_walkers, ndim = initial.shape
    if n_walkers != s.n_walkers:
        raise ValueError(f"initial has {n_walkers} walkers, settings say {s.n_walkers}")
    store = None
    if resume and checkpoint is not None:
        stored = checkpoint_fingerprint(checkpoint)
        if stored is not None and stored != fingerprint:
            raise ValueError(
                f"checkpoint {checkpoint} was made for other data or settings; "
                "rerun without --resume"
            )
        store = load_checkpoint(checkpoint)
    if store is not None and store.shape != (n_walkers, ndim):
        raise ValueError(f"checkpoint {checkpoint} has shape {store.shape}, not {initial.shape}")
    store = store if store is not None else emcee.backends.Backend()
    sampler = emcee.EnsembleSampler(
        n_walkers,
        ndim,
        _adapt(log_prob_fn, n_blobs),
        vectorize=True,
        moves=_moves(s.moves),
        backend=store,
    )
    if sampler.iteration == 0:
        sampler.random_state = np.random.RandomState(seed).get_state()
        start = initial
    else:
        start = None  # continue from the stored last sample and random state
    # Checks happen at multiples of check_every and depend only on the stored chain, so a
    # resumed run makes exactly the decisions of an uninterrupted one.
    c = s.check_every
    while True:
        done = sampler.iteration
        if done >= s.max_steps or (done > 0 and done % c == 0):
            chain = sampler.get_chain()
            tau, converged = _assess(chain[:done], s)
            if done - c >= c:
                previous, _ = _assess(chain[: done - c], s)
                converged = converged and bool(np.all(np.abs(previous - tau) <= 0.05 * tau))
            else:
                converged = False
            if converged or done >= s.max_steps:
                break
        n = min(c - done % c, s.max_steps - done)
        sampler.run_mcmc(start, n, progress=s.progress, store=True)
        start = None
        if checkpoint is not None:
            save_checkpoint(sampler.backend, Path(checkpoint), fingerprint)
    chain = sampler.get_chain()
    burn = _burn(tau, done, s)
    kept = done - burn
    thin = max(1, kept // s.n_draws)
    first = done - thin * min(s.n_draws, kept)
    sel = slice(first, done, thin)
    samples = np.swapaxes(chain[sel], 0, 1)
    log_prob = sampler.get_log_prob()[sel].T
    kept_blobs = np.asarray(sampler.get_blobs()[sel], dtype=float)
    blobs = np.swapaxes(kept_blobs.reshape(samples.shape[1], n_walkers, n_blobs), 0, 1)
    return SamplerRun(
        samples=samples,
        log_prob=log_prob,
        blobs=blobs,
        tau=np.asarray(tau, dtype=float),
        acceptance=np.asarray(sampler.acceptance_fraction, dtype=float),
        n_steps=int(done),
        burn=int(burn),
        first=int(first),
        thin=int(thin),
        converged=converged,
        seed=int(seed),
    )
