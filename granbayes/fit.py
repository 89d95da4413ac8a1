"""The Bayesian fit: joint posteriors of the force law per volume fraction.

:func:`fit` infers the force-term parameters from measured jump heights:

* ``phi_mode="per_phi"`` (default): at every volume fraction one parameter set shared by
  all five commands, plus that volume fraction's scatter, sampled independently;
* ``phi_mode="quadratic"``: every coefficient a quadratic in ``phi - phi_c`` (the thesis's
  ``k(phi)``), fitted jointly over all volume fractions.

:func:`compare_commands` answers the thesis's question "one force law for every jump?":
per volume fraction, the shared law against separate laws per command, by PSIS-LOO.

Every fit derives its seeds from one master seed (``numpy.random.SeedSequence``), so the
same seed gives bit-identical posteriors, including after ``resume``.
"""

from __future__ import annotations

import dataclasses
import hashlib
import importlib.metadata
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import pandas as pd
import xarray as xr
from scipy.optimize import minimize

from . import datatree as gdt
from .experiment import COMMAND_NAMES, Experiment
from .forces import terms_of
from .likelihood import JumpModel, Observations
from .priors import Prior, default_priors
from .sampler import SamplerRun, SamplerSettings, run_ensemble
from .simulator import SolverOptions

__all__ = [
    "FitConfig",
    "FitPart",
    "FitResult",
    "compare_commands",
    "data_hash",
    "find_start",
    "fit",
]


def _default_sampler() -> SamplerSettings:
    return SamplerSettings(n_walkers=16, check_every=100, n_draws=125)


@dataclass(frozen=True)
class FitConfig:
    """What to fit and how.

    Parameters
    ----------
    terms : tuple of str
        Force terms (``depth`` always included).
    phi_mode : {"per_phi", "quadratic"}
        Independent parameters per volume fraction, or quadratic laws in ``phi - phi_c``.
    noise : {"normal", "student_t"}
        Noise family (Student-t: heavy-tailed, ``nu`` degrees of freedom).
    nu : float
        Student-t degrees of freedom.
    sigma_mode : {"per_phi", "global"}
        Scatter per volume fraction or one for all (``per_phi`` mode always per phi).
    sampler : SamplerSettings
        Ensemble size, chain-length rule, kept draws.
    fixed : mapping of str to float
        Parameters held at given values instead of their ``absent`` value.
    options : SolverOptions
        Integrator settings.
    n_threads : int, optional
        numba threads for the simulator.
    """

    terms: tuple[str, ...] = ("depth",)
    phi_mode: str = "per_phi"
    noise: str = "normal"
    nu: float = 4.0
    sigma_mode: str = "per_phi"
    sampler: SamplerSettings = field(default_factory=_default_sampler)
    fixed: Mapping[str, float] = field(default_factory=dict)
    options: SolverOptions = field(default_factory=SolverOptions)
    n_threads: int | None = None

    def __post_init__(self) -> None:
        object.__setattr__(self, "terms", terms_of(self.terms))
        if self.phi_mode not in ("per_phi", "quadratic"):
            raise ValueError(f"phi_mode must be 'per_phi' or 'quadratic', got {self.phi_mode!r}")

    def to_dict(self) -> dict:
        """JSON-ready description (stored in the DataTree attributes)."""
        d = dataclasses.asdict(self)
        d["terms"] = list(self.terms)
        d["fixed"] = dict(self.fixed)
        return d


@dataclass
class FitPart:
    """One ensemble run: a model and its samples."""

    label: str
    model: JumpModel
    run: SamplerRun
    jumps: np.ndarray  # rows of the full table this part fitted


@dataclass
class FitResult:
    """A finished fit.

    Attributes
    ----------
    datatree : xarray.DataTree
        Posterior, log-likelihood, posterior predictive, observed data, sample stats and
        provenance attributes.
    parts : list of FitPart
        The ensemble runs (one per volume fraction, or one).
    config : FitConfig
    seed : int
    warnings : list of str
        Convergence problems, in words.
    """

    datatree: xr.DataTree
    parts: list[FitPart]
    config: FitConfig
    seed: int
    warnings: list[str]

    def diagnostics(self) -> pd.DataFrame:
        """Per run: autocorrelation times, chain length, acceptance, convergence."""
        rows = []
        for part in self.parts:
            r = part.run
            rows.append(
                {
                    "run": part.label,
                    "n_walkers": r.samples.shape[0],
                    "n_steps": r.n_steps,
                    "tau_max": float(np.max(r.tau)),
                    "steps_over_tau": float((r.n_steps - r.burn) / np.max(r.tau)),
                    "burn": r.burn,
                    "first_kept": r.first,
                    "thin": r.thin,
                    "acceptance": float(np.mean(r.acceptance)),
                    "converged": r.converged,
                    **{
                        f"tau[{n}]": float(t)
                        for n, t in zip(part.model.coordinate_names, r.tau, strict=True)
                    },
                }
            )
        return pd.DataFrame(rows)


# ----------------------------------------------------------------------------------------
def find_start(model: JumpModel, rng: np.random.Generator, n_walkers: int) -> np.ndarray:
    """Starting positions: best of a prior sample, polished by Nelder-Mead, plus a ball.

    Parameters
    ----------
    model : JumpModel
        The log-posterior.
    rng : numpy.random.Generator
        Source of randomness.
    n_walkers : int
        Ensemble size.

    Returns
    -------
    ndarray, shape (n_walkers, ndim)
    """
    ndim = model.ndim
    draws = model.sample_prior(rng, min(64 * ndim, 512))
    lp, _ = model(draws)
    best = draws[int(np.argmax(lp))]

    def neg(u: np.ndarray) -> float:
        value = model(u[None, :])[0][0]
        return -value if np.isfinite(value) else 1e300

    res = minimize(
        neg,
        best,
        method="Nelder-Mead",
        options={"maxfev": 150 * ndim, "xatol": 1e-5, "fatol": 1e-4},
    )
    x0 = res.x if res.fun < -lp.max() + 1e-9 else best
    widths = np.diff(model.bounds_u, axis=1)[:, 0]
    out = np.empty((0, ndim))
    while len(out) < n_walkers:
        ball = x0 + 1e-3 * widths * rng.standard_normal((n_walkers, ndim))
        out = np.concatenate([out, ball[np.isfinite(model.log_prior(ball))]])
    return out[:n_walkers]


def _seeds(seed: int, n: int) -> list[int]:
    return [int(s.generate_state(1)[0]) for s in np.random.SeedSequence(seed).spawn(n)]


def _run_part(
    label: str,
    model: JumpModel,
    jumps: np.ndarray,
    config: FitConfig,
    seed: int,
    backend: Path | None,
    resume: bool,
) -> FitPart:
    rng = np.random.default_rng(seed)
    s = config.sampler
    checkpoint = None if backend is None else Path(backend) / f"{label}.h5"
    resuming = resume and checkpoint is not None and checkpoint.exists()
    initial = (
        np.zeros((s.n_walkers, model.ndim)) if resuming else find_start(model, rng, s.n_walkers)
    )
    if checkpoint is not None:
        checkpoint.parent.mkdir(parents=True, exist_ok=True)
    run = run_ensemble(
        model,
        initial,
        model.obs.n_obs,
        seed=seed,
        settings=s,
        checkpoint=checkpoint,
        resume=resume,
        fingerprint=_fingerprint(model, config, seed),
    )
    return FitPart(label, model, run, jumps)


def _fingerprint(model: JumpModel, config: FitConfig, seed: int) -> str:
    """What a checkpoint must match to be resumed: data, priors, model and settings."""
    h = hashlib.sha256()
    h.update(data_hash(model.experiment, model.obs.table).encode())
    h.update(repr(sorted((k, dataclasses.astuple(v)) for k, v in model.priors.items())).encode())
    h.update(repr((model.coordinate_names, config.to_dict(), seed)).encode())
    return h.hexdigest()


def _prepare(table: pd.DataFrame) -> pd.DataFrame:
    table = table.reset_index(drop=True).copy()
    table["jump"] = np.arange(len(table))
    return table


def _make_model(
    obs: Observations, experiment: Experiment, config: FitConfig, priors, phi_mode: str
) -> JumpModel:
    return JumpModel(
        obs,
        experiment,
        config.terms,
        priors=priors,
        phi_mode=phi_mode,
        noise=config.noise,
        nu=config.nu,
        sigma_mode=config.sigma_mode if phi_mode == "quadratic" else "per_phi",
        fixed=config.fixed,
        options=config.options,
        n_threads=config.n_threads,
    )


def fit(
    experiment: Experiment,
    table: pd.DataFrame,
    config: FitConfig | None = None,
    *,
    seed: int = 0,
    priors: Mapping[str, Prior] | None = None,
    backend: str | Path | None = None,
    resume: bool = False,
    data_source: str = "",
) -> FitResult:
    """Fit a force law to measured jump heights.

    Parameters
    ----------
    experiment : Experiment
        Robot, command defaults and ``phi_c``.
    table : pandas.DataFrame
        Validated jumps (:func:`granbayes.load_jumps`).
    config : FitConfig, optional
        Terms, parametrisation, noise, sampler settings.
    seed : int
        Master seed; recorded in the result.
    priors : mapping of str to Prior, optional
        Priors (default: :func:`granbayes.priors.default_priors`).
    backend : str or Path, optional
        Folder of HDF5 checkpoints (one file per run, ``<label>.h5``).
    resume : bool
        Continue the runs stored in ``backend``.
    data_source : str
        Where the data came from (recorded).

    Returns
    -------
    FitResult
    """
    config = config or FitConfig()
    priors = dict(priors if priors is not None else default_priors())
    table = _prepare(table)
    backend = Path(backend) if backend is not None else None
    parts: list[FitPart] = []
    if config.phi_mode == "per_phi":
        phis = np.unique(table["phi"].to_numpy(float))
        for phi, part_seed in zip(phis, _seeds(seed, len(phis)), strict=True):
            sub = table[table["phi"] == phi]
            obs = Observations.from_table(sub)
            model = _make_model(obs, experiment, config, priors, "shared")
            parts.append(
                _run_part(
                    f"phi={phi:g}",
                    model,
                    sub["jump"].to_numpy(),
                    config,
                    part_seed,
                    backend,
                    resume,
                )
            )
    else:
        obs = Observations.from_table(table)
        model = _make_model(obs, experiment, config, priors, "quadratic")
        parts.append(
            _run_part(
                "all", model, table["jump"].to_numpy(), config, _seeds(seed, 1)[0], backend, resume
            )
        )
    return _assemble(parts, experiment, table, config, priors, seed, data_source)


# ----------------------------------------------------------------------------------------
def _replicate(part: FitPart, seed: int) -> tuple[np.ndarray, np.ndarray]:
    """Simulated mean heights and noisy replicates for the kept draws: (chain, draw, obs)."""
    model, run = part.model, part.run
    c, d, ndim = run.samples.shape
    flat = run.samples.reshape(-1, ndim)
    heights, _ = model.predict(flat)
    mean = heights[:, model.obs.config_of_obs]
    phi_idx = np.searchsorted(model.phis, model.obs.table["phi"].to_numpy(float))
    sigma = model.parameter_values(flat)["sigma_mm"][:, phi_idx]
    rng = np.random.default_rng(seed)
    if model.noise == "normal":
        eps = rng.standard_normal(mean.shape)
    else:
        eps = rng.standard_t(model.nu, mean.shape)
    rep = mean + sigma * eps
    return mean.reshape(c, d, -1), rep.reshape(c, d, -1)


def _versions() -> dict[str, str]:
    out = {}
    for pkg in ("granbayes", "numpy", "scipy", "numba", "emcee", "arviz", "xarray"):
        try:
            out[pkg] = importlib.metadata.version(pkg)
        except importlib.metadata.PackageNotFoundError:
            out[pkg] = "unknown"
    return out


def data_hash(experiment: Experiment, table: pd.DataFrame) -> str:
    """SHA-256 of the experiment settings and the jumps table (provenance)."""
    h = hashlib.sha256()
    h.update(repr((experiment.robot, experiment.command, experiment.phi_c)).encode())
    h.update(table.to_csv(index=False).encode())
    return h.hexdigest()


def _assemble(
    parts: list[FitPart],
    experiment: Experiment,
    table: pd.DataFrame,
    config: FitConfig,
    priors: Mapping[str, Prior],
    seed: int,
    data_source: str,
) -> FitResult:
    n_chain = parts[0].run.samples.shape[0]
    n_draw = min(p.run.samples.shape[1] for p in parts)
    n_jump = len(table)
    phis = np.unique(table["phi"].to_numpy(float))
    names = parts[0].model.parameters
    post: dict[str, np.ndarray] = {
        n: np.full((n_chain, n_draw, len(phis)), np.nan) for n in (*names, "sigma_mm")
    }
    dims: dict[str, list[str]] = {n: ["phi"] for n in post}
    loglik = np.full((n_chain, n_draw, n_jump), np.nan)
    sim = np.full_like(loglik, np.nan)
    rep = np.full_like(loglik, np.nan)
    lp = np.full((n_chain, n_draw, len(parts)), np.nan)
    rep_seeds = _seeds(seed + 1, len(parts))
    for i, part in enumerate(parts):
        r = part.run
        samples = r.samples[:, -n_draw:]
        flat = samples.reshape(-1, samples.shape[-1])
        values = part.model.parameter_values(flat, phis)
        cols = np.searchsorted(phis, part.model.phis)
        for n in post:
            v = values[n].reshape(n_chain, n_draw, len(phis))
            post[n][..., cols] = v[..., cols]
        loglik[..., part.jumps] = r.blobs[:, -n_draw:]
        trimmed = dataclasses.replace(part, run=dataclasses.replace(r, samples=samples))
        m, y = _replicate(trimmed, rep_seeds[i])
        sim[..., part.jumps] = m
        rep[..., part.jumps] = y
        lp[..., i] = r.log_prob[:, -n_draw:]
        if config.phi_mode == "quadratic":
            for j, cname in enumerate(part.model.coordinate_names):
                if ":c" in cname:
                    pname, order = cname.split(":c")
                    key = f"{pname}_coef"
                    post.setdefault(key, np.zeros((n_chain, n_draw, 3)))[..., int(order)] = samples[
                        ..., j
                    ]
                    dims[key] = ["order"]
    coords = {"phi": phis, "order": np.arange(3), "run": [p.label for p in parts]}
    observed = table.drop(columns=["jump"])
    warnings_ = [
        f"run {p.label}: not converged after {p.run.n_steps} steps "
        f"(needs {config.sampler.tau_factor:g} x tau = "
        f"{config.sampler.tau_factor * np.max(p.run.tau):.0f} steps after burn-in); "
        "raise --max-steps"
        for p in parts
        if not p.run.converged
    ]
    attrs = {
        "seed": int(seed),
        "versions": _versions(),
        "config": config.to_dict(),
        "priors": {k: dataclasses.asdict(v) for k, v in priors.items()},
        "data_sha256": data_hash(experiment, observed),
        "data_source": data_source,
        "experiment": {
            "robot": dataclasses.asdict(experiment.robot),
            "command": dataclasses.asdict(experiment.command),
            "phi_c": experiment.phi_c,
        },
        "runs": [
            {
                "label": p.label,
                "coordinates": p.model.coordinate_names,
                "tau": p.run.tau.tolist(),
                "n_steps": p.run.n_steps,
                "burn": p.run.burn,
                "first_kept": p.run.first,
                "thin": p.run.thin,
                "acceptance": float(np.mean(p.run.acceptance)),
                "converged": p.run.converged,
            }
            for p in parts
        ],
        "interval": f"{gdt.CI_PROB:.0%} equal-tailed",
    }
    dt = gdt.build_datatree(
        post,
        dims=dims,
        coords=coords,
        log_likelihood=loglik,
        posterior_predictive={"height_mm": rep, "height_sim_mm": sim},
        observed=observed,
        sample_stats={"lp": lp},
        attrs=attrs,
        stats_dims={"lp": ["run"]},
    )
    return FitResult(dt, parts, config, seed, warnings_)


# ----------------------------------------------------------------------------------------
def compare_commands(
    experiment: Experiment,
    table: pd.DataFrame,
    shared: FitResult,
    *,
    seed: int = 0,
    priors: Mapping[str, Prior] | None = None,
    ci_prob: float = gdt.CI_PROB,
    details: bool = False,
) -> pd.DataFrame | tuple[pd.DataFrame, pd.DataFrame]:
    """One force law for all commands, or one per command? Per volume fraction.

    For every volume fraction fitted in ``shared`` (``per_phi`` mode), fits each command
    separately with the same terms and priors and compares the two models by PSIS-LOO.
    Posterior overlap: whether the per-command ``ci_prob`` intervals of each parameter
    share a common value.

    Parameters
    ----------
    experiment : Experiment
    table : pandas.DataFrame
        The jumps that ``shared`` was fitted to.
    shared : FitResult
        A ``per_phi`` fit.
    seed : int
        Master seed of the per-command fits.
    priors : mapping, optional
    ci_prob : float
        Interval probability for the overlap check.
    details : bool
        Also return the per-command posterior intervals.

    Returns
    -------
    pandas.DataFrame
        One row per volume fraction: ``elpd_shared``, ``elpd_per_command``, ``elpd_diff``
        (shared minus per-command), ``elpd_diff_se``, max Pareto k of both, the preferred
        model, and per parameter whether the per-command intervals overlap.
    pandas.DataFrame
        Only with ``details``: one row per volume fraction, command and parameter with the
        posterior ``median``, ``lo`` and ``hi`` (``ci_prob`` equal-tailed) of the
        per-command fit.
    """
    if shared.config.phi_mode != "per_phi":
        raise ValueError("compare_commands needs a per_phi fit")
    priors = dict(priors if priors is not None else default_priors())
    table = _prepare(table)
    config = shared.config
    rows = []
    per_command_rows = []
    seeds = iter(_seeds(seed + 7, 5 * len(shared.parts)))
    for part in shared.parts:
        phi = float(part.model.phis[0])
        sub_parts = []
        for command in COMMAND_NAMES:
            sub = table[(table["phi"] == phi) & (table["command"] == command)]
            if sub.empty:
                continue
            obs = Observations.from_table(sub)
            model = _make_model(obs, experiment, config, priors, "shared")
            sub_parts.append(
                (
                    command,
                    _run_part(
                        command, model, sub["jump"].to_numpy(), config, next(seeds), None, False
                    ),
                )
            )
        n_draw = min(p.run.samples.shape[1] for _, p in [*sub_parts, ("", part)])
        order = np.concatenate([p.jumps for _, p in sub_parts])
        ll_sep = np.concatenate([p.run.blobs[:, -n_draw:] for _, p in sub_parts], axis=-1)
        pos = {j: i for i, j in enumerate(part.jumps)}
        ll_shared = part.run.blobs[:, -n_draw:][..., [pos[j] for j in order]]
        obs_table = table.set_index("jump").loc[order].reset_index(drop=True)
        models = {}
        for name, ll in (("shared", ll_shared), ("per_command", ll_sep)):
            models[name] = gdt.build_datatree(
                {"dummy": np.zeros(ll.shape[:2])},
                dims={},
                coords={},
                log_likelihood=ll,
                posterior_predictive={},
                observed=obs_table[["height_mm"]],
                sample_stats={},
                attrs={},
            )
        loo = {k: gdt.loo(v) for k, v in models.items()}
        diff, diff_se = gdt.elpd_difference(loo["shared"]["elpd_i"], loo["per_command"]["elpd_i"])
        row = {
            "phi": phi,
            "elpd_shared": loo["shared"]["elpd"],
            "elpd_per_command": loo["per_command"]["elpd"],
            "elpd_diff": diff,
            "elpd_diff_se": diff_se,
            "max_pareto_k_shared": loo["shared"]["max_pareto_k"],
            "max_pareto_k_per_command": loo["per_command"]["max_pareto_k"],
            "preferred": "shared" if diff > -2.0 * diff_se else "per_command",
        }
        lo_q, hi_q = (1 - ci_prob) / 2, 1 - (1 - ci_prob) / 2
        for pname in part.model.parameters:
            lows, highs = [], []
            for command, p in sub_parts:
                idx = p.model.coordinate_names.index(pname)
                v = p.model.priors[pname].to_value(p.run.samples[..., idx].ravel())
                lows.append(np.quantile(v, lo_q))
                highs.append(np.quantile(v, hi_q))
                per_command_rows.append(
                    {
                        "phi": phi,
                        "command": command,
                        "parameter": pname,
                        "median": float(np.median(v)),
                        "lo": float(lows[-1]),
                        "hi": float(highs[-1]),
                    }
                )
            row[f"{pname}_intervals_overlap"] = bool(max(lows) <= min(highs))
        rows.append(row)
    if details:
        return pd.DataFrame(rows), pd.DataFrame(per_command_rows)
    return pd.DataFrame(rows)
