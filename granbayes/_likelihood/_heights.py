"""Jump heights: the measurements grouped into simulations, and their observation model.

Noise: Gaussian (default) or Student-t (``noise="student_t"``, ``nu`` degrees of freedom,
fixed; a heavy-tailed option robust to outlying trials), with the scatter ``sigma_mm``
fitted per volume fraction (default) or globally. The unit of leave-one-out is one jump.
With ``bed`` (a :class:`~granbayes._likelihood._beds.BedPhi` with ``phi_sd > 0``) each jump's
bed has a latent volume fraction, integrated out by quadrature: every configuration is
simulated at the quadrature's nodes about its measured phi.
"""

from __future__ import annotations

import functools
import math
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import ClassVar, Literal

import numpy as np
import pandas as pd
from scipy.special import gammaln

from .._priors import Prior, default_priors
from ..commands import SETTINGS, CommandProgram, CommandSettings, build_command
from ._beds import BedPhi
from ._blocks import Block, Coordinate, JumpRequest, Law, Simulated

__all__ = ["HeightBlock", "NoiseFamily", "Observations", "SigmaMode"]

#: Noise family of the measured heights.
NoiseFamily = Literal["normal", "student_t"]
#: The scatter ``sigma_mm``: one per volume fraction, or one for all.
SigmaMode = Literal["per_phi", "global"]

#: Fine-grid steps per interval between a latent bed phi's nodes (0.125 sd with the default
#: nodes): the trapezoid rule resolves a jump's density in phi while its height moves up to
#: about 8 scatters per sd of phi.
_PER_INTERVAL = 8

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


class HeightBlock(Block):
    """Measured jump heights: Gaussian or Student-t scatter around the simulated height.

    Parameters
    ----------
    observations : Observations
        The jumps.
    noise : {"normal", "student_t"}
        Noise family.
    nu : float
        Degrees of freedom of the Student-t noise.
    sigma_mode : {"per_phi", "global"}
        Whether the scatter ``sigma_mm`` is fitted per volume fraction or once.
    bed : BedPhi, optional
        Each jump's bed's true volume fraction about the measured one, integrated out
        (default: measured exactly).
    """

    kind = "heights"
    unit_dim = "jump"
    variable = "height_mm"

    def __init__(
        self,
        observations: Observations,
        *,
        noise: NoiseFamily = "normal",
        nu: float = 4.0,
        sigma_mode: SigmaMode = "per_phi",
        bed: BedPhi | None = None,
    ) -> None:
        if noise not in ("normal", "student_t"):
            raise ValueError(f"noise must be 'normal' or 'student_t', got {noise!r}")
        if sigma_mode not in ("per_phi", "global"):
            raise ValueError(f"sigma_mode must be 'per_phi' or 'global', got {sigma_mode!r}")
        if not nu > 0:
            raise ValueError("nu must be > 0")
        self.obs = observations
        self.noise = noise
        self.nu = float(nu)
        self.sigma_mode = sigma_mode
        self.bed = bed if bed is not None else BedPhi()
        self._phis = observations.phis
        self._phi_index_of_obs = np.searchsorted(
            self._phis, observations.table["phi"].to_numpy(float)
        )
        self._y = observations.height_mm
        self._coords: list[Coordinate] = []
        self._sigma = self.sigma_of

    predictive_dims: ClassVar[Mapping[str, str]] = {"height_mm": "jump", "height_sim_mm": "jump"}

    @property
    def table(self) -> pd.DataFrame:
        """The jumps."""
        return self.obs.table

    @property
    def n_units(self) -> int:
        """Number of jumps."""
        return self.obs.n_obs

    @property
    def phis(self) -> np.ndarray:
        """Volume fractions of the jumps."""
        return self._phis

    def coordinates(self, priors: Mapping[str, Prior], phis: np.ndarray) -> list[Coordinate]:
        """``sigma_mm`` once (``global``) or per volume fraction of the jumps.

        Parameters
        ----------
        priors : mapping of str to Prior
            Its prior is ``priors["sigma_mm"]`` (default: the package's).
        phis : ndarray
            Volume fractions of the whole model (unused: the jumps' own are taken).

        Returns
        -------
        list of Coordinate
        """
        prior = priors.get("sigma_mm") or default_priors()["sigma_mm"]
        if self.sigma_mode == "global":
            self._coords = [Coordinate("sigma_mm", "sigma_mm", prior)]
        else:
            self._coords = [
                Coordinate(f"sigma_mm[{phi:g}]", "sigma_mm", prior, phi=float(phi))
                for phi in self._phis
            ]
        return list(self._coords)

    def jump_request(self) -> JumpRequest:
        """One simulation per configuration (volume fraction, command, settings) and node.

        Node-minor: configuration ``c`` at node ``q`` is jump ``c * bed.size + q`` (one
        node, the measured phi, when the bed's phi is exact).
        """
        size = self.bed.size
        if size == 1:
            return JumpRequest(self.obs.config_phi, self.obs.programs)
        programs = [p for p in self.obs.programs for _ in range(size)]
        return JumpRequest(self.bed.nodes(self.obs.config_phi), programs)

    def _node_heights(self, sim: Simulated) -> np.ndarray:
        """Simulated height [mm] of every jump at every node: shape (n, n_jumps, size)."""
        n = sim.heights_mm.shape[0]
        per_config = sim.heights_mm.reshape(n, -1, self.bed.size)
        return per_config[:, self.obs.config_of_obs, :]

    # the observation model: the only place where the noise family is written down
    def sigma_at(self, u: np.ndarray, phis: np.ndarray) -> np.ndarray:
        """Scatter [mm] at volume fractions ``phis``: shape (n, len(phis)), NaN if unfitted.

        Parameters
        ----------
        u : ndarray, shape (n, n_coordinates)
            The block's coordinates.
        phis : ndarray
            Volume fractions.

        Returns
        -------
        ndarray
        """
        sig = np.full((u.shape[0], len(phis)), np.nan)
        for j, c in enumerate(self._coords):
            value = c.prior.to_value(u[:, j])
            for i, phi in enumerate(phis):
                if c.phi is None or math.isclose(c.phi, phi, abs_tol=1e-12):
                    sig[:, i] = value
        return sig

    def sigma_of(self, u: np.ndarray, obs: Observations | None = None) -> np.ndarray:
        """Noise scale [mm] of every jump of ``obs`` (default: the block's): (n, n_obs).

        Parameters
        ----------
        u : ndarray, shape (n, n_coordinates)
            The block's coordinates.
        obs : Observations, optional
            Jumps at volume fractions the block has a scatter for.

        Returns
        -------
        ndarray

        Raises
        ------
        ValueError
            For a jump at a volume fraction without a fitted scatter.
        """
        if obs is None or obs is self.obs:  # the likelihood's own data (every sampler call)
            return self.sigma_at(u, self._phis)[:, self._phi_index_of_obs]
        phis = obs.table["phi"].to_numpy(float)
        fitted = np.array([c.phi for c in self._coords if c.phi is not None])
        if len(fitted):
            index = np.searchsorted(fitted, phis).clip(0, len(fitted) - 1)
            if not np.allclose(fitted[index], phis, atol=1e-12):
                missing = sorted(set(phis) - set(fitted))
                raise ValueError(f"no fitted scatter at phi = {missing}")
            return self.sigma_at(u, fitted)[:, index]
        return np.repeat(self.sigma_at(u, phis[:1]), len(phis), axis=1)

    def with_data(self, observations: Observations | pd.DataFrame) -> HeightBlock:
        """A block of other jumps under this block's coordinates (held-out jumps, new data).

        Parameters
        ----------
        observations : Observations or pandas.DataFrame
            Jumps at volume fractions this block has a scatter for.

        Returns
        -------
        HeightBlock
        """
        if isinstance(observations, pd.DataFrame):
            observations = Observations.from_table(observations)
        other = HeightBlock(
            observations, noise=self.noise, nu=self.nu, sigma_mode=self.sigma_mode, bed=self.bed
        )
        other._coords = self._coords
        other._sigma = self.sigma_of
        return other

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

    def log_lik(self, u: np.ndarray, law: Law, sim: Simulated | None) -> np.ndarray:
        """Pointwise log-likelihood of the jumps given their simulated heights.

        Parameters
        ----------
        u : ndarray, shape (n, n_coordinates)
            The block's coordinates.
        law : callable or None
            The force law (unused: the heights carry it).
        sim : Simulated
            The simulated height of every configuration (at every node).

        Returns
        -------
        ndarray, shape (n, n_jumps)
            ``-inf`` for a walker any of whose simulations failed. With a latent bed phi,
            each jump's density integrated over it (:mod:`granbayes._likelihood._beds`).
        """
        if self.bed.size == 1:
            mean = sim.heights_mm[:, self.obs.config_of_obs]
            ll = self.log_density(self._y[None, :], mean, self._sigma(u, self.obs))
        else:  # interpolated between the nodes, integrated on the fine grid
            _, log_w = self.bed.grid(_PER_INTERVAL)
            mean = self._node_heights(sim) @ self.bed.spline(_PER_INTERVAL)
            sigma = self._sigma(u, self.obs)[:, :, None]
            ll = self.bed.integrate(self.log_density(self._y[None, :, None], mean, sigma), log_w)
        ll[~np.all(sim.ok, axis=1)] = -np.inf
        return ll

    def n_extras(self) -> int:
        """The simulated height of every configuration (at every node) is kept with each draw."""
        return len(self.obs.configs) * self.bed.size

    def extras(self, sim: Simulated | None) -> np.ndarray:
        """The simulated height of every configuration (at every node, node-minor) [mm].

        Parameters
        ----------
        sim : Simulated
            The simulator's answer.

        Returns
        -------
        ndarray, shape (n, n_configs * bed.size)
        """
        return sim.heights_mm

    def from_extras(self, extras: np.ndarray) -> Simulated:
        """The simulated heights kept with every draw stand for its simulation.

        Parameters
        ----------
        extras : ndarray, shape (n, n_configs * bed.size)
            Simulated height of every configuration (at every node) [mm] (NaN where it
            failed).

        Returns
        -------
        Simulated
        """
        return Simulated(extras, np.isfinite(extras))

    def predictive(
        self, u: np.ndarray, law: Law, sim: Simulated | None, rng: np.random.Generator
    ) -> dict[str, np.ndarray]:
        """Simulated heights and replicated measurements [mm] of every jump.

        Parameters
        ----------
        u : ndarray, shape (n, n_coordinates)
            The block's coordinates of n draws.
        law : callable
            The force law (unused: the heights carry it).
        sim : Simulated
            The simulated height of every configuration.
        rng : numpy.random.Generator
            Source of the replicate noise.

        Returns
        -------
        dict of str to ndarray, shape (n, n_jumps)
            ``height_sim_mm`` (no noise) and ``height_mm`` (plus one draw of the noise;
            NaN where a simulation failed). With a latent bed phi, each replicate's bed
            is one draw of it (:meth:`BedPhi.draw`): ``height_sim_mm`` is the height on
            that bed (the spline between the nodes).
        """
        if self.bed.size == 1:
            mean = sim.heights_mm[:, self.obs.config_of_obs]
        else:
            heights = self._node_heights(sim)
            mean = self.bed.interpolate(heights, self.bed.draw(rng, heights.shape[:2]))
        rep = self.add_noise(mean, self._sigma(u, self.obs), rng)
        return {"height_mm": rep, "height_sim_mm": mean}

    def values(self, u: np.ndarray, phis: np.ndarray) -> dict[str, np.ndarray]:
        """``sigma_mm`` [mm] at ``phis`` (NaN where it was not fitted).

        Parameters
        ----------
        u : ndarray, shape (n, n_coordinates)
            The block's coordinates.
        phis : ndarray
            Volume fractions.

        Returns
        -------
        dict of str to ndarray, shape (n, len(phis))
        """
        return {"sigma_mm": self.sigma_at(u, phis)}
