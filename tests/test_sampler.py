"""Tests of the ensemble driver (``granbayes.sampler.run_ensemble``) on analytic targets.

The target is a correlated 2-D Gaussian written in plain numpy, so the true posterior
moments are known exactly and a run costs about a millisecond per step (HDF5
checkpointing adds a few milliseconds per step, so the resume tests use short chains).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from granbayes.sampler import SamplerRun, SamplerSettings, load_checkpoint, run_ensemble

MU = np.array([1.0, -2.0])
SD = np.array([1.0, 2.0])
RHO = 0.9
COV = np.array([[SD[0] ** 2, RHO * SD[0] * SD[1]], [RHO * SD[0] * SD[1], SD[1] ** 2]])
PREC = np.linalg.inv(COV)
N_BLOBS = 3


def gaussian(x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Correlated Gaussian log density (unnormalised) and three per-"observation" terms.

    Element-wise arithmetic only, so a row's value does not depend on the batch it is in
    (the blobs can be recomputed exactly from the samples).
    """
    d0 = x[:, 0] - MU[0]
    d1 = x[:, 1] - MU[1]
    lp = -0.5 * (PREC[0, 0] * d0 * d0 + 2.0 * PREC[0, 1] * d0 * d1 + PREC[1, 1] * d1 * d1)
    blobs = np.column_stack([-0.5 * d0 * d0, -0.5 * d1 * d1, x[:, 0] + x[:, 1]])
    return lp, blobs


class Counting:
    """Wrap a target; count calls and raise KeyboardInterrupt at call ``interrupt_at``.

    Simulates a user pressing Ctrl-C while the sampler evaluates the log-probability.
    """

    def __init__(self, fn=gaussian, interrupt_at: int | None = None) -> None:
        self.fn = fn
        self.interrupt_at = interrupt_at
        self.calls = 0

    def __call__(self, x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        self.calls += 1
        if self.interrupt_at is not None and self.calls >= self.interrupt_at:
            raise KeyboardInterrupt
        return self.fn(x)


def start(n_walkers: int = 16, ndim: int = 2) -> np.ndarray:
    """A small ball of starting positions away from the mode (fixed)."""
    return np.array([0.0, 0.0]) + 0.1 * np.random.default_rng(0).standard_normal((n_walkers, ndim))


CONVERGE = SamplerSettings(n_walkers=16, check_every=100, max_steps=5000, n_draws=250)
SHORT = SamplerSettings(n_walkers=16, check_every=100, max_steps=300, n_draws=50)
RESUME = SamplerSettings(n_walkers=12, check_every=50, max_steps=2000, n_draws=60, tau_factor=20.0)
RESUME_STRETCH = SamplerSettings(
    n_walkers=12, check_every=100, max_steps=400, n_draws=60, moves="stretch"
)


def assert_same_run(a: SamplerRun, b: SamplerRun) -> None:
    """Bit-identical draws, log-probabilities, blobs and bookkeeping."""
    np.testing.assert_array_equal(a.samples, b.samples)
    np.testing.assert_array_equal(a.log_prob, b.log_prob)
    np.testing.assert_array_equal(a.blobs, b.blobs)
    np.testing.assert_array_equal(a.tau, b.tau)
    np.testing.assert_array_equal(a.acceptance, b.acceptance)
    assert (a.n_steps, a.burn, a.first, a.thin, a.converged, a.seed) == (
        b.n_steps,
        b.burn,
        b.first,
        b.thin,
        b.converged,
        b.seed,
    )


@pytest.fixture(scope="module")
def converged_run() -> SamplerRun:
    """One converged run of the Gaussian (DE moves, 16 walkers, seed 1)."""
    return run_ensemble(gaussian, start(), N_BLOBS, seed=1, settings=CONVERGE)


def test_converges_with_enough_autocorrelation_times(converged_run: SamplerRun) -> None:
    """The run stops converged with >= 50 tau of chain after burn-in; shapes as documented."""
    r = converged_run
    assert r.converged
    assert np.all(np.isfinite(r.tau)) and np.all(r.tau > 0)
    assert r.n_steps - r.burn >= CONVERGE.tau_factor * np.max(r.tau)
    assert r.n_steps < CONVERGE.max_steps
    assert r.n_steps % CONVERGE.check_every == 0
    assert r.burn >= np.ceil(CONVERGE.burn_factor * np.max(r.tau)) or r.burn == r.n_steps // 2
    n_draws = r.samples.shape[1]
    assert r.samples.shape == (16, CONVERGE.n_draws, 2)
    assert r.log_prob.shape == (16, n_draws)
    assert r.blobs.shape == (16, n_draws, N_BLOBS)
    assert r.first >= r.burn
    assert r.first + r.thin * n_draws == r.n_steps
    assert r.acceptance.shape == (16,)
    assert np.all((r.acceptance > 0.05) & (r.acceptance < 0.95))
    assert r.seed == 1


def test_posterior_moments(converged_run: SamplerRun) -> None:
    """Mean and covariance of the kept draws match the Gaussian's.

    The run keeps >= 50 tau after burn-in with 16 walkers, so the effective sample size
    is >= ~800: the standard error of a mean is <= 0.035 sd, of a variance <= 5 %, of the
    correlation <= 0.007. Tolerances are about 4 standard errors: 0.15 sd for the means,
    20 % for the variances, 0.03 for the correlation (deterministic given the seed).
    """
    x = converged_run.samples.reshape(-1, 2)
    assert np.all(np.abs(x.mean(axis=0) - MU) <= 0.15 * SD)
    cov = np.cov(x.T)
    np.testing.assert_allclose(np.diag(cov), SD**2, rtol=0.2)
    rho = cov[0, 1] / np.sqrt(cov[0, 0] * cov[1, 1])
    assert rho == pytest.approx(RHO, abs=0.03)


def test_log_prob_and_blobs_belong_to_the_draws(converged_run: SamplerRun) -> None:
    """The kept log-probabilities and blobs are those of the kept draws (exactly)."""
    r = converged_run
    lp, blobs = gaussian(r.samples.reshape(-1, 2))
    np.testing.assert_array_equal(r.log_prob.ravel(), lp)
    np.testing.assert_array_equal(r.blobs.reshape(-1, N_BLOBS), blobs)


def test_same_seed_bit_identical_different_seed_differs() -> None:
    """A seed fixes the run completely; another seed gives another chain."""
    a = run_ensemble(gaussian, start(), N_BLOBS, seed=7, settings=SHORT)
    b = run_ensemble(gaussian, start(), N_BLOBS, seed=7, settings=SHORT)
    c = run_ensemble(gaussian, start(), N_BLOBS, seed=8, settings=SHORT)
    assert_same_run(a, b)
    assert c.samples.shape == a.samples.shape
    assert not np.array_equal(a.samples, c.samples)
    assert c.seed == 8


@pytest.mark.parametrize("moves", ["de", "stretch"])
def test_max_steps_cap(moves: str) -> None:
    """A cap shorter than 50 tau stops the run unconverged at exactly ``max_steps``.

    250 is not a multiple of ``check_every`` = 100, so the last chunk is a partial one.
    """
    s = SamplerSettings(n_walkers=16, check_every=100, max_steps=250, n_draws=50, moves=moves)
    r = run_ensemble(gaussian, start(), N_BLOBS, seed=2, settings=s)
    assert not r.converged
    assert r.n_steps == 250
    assert r.first + r.thin * r.samples.shape[1] == 250
    assert np.all(np.isfinite(r.samples))


def _truncated(x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The Gaussian cut at ``x0 > 1.5`` (-inf, NaN blobs) and NaN where ``x1 > 0``."""
    lp, blobs = gaussian(x)
    lp = np.where(x[:, 0] > 1.5, -np.inf, lp)
    blobs[x[:, 0] > 1.5] = np.nan
    lp = np.where(x[:, 1] > 0.0, np.nan, lp)
    return lp, blobs


@pytest.mark.filterwarnings("ignore:invalid value encountered:RuntimeWarning")
def test_minus_inf_and_nan_regions_never_crash() -> None:
    """-inf and NaN log-probabilities are rejected, even for walkers that start there.

    Two of the 16 walkers start in the forbidden half-plane; after burn-in every kept
    draw is in the allowed region with a finite log-probability and finite blobs.
    """
    initial = start()
    initial[:2, 0] = 2.5
    s = SamplerSettings(n_walkers=16, check_every=100, max_steps=600, n_draws=50)
    r = run_ensemble(_truncated, initial, N_BLOBS, seed=3, settings=s)
    x = r.samples.reshape(-1, 2)
    assert np.all(x[:, 0] <= 1.5)
    assert np.all(x[:, 1] <= 0.0)
    assert np.all(np.isfinite(r.log_prob))
    assert np.all(np.isfinite(r.blobs))


def test_wrong_number_of_walkers() -> None:
    """Starting positions must match ``n_walkers``."""
    with pytest.raises(ValueError, match="walkers"):
        run_ensemble(gaussian, start(10), N_BLOBS, seed=0, settings=SHORT)


def test_single_blob_keeps_its_axis() -> None:
    """``blobs`` has shape (n_walkers, n_draws, m) also for m = 1 (a single jump).

    A volume fraction (or a command in ``compare_commands``) with one measured jump has
    ``m = 1``; emcee squeezes length-1 blob axes, and ``run_ensemble`` returns
    ``(n_walkers, n_draws)``, which the fit cannot place into its (chain, draw, jump)
    log-likelihood array.
    """

    def one(x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        lp, blobs = gaussian(x)
        return lp, blobs[:, :1]

    r = run_ensemble(one, start(), 1, seed=0, settings=SHORT)
    assert r.blobs.shape == (16, r.samples.shape[1], 1)


# ----------------------------------------------------------------------------------------
# Checkpointing and resume
# ----------------------------------------------------------------------------------------


@pytest.fixture(scope="module")
def resume_reference() -> SamplerRun:
    """The uninterrupted run (no backend) that every resumed DE run must reproduce."""
    return run_ensemble(gaussian, start(12), N_BLOBS, seed=5, settings=RESUME)


# The initial state costs one call; a step of the stretch move two (one per half of the
# ensemble), of the DE move two or four (the snooker move splits the ensemble in four).
# With the stretch move, call 2 s + 2 is therefore the first call of step s + 1.
@pytest.mark.parametrize(
    ("moves", "interrupts", "min_stored"),
    [
        pytest.param("de", (151,), (50,), id="de-in-the-second-chunk"),
        pytest.param("de", (1,), (0,), id="de-at-the-first-call"),
        pytest.param("de", (200, 150), (50, 100), id="de-twice"),
        pytest.param("stretch", (2 * 100 + 2,), (100,), id="stretch-right-after-a-check"),
    ],
)
def test_resume_is_bit_identical(
    tmp_path: Path,
    resume_reference: SamplerRun,
    moves: str,
    interrupts: tuple[int, ...],
    min_stored: tuple[int, ...],
) -> None:
    """Interrupted (KeyboardInterrupt) and resumed runs equal an uninterrupted one, bit for bit.

    The HDF5 checkpoint stores the chain and emcee's random state after every chunk of
    ``check_every`` steps, and the convergence checks depend only on the stored chain, so
    resuming (and redoing the lost part of a chunk) must change nothing. ``min_stored``:
    steps the checkpoint must hold after each interruption (so resuming is exercised).
    The stretch run is capped at 400 steps (its tau is ~4x that of DE) to stay cheap.
    """
    settings = RESUME if moves == "de" else RESUME_STRETCH
    if moves == "de":
        reference = resume_reference
        assert reference.converged
    else:
        reference = run_ensemble(gaussian, start(12), N_BLOBS, seed=5, settings=settings)
    h5 = tmp_path / "chains.h5"
    stored = []
    for i, at in enumerate(interrupts):
        with pytest.raises(KeyboardInterrupt):
            run_ensemble(
                Counting(interrupt_at=at),
                start(12),
                N_BLOBS,
                seed=5,
                settings=settings,
                checkpoint=h5,
                resume=i > 0,
            )
        saved = load_checkpoint(h5)
        stored.append(0 if saved is None else saved.iteration)
    assert all(n >= m for n, m in zip(stored, min_stored, strict=True)), stored
    assert stored == sorted(stored)
    # 'initial' is ignored once a chunk is stored (the stored last positions are used);
    # a run interrupted before its first checkpoint starts afresh from 'initial'
    initial = np.zeros((12, 2)) if stored[-1] > 0 else start(12)
    resumed = run_ensemble(
        gaussian, initial, N_BLOBS, seed=5, settings=settings, checkpoint=h5, resume=True
    )
    assert_same_run(resumed, reference)


def test_resume_finished_run_and_reset(tmp_path: Path, resume_reference: SamplerRun) -> None:
    """Resuming a finished run does no new work; without ``resume`` it starts afresh."""
    h5 = tmp_path / "chains.h5"
    first = run_ensemble(gaussian, start(12), N_BLOBS, seed=5, settings=RESUME, checkpoint=h5)
    assert_same_run(first, resume_reference)
    fn = Counting()
    again = run_ensemble(
        fn, start(12), N_BLOBS, seed=5, settings=RESUME, checkpoint=h5, resume=True
    )
    assert fn.calls == 0
    assert_same_run(again, resume_reference)
    fresh = run_ensemble(gaussian, start(12), N_BLOBS, seed=5, settings=RESUME, checkpoint=h5)
    assert_same_run(fresh, resume_reference)
