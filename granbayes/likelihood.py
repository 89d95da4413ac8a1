"""Likelihood of measured jump heights under a force law, with its priors.

A :class:`JumpModel` turns a matrix of walker positions (in sampling coordinates, see
:mod:`granbayes.priors`) into log-posterior values and per-jump log-likelihoods, simulating
every (walker, experimental configuration) pair in one batched simulator call. A failed
simulation makes that walker's log-probability ``-inf``; nothing raises.

Parametrisations of the force law across volume fractions (``phi_mode``):

``"shared"``
    one value per parameter for all jumps in the data (used per volume fraction: one
    force law for all five commands, the thesis's question);
``"quadratic"``
    each parameter a quadratic in ``x = phi - phi_c`` in its sampling coordinate (log for
    log-scale parameters such as ``k``, square root for coefficients with a uniform prior
    from zero such as ``c_d``), fitted jointly over all volume fractions.

Noise: Gaussian (default) or Student-t (``noise="student_t"``, ``nu`` degrees of freedom,
fixed; a heavy-tailed option robust to outlying trials), with the scatter ``sigma_mm``
fitted per volume fraction (default) or globally.
"""

from __future__ import annotations

import functools
import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Literal

import numpy as np
import pandas as pd
from scipy.special import gammaln

from .commands import SETTINGS, CommandProgram, CommandSettings, build_command
from .experiment import Experiment
from .forces import PARAMETERS, TERMS, terms_of
from .priors import Prior, default_priors
from .simulator import SolverSettings, build_rows, simulate_rows

__all__ = [
    "Evaluation",
    "JumpModel",
    "NoiseFamily",
    "Observations",
    "PhiMode",
    "SigmaMode",
    "evaluate_models",
]

#: Parametrisation of a model across volume fractions (module docstring).
PhiMode = Literal["shared", "quadratic"]
#: Noise family of the measured heights.
NoiseFamily = Literal["normal", "student_t"]
#: The scatter ``sigma_mm``: one per volume fraction, or one for all.
SigmaMode = Literal["per_phi", "global"]

#: Columns that define one simulation: the volume fraction, the command and its settings.
_CONFIG_COLUMNS = ("phi", "command", *SETTINGS)


@dataclass(frozen=True)
class Observations:
    """Measured jumps grouped by simulation configuration.

    Attributes
    ----------
    table : pandas.DataFrame
        One row per jump (``load_jumps`` output): ``phi``, ``command``, ``height_mm`` and
        the command settings.
    configs : pandas.DataFrame
        Unique ``(phi, command, settings)`` rows; one simulation each.
    config_of_obs : ndarray of int, shape (n_obs,)
        Row of ``configs`` for every jump.
    programs : list of CommandProgram
        One program per config.
    """

    table: pd.DataFrame
    configs: pd.DataFrame
    config_of_obs: np.ndarray
    programs: list[CommandProgram] = field(repr=False)

    @classmethod
    def from_table(cls, table: pd.DataFrame) -> Observations:
        """Group a validated jumps table (see :func:`granbayes.load_jumps`)."""
        table = table.reset_index(drop=True)
        configs = (
            table[list(_CONFIG_COLUMNS)]
            .drop_duplicates()
            .sort_values(list(_CONFIG_COLUMNS))
            .reset_index(drop=True)
        )
        key = pd.MultiIndex.from_frame(configs)
        config_of_obs = key.get_indexer(pd.MultiIndex.from_frame(table[list(_CONFIG_COLUMNS)]))
        programs = [
            build_command(r.command, CommandSettings(**{s: getattr(r, s) for s in SETTINGS}))
            for r in configs.itertuples()
        ]
        return cls(table, configs, np.asarray(config_of_obs, dtype=np.int64), programs)

    def subset(self, mask: np.ndarray | pd.Series) -> Observations:
        """Observations restricted to the jumps where ``mask`` is true.

        Parameters
        ----------
        mask : ndarray or pandas.Series of bool
            One entry per jump.

        Returns
        -------
        Observations
        """
        return Observations.from_table(self.table[np.asarray(mask)])

    @functools.cached_property
    def config_phi(self) -> np.ndarray:
        """Volume fraction of every config (computed once)."""
        return self.configs["phi"].to_numpy(float)

    @property
    def n_obs(self) -> int:
        """Number of jumps."""
        return len(self.table)

    @property
    def phis(self) -> np.ndarray:
        """Sorted distinct volume fractions."""
        return np.unique(self.table["phi"].to_numpy(dtype=float))

    @property
    def height_mm(self) -> np.ndarray:
        """Measured heights [mm]."""
        return self.table["height_mm"].to_numpy(dtype=float)


@dataclass(frozen=True)
class _Coordinate:
    """One sampled coordinate: a parameter (or polynomial coefficient) with its prior."""

    name: str  # e.g. "k", "k:c1", "sigma_mm[0.592]"
    parameter: str  # physical parameter it belongs to
    prior: Prior
    order: int = 0  # polynomial order in quadratic mode
    phi: float | None = None  # for per-phi noise


class JumpModel:
    """Log-posterior of jump heights for a force law.

    Parameters
    ----------
    observations : Observations
        The data.
    experiment : Experiment
        Robot, command defaults and ``phi_c``.
    terms : sequence of str
        Force terms to fit (``depth`` is always included); parameters of other terms take
        their ``absent`` value unless given in ``fixed``.
    priors : mapping of str to Prior, optional
        Priors per parameter (defaults: :func:`granbayes.priors.default_priors`).
    phi_mode : {"shared", "quadratic"}
        Parametrisation across volume fractions (module docstring).
    noise : {"normal", "student_t"}
        Noise family.
    nu : float
        Degrees of freedom of the Student-t noise.
    sigma_mode : {"per_phi", "global"}
        Whether the scatter is fitted per volume fraction or once.
    fixed : mapping of str to float, optional
        Values of parameters that are not fitted (override ``absent``).
    options : SolverSettings, optional
        Integrator settings.
    n_threads : int, optional
        numba threads for the simulator.
    """

    def __init__(
        self,
        observations: Observations,
        experiment: Experiment,
        terms: Sequence[str],
        *,
        priors: Mapping[str, Prior] | None = None,
        phi_mode: PhiMode = "shared",
        noise: NoiseFamily = "normal",
        nu: float = 4.0,
        sigma_mode: SigmaMode = "per_phi",
        fixed: Mapping[str, float] | None = None,
        options: SolverSettings | None = None,
        n_threads: int | None = None,
    ) -> None:
        if phi_mode not in ("shared", "quadratic"):
            raise ValueError(f"phi_mode must be 'shared' or 'quadratic', got {phi_mode!r}")
        if noise not in ("normal", "student_t"):
            raise ValueError(f"noise must be 'normal' or 'student_t', got {noise!r}")
        if sigma_mode not in ("per_phi", "global"):
            raise ValueError(f"sigma_mode must be 'per_phi' or 'global', got {sigma_mode!r}")
        if not nu > 0:
            raise ValueError("nu must be > 0")
        self.obs = observations
        self.experiment = experiment
        self.terms = terms_of(terms)
        self.priors = dict(priors if priors is not None else default_priors())
        self.phi_mode = phi_mode
        self.noise = noise
        self.nu = float(nu)
        self.sigma_mode = sigma_mode
        self.fixed = dict(fixed or {})
        self.options = options or SolverSettings()
        self.n_threads = n_threads
        self.parameters = tuple(p.name for t in self.terms for p in TERMS[t].parameters)
        self._phis = observations.phis
        self._x_config = observations.configs["phi"].to_numpy(float) - experiment.phi_c
        self._x_phis = self._phis - experiment.phi_c
        self._coords = self._build_coordinates()
        obs_phi = observations.table["phi"].to_numpy(float)
        self._phi_index_of_obs = np.searchsorted(self._phis, obs_phi)
        self._y = observations.height_mm

    # ------------------------------------------------------------------------------------
    def _build_coordinates(self) -> list[_Coordinate]:
        coords: list[_Coordinate] = []
        span = float(np.max(np.abs(self._x_phis))) if self._x_phis.size else 0.0
        for name in self.parameters:
            prior = self.priors[name]
            if self.phi_mode == "shared":
                coords.append(_Coordinate(name, name, prior))
                continue
            coords.append(_Coordinate(f"{name}:c0", name, prior, order=0))
            lo, hi = prior.bounds_u
            width = hi - lo
            scale = max(span, 0.005)
            for order in (1, 2):
                bound = width / scale**order
                coef_prior = Prior("uniform", -bound, bound, unit=f"{prior.unit} per phi^{order}")
                coords.append(_Coordinate(f"{name}:c{order}", name, coef_prior, order=order))
        sigma_prior = self.priors["sigma_mm"]
        if self.sigma_mode == "global":
            coords.append(_Coordinate("sigma_mm", "sigma_mm", sigma_prior))
        else:
            coords.extend(
                _Coordinate(f"sigma_mm[{phi:g}]", "sigma_mm", sigma_prior, phi=float(phi))
                for phi in self._phis
            )
        return coords

    @property
    def coordinate_names(self) -> list[str]:
        """Names of the sampled coordinates, in column order."""
        return [c.name for c in self._coords]

    @property
    def coordinate_priors(self) -> list[Prior]:
        """Prior of every sampled coordinate, in column order."""
        return [c.prior for c in self._coords]

    @property
    def bounds_u(self) -> np.ndarray:
        """Prior bounds of every sampled coordinate, shape (ndim, 2), in sampling units."""
        return np.array([c.prior.bounds_u for c in self._coords])

    @property
    def ndim(self) -> int:
        """Number of sampled coordinates."""
        return len(self._coords)

    @property
    def phis(self) -> np.ndarray:
        """Volume fractions present in the data."""
        return self._phis

    def log_prior(self, u: np.ndarray) -> np.ndarray:
        """Log prior density of walker positions ``u`` (shape (n, ndim)) [nats].

        Parameters
        ----------
        u : ndarray, shape (n, ndim)
            Positions in sampling coordinates.

        Returns
        -------
        ndarray, shape (n,)
            ``-inf`` outside the prior's support.
        """
        u = np.atleast_2d(u)
        lp = np.zeros(u.shape[0])
        for j, c in enumerate(self._coords):
            lp += c.prior.logpdf_u(u[:, j])
        if self.phi_mode == "quadratic":  # the implied values must respect the bounds
            values = self._parameter_u(u, self._x_phis)
            for name in self.parameters:
                lo, hi = self.priors[name].bounds_u
                v = values[name]
                lp[np.any((v < lo) | (v > hi), axis=1)] = -np.inf
        return lp

    def log_prior_density(self, u: np.ndarray) -> np.ndarray:
        """Log prior density [nats] of walker positions in the parameters' own units.

        :meth:`log_prior` is the density of the sampling coordinates (flat for log-uniform
        priors); this is the density of the physical values the posterior reports
        (``log p_u(u) - log |d value / d u|``), the one ArviZ's prior-sensitivity analysis
        power-scales. In quadratic mode the coordinates are polynomial coefficients and
        the two coincide.

        Parameters
        ----------
        u : ndarray, shape (n, ndim)
            Positions in sampling coordinates.

        Returns
        -------
        ndarray, shape (n,)
        """
        u = np.atleast_2d(u)
        lp = self.log_prior(u)
        if self.phi_mode == "shared":
            for j, c in enumerate(self._coords):
                lp = lp - c.prior.log_jacobian(u[:, j])
        return lp

    def _parameter_u(self, u: np.ndarray, x: np.ndarray) -> dict[str, np.ndarray]:
        """Parameters in sampling coordinates at offsets ``x = phi - phi_c``: (n, len(x))."""
        out: dict[str, np.ndarray] = {}
        for j, c in enumerate(self._coords):
            if c.parameter == "sigma_mm":
                continue
            term = u[:, j : j + 1] * (x[None, :] ** c.order)
            out[c.parameter] = out[c.parameter] + term if c.parameter in out else term
        return out

    def parameter_values(self, u: np.ndarray, phis: np.ndarray | None = None) -> dict:
        """Physical parameter values [SI] at volume fractions ``phis``.

        Parameters
        ----------
        u : ndarray, shape (n, ndim)
            Walker positions.
        phis : ndarray, optional
            Volume fractions (default: those of the data).

        Returns
        -------
        dict of str to ndarray, shape (n, len(phis))
            Force parameters and ``sigma_mm`` (sigma is NaN at phis it was not fitted for).
        """
        u = np.atleast_2d(u)
        phis = self._phis if phis is None else np.asarray(phis, float)
        x = phis - self.experiment.phi_c
        vals = {name: self.priors[name].to_value(v) for name, v in self._parameter_u(u, x).items()}
        vals["sigma_mm"] = self._sigma_at(u, phis)
        return vals

    def _sigma_at(self, u: np.ndarray, phis: np.ndarray) -> np.ndarray:
        sig = np.full((u.shape[0], len(phis)), np.nan)
        for j, c in enumerate(self._coords):
            if c.parameter != "sigma_mm":
                continue
            value = c.prior.to_value(u[:, j])
            for i, phi in enumerate(phis):
                if c.phi is None or math.isclose(c.phi, phi, abs_tol=1e-12):
                    sig[:, i] = value
        return sig

    # ------------------------------------------------------------------------------------
    def simulation_rows(
        self, u: np.ndarray, observations: Observations | None = None
    ) -> tuple[np.ndarray, np.ndarray]:
        """Integrator rows of every (walker, configuration) pair, walker-major.

        Parameters
        ----------
        u : ndarray, shape (n, ndim)
            Walker positions.
        observations : Observations, optional
            Configurations to simulate (default: the model's data).

        Returns
        -------
        rows : ndarray, shape (n * n_configs, len(ROW_FIELDS))
        program_index : ndarray of int, shape (n * n_configs,)
            Index of each row's program in ``observations.programs``.
        """
        u = np.atleast_2d(u)
        obs = observations or self.obs
        config_phi = obs.config_phi
        n, m = u.shape[0], len(config_phi)
        x_eval = np.zeros(1) if self.phi_mode == "shared" else config_phi - self.experiment.phi_c
        values = {
            name: self.priors[name].to_value(v) for name, v in self._parameter_u(u, x_eval).items()
        }
        params: dict[str, np.ndarray] = {}
        for p in PARAMETERS:
            if p.name in values:
                params[p.name] = np.broadcast_to(values[p.name], (n, m)).reshape(-1)
            elif p.name in self.fixed:
                params[p.name] = np.full(n * m, float(self.fixed[p.name]))
        phi = np.broadcast_to(config_phi, (n, m)).reshape(-1)
        rows = build_rows(self.experiment.robot, phi, params)
        return rows, np.tile(np.arange(m), n)

    def predict(
        self,
        u: np.ndarray,
        observations: Observations | None = None,
    ) -> tuple[np.ndarray, np.ndarray]:
        """Simulated heights [mm] for every walker and configuration.

        Parameters
        ----------
        u : ndarray, shape (n, ndim)
            Walker positions.
        observations : Observations, optional
            Configurations to predict (default: the model's data). Their volume fractions
            must be ones the model can evaluate (any phi in quadratic mode).

        Returns
        -------
        heights_mm : ndarray, shape (n, n_configs)
        ok : ndarray of bool, shape (n,)
            Whether every simulation of the walker succeeded.
        """
        u = np.atleast_2d(u)
        obs = observations or self.obs
        rows, index = self.simulation_rows(u, obs)
        res = simulate_rows(
            rows, obs.programs, index, options=self.options, n_threads=self.n_threads
        )
        heights = res.height_mm.reshape(u.shape[0], -1)
        return heights, np.all(res.ok.reshape(heights.shape), axis=1)

    # ------------------------------------------------------------------------------------
    # the observation model: the only place where the noise family is written down
    def mean_and_sigma(
        self, u: np.ndarray, observations: Observations | None = None
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Predictive mean and scatter [mm] of every jump, for every walker position.

        Parameters
        ----------
        u : ndarray, shape (n, ndim)
            Walker positions.
        observations : Observations, optional
            Jumps to predict (default: the model's data); their volume fractions must be
            ones the model has a scatter for.

        Returns
        -------
        mean_mm, sigma_mm : ndarray, shape (n, n_obs)
            Simulated height and noise scale of every jump.
        ok : ndarray of bool, shape (n,)
            Whether every simulation of the walker succeeded.
        """
        u = np.atleast_2d(u)
        obs = observations or self.obs
        heights, ok = self.predict(u, obs)
        return heights[:, obs.config_of_obs], self._sigma_of(u, obs), ok

    def _sigma_of(self, u: np.ndarray, obs: Observations) -> np.ndarray:
        """Noise scale [mm] of every jump of ``obs``: shape (n, n_obs)."""
        if obs is self.obs:  # the likelihood's own data (every sampler call)
            return self._sigma_at(u, self._phis)[:, self._phi_index_of_obs]
        phis = obs.table["phi"].to_numpy(float)
        index = np.searchsorted(self._phis, phis).clip(0, len(self._phis) - 1)
        if not np.allclose(self._phis[index], phis, atol=1e-12):
            missing = sorted(set(phis) - set(self._phis))
            raise ValueError(f"no fitted scatter at phi = {missing}")
        return self._sigma_at(u, self._phis)[:, index]

    def log_density(self, y_mm: np.ndarray, mean_mm: np.ndarray, sigma_mm: np.ndarray):
        """Log density of heights ``y_mm`` given predictive mean and scatter [mm].

        Parameters
        ----------
        y_mm, mean_mm, sigma_mm : ndarray
            Heights, predictive means and scatters [mm] (broadcast).

        Returns
        -------
        ndarray
            Log density [nats, per mm].
        """
        r = (y_mm - mean_mm) / sigma_mm
        if self.noise == "normal":
            return -0.5 * r * r - np.log(sigma_mm) - 0.5 * math.log(2.0 * math.pi)
        nu = self.nu
        const = gammaln(0.5 * (nu + 1)) - gammaln(0.5 * nu) - 0.5 * math.log(nu * math.pi)
        return const - np.log(sigma_mm) - 0.5 * (nu + 1) * np.log1p(r * r / nu)

    def log_likelihood(self, u: np.ndarray, heights_mm: np.ndarray) -> np.ndarray:
        """Pointwise log-likelihood of the data given simulated config heights.

        Parameters
        ----------
        u : ndarray, shape (n, ndim)
            Walker positions (for the noise parameters).
        heights_mm : ndarray, shape (n, n_configs)
            Simulated heights.

        Returns
        -------
        ndarray, shape (n, n_obs)
        """
        mean = heights_mm[:, self.obs.config_of_obs]
        sigma = self._sigma_of(np.atleast_2d(u), self.obs)
        return self.log_density(self._y[None, :], mean, sigma)

    def log_predictive_density(self, u: np.ndarray, observations: Observations) -> np.ndarray:
        """Log p(y_i | draws) of (held-out) jumps, averaged over the draws ``u``.

        Parameters
        ----------
        u : ndarray, shape (n, ndim)
            Posterior draws.
        observations : Observations
            The jumps to score.

        Returns
        -------
        ndarray, shape (n_obs,)
            ``log mean_s p(y_i | u_s)`` [nats]; a failed simulation counts as zero density.
        """
        mean, sigma, ok = self.mean_and_sigma(u, observations)
        ll = self.log_density(observations.height_mm[None, :], mean, sigma)
        ll[~ok] = -np.inf
        return np.logaddexp.reduce(ll, axis=0) - math.log(len(ll))

    def sample_predictive(
        self, u: np.ndarray, rng: np.random.Generator, observations: Observations | None = None
    ) -> tuple[np.ndarray, np.ndarray]:
        """Simulated heights and replicated measurements [mm] for every draw.

        Parameters
        ----------
        u : ndarray, shape (n, ndim)
            Posterior draws.
        rng : numpy.random.Generator
            Source of the replicate noise.
        observations : Observations, optional
            Jumps to replicate (default: the model's data).

        Returns
        -------
        mean_mm, replicate_mm : ndarray, shape (n, n_obs)
            The simulated height, and it plus one draw of the noise (NaN where a
            simulation failed).
        """
        mean, sigma, _ = self.mean_and_sigma(u, observations)
        return mean, self.add_noise(mean, sigma, rng)

    def add_noise(
        self, mean_mm: np.ndarray, sigma_mm: np.ndarray, rng: np.random.Generator
    ) -> np.ndarray:
        """One draw of a measured height [mm] per simulated height, by the noise family.

        Parameters
        ----------
        mean_mm : ndarray
            Simulated heights.
        sigma_mm : ndarray
            Noise scale of every height (broadcast against ``mean_mm``).
        rng : numpy.random.Generator
            Source of the noise.

        Returns
        -------
        ndarray
            ``mean_mm + sigma_mm * eps`` with ``eps`` standard normal or Student-t(``nu``).
        """
        mean_mm = np.asarray(mean_mm, dtype=float)
        if self.noise == "normal":
            eps = rng.standard_normal(mean_mm.shape)
        else:
            eps = rng.standard_t(self.nu, mean_mm.shape)
        return mean_mm + sigma_mm * eps

    def __call__(self, u: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Log-posterior and pointwise log-likelihood of walker positions.

        Parameters
        ----------
        u : ndarray, shape (n, ndim)
            Walker positions in sampling coordinates.

        Returns
        -------
        log_prob : ndarray, shape (n,)
            Log prior + log likelihood; ``-inf`` outside the prior or if a simulation
            failed.
        log_lik : ndarray, shape (n, n_obs)
            Pointwise log-likelihood (``-inf`` rows where ``log_prob`` is ``-inf``).
        """
        ev = evaluate_models([self], [u])[0]
        return ev.log_prob, ev.log_lik

    def sample_prior(self, rng: np.random.Generator, size: int) -> np.ndarray:
        """Draw walker positions from the prior (quadratic mode: bound-respecting).

        Parameters
        ----------
        rng : numpy.random.Generator
            Source of randomness.
        size : int
            Number of positions.

        Returns
        -------
        ndarray, shape (size, ndim)
        """
        out = np.empty((0, self.ndim))
        for _ in range(200):
            draw = np.column_stack([c.prior.sample_u(rng, 4 * size) for c in self._coords])
            if self.phi_mode == "quadratic":  # start near constant laws
                for j, c in enumerate(self._coords):
                    if c.order > 0:
                        draw[:, j] *= 0.05
            draw = draw[np.isfinite(self.log_prior(draw))]
            out = np.concatenate([out, draw])
            if len(out) >= size:
                return out[:size]
        raise RuntimeError("could not draw from the prior within its bounds")


@dataclass(frozen=True)
class Evaluation:
    """The log-posterior of walker positions under one model, with what it was made of.

    Attributes
    ----------
    log_prob : ndarray, shape (n,)
        Log prior + log likelihood [nats]; ``-inf`` outside the prior or where a
        simulation failed.
    log_lik : ndarray, shape (n, n_obs)
        Pointwise log-likelihood of the model's jumps (``-inf`` rows where ``log_prob`` is
        ``-inf``).
    heights_mm : ndarray, shape (n, n_configs)
        Simulated height of every configuration [mm] (NaN outside the prior).
    """

    log_prob: np.ndarray
    log_lik: np.ndarray
    heights_mm: np.ndarray


def evaluate_models(
    models: Sequence[JumpModel], positions: Sequence[np.ndarray]
) -> list[Evaluation]:
    """Evaluate walker positions under several models with one simulator call.

    The volume fractions of a fit, the candidate laws of a screening or the refits of a
    cross-validation are independent models; their simulations (every walker inside its
    model's prior, every configuration) are concatenated into one batch for the compiled
    simulator, which then runs in parallel over all of them. The simulator works jump by
    jump, so each model's values are those of evaluating it alone.

    Parameters
    ----------
    models : sequence of JumpModel
        The models; they must share the integrator settings and thread count.
    positions : sequence of ndarray
        Walker positions per model, shape ``(n_i, ndim_i)`` (``n_i`` may be 0).

    Returns
    -------
    list of Evaluation
        One per model, in order.
    """
    if not models:
        return []
    options, n_threads = models[0].options, models[0].n_threads
    if any(m.options != options or m.n_threads != n_threads for m in models):
        raise ValueError("models evaluated together must share solver settings and threads")
    prepared = []
    rows, index, programs = [], [], []
    for model, u in zip(models, positions, strict=True):
        u = np.atleast_2d(np.asarray(u, dtype=float)).reshape(-1, model.ndim)
        lp = model.log_prior(u) if len(u) else np.empty(0)
        good = np.isfinite(lp)
        if np.any(good):
            r, i = model.simulation_rows(u[good])
            rows.append(r)
            index.append(i + len(programs))
            programs.extend(model.obs.programs)
        prepared.append((model, u, lp, good))
    heights = ok = None
    if rows:
        res = simulate_rows(
            np.concatenate(rows),
            programs,
            np.concatenate(index),
            options=options,
            n_threads=n_threads,
        )
        heights, ok = res.height_mm, res.ok
    out = []
    start = 0
    for model, u, lp, good in prepared:
        n, m = len(u), len(model.obs.configs)
        sim = np.full((n, m), np.nan)
        loglik = np.full((n, model.obs.n_obs), -np.inf)
        n_good = int(np.sum(good))
        if n_good:
            stop = start + n_good * m
            h = heights[start:stop].reshape(n_good, m)
            fine = np.all(ok[start:stop].reshape(n_good, m), axis=1)
            start = stop
            ll = model.log_likelihood(u[good], h)
            ll[~fine] = -np.inf
            loglik[good] = ll
            sim[good] = h
            total = ll.sum(axis=1)
            total[~np.isfinite(total)] = -np.inf
            lp = lp.copy()
            lp[good] = lp[good] + total
        out.append(Evaluation(lp, loglik, sim))
    return out
