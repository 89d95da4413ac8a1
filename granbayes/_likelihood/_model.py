"""The log-posterior of a force law given every kind of measurement: :class:`JumpModel`.

A :class:`JumpModel` turns a matrix of walker positions (in sampling coordinates, see
:mod:`granbayes._priors`) into log-posterior values and per-unit log-likelihoods. It owns
the force law (its coordinates and their priors); each kind of measurement is a
:class:`~granbayes._likelihood.Block` with its own coordinates and observation model. Every
(walker, simulated jump) pair of every block is simulated in one batched simulator call
(:func:`evaluate_models`, which also batches several models). A failed simulation makes
that walker's log-probability ``-inf``; nothing raises.

Parametrisations of the force law across volume fractions (``phi_mode``):

``"per_phi"``
    one value per parameter for all measurements of the model (used per volume fraction:
    one force law for all five commands, the thesis's question);
``"quadratic"``
    each parameter a quadratic in ``x = phi - phi_c`` in its sampling coordinate (log for
    log-scale parameters such as ``k``, square root for coefficients with a uniform prior
    from zero such as ``c_d``), fitted jointly over all volume fractions;
``"per_phi_joint"``
    one value per parameter and volume fraction (coordinates ``k[0.602]``), every volume
    fraction in one model: the per-phi laws of ``"per_phi"``, sampled together so that a
    calibrated robot is one value for all of them (``FitSettings.calibration="pool"``).
    Its law exists only at the model's volume fractions (NaN elsewhere).

Length: about 800 lines for one job, the force law's side of the posterior: coordinates
of every parametrisation (per phi, quadratic in phi), the priors' densities, the one
simulator call for every block of every model, and the predictive replicates; each block
of measurements lives in its own module.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Literal

import numpy as np

from .._experiment import Experiment
from .._priors import Prior, default_priors
from .._simulator import (
    ROBOT_FIELDS,
    SolverSettings,
    build_rows,
    simulate_frames_rows,
    simulate_rows,
)
from ..forces import PARAMETERS, TERMS, terms_of
from ._blocks import Block, Coordinate, Law, Simulated
from ._heights import HeightBlock, NoiseFamily, Observations, SigmaMode

__all__ = ["CALIBRATED_KEYS", "Evaluation", "JumpModel", "PhiMode", "evaluate_models"]

#: Robot parameters a model can sample from their calibration (``calibrated``): the robot's
#: own (one column each of the integrator rows) and the stroke ``amplitude_mm`` (a factor on
#: every command's waveform, which is proportional to it).
CALIBRATED_KEYS: tuple[str, ...] = (*ROBOT_FIELDS, "amplitude_mm")

#: Parametrisation of a model across volume fractions (module docstring).
PhiMode = Literal["per_phi", "quadratic", "per_phi_joint"]


class JumpModel:
    """Log-posterior of a force law given measurements of one or more kinds.

    Parameters
    ----------
    observations : Observations or sequence of Block
        The jump heights (a :class:`HeightBlock` is made of them with ``noise``, ``nu``
        and ``sigma_mode``), or the blocks of every kind of measurement.
    experiment : Experiment
        Robot, command defaults and ``phi_c``.
    terms : sequence of str
        Force terms to fit (``depth`` is always included); parameters of other terms take
        their ``absent`` value unless given in ``fixed``.
    priors : mapping of str to Prior, optional
        Priors per parameter (defaults: :func:`granbayes.default_priors`; a block's
        own parameters fall back on the block's defaults).
    phi_mode : {"per_phi", "quadratic", "per_phi_joint"}
        Parametrisation across volume fractions (module docstring).
    noise : {"normal", "student_t"}
        Noise family of the heights (when ``observations`` are heights).
    nu : float
        Degrees of freedom of the Student-t noise.
    sigma_mode : {"per_phi", "global"}
        Whether the heights' scatter is fitted per volume fraction or once.
    fixed : mapping of str to float, optional
        Values of parameters that are not fitted (override ``absent``).
    settings : SolverSettings, optional
        Integrator settings.
    n_threads : int, optional
        numba threads for the simulator.
    calibrated : mapping of str to Prior, optional
        Robot parameters (``[robot]`` keys, and ``amplitude_mm``, the stroke) known only
        to a calibration: each becomes one sampled coordinate, shared by every volume
        fraction, command and kind of measurement of the model, with its calibration as
        prior (:func:`granbayes._priors.calibration_priors`). The rest of the robot stays
        at the experiment's values; without ``calibrated`` the model is the fixed-robot
        model, coordinate for coordinate.
    """

    def __init__(
        self,
        observations: Observations | Sequence[Block],
        experiment: Experiment,
        terms: Sequence[str],
        *,
        priors: Mapping[str, Prior] | None = None,
        phi_mode: PhiMode = "per_phi",
        noise: NoiseFamily = "normal",
        nu: float = 4.0,
        sigma_mode: SigmaMode = "per_phi",
        fixed: Mapping[str, float] | None = None,
        settings: SolverSettings | None = None,
        n_threads: int | None = None,
        calibrated: Mapping[str, Prior] | None = None,
    ) -> None:
        if phi_mode not in ("per_phi", "quadratic", "per_phi_joint"):
            raise ValueError(
                f"phi_mode must be 'per_phi', 'quadratic' or 'per_phi_joint', got {phi_mode!r}"
            )
        if isinstance(observations, Observations):
            blocks: list[Block] = [
                HeightBlock(observations, noise=noise, nu=nu, sigma_mode=sigma_mode)
            ]
        else:
            blocks = list(observations)
        if not blocks:
            raise ValueError("a model needs measurements: no block given")
        kinds = [b.kind for b in blocks]
        if len(set(kinds)) != len(kinds):
            raise ValueError(f"one block per kind of measurement, got {kinds}")
        self.blocks = blocks
        self.experiment = experiment
        self.terms = terms_of(terms)
        self.priors = dict(priors if priors is not None else default_priors())
        self.phi_mode = phi_mode
        self.fixed = dict(fixed or {})
        self.options = settings or SolverSettings()
        self.n_threads = n_threads
        self.parameters = tuple(p.name for t in self.terms for p in TERMS[t].parameters)
        self._phis = np.unique(np.concatenate([b.phis for b in blocks]))
        self._x_phis = self._phis - experiment.phi_c
        self._law = self._law_coordinates()
        #: each parameter's law columns (one per coordinate; per phi, in phi order)
        self._columns = {
            name: [j for j, c in enumerate(self._law) if c.parameter == name]
            for name in self.parameters
        }
        self.calibrated = dict(calibrated or {})
        unknown = set(self.calibrated) - set(CALIBRATED_KEYS)
        if unknown:
            raise ValueError(
                f"calibrated parameters must be among {CALIBRATED_KEYS}, got {sorted(unknown)}"
            )
        self._calibration = [Coordinate(k, k, p) for k, p in self.calibrated.items()]
        self._coords = list(self._law) + self._calibration
        self._slices: list[slice] = []
        for block in blocks:
            own = block.coordinates(self.priors, self._phis)
            self._slices.append(slice(len(self._coords), len(self._coords) + len(own)))
            self._coords.extend(own)
        self._requests = [b.jump_request() for b in blocks]

    # ------------------------------------------------------------------------------------
    @property
    def heights(self) -> HeightBlock | None:
        """The block of jump heights (``None`` if the model has none)."""
        return next((b for b in self.blocks if isinstance(b, HeightBlock)), None)

    @property
    def obs(self) -> Observations:
        """The jump heights the model fits."""
        block = self.heights
        if block is None:
            raise AttributeError("this model fits no jump heights")
        return block.obs

    @property
    def noise(self) -> NoiseFamily:
        """Noise family of the heights."""
        return self.heights.noise

    @property
    def nu(self) -> float:
        """Student-t degrees of freedom of the heights' noise."""
        return self.heights.nu

    @property
    def sigma_mode(self) -> SigmaMode:
        """Whether the heights' scatter is per volume fraction or global."""
        return self.heights.sigma_mode

    @property
    def n_units(self) -> int:
        """Units of leave-one-out over every block, in block order."""
        return sum(b.n_units for b in self.blocks)

    @property
    def n_extras(self) -> int:
        """Values kept with every draw beside the log-likelihood (see :meth:`blob`)."""
        return sum(b.n_extras() for b in self.blocks)

    def _law_coordinates(self) -> list[Coordinate]:
        coords: list[Coordinate] = []
        span = float(np.max(np.abs(self._x_phis))) if self._x_phis.size else 0.0
        for name in self.parameters:
            prior = self.priors[name]
            if self.phi_mode == "per_phi":
                coords.append(Coordinate(name, name, prior))
                continue
            if self.phi_mode == "per_phi_joint":
                coords.extend(
                    Coordinate(f"{name}[{phi:g}]", name, prior, phi=float(phi))
                    for phi in self._phis
                )
                continue
            coords.append(Coordinate(f"{name}:c0", name, prior, order=0))
            lo, hi = prior.bounds_u
            width = hi - lo
            scale = max(span, 0.005)
            for order in (1, 2):
                bound = width / scale**order
                coef_prior = Prior("uniform", -bound, bound, unit=f"{prior.unit} per phi^{order}")
                coords.append(Coordinate(f"{name}:c{order}", name, coef_prior, order=order))
        return coords

    @property
    def coordinates(self) -> list[Coordinate]:
        """Every sampled coordinate: the law's, then each block's, in column order."""
        return list(self._coords)

    @property
    def n_law(self) -> int:
        """Number of the force law's coordinates (the first columns)."""
        return len(self._law)

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

    def block_coordinates(self, u: np.ndarray, block: int) -> np.ndarray:
        """The columns of ``u`` that are block ``block``'s own coordinates.

        Parameters
        ----------
        u : ndarray, shape (n, ndim)
            Walker positions.
        block : int
            Index into :attr:`blocks`.

        Returns
        -------
        ndarray, shape (n, n_block_coordinates)
        """
        return np.atleast_2d(u)[:, self._slices[block]]

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

    @property
    def closed_form_blocks(self) -> list[int]:
        """Indices of the blocks whose likelihood needs no simulation (intrusion curves)."""
        return [i for i, request in enumerate(self._requests) if request is None]

    @property
    def closed_form_columns(self) -> np.ndarray:
        """Which coordinates the closed-form blocks' likelihood depends on, shape (ndim,).

        The law's, the calibrated robot's and those blocks' own; all ``False`` when the
        model has no such block.
        """
        mask = np.zeros(self.ndim, dtype=bool)
        blocks = self.closed_form_blocks
        if blocks:
            mask[: len(self._law) + len(self._calibration)] = True
            for i in blocks:
                mask[self._slices[i]] = True
        return mask

    def closed_form_log_prob(self, u: np.ndarray) -> np.ndarray:
        """Log prior + the closed-form blocks' log-likelihood [nats], no simulation.

        The posterior given only the measurements whose model force is closed-form
        (intrusion curves; physics-model.md section 5b), up to a constant.

        Parameters
        ----------
        u : ndarray, shape (n, ndim)
            Positions in sampling coordinates.

        Returns
        -------
        ndarray, shape (n,)
            ``-inf`` outside the prior's support or where a force could not be computed.
        """
        u = np.atleast_2d(np.asarray(u, dtype=float))
        lp = self.log_prior(u)
        good = np.isfinite(lp)
        if np.any(good):
            ug = u[good]
            law = _law_of(self, ug)
            total = np.zeros(len(ug))
            for i in self.closed_form_blocks:
                ll = self.blocks[i].log_lik(self.block_coordinates(ug, i), law, None)
                total += ll.sum(axis=1)
            total[~np.isfinite(total)] = -np.inf
            lp = lp.copy()
            lp[good] += total
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
        if self.phi_mode != "quadratic":
            for j, c in enumerate(self._coords):
                lp = lp - c.prior.log_jacobian(u[:, j])
        return lp

    def _parameter_u(self, u: np.ndarray, x: np.ndarray) -> dict[str, np.ndarray]:
        """Parameters in sampling coordinates at offsets ``x = phi - phi_c``: (n, len(x))."""
        out: dict[str, np.ndarray] = {}
        if self.phi_mode == "per_phi_joint":  # each volume fraction's own coordinate
            at = np.abs(x[:, None] - self._x_phis[None, :])  # the model has >= 1 phi
            which = np.argmin(at, axis=1)
            missing = at[np.arange(len(x)), which] > 1e-9
            for name, columns in self._columns.items():
                values = u[:, columns][:, which]
                values[:, missing] = np.nan
                out[name] = values
            return out
        for j, c in enumerate(self._law):
            term = u[:, j : j + 1] * (x[None, :] ** c.order)
            out[c.parameter] = out[c.parameter] + term if c.parameter in out else term
        return out

    def law_values(self, u: np.ndarray, phis: np.ndarray) -> dict[str, np.ndarray]:
        """The fitted force parameters [SI] at volume fractions ``phis``: (n, len(phis)).

        Parameters
        ----------
        u : ndarray, shape (n, ndim)
            Walker positions.
        phis : ndarray
            Volume fractions (any, in quadratic mode; ``shared``: the law is constant).

        Returns
        -------
        dict of str to ndarray
        """
        u = np.atleast_2d(u)
        phis = np.asarray(phis, dtype=float)
        x = phis - self.experiment.phi_c
        return {name: self.priors[name].to_value(v) for name, v in self._parameter_u(u, x).items()}

    def parameter_values(self, u: np.ndarray, phis: np.ndarray | None = None) -> dict:
        """Physical parameter values at volume fractions ``phis``.

        Parameters
        ----------
        u : ndarray, shape (n, ndim)
            Walker positions.
        phis : ndarray, optional
            Volume fractions (default: those of the data).

        Returns
        -------
        dict of str to ndarray, shape (n, len(phis))
            Force parameters [SI] and every block's parameters (e.g. ``sigma_mm``; NaN at
            volume fractions they were not fitted for).
        """
        u = np.atleast_2d(u)
        phis = self._phis if phis is None else np.asarray(phis, float)
        vals = self.law_values(u, phis)
        for name, values in self.calibration_values(u).items():
            vals[name] = np.repeat(values[:, None], len(phis), axis=1)
        for i, block in enumerate(self.blocks):
            vals.update(block.values(self.block_coordinates(u, i), phis))
        return vals

    def calibration_values(self, u: np.ndarray) -> dict[str, np.ndarray]:
        """The calibrated robot parameters of walkers ``u`` [their units]: shape (n,) each.

        Parameters
        ----------
        u : ndarray, shape (n, ndim)
            Walker positions.

        Returns
        -------
        dict of str to ndarray
            Empty for a model of a robot known exactly.
        """
        u = np.atleast_2d(u)
        start = self.n_law
        return {c.name: c.prior.to_value(u[:, start + j]) for j, c in enumerate(self._calibration)}

    def amplitude_scale(self, u: np.ndarray) -> np.ndarray | None:
        """The stroke of walkers ``u`` over the command's: shape (n,), or ``None`` (exact).

        Parameters
        ----------
        u : ndarray, shape (n, ndim)
            Walker positions.

        Returns
        -------
        ndarray or None
        """
        if "amplitude_mm" not in self.calibrated:
            return None
        stroke = self.calibration_values(u)["amplitude_mm"]
        return stroke / self.experiment.command.amplitude_mm

    # ------------------------------------------------------------------------------------
    def rows_for(self, u: np.ndarray, phi: np.ndarray) -> np.ndarray:
        """Integrator rows of every (walker, jump) pair, walker-major.

        Parameters
        ----------
        u : ndarray, shape (n, ndim)
            Walker positions.
        phi : ndarray, shape (m,)
            Volume fraction of every jump.

        Returns
        -------
        ndarray, shape (n * m, len(ROW_FIELDS))
        """
        u = np.atleast_2d(u)
        n, m = u.shape[0], len(phi)
        x_eval = np.zeros(1) if self.phi_mode == "per_phi" else phi - self.experiment.phi_c
        values = {
            name: self.priors[name].to_value(v) for name, v in self._parameter_u(u, x_eval).items()
        }
        params: dict[str, np.ndarray] = {}
        for p in PARAMETERS:
            if p.name in values:
                params[p.name] = np.broadcast_to(values[p.name], (n, m)).reshape(-1)
            elif p.name in self.fixed:
                params[p.name] = np.full(n * m, float(self.fixed[p.name]))
        rows = build_rows(self.experiment.robot, np.broadcast_to(phi, (n, m)).reshape(-1), params)
        for name, value in self.calibration_values(u).items():
            if name in ROBOT_FIELDS:
                rows[:, ROBOT_FIELDS.index(name)] = np.repeat(value, m)
        return rows

    def simulation_rows(
        self, u: np.ndarray, observations: Observations | None = None
    ) -> tuple[np.ndarray, np.ndarray]:
        """Integrator rows of every (walker, height configuration) pair, walker-major.

        Parameters
        ----------
        u : ndarray, shape (n, ndim)
            Walker positions.
        observations : Observations, optional
            Configurations to simulate (default: the model's jump heights).

        Returns
        -------
        rows : ndarray, shape (n * n_configs, len(ROW_FIELDS))
        program_index : ndarray of int, shape (n * n_configs,)
            Index of each row's program in ``observations.programs``.
        """
        u = np.atleast_2d(u)
        obs = observations or self.obs
        m = len(obs.config_phi)
        return self.rows_for(u, obs.config_phi), np.tile(np.arange(m), u.shape[0])

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
        scale = self.amplitude_scale(u)
        res = simulate_rows(
            rows,
            obs.programs,
            index,
            settings=self.options,
            n_threads=self.n_threads,
            amplitude_scale=None if scale is None else np.repeat(scale, len(obs.config_phi)),
        )
        heights = res.height_mm.reshape(u.shape[0], -1)
        return heights, np.all(res.ok.reshape(heights.shape), axis=1)

    # ------------------------------------------------------------------------------------
    # jump heights: the observation model is the heights block's
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
            Simulated height (at the measured volume fraction, also when the fit
            integrates each bed's) and noise scale of every jump.
        ok : ndarray of bool, shape (n,)
            Whether every simulation of the walker succeeded.
        """
        u = np.atleast_2d(u)
        obs = observations or self.obs
        heights, ok = self.predict(u, obs)
        return heights[:, obs.config_of_obs], self._sigma_of(u, obs), ok

    def _sigma_of(self, u: np.ndarray, obs: Observations) -> np.ndarray:
        """Noise scale [mm] of every jump of ``obs``: shape (n, n_obs)."""
        i = self.blocks.index(self.heights)
        return self.heights.sigma_of(self.block_coordinates(u, i), obs)

    def log_density(self, y_mm: np.ndarray, mean_mm: np.ndarray, sigma_mm: np.ndarray):
        """Log density of heights given predictive mean and scatter [mm].

        The heights block's (:meth:`granbayes._likelihood.HeightBlock.log_density`).

        Parameters
        ----------
        y_mm, mean_mm, sigma_mm : ndarray
            Heights, predictive means and scatters [mm] (broadcast).

        Returns
        -------
        ndarray
            Log density [nats, per mm].
        """
        return self.heights.log_density(y_mm, mean_mm, sigma_mm)

    def add_noise(
        self, mean_mm: np.ndarray, sigma_mm: np.ndarray, rng: np.random.Generator
    ) -> np.ndarray:
        """One draw of a measured height [mm] per simulated height.

        The heights block's (:meth:`granbayes._likelihood.HeightBlock.add_noise`).

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
        """
        return self.heights.add_noise(mean_mm, sigma_mm, rng)

    def log_likelihood(self, u: np.ndarray, heights_mm: np.ndarray) -> np.ndarray:
        """Pointwise log-likelihood of the jump heights given simulated config heights.

        Parameters
        ----------
        u : ndarray, shape (n, ndim)
            Walker positions (for the noise parameters).
        heights_mm : ndarray, shape (n, n_configs * bed.size)
            Simulated heights of every configuration (at every node of a latent bed phi,
            node-minor: the heights block's :meth:`~HeightBlock.jump_request` order).

        Returns
        -------
        ndarray, shape (n, n_obs)
        """
        u = np.atleast_2d(u)
        i = self.blocks.index(self.heights)
        sim = Simulated(heights_mm, np.ones(heights_mm.shape, dtype=bool))
        return self.heights.log_lik(self.block_coordinates(u, i), None, sim)

    def log_predictive_density(
        self, u: np.ndarray, observations: Observations | Sequence[Block]
    ) -> np.ndarray:
        """Log p(y_i | draws) of (held-out) units, averaged over the draws ``u``.

        Parameters
        ----------
        u : ndarray, shape (n, ndim)
            Posterior draws.
        observations : Observations or sequence of Block
            The jumps to score, or blocks of held-out units of any kind (made with each
            kind's ``with_data`` from this model's blocks, so they read its coordinates).

        Returns
        -------
        ndarray, shape (n_units,)
            ``log mean_s p(y_i | u_s)`` [nats], the blocks' units in order; a failed
            simulation counts as zero density.
        """
        u = np.atleast_2d(u)
        if isinstance(observations, Observations):
            observations = [self.heights.with_data(observations)]
        ll = np.concatenate(self._block_log_lik(u, list(observations)), axis=1)
        return np.logaddexp.reduce(ll, axis=0) - math.log(len(ll))

    def _block_log_lik(self, u: np.ndarray, blocks: Sequence[Block]) -> list[np.ndarray]:
        """Pointwise log-likelihood of ``blocks`` (this model's coordinates) under ``u``."""
        sims = _simulate([(self, u, [b.jump_request() for b in blocks])])[0]
        law = _law_of(self, u)
        out = []
        for block, sim in zip(blocks, sims, strict=True):
            i = next(j for j, b in enumerate(self.blocks) if b.kind == block.kind)
            out.append(block.log_lik(self.block_coordinates(u, i), law, sim))
        return out

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

    def predictive(
        self,
        u: np.ndarray,
        rng: np.random.Generator,
        extras: np.ndarray | None = None,
        blocks: Sequence[int] | None = None,
    ) -> list[dict[str, np.ndarray]]:
        """Predictive replicates of every block's measurements for draws ``u``.

        Blocks whose kept values (``extras``, the sampler's blobs) stand for their
        simulation use them; the others are simulated, all in one simulator call. The
        blocks draw their noise from ``rng`` in block order.

        Parameters
        ----------
        u : ndarray, shape (n, ndim)
            Draws (posterior or prior).
        rng : numpy.random.Generator
            Source of the replicate noise.
        extras : ndarray, shape (n, n_extras), optional
            The draws' kept values (:meth:`evaluate_models`' ``extras``).
        blocks : sequence of int, optional
            Only these blocks (the others give an empty dict); default: all.

        Returns
        -------
        list of dict of str to ndarray
            Per block, its :meth:`Block.predictive` variables, shape (n, rows of its
            table).
        """
        u = np.atleast_2d(u)
        wanted = set(range(len(self.blocks)) if blocks is None else blocks)
        known: list[Simulated | None] = [None] * len(self.blocks)
        if extras is not None:
            start = 0
            for i, block in enumerate(self.blocks):
                stop = start + block.n_extras()
                if stop > start:
                    known[i] = block.from_extras(extras[:, start:stop])
                start = stop
        requests = [
            None if k is not None or i not in wanted else r
            for i, (k, r) in enumerate(zip(known, self._requests, strict=True))
        ]
        sims = _simulate([(self, u, requests)])[0]
        law = _law_of(self, u)
        out: list[dict[str, np.ndarray]] = []
        for i, block in enumerate(self.blocks):
            if i not in wanted:
                out.append({})
                continue
            sim = known[i] if known[i] is not None else sims[i]
            out.append(block.predictive(self.block_coordinates(u, i), law, sim, rng))
        return out

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
        log_lik : ndarray, shape (n, n_units)
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
    log_lik : ndarray, shape (n, n_units)
        Pointwise log-likelihood of the model's units, block by block (``-inf`` rows where
        ``log_prob`` is ``-inf``).
    extras : ndarray, shape (n, n_extras)
        What the blocks keep with every draw (the heights block: the simulated height of
        every configuration [mm]); NaN outside the prior.
    """

    log_prob: np.ndarray
    log_lik: np.ndarray
    extras: np.ndarray


def _law_of(model: JumpModel, u: np.ndarray) -> Law:
    """The force law of walkers ``u`` as the blocks see it."""
    return Law(lambda phis: model.law_values(u, phis), lambda phis: model.rows_for(u, phis))


def _simulate(jobs: Sequence[tuple[JumpModel, np.ndarray, Sequence]]) -> list[list]:
    """Every jump request of every job in one simulator call.

    A job is ``(model, u, requests)``: walkers ``u`` (n, ndim) of ``model`` and one
    :class:`JumpRequest` (or ``None``) per block. Returns, per job, one :class:`Simulated`
    (or ``None``) per request.
    """
    plain: list[tuple] = []  # (job, request, rows, programs) of heights-only requests
    tracked: list[tuple] = []  # the same for requests with frames
    options = n_threads = None
    for j, (model, u, requests) in enumerate(jobs):
        options, n_threads = model.options, model.n_threads
        for i, req in enumerate(requests):
            if req is None or len(u) == 0:
                continue
            scale = model.amplitude_scale(u)  # None: the command's stroke
            scale = None if scale is None else np.repeat(scale, req.n_jumps)
            entry = (j, i, len(u), req, model.rows_for(u, req.phi), scale)
            (plain if req.frame_times_s is None else tracked).append(entry)
    out: list[list] = [[None] * len(r) for _, _, r in jobs]
    # heights-only jumps and tracked jumps are two batched calls: the frame simulator
    # gives the same heights bit for bit, but reading frames is not free
    for entries, with_frames in ((plain, False), (tracked, True)):
        if not entries:
            continue
        rows, index, programs, times, counts, scales = [], [], [], [], [], []
        for _, _, n, req, r, scale in entries:
            rows.append(r)
            scales.append(scale)
            index.append(np.tile(np.arange(req.n_jumps), n) + len(programs))
            programs.extend(req.programs)
            if with_frames:
                times.append(np.tile(np.concatenate(req.frame_times_s), n))
                counts.append(np.tile([len(t) for t in req.frame_times_s], n))
        scale = None  # every model's stroke is its command's: the programs as they are
        if any(s is not None for s in scales):
            scale = np.concatenate(
                [np.ones(len(r)) if s is None else s for r, s in zip(rows, scales, strict=True)]
            )
        if with_frames:
            res = simulate_frames_rows(
                np.concatenate(rows),
                programs,
                np.concatenate(index),
                np.concatenate(times),
                np.concatenate([[0], np.cumsum(np.concatenate(counts))]),
                settings=options,
                n_threads=n_threads,
                amplitude_scale=scale,
            )
            frames = res.frames_flat
        else:
            res = simulate_rows(
                np.concatenate(rows),
                programs,
                np.concatenate(index),
                settings=options,
                n_threads=n_threads,
                amplitude_scale=scale,
            )
        start = start_f = 0
        for j, i, n, req, _, _ in entries:
            m = req.n_jumps
            stop = start + n * m
            sim_frames = None
            if with_frames:
                f = sum(len(t) for t in req.frame_times_s)
                sim_frames = frames[start_f : start_f + n * f].reshape(n, f, frames.shape[-1])
                start_f += n * f
            out[j][i] = Simulated(
                res.height_mm[start:stop].reshape(n, m),
                res.ok[start:stop].reshape(n, m),
                sim_frames,
            )
            start = stop
    return out


def evaluate_models(
    models: Sequence[JumpModel], positions: Sequence[np.ndarray]
) -> list[Evaluation]:
    """Evaluate walker positions under several models with one simulator call.

    The volume fractions of a fit, the candidate laws of a screening or the refits of a
    cross-validation are independent models; their simulations (every walker inside its
    model's prior, every jump of every block) are concatenated into one batch for the
    compiled simulator, which then runs in parallel over all of them. The simulator works
    jump by jump, so each model's values are those of evaluating it alone.

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
    for model, u in zip(models, positions, strict=True):
        u = np.atleast_2d(np.asarray(u, dtype=float)).reshape(-1, model.ndim)
        lp = model.log_prior(u) if len(u) else np.empty(0)
        good = np.isfinite(lp)
        prepared.append((model, u, lp, good))
    sims = _simulate([(m, u[good], m._requests) for m, u, _, good in prepared])
    out = []
    for (model, u, lp, good), sim in zip(prepared, sims, strict=True):
        n = len(u)
        extras = np.full((n, model.n_extras), np.nan)
        loglik = np.full((n, model.n_units), -np.inf)
        if np.any(good):
            ug = u[good]
            law = _law_of(model, ug)
            lls, kept = [], []
            for i, block in enumerate(model.blocks):
                ll = block.log_lik(model.block_coordinates(ug, i), law, sim[i])
                lls.append(ll)
                kept.append(block.extras(sim[i]) if block.n_extras() else np.empty((len(ug), 0)))
            ll = np.concatenate(lls, axis=1)
            loglik[good] = ll
            extras[good] = np.concatenate(kept, axis=1)
            total = ll.sum(axis=1)
            total[~np.isfinite(total)] = -np.inf
            lp = lp.copy()
            lp[good] = lp[good] + total
        out.append(Evaluation(lp, loglik, extras))
    return out
