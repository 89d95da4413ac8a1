"""A prepared bed's true volume fraction, integrated out of the likelihood.

The contract (data-format.md, ``[bed] phi_sd``): each prepared bed's true phi is
``Normal(measured phi, phi_sd)``. The tables say which bed a measurement comes from only
through its row: ``jumps.csv`` and ``intrusions.csv`` have no bed identifier, and the
thesis's protocol prepares the bed afresh before every jump and every intrusion. So a bed
here is a unit of leave-one-out: **one jump, one intrusion test**, each on its own bed. (A
lab that prepares one bed per target volume fraction instead has an error shared by every
measurement at it: a per-phi fit absorbs it into that volume fraction's coefficients,
which then belong to the bed actually prepared.)

The marginal likelihood of a unit ``y`` is, with ``x = (phi - phi_m) / phi_sd``,

    p(y) = integral p(y | phi_m + phi_sd x) N(x; 0, 1) dx.

**How it is computed, and why not plain Gauss-Hermite.** The integrand is narrow whenever
the measurement pins the bed's phi better than ``phi_sd`` does: a jump whose height moves by
more than its scatter over one ``phi_sd`` (``k`` of the reference truth changes by 8% per
0.002), and above all an intrusion curve (dozens of force readings with 0.3 N noise on
forces of 10-100 N locate its bed's phi to a hundredth of ``phi_sd``). Gauss-Hermite nodes
placed for the normal weight miss such a peak: measured on jumps whose heights move 4 mm
per ``phi_sd`` against a 2 mm scatter, 5 and 9 nodes err by up to 0.43 and 0.19 nats per
jump. So the simulator is run at ``n_nodes`` volume fractions spread evenly over
``+/- reach_sd`` standard deviations and each unit's prediction is interpolated between
them; the density of the measurement is then integrated with a rule that resolves its
peak. Jump heights: a cubic spline through the nodes (measured against piecewise-linear,
PCHIP and Akima interpolation: with 9 nodes it erred least but Akima's, and it is linear in
the node values, so one matrix), the density on a fine grid (trapezoid rule against the
normal weight, renormalised over ``+/- reach_sd``: the 6e-5 of mass beyond 4 sd is
dropped). Intrusion forces, closed-form and smooth in phi: a least-squares polynomial of
degree <= 4 through the nodes, which makes a test's sum of squares a polynomial in ``x``,
integrated by adaptive Gauss-Hermite quadrature (about the mode of each test's integrand,
however narrow). The error against brute-force integration is measured in
``tests/test_latent_phi.py``: a simulated height is not smooth in phi at the scale of
regime switches, so a jump whose height moves several scatters per ``phi_sd`` is the hard
case (0.02 nats per jump with 9 nodes where heights move 5 mm per sd against 1 mm).

A unit's log-likelihood stays one value per unit (jump, test), so PSIS-LOO, moment
matching and K-fold see the same units. The cost: ``n_nodes`` simulations per configuration
instead of one (configurations are shared by the jumps at one measured phi, so the nodes
are too), plus the fine-grid densities (array arithmetic).

Only a law that is defined between measured volume fractions can be evaluated at a node:
the smooth laws in ``phi - phi_c`` (``phi_mode="quadratic"``). The fit decides where it
applies (:mod:`granbayes._fitting`); here is only the integration.
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass

import numpy as np
from scipy.interpolate import CubicSpline
from scipy.special import logsumexp

__all__ = ["BedPhi"]


def _polyval(coef: np.ndarray, x: np.ndarray) -> np.ndarray:
    """Polynomials (coefficients ``(..., d + 1)``, lowest first) at ``x`` ``(..., K)``.

    NumPy's Horner evaluation, with the coefficients on the last axis and broadcast
    against ``x``.
    """
    return np.polynomial.polynomial.polyval(x, np.moveaxis(coef, -1, 0)[..., None], tensor=False)


@functools.lru_cache(maxsize=4)
def _gauss_hermite(n: int) -> tuple[np.ndarray, np.ndarray]:
    """Probabilists' Gauss-Hermite nodes and weights: ``integral f(z) exp(-z^2/2) dz``."""
    z, w = np.polynomial.hermite_e.hermegauss(n)
    return z, w


@dataclass(frozen=True)
class BedPhi:
    """A bed's latent volume fraction about its measured value, and its integration.

    Parameters
    ----------
    phi_sd : float
        Standard deviation of a bed's true volume fraction about the measured one [-];
        0: measured exactly (one node: the plain likelihood, bit for bit).
    n_nodes : int
        Volume fractions simulated per measured one (>= 3), evenly spread over
        ``+/- reach_sd`` standard deviations (odd counts include the measured value).
    reach_sd : float
        Half-width of the integration range [standard deviations of phi].
    """

    phi_sd: float = 0.0
    n_nodes: int = 9
    reach_sd: float = 4.0

    def __post_init__(self) -> None:
        """Check the values."""
        if not (math.isfinite(self.phi_sd) and self.phi_sd >= 0.0):
            raise ValueError(f"phi_sd must be finite and >= 0, got {self.phi_sd!r}")
        if int(self.n_nodes) != self.n_nodes or self.n_nodes < 3:
            raise ValueError(f"n_nodes must be an integer >= 3, got {self.n_nodes!r}")
        if not (math.isfinite(self.reach_sd) and self.reach_sd > 0.0):
            raise ValueError(f"reach_sd must be finite and > 0, got {self.reach_sd!r}")

    @property
    def latent(self) -> bool:
        """Whether the volume fraction is integrated out (``phi_sd > 0``)."""
        return self.phi_sd > 0.0

    @property
    def size(self) -> int:
        """Simulations per measured configuration: ``n_nodes``, or 1 when exact."""
        return int(self.n_nodes) if self.latent else 1

    @functools.cached_property
    def x_nodes(self) -> np.ndarray:
        """The nodes in standard deviations of phi, shape (size,)."""
        if not self.latent:
            return np.zeros(1)
        return np.linspace(-self.reach_sd, self.reach_sd, int(self.n_nodes))

    @property
    def offsets(self) -> np.ndarray:
        """Offsets of the nodes from the measured volume fraction [-], shape (size,)."""
        return self.phi_sd * self.x_nodes

    def nodes(self, phi: np.ndarray) -> np.ndarray:
        """The nodes of every measured volume fraction, node-minor: shape (len(phi) * size,).

        Parameters
        ----------
        phi : ndarray
            Measured volume fractions.

        Returns
        -------
        ndarray
            ``phi[i] + offsets[q]`` at position ``i * size + q``.
        """
        phi = np.asarray(phi, dtype=float)
        return (phi[:, None] + self.offsets[None, :]).reshape(-1)

    @functools.lru_cache(maxsize=4)  # noqa: B019 (frozen, hashable, few instances)
    def grid(self, per_interval: int) -> tuple[np.ndarray, np.ndarray]:
        """A fine grid over ``+/- reach_sd`` and its log quadrature weights.

        Parameters
        ----------
        per_interval : int
            Grid steps per interval between nodes.

        Returns
        -------
        x : ndarray, shape (K,)
            Grid points [standard deviations of phi].
        log_w : ndarray, shape (K,)
            Log weights: trapezoid rule times the normal density, normalised to sum 1.
        """
        k = per_interval * (int(self.n_nodes) - 1) + 1
        x = np.linspace(-self.reach_sd, self.reach_sd, k)
        w = np.exp(-0.5 * x * x)
        w[[0, -1]] *= 0.5
        return x, np.log(w / w.sum())

    @functools.lru_cache(maxsize=4)  # noqa: B019
    def spline(self, per_interval: int) -> np.ndarray:
        """Cubic-spline interpolation from the nodes to :meth:`grid`: shape (size, K).

        Parameters
        ----------
        per_interval : int
            Grid steps per interval between nodes.

        Returns
        -------
        ndarray
            ``values_at_grid = values_at_nodes @ matrix`` (a not-a-knot cubic spline is
            linear in the values it interpolates).
        """
        x, _ = self.grid(per_interval)
        return self.spline_basis(x).T

    def spline_basis(self, x: np.ndarray) -> np.ndarray:
        """The cubic spline's weights of every node at ``x``: shape (*x.shape, size).

        Parameters
        ----------
        x : ndarray
            Where [standard deviations of phi], within the reach.

        Returns
        -------
        ndarray
        """
        return CubicSpline(self.x_nodes, np.eye(self.size))(np.asarray(x, dtype=float))

    def polynomial(self, degree: int) -> np.ndarray:
        """Least-squares polynomial in ``x`` through the nodes: shape (degree + 1, size).

        Parameters
        ----------
        degree : int
            Degree (< ``n_nodes``).

        Returns
        -------
        ndarray
            ``coefficients = matrix @ values_at_nodes``, lowest power first.
        """
        vander = np.vander(self.x_nodes, degree + 1, increasing=True)
        return np.linalg.pinv(vander)

    def interpolate(self, values: np.ndarray, x: np.ndarray) -> np.ndarray:
        """The cubic spline through node values, at latent ``x``.

        Parameters
        ----------
        values : ndarray, shape (..., size)
            Values at the nodes.
        x : ndarray, shape (...)
            Where [standard deviations of phi], within the reach.

        Returns
        -------
        ndarray, shape (...)
        """
        return np.sum(values * self.spline_basis(x), axis=-1)

    def integrate_polynomial(self, q: np.ndarray, n_points: int = 24) -> np.ndarray:
        """``log integral exp(-q(x) / 2) N(x; 0, 1) dx`` for polynomials ``q`` in ``x``.

        Adaptive Gauss-Hermite quadrature (the integrand's mode and curvature found per
        unit, then ``n_points`` Gauss-Hermite points scaled to them; exact for a Gaussian
        integrand, and accurate for a peak of any width, unlike a fixed grid).

        Parameters
        ----------
        q : ndarray, shape (..., degree + 1)
            Coefficients of each unit's ``q(x)`` (a sum of squared standardised
            residuals), lowest power first.
        n_points : int
            Gauss-Hermite points about each mode.

        Returns
        -------
        ndarray, shape (...)
            ``-inf`` where not finite.
        """
        q = np.asarray(q, dtype=float)
        d1 = q[..., 1:] * np.arange(1, q.shape[-1])  # q'
        d2 = d1[..., 1:] * np.arange(1, d1.shape[-1])  # q''

        def g(x):  # log integrand without the normal's constant
            return -0.5 * _polyval(q, x) - 0.5 * x * x

        x0, _ = self.grid(16)
        start = np.argmax(g(np.broadcast_to(x0, (*q.shape[:-1], len(x0)))), axis=-1)
        x = x0[start].astype(float)
        with np.errstate(all="ignore"):
            for _ in range(8):  # Newton on g'(x) = -q'(x)/2 - x
                grad = -0.5 * _polyval(d1, x[..., None])[..., 0] - x
                curv = -0.5 * _polyval(d2, x[..., None])[..., 0] - 1.0
                step = np.where(curv < 0, -grad / curv, 0.0)
                x = x + np.clip(step, -0.5, 0.5)
            curv = 0.5 * _polyval(d2, x[..., None])[..., 0] + 1.0
            scale = 1.0 / np.sqrt(np.where(curv > 0, curv, 1.0))
            z, w = _gauss_hermite(n_points)
            pts = x[..., None] + scale[..., None] * z
            log_int = logsumexp(g(pts) + 0.5 * z * z + np.log(w), axis=-1)
            out = log_int + np.log(scale) - 0.5 * math.log(2.0 * math.pi)
        out = np.asarray(out, dtype=float)
        out[~np.isfinite(out)] = -np.inf
        return out

    def integrate(self, log_lik: np.ndarray, log_w: np.ndarray) -> np.ndarray:
        """``log sum_k w_k exp(log_lik[..., k])``: a unit's marginal log-likelihood.

        Parameters
        ----------
        log_lik : ndarray, shape (..., K)
            The unit's log-likelihood at every grid point.
        log_w : ndarray, shape (K,)
            The grid's log weights (:meth:`grid`).

        Returns
        -------
        ndarray, shape (...)
            ``-inf`` where every grid point is (or any is NaN).
        """
        with np.errstate(invalid="ignore"):
            out = logsumexp(log_lik + log_w, axis=-1)
        out = np.asarray(out)
        out[np.isnan(out)] = -np.inf
        return out

    def draw(self, rng: np.random.Generator, shape: tuple[int, ...]) -> np.ndarray:
        """Latent ``x`` of replicated units' beds: Normal(0, 1) truncated to the reach.

        Parameters
        ----------
        rng : numpy.random.Generator
            Source of randomness.
        shape : tuple of int
            Shape of the draw.

        Returns
        -------
        ndarray
            Standard deviations of phi.
        """
        x = rng.standard_normal(shape)
        bad = np.abs(x) > self.reach_sd
        while np.any(bad):
            x[bad] = rng.standard_normal(int(bad.sum()))
            bad = np.abs(x) > self.reach_sd
        return x
