"""A seeded fake fit: a DataTree with every group of a real fit, made without a sampler."""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np
import pandas as pd
import xarray as xr

from .._experiment import Experiment

__all__ = ["fake_fit"]


def fake_fit(
    seed: int = 0,
    *,
    terms: Sequence[str] = ("depth", "drag"),
    phis: Sequence[float] = (0.602, 0.622),
    commands: Sequence[str] = ("single", "preload", "stutter"),
    freqs_hz: Sequence[float] = (8.0, 12.0),
    trials: int = 3,
    n_ensembles: int = 2,
    n_walkers: int = 4,
    n_draws: int = 50,
    n_prior_draws: int = 40,
) -> xr.DataTree:
    """A seeded fit's DataTree, made without a sampler or a simulator (SYNTHETIC).

    It has every group (``posterior``, ``log_likelihood``, ``posterior_predictive``,
    ``observed_data``, ``sample_stats``, ``prior``, ``prior_predictive``, ``log_prior``),
    variable, dimension, unit and attribute of a fit of ``granbayes.fit`` with the same
    design (``tests/test_testing.py`` checks it against a real one), so statistics,
    figures and reports can be tested without sampling. The numbers are consistent but not
    physical: the posterior is Gaussian about a plausible law per volume fraction, the
    simulated height of a cell is a linear surrogate in the parameters, the log-likelihood
    is the Gaussian observation model's, the measured heights are drawn from it (their
    ``source`` says SYNTHETIC), and the run records say converged.

    Parameters
    ----------
    seed : int
        Seed of every draw.
    terms : sequence of str
        Force terms of the law (``depth`` always included).
    phis, commands, freqs_hz : sequences
        The design.
    trials : int
        Jumps per cell.
    n_ensembles, n_walkers : int
        Ensembles per run and walkers per ensemble (chains = their product).
    n_draws : int
        Draws per chain.
    n_prior_draws : int
        Prior draws (0: no ``prior`` and ``prior_predictive`` groups).

    Returns
    -------
    xarray.DataTree
    """
    import dataclasses

    from .. import stats
    from .._datatree import build_datatree
    from .._fitting import FitSettings, _variable_attrs, data_hash
    from .._priors import default_priors
    from .._provenance import environment
    from ..forces import TERMS, terms_of

    rng = np.random.default_rng(seed)
    terms = terms_of(terms)
    names = tuple(p.name for t in terms for p in TERMS[t].parameters)
    phis = np.asarray(sorted(phis), dtype=float)
    exp = Experiment()
    rows = [
        {
            "phi": phi,
            "command": command,
            "freq_hz": freq,
            "amplitude_mm": exp.command.amplitude_mm,
            "delay_ms": exp.command.delay_ms,
            "settle_periods": exp.command.settle_periods,
            "trial": trial,
        }
        for phi in phis
        for freq in freqs_hz
        for command in commands
        for trial in range(1, trials + 1)
    ]
    observed = pd.DataFrame(rows)
    n_jump = len(observed)
    n_chain = n_ensembles * n_walkers
    priors = default_priors()
    # a plausible law per volume fraction and the surrogate's slopes per cell
    centre = {
        name: np.array([_fake_centre(name, phi) for phi in phis]) for name in (*names, "sigma_mm")
    }
    cell = observed.groupby(["phi", "command", "freq_hz"], sort=False).ngroup().to_numpy()
    n_cell = int(cell.max()) + 1
    base_mm = rng.uniform(20.0, 80.0, n_cell)
    slope = {name: rng.normal(0.0, 1.0, n_cell) for name in names}
    phi_col = np.searchsorted(phis, observed["phi"].to_numpy(dtype=float))

    def draw(n: int, spread: float) -> dict[str, np.ndarray]:
        out = {}
        for name, c in centre.items():
            scale = spread * (np.abs(c) + (1.0 if name != "k" else 0.0))
            v = c[None, None, :] + scale * rng.standard_normal((n_chain, n, len(phis)))
            lo = priors[name].lower if name in priors else 0.0
            out[name] = np.maximum(v, lo + 1e-9) if name != "r_unload" else np.maximum(v, 1.0)
        return out

    def simulate(values: dict[str, np.ndarray]) -> np.ndarray:
        sim = base_mm[cell][None, None, :].repeat(values["sigma_mm"].shape[1], axis=1)
        sim = np.broadcast_to(sim, (values["sigma_mm"].shape[0], *sim.shape[1:])).copy()
        for name in names:
            rel = values[name][..., phi_col] / np.where(
                centre[name][phi_col] == 0.0, 1.0, centre[name][phi_col]
            )
            sim += slope[name][cell] * 5.0 * (rel - 1.0)
        return sim

    post = draw(n_draws, 0.02)
    sim = simulate(post)
    sigma_jump = post["sigma_mm"][..., phi_col]
    true_sim = simulate({k: v[:1, :1] * 0 + centre[k][None, None, :] for k, v in post.items()})
    y = true_sim[0, 0] + centre["sigma_mm"][phi_col] * rng.standard_normal(n_jump)
    observed["height_mm"] = np.round(y, 3)
    observed["source"] = f"synthetic: granbayes.testing.fake_fit seed={seed}"
    r = (y[None, None, :] - sim) / sigma_jump
    log_lik = -0.5 * r * r - np.log(sigma_jump) - 0.5 * math.log(2.0 * math.pi)
    rep = sim + sigma_jump * rng.standard_normal(sim.shape)
    prior, prior_pred = {}, {}
    if n_prior_draws:
        prior = draw(n_prior_draws, 0.3)
        prior = {k: v[:1] for k, v in prior.items()}
        psim = simulate(prior)
        prior_pred = {
            "height_mm": psim + prior["sigma_mm"][..., phi_col] * rng.standard_normal(psim.shape)
        }
    lp = log_lik.reshape(n_chain, n_draws, -1)
    lp_run = np.stack([lp[..., phi_col == i].sum(axis=-1) for i in range(len(phis))], axis=-1)
    labels = [f"phi={phi:g}" for phi in phis]
    coords = [*names, "sigma_mm"]
    run = {
        "n_ensembles": n_ensembles,
        "n_chains": n_chain,
        "tau": [[10.0] * len(coords)] * n_ensembles,
        "rhat": [1.004] * len(coords),
        "ess_bulk": [450.0] * len(coords),
        "ess_tail": [420.0] * len(coords),
        "n_steps": 300,
        "burn": [30] * n_ensembles,
        "thin": 2,
        "acceptance": 0.35,
        "converged": True,
        "warnings": [],
    }
    config = FitSettings(terms=terms, n_prior_draws=n_prior_draws)
    table = observed.drop(columns=["height_mm"]).assign(height_mm=observed["height_mm"])
    attrs = {
        "seed": int(seed),
        **environment(),
        "config": config.to_dict(),
        "priors": {k: dataclasses.asdict(v) for k, v in priors.items()},
        "calibrated": {},  # a robot known exactly
        "data_sha256": data_hash(exp, table),
        "data_source": "granbayes.testing.fake_fit (SYNTHETIC)",
        "experiment": {
            "robot": dataclasses.asdict(exp.robot),
            "command": dataclasses.asdict(exp.command),
            "phi_c": exp.phi_c,
            "uncertainty": exp.uncertainty,
            "phi_sd": exp.phi_sd,
        },
        "parameters": list(names),
        "runs": [
            {
                "label": label,
                "coordinates": [*names, f"sigma_mm[{phi:g}]"],
                **run,
            }
            for label, phi in zip(labels, phis, strict=True)
        ],
        "converged": True,
        "warnings": [],
        "interval": f"{stats.CI_PROB:.0%} equal-tailed",
        "log_prior": "density of the reported parameter values, summed over runs",
    }
    return build_datatree(
        post,
        dims={name: ["phi"] for name in post},
        coords={"phi": phis, "run": labels},
        log_likelihood=log_lik,
        posterior_predictive={"height_mm": rep, "height_sim_mm": sim},
        observed=observed,
        sample_stats={"lp": lp_run},
        attrs=attrs,
        stats_dims={"lp": ["run"]},
        prior=prior,
        prior_predictive=prior_pred,
        log_prior={"log_prior": rng.normal(-10.0, 1.0, (n_chain, n_draws))},
        var_attrs=_variable_attrs(names),
    )


def _fake_centre(name: str, phi: float) -> float:
    """A plausible value of a parameter at ``phi`` for :func:`fake_fit` [SI; mm for sigma]."""
    x = phi - 0.612
    values = {
        "k": 4000.0 + 1.5e5 * x + 2.0e6 * x * x,
        "c_d": 20.0,
        "kappa": 1.0,
        "k2": 1.0e5,
        "b": 20.0,
        "c_comp": 0.5,
        "r_unload": 20.0,
        "sigma_mm": 3.0,
    }
    return values.get(name, 1.0)
