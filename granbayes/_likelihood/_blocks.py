"""What a kind of measurement contributes to a model: its block of the likelihood.

A :class:`Block` holds the measurements of one kind that one model fits (jump heights,
tracked trajectories, intrusion curves, ...), its own sampled coordinates (noise scales,
correlation times: never force parameters, which belong to the law), what it asks the
compiled simulator for (:class:`JumpRequest`), and its observation model: the pointwise
log-likelihood of its units (the unit of leave-one-out: a jump, a tracked jump, an
intrusion test), posterior-predictive replicates, and the values of its coordinates per
volume fraction for the posterior. The model (:class:`granbayes._likelihood.JumpModel`)
owns the force law and knows blocks only through this interface; the registry of kinds
(:mod:`granbayes.kinds`) says which block reads which file.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from typing import ClassVar

import numpy as np
import pandas as pd

from .._priors import Prior
from ..commands import CommandProgram
from ._beds import BedPhi

__all__ = ["Block", "Coordinate", "JumpRequest", "Law", "ObservationSettings", "Simulated"]


class Law:
    """The force law of n walkers, as the blocks see it (made by the model).

    Parameters
    ----------
    values : callable
        ``values(phis)[name]``: every fitted force parameter [SI] at volume fractions
        ``phis``, shape ``(n, len(phis))``.
    rows : callable
        ``rows(phis)``: the integrator rows (robot, phi and every force parameter,
        ``granbayes._simulator.build_rows`` layout) of every (walker, phi) pair,
        walker-major, shape ``(n * len(phis), ROW_SIZE)``.
    """

    def __init__(
        self,
        values: Callable[[np.ndarray], Mapping[str, np.ndarray]],
        rows: Callable[[np.ndarray], np.ndarray],
    ) -> None:
        self.values = values
        self.rows = rows


@dataclass(frozen=True)
class ObservationSettings:
    """How the blocks model their measurements (the settings of every kind's noise).

    Attributes
    ----------
    noise : {"normal", "student_t"}
        Noise family of the jump heights.
    nu : float
        Student-t degrees of freedom.
    sigma_mode : {"per_phi", "global"}
        The heights' scatter per volume fraction or one for all.
    max_offset_frames : float
        The largest offset of a camera's clock from the command's [frames], marginalised
        (tracked jumps) with a uniform prior over +/- this many frame intervals (rounded
        up, plus half a grid step; :mod:`granbayes._likelihood._trajectories`). "A few
        frames" (physics-model.md section 5b): 5 covers a clock offset of standard
        deviation 2 frames in 98.8% of jumps.
    offset_step_ms : float
        The largest step of the grid the clock offset is linearised about [ms].
    bed : BedPhi
        Each bed's true volume fraction about the measured one, integrated out by the
        blocks of jump heights and intrusion tests (default: measured exactly). Tracked
        jumps take the measured phi.
    """

    noise: str = "normal"
    nu: float = 4.0
    sigma_mode: str = "per_phi"
    max_offset_frames: float = 5.0
    offset_step_ms: float = 0.25
    bed: BedPhi = field(default_factory=BedPhi)


@dataclass(frozen=True)
class Coordinate:
    """One sampled coordinate: a parameter (or polynomial coefficient) with its prior.

    Attributes
    ----------
    name : str
        Column name, e.g. ``"k"``, ``"k:c1"``, ``"sigma_mm[0.592]"``.
    parameter : str
        The physical parameter it belongs to.
    prior : Prior
        Its prior (in the parameter's unit; sampled in its sampling coordinate).
    order : int
        Polynomial order in ``phi - phi_c`` (quadratic laws); 0 otherwise.
    phi : float, optional
        The volume fraction a per-phi coordinate belongs to (``None``: all).
    """

    name: str
    parameter: str
    prior: Prior
    order: int = 0
    phi: float | None = None


@dataclass(frozen=True)
class JumpRequest:
    """Jumps a block asks the compiled simulator for: one per configuration.

    Attributes
    ----------
    phi : ndarray, shape (m,)
        Volume fraction of each simulated jump [-].
    programs : list of CommandProgram
        Its command program.
    frame_times_s : list of ndarray, optional
        Times [s] on the command's clock at which the foot and rod positions are wanted,
        one array per jump (``None``: heights only).
    """

    phi: np.ndarray
    programs: list[CommandProgram] = field(repr=False)
    frame_times_s: list[np.ndarray] | None = field(default=None, repr=False)

    @property
    def n_jumps(self) -> int:
        """Number of simulated jumps."""
        return len(self.programs)


@dataclass(frozen=True)
class Simulated:
    """What the simulator returned for a block's :class:`JumpRequest`, for n walkers.

    Attributes
    ----------
    heights_mm : ndarray, shape (n, m)
        Jump heights [mm] (NaN where the simulation failed).
    ok : ndarray of bool, shape (n, m)
        Whether each simulation succeeded.
    frames : ndarray, shape (n, n_frames, 4), optional
        Foot height, rod displacement [mm] and foot, rod velocity [mm/s] at every requested
        frame time, the jumps' frames concatenated in request order.
    """

    heights_mm: np.ndarray
    ok: np.ndarray
    frames: np.ndarray | None = None


class Block:
    """The likelihood block of one kind of measurement (see the module docstring).

    Subclasses set the class attributes and implement the methods; the defaults describe
    a block that needs no simulation and has no coordinates.

    Attributes
    ----------
    kind : str
        The registry name of its kind (:data:`granbayes.kinds.KINDS`).
    unit_dim : str
        Dimension of its units of leave-one-out in a fit's DataTree.
    variable : str
        Name of its pointwise log-likelihood in the DataTree's ``log_likelihood`` group.
    max_predictive_draws : int or None
        Most posterior draws whose replicates a fit keeps, thinned evenly over
        ``(chain, draw)`` onto the dimension ``predictive_draw`` (``None``: every draw,
        on ``(chain, draw)``): for measurements with many elements per unit (frames).
    """

    kind: str = ""
    unit_dim: str = ""
    variable: str = ""
    max_predictive_draws: int | None = None

    @property
    def table(self) -> pd.DataFrame:
        """The block's measurements, one row per record of its file."""
        raise NotImplementedError

    @property
    def n_units(self) -> int:
        """Number of units (leave-one-out is over units)."""
        raise NotImplementedError

    @property
    def phis(self) -> np.ndarray:
        """Sorted distinct volume fractions of its measurements."""
        raise NotImplementedError

    def with_data(self, table: pd.DataFrame) -> Block:
        """A block of other measurements of its kind under this block's coordinates.

        Held-out units of a cross-validation, or a new experiment, scored with the fitted
        block's noise parameters.

        Parameters
        ----------
        table : pandas.DataFrame
            Measurements of the block's kind at volume fractions it has parameters for.

        Returns
        -------
        Block
        """
        raise NotImplementedError

    def coordinates(self, priors: Mapping[str, Prior], phis: np.ndarray) -> list[Coordinate]:
        """The block's sampled coordinates.

        Parameters
        ----------
        priors : mapping of str to Prior
            Priors by parameter name (a block falls back on its own defaults).
        phis : ndarray
            Volume fractions of the whole model.

        Returns
        -------
        list of Coordinate
        """
        return []

    def jump_request(self) -> JumpRequest | None:
        """The jumps to simulate (``None``: the block needs no compiled simulation)."""
        return None

    def log_lik(self, u: np.ndarray, law: Law, sim: Simulated | None) -> np.ndarray:
        """Pointwise log-likelihood of the block's units.

        Parameters
        ----------
        u : ndarray, shape (n, n_coordinates)
            The block's own coordinates (sampling coordinates) of n walkers.
        law : callable
            The force law of the walkers (:class:`Law`).
        sim : Simulated or None
            The simulator's answer to :meth:`jump_request`.

        Returns
        -------
        ndarray, shape (n, n_units)
            ``-inf`` where a simulation failed.
        """
        raise NotImplementedError

    def n_extras(self) -> int:
        """Values per walker the sampler keeps beside the log-likelihood (its blob)."""
        return 0

    def extras(self, sim: Simulated | None) -> np.ndarray:
        """The kept values (see :meth:`n_extras`).

        Parameters
        ----------
        sim : Simulated or None
            The simulator's answer to :meth:`jump_request`.

        Returns
        -------
        ndarray, shape (n, n_extras)
        """
        n = 0 if sim is None else sim.heights_mm.shape[0]
        return np.empty((n, 0))

    def from_extras(self, extras: np.ndarray) -> Simulated | None:
        """The simulation a draw's kept values stand for (see :meth:`n_extras`).

        Parameters
        ----------
        extras : ndarray, shape (n, n_extras)
            The values :meth:`extras` returned.

        Returns
        -------
        Simulated or None
            ``None`` if the kept values cannot replace a simulation.
        """
        return None

    #: The dimension of each posterior-predictive variable of the block: one value per
    #: row of :attr:`table`.
    predictive_dims: ClassVar[Mapping[str, str]] = {}

    def predictive(
        self, u: np.ndarray, law: Law, sim: Simulated | None, rng: np.random.Generator
    ) -> dict[str, np.ndarray]:
        """Posterior- (or prior-) predictive replicates of the block's measurements.

        Parameters
        ----------
        u : ndarray, shape (n, n_coordinates)
            The block's coordinates of n draws.
        law : callable
            The force law of the walkers (:class:`Law`).
        sim : Simulated or None
            The simulator's answer to :meth:`jump_request` for the draws.
        rng : numpy.random.Generator
            Source of the replicate noise.

        Returns
        -------
        dict of str to ndarray, shape (n, len(table))
            Variables named in :attr:`predictive_dims`.
        """
        return {}

    def values(self, u: np.ndarray, phis: np.ndarray) -> dict[str, np.ndarray]:
        """The block's parameters [their units] at volume fractions ``phis``.

        Parameters
        ----------
        u : ndarray, shape (n, n_coordinates)
            The block's coordinates.
        phis : ndarray
            Volume fractions.

        Returns
        -------
        dict of str to ndarray, shape (n, len(phis))
            NaN at volume fractions the block has no value for.
        """
        return {}


def noise_coordinates(name: str, prior: Prior, phis: np.ndarray, per_phi: bool) -> list[Coordinate]:
    """Coordinates of a noise parameter: one per volume fraction, or one for all.

    Parameters
    ----------
    name : str
        The parameter (``force_sd_N``, ``frame_tau_ms``, ...).
    prior : Prior
        Its prior.
    phis : ndarray
        The volume fractions of the block's measurements.
    per_phi : bool
        One coordinate per volume fraction (named ``name[phi]``), else one (``name``).

    Returns
    -------
    list of Coordinate
    """
    if not per_phi:
        return [Coordinate(name, name, prior)]
    return [Coordinate(f"{name}[{phi:g}]", name, prior, phi=float(phi)) for phi in phis]


def coordinate_values(
    coords: list[Coordinate], u: np.ndarray, phis: np.ndarray
) -> dict[str, np.ndarray]:
    """The parameters of per-phi (or global) noise coordinates at volume fractions ``phis``.

    Parameters
    ----------
    coords : list of Coordinate
        A block's coordinates, each of one parameter at one ``phi`` (or at all: ``None``).
    u : ndarray, shape (n, len(coords))
        Their values in sampling coordinates.
    phis : ndarray
        Volume fractions.

    Returns
    -------
    dict of str to ndarray, shape (n, len(phis))
        Per parameter its value [its unit]; NaN at volume fractions it has none for.
    """
    out: dict[str, np.ndarray] = {}
    for j, c in enumerate(coords):
        arr = out.setdefault(c.parameter, np.full((u.shape[0], len(phis)), np.nan))
        value = c.prior.to_value(u[:, j])
        for i, phi in enumerate(phis):
            if c.phi is None or math.isclose(c.phi, phi, abs_tol=1e-12):
                arr[:, i] = value
    return out
