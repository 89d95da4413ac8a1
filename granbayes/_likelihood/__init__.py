"""Likelihood of measurements under a force law, with its priors.

The public surface: :class:`JumpModel` (the force law and the blocks of every kind of
measurement), :func:`evaluate_models` (many models, one simulator call), the block
interface (:class:`Block`, :class:`Coordinate`, :class:`JumpRequest`, :class:`Simulated`),
the quadrature of a bed's latent volume fraction (:class:`BedPhi`) and the blocks of the
library's kinds (:class:`HeightBlock` with its grouped :class:`Observations`,
:class:`TrajectoryBlock`, :class:`IntrusionBlock`). Implementation modules: ``_model`` (the
law and evaluation), ``_blocks`` (the interface), ``_beds`` (a bed's latent volume
fraction), ``_heights`` (jump heights), ``_trajectories`` (tracked jumps), ``_intrusions``
(intrusion curves).
"""

from ._beds import BedPhi
from ._blocks import Block, Coordinate, JumpRequest, Law, ObservationSettings, Simulated
from ._heights import HeightBlock, NoiseFamily, Observations, SigmaMode
from ._intrusions import IntrusionBlock
from ._model import CALIBRATED_KEYS, Evaluation, JumpModel, PhiMode, evaluate_models
from ._trajectories import TrajectoryBlock

__all__ = [
    "CALIBRATED_KEYS",
    "BedPhi",
    "Block",
    "Coordinate",
    "Evaluation",
    "HeightBlock",
    "IntrusionBlock",
    "JumpModel",
    "JumpRequest",
    "Law",
    "NoiseFamily",
    "ObservationSettings",
    "Observations",
    "PhiMode",
    "SigmaMode",
    "Simulated",
    "TrajectoryBlock",
    "evaluate_models",
]
