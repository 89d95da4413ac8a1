"""Intrusion curves: force-depth samples of constant-speed intrusions, and their noise.

Each test drives the foot alone at a constant speed into a fresh bed
(physics-model.md section 5b); the model's force at every sample's depth is closed-form
(:func:`granbayes.intrusion_force_rows`, no ODE), so the block asks the jump
simulator for nothing. Observation model: the measured force is the model's plus
independent Gaussian noise of a fitted scale ``force_sd_N`` [N] per volume fraction (one
load cell, read at depths much farther apart than the cell's response: white noise). The
unit of leave-one-out is a whole test (its samples are one curve, not exchangeable).
With ``bed`` (a :class:`~granbayes._likelihood._beds.BedPhi` with ``phi_sd > 0``) each test's
bed has a latent volume fraction, shared by its samples and integrated out by quadrature
per test.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import ClassVar

import numpy as np
import pandas as pd

from .._priors import Prior
from .._simulator import ROW_FIELDS, intrusion_force_rows
from ._beds import BedPhi
from ._blocks import Block, Coordinate, Law, Simulated, coordinate_values, noise_coordinates

__all__ = ["IntrusionBlock"]

_ROW_RADIUS = ROW_FIELDS.index("foot_radius")

#: Highest degree of a sample's force as a polynomial in its bed's latent phi.
_DEGREE = 4

#: Default prior of the force noise: a load cell's noise, from 1 mN to 20 N.
FORCE_SD_PRIOR = Prior(
    "loguniform", 1e-3, 20.0, unit="N", why="noise of the intrusion rig's force readings"
)


class IntrusionBlock(Block):
    """Measured intrusion forces: Gaussian noise ``force_sd_N`` around the model's force.

    Parameters
    ----------
    table : pandas.DataFrame
        Samples of intrusion tests (``load_intrusions``): ``test``, ``phi``,
        ``speed_mm_s``, ``depth_mm``, ``force_N``, ``foot_radius`` (NaN: the robot's).
    sd_mode : {"per_phi", "global"}
        The force noise per volume fraction, or one for all.
    bed : BedPhi, optional
        Each test's bed's true volume fraction about the measured one, integrated out
        (default: measured exactly).
    """

    kind = "intrusions"
    unit_dim = "test"
    variable = "intrusion"
    predictive_dims: ClassVar[Mapping[str, str]] = {"force_N": "reading", "force_sim_N": "reading"}

    def __init__(
        self, table: pd.DataFrame, *, sd_mode: str = "per_phi", bed: BedPhi | None = None
    ) -> None:
        self._table = table.reset_index(drop=True)
        self.sd_mode = sd_mode
        self.bed = bed if bed is not None else BedPhi()
        codes, _ = pd.factorize(self._table["test"].astype(str), sort=False)
        self._unit = np.asarray(codes, dtype=np.int64)
        self._n_units = int(self._unit.max()) + 1 if len(self._unit) else 0
        self._y = self._table["force_N"].to_numpy(float)
        self._depth = self._table["depth_mm"].to_numpy(float)
        self._speed = self._table["speed_mm_s"].to_numpy(float)
        phi = self._table["phi"].to_numpy(float)
        radius = self._table["foot_radius"].to_numpy(float)
        # one integrator row per (phi, foot radius) a test uses
        keys = pd.DataFrame({"phi": phi, "radius": np.nan_to_num(radius, nan=-1.0)})
        codes, uniques = pd.factorize(pd.MultiIndex.from_frame(keys), sort=True)
        self._variant = np.asarray(codes, dtype=np.int64)
        self._variant_phi = np.array([u[0] for u in uniques], dtype=float)
        self._variant_radius = np.array([u[1] for u in uniques], dtype=float)
        self._phis = np.unique(phi)
        self._sample_phi_index = np.searchsorted(self._phis, phi)
        self._order = np.argsort(self._unit, kind="stable")
        self._starts = np.searchsorted(self._unit[self._order], np.arange(self._n_units))
        self._coords: list[Coordinate] = []

    @property
    def table(self) -> pd.DataFrame:
        """The samples."""
        return self._table

    @property
    def n_units(self) -> int:
        """Number of tests."""
        return self._n_units

    @property
    def phis(self) -> np.ndarray:
        """Volume fractions of the tests."""
        return self._phis

    def coordinates(self, priors: Mapping[str, Prior], phis: np.ndarray) -> list[Coordinate]:
        """``force_sd_N`` per volume fraction of the tests (or once, ``global``).

        Parameters
        ----------
        priors : mapping of str to Prior
            ``priors["force_sd_N"]`` if given (default :data:`FORCE_SD_PRIOR`).
        phis : ndarray
            Volume fractions of the whole model (unused).

        Returns
        -------
        list of Coordinate
        """
        prior = priors.get("force_sd_N", FORCE_SD_PRIOR)
        per_phi = self.sd_mode != "global"
        self._coords = noise_coordinates("force_sd_N", prior, self._phis, per_phi)
        return list(self._coords)

    def with_data(self, table: pd.DataFrame) -> IntrusionBlock:
        """Other tests under this block's coordinates.

        Parameters
        ----------
        table : pandas.DataFrame
            Samples at volume fractions this block has a noise scale for.

        Returns
        -------
        IntrusionBlock
        """
        other = IntrusionBlock(table, sd_mode=self.sd_mode, bed=self.bed)
        other._coords = self._coords
        return other

    def _sd(self, u: np.ndarray) -> np.ndarray:
        """Noise scale [N] of every sample: (n, n_samples)."""
        at = self.values(u, self._phis)["force_sd_N"]
        if np.any(np.isnan(at)):
            missing = self._phis[np.any(np.isnan(at), axis=0)]
            raise ValueError(f"no fitted force noise at phi = {missing.tolist()}")
        return at[:, self._sample_phi_index]

    def force_N(self, law: Law) -> np.ndarray:
        """The model's force [N] at every sample for every walker: (n, n_samples).

        Parameters
        ----------
        law : Law
            The force law of n walkers.

        Returns
        -------
        ndarray
            NaN where a walker's law is not valid; at the measured volume fractions.
        """
        return self._node_force_N(law, BedPhi())[..., 0]

    def _node_force_N(self, law: Law, bed: BedPhi) -> np.ndarray:
        """The force [N] at every sample and node of ``bed``: (n, n_samples, bed.size)."""
        size = bed.size
        n_var = len(self._variant_phi) * size  # one integrator row per variant and node
        rows = law.rows(bed.nodes(self._variant_phi))
        n = rows.shape[0] // max(n_var, 1)
        given = np.repeat(self._variant_radius > 0, size)
        if np.any(given):
            rows = rows.reshape(n, n_var, -1)
            rows[:, given, _ROW_RADIUS] = np.repeat(self._variant_radius, size)[given]
            rows = rows.reshape(n * n_var, -1)
        m = len(self._y)
        row_of = (self._variant[:, None] * size + np.arange(size)[None, :]).reshape(-1)
        index = (np.arange(n)[:, None] * n_var + row_of[None, :]).reshape(-1)
        depth = np.tile(np.repeat(self._depth, size), n)
        speed = np.tile(np.repeat(self._speed, size), n)
        force = intrusion_force_rows(rows, depth, speed, index)
        return force.reshape(n, m, size)

    def _force_polynomial(self, law: Law) -> np.ndarray:
        """Each sample's force [N] as a polynomial in its bed's latent ``x``.

        Shape (n, n_samples, degree + 1), lowest power first: the least-squares
        polynomial of degree ``min(4, n_nodes - 1)`` through the force at the nodes (the
        closed-form force is smooth in phi).
        """
        degree = min(_DEGREE, self.bed.size - 1)
        return self._node_force_N(law, self.bed) @ self.bed.polynomial(degree).T

    def _per_test(self, values: np.ndarray) -> np.ndarray:
        """Sum per test of per-sample values (n, n_samples) -> (n, n_tests)."""
        return np.add.reduceat(values[:, self._order], self._starts, axis=1)

    def log_lik(self, u: np.ndarray, law: Law, sim: Simulated | None) -> np.ndarray:
        """Pointwise log-likelihood of every test (its samples summed).

        Parameters
        ----------
        u : ndarray, shape (n, n_coordinates)
            The block's coordinates.
        law : Law
            The force law of the walkers.
        sim : None
            Unused (the force is closed-form).

        Returns
        -------
        ndarray, shape (n, n_tests)
            ``-inf`` for a test whose force could not be computed. With a latent bed phi,
            each test's density integrated over it (:mod:`granbayes._likelihood._beds`).
        """
        if self.bed.size == 1:
            force = self.force_N(law)
            sd = self._sd(u)
            r = (self._y[None, :] - force) / sd
            logd = -0.5 * r * r - np.log(sd) - 0.5 * math.log(2.0 * math.pi)
            ll = self._per_test(logd)
        else:  # each test's sum of squares is a polynomial in its bed's latent x
            sd = self._sd(u)
            b = -self._force_polynomial(law) / sd[:, :, None]
            b[:, :, 0] += self._y[None, :] / sd
            d = b.shape[-1] - 1
            sq = np.zeros((*b.shape[:2], 2 * d + 1))
            for p in range(d + 1):
                sq[:, :, p : p + d + 1] += b[:, :, p : p + 1] * b
            n, m, k = sq.shape
            q = self._per_test(sq.transpose(0, 2, 1).reshape(n * k, m))
            q = q.reshape(n, k, -1).transpose(0, 2, 1)
            const = self._per_test(-np.log(sd) - 0.5 * math.log(2.0 * math.pi))
            ll = const + self.bed.integrate_polynomial(q)
        ll[~np.isfinite(ll)] = -np.inf
        return ll

    def predictive(
        self, u: np.ndarray, law: Law, sim: Simulated | None, rng: np.random.Generator
    ) -> dict[str, np.ndarray]:
        """The model's force and replicated measurements [N] at every sample.

        Parameters
        ----------
        u : ndarray, shape (n, n_coordinates)
            The block's coordinates of n draws.
        law : Law
            The force law of the draws.
        sim : None
            Unused.
        rng : numpy.random.Generator
            Source of the replicate noise.

        Returns
        -------
        dict of str to ndarray, shape (n, n_samples)
            ``force_sim_N`` (no noise) and ``force_N`` (plus one draw of the noise). With
            a latent bed phi, each replicated test's bed is one draw of it
            (:meth:`BedPhi.draw`), shared by the test's samples.
        """
        if self.bed.size == 1:
            force = self.force_N(law)
        else:
            coef = self._force_polynomial(law)
            x = self.bed.draw(rng, (coef.shape[0], self._n_units))[:, self._unit]
            force = np.polynomial.polynomial.polyval(x, coef.transpose(2, 0, 1), tensor=False)
        rep = force + self._sd(u) * rng.standard_normal(force.shape)
        return {"force_N": rep, "force_sim_N": force}

    def values(self, u: np.ndarray, phis: np.ndarray) -> dict[str, np.ndarray]:
        """``force_sd_N`` [N] at ``phis`` (NaN where it was not fitted).

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
        return coordinate_values(self._coords, u, phis)
