"""Study: is the rank plot's multi-chain uniformity test calibrated on ensemble draws?

Under the null hypothesis (every ensemble samples the same distribution) a calibrated test
rejects at level alpha in a fraction alpha of the replicates. Each replicate samples a
SYNTHETIC target, a 3-D Gaussian with one correlation of 0.9, the way a fit samples:
4 independent emcee ensembles of 12 walkers, the fit's differential-evolution moves
(``granbayes._sampler``), 300 steps of which the first 100 are burn-in, started from
independent normal draws (seeds from ``numpy.random.SeedSequence(SEED)``). The thinning
step is the rank plot's: the number of draws over their smallest ESS (ArviZ's bulk and
tail ESS over every walker, as the sampler computes it). For each coordinate, ArviZ's
multi-chain test (``mchain_uniformity_test``, the p-value of ``arviz_plots.plot_rank``)
runs on:

* ``concatenated``: each ensemble's walkers concatenated step by step, every ``step``-th
  draw kept (the rank plot before this study);
* ``every walker``: every walker's draws thinned by ``step``;
* ``one walker in turn``: :func:`granbayes.stats._summaries.rank_test_draws`, the rank
  plot's draws now.

With ``--ess N``: instead, whether the ESS the stopping rule requires (ArviZ's bulk ESS with
every walker a chain) is right for means: over N replicates, the ESS against the one the
spread of the replicates' posterior means implies (variance / variance of the means).

Usage: ``python benchmarks/rank_test_calibration.py [--replicates 30] [--ess 60]`` (about
1.5 and 2 minutes on one core); writes ``benchmarks/results/rank_test_calibration.md``
(the ESS check: ``rank_test_ess.md``).
"""

from __future__ import annotations

import argparse
import json
import logging
import math
from pathlib import Path

import emcee
import numpy as np
import xarray as xr

HERE = Path(__file__).resolve().parent
SEED = 20261129
N_DIM, WALKERS, ENSEMBLES, STEPS, BURN = 3, 12, 4, 300, 100
COV = np.array([[1.0, 0.9, 0.0], [0.9, 1.0, 0.0], [0.0, 0.0, 1.0]])
ALPHAS = (0.01, 0.05, 0.2)


def _log_prob(x: np.ndarray, precision: np.ndarray) -> float:
    return -0.5 * float(x @ precision @ x)


def sample(seed: np.random.SeedSequence) -> np.ndarray:
    """One replicate: draws of shape (ensemble, kept step, walker, coordinate)."""
    from granbayes._sampler import _moves

    precision = np.linalg.inv(COV)
    chains = []
    for child in seed.spawn(ENSEMBLES):
        rng = np.random.default_rng(child)
        sampler = emcee.EnsembleSampler(
            WALKERS, N_DIM, _log_prob, args=(precision,), moves=_moves("de")
        )
        sampler._random = np.random.RandomState(int(rng.integers(2**31)))
        sampler.run_mcmc(rng.normal(size=(WALKERS, N_DIM)), STEPS, progress=False)
        chains.append(sampler.get_chain(discard=BURN))
    return np.stack(chains)


def thinning_step(draws: np.ndarray) -> int:
    """The rank plot's step: every walker's draws over the smallest ESS (bulk or tail,
    ArviZ's, walkers as chains), as :func:`granbayes.figures.plot_rank` takes it from a
    fit's ESS (:mod:`granbayes._sampler` computes it so, with the same tail probability)."""
    from arviz_stats.base import array_stats

    from granbayes._sampler import TAIL_PROB

    walkers = draws.transpose(0, 2, 1, 3).reshape(-1, draws.shape[1], draws.shape[3])
    ess = [
        float(array_stats.ess(walkers[..., d], chain_axis=0, draw_axis=1, **kwargs))
        for d in range(draws.shape[3])
        for kwargs in ({"method": "bulk"}, {"method": "tail", "prob": TAIL_PROB})
    ]
    return max(1, math.ceil(walkers.shape[0] * walkers.shape[1] / min(ess)))


def p_value(draws: np.ndarray) -> float:
    """ArviZ's multi-chain uniformity test of draws shaped (chain, draw)."""
    import arviz_stats  # noqa: F401  (the azstats accessor)

    ranks = xr.DataArray(draws, dims=("chain", "draw")).azstats.compute_ranks(
        dim=["chain", "draw"], relative=True
    )
    return float(ranks.azstats.mchain_uniformity_test(dim=["chain", "draw"])[0])


def fit_tree(draws: np.ndarray) -> xr.DataTree:
    """The draws (ensemble, step, walker) of one coordinate as a fit's DataTree."""
    post = xr.Dataset(
        {"x": (("chain", "draw"), draws.transpose(0, 2, 1).reshape(-1, draws.shape[1]))}
    )
    tree = xr.DataTree.from_dict({"posterior": post})
    tree.attrs["runs"] = json.dumps([{"n_ensembles": ENSEMBLES, "n_chains": ENSEMBLES * WALKERS}])
    return tree


def ess_check(replicates: int, out: Path) -> None:
    """The ESS of every walker as a chain against the spread of the means (module doc)."""
    from arviz_stats.base import array_stats

    means, ess = [], []
    for child in np.random.SeedSequence([SEED, 1]).spawn(replicates):
        c = sample(child)
        walkers = c.transpose(0, 2, 1, 3).reshape(-1, c.shape[1], c.shape[3])
        means.append(walkers.mean(axis=(0, 1)))
        ess.append(
            [
                float(array_stats.ess(walkers[..., d], chain_axis=0, draw_axis=1, method="bulk"))
                for d in range(N_DIM)
            ]
        )
    implied = np.diag(COV) / np.var(np.array(means), axis=0, ddof=1)
    reported = np.median(np.array(ess), axis=0)
    lines = [
        "# Is the stopping rule's ESS right for means on ensemble draws? (SYNTHETIC)",
        "",
        f"`benchmarks/rank_test_calibration.py --ess {replicates}` (seed [{SEED}, 1]): "
        f"{replicates} replicates of the rank-test study's Gaussian, sampled the same way.",
        "",
        "| coordinate | ArviZ bulk ESS, walkers as chains (median) | ESS implied by the "
        "spread of the means | ratio |",
        "|---|---:|---:|---:|",
        *(
            f"| {d} | {reported[d]:.0f} | {implied[d]:.0f} | {reported[d] / implied[d]:.2f} |"
            for d in range(N_DIM)
        ),
        "",
        f"The implied ESS is a variance estimate from {replicates} values: relative SE about "
        f"{math.sqrt(2 / (replicates - 1)):.0%}.",
    ]
    out.write_text("\n".join(lines) + "\n")
    print("\n".join(lines))


def main(argv: list[str] | None = None) -> int:
    """Run the study and write its table."""
    from granbayes.stats._summaries import rank_test_draws

    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--replicates", type=int, default=30)
    parser.add_argument("--out", type=Path, default=HERE / "results" / "rank_test_calibration.md")
    parser.add_argument("--ess", type=int, default=0, metavar="N", help="the ESS check instead")
    args = parser.parse_args(argv)
    logging.getLogger("emcee").setLevel(logging.ERROR)  # short-chain warnings of tau
    if args.ess:
        ess_check(args.ess, args.out.with_name("rank_test_ess.md"))
        return 0
    schemes = ("concatenated", "every walker", "one walker in turn")
    p = {s: [] for s in schemes}
    steps = []
    for child in np.random.SeedSequence(SEED).spawn(args.replicates):
        c = sample(child)
        step = thinning_step(c)
        steps.append(step)
        for d in range(N_DIM):
            x = c[..., d]
            p["concatenated"].append(p_value(x.reshape(ENSEMBLES, -1)[:, ::step]))
            p["every walker"].append(p_value(x[:, ::step, :].reshape(ENSEMBLES, -1)))
            p["one walker in turn"].append(
                p_value(rank_test_draws(fit_tree(x), ["x"], step)["x"].values)
            )
    n = len(p[schemes[0]])
    lines = [
        "# Is the rank plot's uniformity test calibrated on ensemble draws? (SYNTHETIC)",
        "",
        f"`benchmarks/rank_test_calibration.py --replicates {args.replicates}` (seed {SEED}): "
        f"{args.replicates} replicates x {N_DIM} coordinates = {n} p-values per scheme under "
        f"the null (every ensemble samples the same Gaussian); {ENSEMBLES} ensembles x "
        f"{WALKERS} walkers, differential-evolution moves, {STEPS - BURN} kept steps; "
        f"thinning step (draws over the smallest ESS) {min(steps)}-{max(steps)} steps.",
        "",
        "| draws given to the test | "
        + " | ".join(f"rejects at alpha = {a:g}" for a in ALPHAS)
        + " | draws per ensemble |",
        "|---|" + "---|" * (len(ALPHAS) + 1),
    ]
    per_ensemble = {
        "concatenated": f"{(STEPS - BURN) * WALKERS // int(np.median(steps))}",
        "every walker": f"{math.ceil((STEPS - BURN) / np.median(steps)) * WALKERS}",
        "one walker in turn": f"{math.ceil((STEPS - BURN) / np.median(steps))}",
    }
    for s in schemes:
        v = np.asarray(p[s])
        rates = [f"{np.mean(v < a):.3f} ({int(np.sum(v < a))}/{n})" for a in ALPHAS]
        lines.append(f"| {s} | " + " | ".join(rates) + f" | {per_ensemble[s]} |")
    se = [f"{math.sqrt(a * (1 - a) / n):.3f}" for a in ALPHAS]
    lines += [
        "",
        f"A calibrated test rejects in a fraction alpha (binomial SE at these alphas: "
        f"{', '.join(se)}, if the {n} p-values were independent; the {N_DIM} coordinates of "
        "a replicate are not).",
    ]
    args.out.write_text("\n".join(lines) + "\n")
    print("\n".join(lines))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
