"""Study: does the ``de`` moves' snooker update sample its target? emcee 3.1.6's does not.

Two parts, both SYNTHETIC:

a. **A standard normal** in 3, 5, 8 and 13 dimensions (the fits' sizes: heights alone per
   volume fraction, with the robot's copies, the joint fit, the pooled calibration),
   sampled by emcee's own ``EnsembleSampler`` with the fit's mixture (80% differential
   evolution, 20% snooker; ``max(32, 4 d)`` walkers, 4,000 steps, the first 500 dropped)
   with emcee 3.1.6's ``DESnookerMove`` and with granbayes's ``SnookerMove`` (the fix of
   dfm/emcee#531), and the snooker update alone in 8 dimensions. Reported: the mean
   standard deviation per coordinate (1 if right) and the target's mass inside the
   sample's 90% equal-tailed interval (0.90 if right).
b. **The joint fit's force noise** (``--replicates``: replicates of ``sbc_joint.py``'s
   design and seed 20261129, refitted by ``granbayes.fit``). Given the law and the robot,
   the posterior of ``force_sd_N`` is known in closed form: with ``N`` force readings of
   residual sum of squares ``R`` and its log-uniform prior, ``1 / force_sd_N^2`` is
   Gamma(``N / 2``, rate ``R / 2``) truncated to the prior's range. For every kept draw,
   the conditional CDF at the draw's own ``force_sd_N`` (a probability integral
   transform, PIT) is uniform if the sampler samples the joint posterior; a PIT piled in
   the middle means draws too rarely in the tails. Each draw's ``R`` comes from its
   intrusion curves' log-likelihood. Reported per replicate: the PIT's deciles' counts,
   the share in the outer tenths (0.2 if right) and the sampled standard deviation of
   ``log force_sd_N`` against the conditional one, ``1 / sqrt(2 N)`` (the marginal can
   only be wider).

Usage: ``python benchmarks/snooker_move.py [--replicates 48,9] [--seed 0] [--fit-snooker
emcee --name before]`` (part a about 2 minutes on one core, part b about a minute per
replicate; ``--fit-snooker emcee`` refits part b with emcee 3.1.6's update, as every fit
was made before); writes ``benchmarks/results/snooker_move[_NAME].md`` and ``.json``.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import tempfile
from pathlib import Path

import emcee
import numpy as np
from scipy import stats as st

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))

from _machine import machine_info, machine_markdown  # noqa: E402

from granbayes._sampler import SnookerMove  # noqa: E402

#: The master seed of ``sbc_joint.py``'s fresh data sets.
JOINT_SEED = 20261129


def normal_case(ndim: int, snooker: type, alone: bool, seed: int) -> dict:
    """Sample a standard normal with the fit's mixture (or the snooker update alone)."""
    n_walkers = max(32, 4 * ndim)
    moves = [(snooker(), 1.0)] if alone else [(emcee.moves.DEMove(), 0.8), (snooker(), 0.2)]
    sampler = emcee.EnsembleSampler(
        n_walkers, ndim, lambda x: -0.5 * np.sum(x * x, axis=1), vectorize=True, moves=moves
    )
    sampler.random_state = np.random.RandomState(seed).get_state()
    rng = np.random.default_rng(seed)
    sampler.run_mcmc(rng.standard_normal((n_walkers, ndim)), 4000, progress=False)
    x = sampler.get_chain(discard=500).reshape(-1, ndim)
    lo, hi = np.quantile(x, [0.05, 0.95], axis=0)
    mass = st.norm.cdf(hi) - st.norm.cdf(lo)
    return {
        "ndim": ndim,
        "snooker": "emcee 3.1.6" if snooker is emcee.moves.DESnookerMove else "granbayes",
        "moves": "snooker alone" if alone else "80% DE + 20% snooker",
        "walkers": n_walkers,
        "sd": float(np.mean(np.std(x, axis=0))),
        "mass_in_90": float(np.mean(mass)),
    }


def force_noise_case(replicate: int, folder: Path) -> dict:
    """Refit a joint-SBC replicate and check ``force_sd_N`` against its conditional."""
    import sbc_joint as sj

    from granbayes import default_priors, load_experiment, load_measurements
    from granbayes._fitting import FitSettings, fit
    from granbayes._likelihood._model import evaluate_models
    from granbayes._sampler import SamplerSettings
    from granbayes._sbc import draw_measurements
    from granbayes.campaign import spawn_seeds

    folder = sj.design_folder(folder)
    experiment = load_experiment(folder)
    design = load_measurements(folder, experiment)
    priors = {**default_priors(), **sj.NOISE_PRIORS}
    settings = FitSettings(terms=sj.TERMS, sampler=SamplerSettings())
    replicate_seed = spawn_seeds(JOINT_SEED, max(50, replicate + 1))[replicate]
    truth_seed, fit_seed = spawn_seeds(replicate_seed, 2)
    table, _ = draw_measurements(
        experiment, design, settings, priors, np.random.default_rng(truth_seed)
    )
    part = fit(experiment, table, settings, seed=fit_seed, priors=priors).parts[0]
    model, run = part.model, part.run
    u = run.samples.reshape(-1, model.ndim)
    sd = model.parameter_values(u)["force_sd_N"][:, 0]
    kinds = [b.kind for b in model.blocks]
    edges = np.cumsum([0] + [b.n_units for b in model.blocks])
    i = kinds.index("intrusions")
    log_lik = evaluate_models([model], [u])[0].log_lik[:, edges[i] : edges[i + 1]].sum(axis=1)
    n = len(table.tables["intrusions"])
    rss = -2.0 * sd**2 * (log_lik + 0.5 * n * np.log(2.0 * math.pi * sd**2))
    prior = priors["force_sd_N"]
    gamma = st.gamma(a=n / 2.0, scale=2.0 / rss)
    top, bottom = gamma.cdf(1.0 / prior.lower**2), gamma.cdf(1.0 / prior.upper**2)
    pit = (top - gamma.cdf(1.0 / sd**2)) / (top - bottom)
    counts = np.histogram(pit, bins=10, range=(0.0, 1.0))[0]
    return {
        "replicate": replicate,
        "readings": n,
        "draws": len(sd),
        "n_steps": int(run.n_steps),
        "converged": bool(run.converged),
        "pit_deciles": counts.tolist(),
        "pit_outer_tenths": float((counts[0] + counts[-1]) / counts.sum()),
        "sd_log_force_sd": float(np.std(np.log(sd))),
        "conditional_sd_log_force_sd": 1.0 / math.sqrt(2.0 * n),
    }


def main(argv: list[str] | None = None) -> int:
    """Run both parts and write the report."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seed", type=int, default=0, help="seed of part a")
    parser.add_argument(
        "--replicates", default="48,9", help="joint-SBC replicates of part b ('' for none)"
    )
    parser.add_argument(
        "--fit-snooker",
        choices=("granbayes", "emcee"),
        default="granbayes",
        help="the snooker update of part b's fits ('emcee': the fits as they were before it)",
    )
    parser.add_argument("--name", help="results named snooker_move_NAME")
    args = parser.parse_args(argv)
    if args.fit_snooker == "emcee":  # the fits before granbayes replaced emcee's update
        import granbayes._sampler

        granbayes._sampler.SnookerMove = emcee.moves.DESnookerMove
    normal = [
        normal_case(d, s, False, args.seed)
        for d in (3, 5, 8, 13)
        for s in (emcee.moves.DESnookerMove, SnookerMove)
    ]
    normal += [normal_case(8, s, True, args.seed) for s in (emcee.moves.DESnookerMove, SnookerMove)]
    reps = [int(r) for r in args.replicates.split(",") if r.strip()]
    with tempfile.TemporaryDirectory() as tmp:
        force = [force_noise_case(r, Path(tmp) / "design") for r in reps]
    info = machine_info(("numpy", "emcee", "numba"))
    stem = "snooker_move" + (f"_{args.name}" if args.name else "")
    out = {
        "normal": normal,
        "force_noise": force,
        "fit_snooker": args.fit_snooker,
        "seed": args.seed,
        "machine": info,
    }
    (HERE / "results").mkdir(exist_ok=True)
    (HERE / "results" / f"{stem}.json").write_text(json.dumps(out, indent=1) + "\n")
    lines = [
        "# The snooker update: emcee 3.1.6's against granbayes's (SYNTHETIC targets)",
        "",
        f"`benchmarks/snooker_move.py --seed {args.seed} --replicates {args.replicates} "
        f"--fit-snooker {args.fit_snooker}`.",
        "",
        "## a. A standard normal (4,000 steps, the first 500 dropped)",
        "",
        "| dimensions | moves | snooker update | walkers | sd per coordinate (1) "
        "| target mass in the sample's 90% interval (0.90) |",
        "|---|---|---|---|---|---|",
    ]
    lines += [
        f"| {r['ndim']} | {r['moves']} | {r['snooker']} | {r['walkers']} | {r['sd']:.3f} "
        f"| {r['mass_in_90']:.3f} |"
        for r in normal
    ]
    if force:
        lines += [
            "",
            "## b. The joint fit's force noise against its closed-form conditional",
            "",
            f"Replicates of `sbc_joint.py`'s design, seed {JOINT_SEED}, refitted with "
            + (
                "the code as it is"
                if args.fit_snooker == "granbayes"
                else "emcee 3.1.6's snooker update in the fit's moves (the fits before)"
            )
            + ". PIT: the conditional CDF of each kept draw's `force_sd_N` given "
            "its law (uniform if the joint posterior is sampled; outer tenths 0.2).",
            "",
            "| replicate | readings | draws | steps | converged | PIT deciles | outer tenths "
            "| sd of log force_sd_N | conditional sd |",
            "|---|---|---|---|---|---|---|---|---|",
        ]
        lines += [
            f"| {r['replicate']} | {r['readings']} | {r['draws']} | {r['n_steps']} "
            f"| {r['converged']} | {' '.join(map(str, r['pit_deciles']))} "
            f"| {r['pit_outer_tenths']:.3f} | {r['sd_log_force_sd']:.4f} "
            f"| {r['conditional_sd_log_force_sd']:.4f} |"
            for r in force
        ]
    lines += ["", *machine_markdown(info)]
    (HERE / "results" / f"{stem}.md").write_text("\n".join(lines) + "\n")
    print("\n".join(lines))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
