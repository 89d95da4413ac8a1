"""Tracked jumps (``trajectories.csv``): a camera's frames of the foot and the rod."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd
import xarray as xr

from .. import stats
from .._experiment import Experiment
from .._likelihood import ObservationSettings, TrajectoryBlock
from .._measurements import load_trajectories
from ..commands import SETTINGS, CommandSettings, build_command
from ._kind import FigureName, Kind

__all__ = ["PHASES", "TRAJECTORIES", "frame_phases"]

#: The phases of a tracked jump, the residual cells of a trajectory (with command and
#: setting): before the push-off segment (``stance``), from its start until the measured
#: foot leaves the surface (``push-off``), the rise to the highest measured frame
#: (``flight``) and everything after it (``descent``, the landing included).
PHASES: tuple[str, ...] = ("stance", "push-off", "flight", "descent")

#: Foot height [mm] two successive frames must exceed after the push-off starts for the
#: foot to count as airborne (twice the flight the jump height requires,
#: physics-model.md section 5, so that tracking noise does not trigger it).
LIFTOFF_MM = 2.0

#: Per-jump columns stored as coordinates of the ``trajectory`` dimension.
_UNIT_COLUMNS = ("phi", "command", "trial", *SETTINGS, "source")


def frame_phases(table: pd.DataFrame) -> np.ndarray:
    """The phase (:data:`PHASES`) of every frame of a trajectories table.

    From the command's clock and the measured foot height: ``stance`` before the push-off
    segment starts; ``push-off`` until two successive frames show the foot above
    :data:`LIFTOFF_MM`; ``flight`` until the highest frame after that; ``descent`` after
    it. Without a foot column, frames after the command's end are ``descent``.

    Parameters
    ----------
    table : pandas.DataFrame
        Frames (:func:`granbayes.load_trajectories`).

    Returns
    -------
    ndarray of str
    """
    out = np.empty(len(table), dtype=object)
    t = table["t_s"].to_numpy(float)
    foot = table["x_foot_mm"].to_numpy(float) if "x_foot_mm" in table else None
    for _, idx in table.groupby(table["jump"].astype(str), sort=False).indices.items():
        first = table.iloc[idx[0]]
        settings = CommandSettings(**{s: float(first[s]) for s in SETTINGS})
        program = build_command(str(first["command"]), settings)
        t_push = float(program.boundaries[program.pushoff_index])
        tj = t[idx]
        phase = np.where(tj < t_push, "stance", "push-off").astype(object)
        if foot is None:
            phase[tj > program.t_end] = "descent"
        else:
            fj = foot[idx]
            up = (tj >= t_push) & (fj > LIFTOFF_MM)
            both = np.flatnonzero(up[:-1] & up[1:])
            if len(both):
                lift = both[0]
                apex = lift + int(np.argmax(fj[lift:]))
                phase[lift : apex + 1] = "flight"
                phase[apex + 1 :] = "descent"
        out[idx] = phase
    return out


def _load(path: Path, experiment: Experiment) -> pd.DataFrame:
    return load_trajectories(path, experiment)


def _block(table: pd.DataFrame, settings: ObservationSettings) -> TrajectoryBlock:
    return TrajectoryBlock(table, settings)


def _to_observed(table: pd.DataFrame) -> xr.Dataset:
    """Positions over ``frame``; each tracked jump's columns over ``trajectory``."""
    codes, ids = pd.factorize(table["jump"].astype(str), sort=False)
    first = pd.Series(np.arange(len(table))).groupby(codes).first().to_numpy()
    data = {c: ("frame", table[c].to_numpy(float)) for c in ("x_foot_mm", "x_rod_mm") if c in table}
    coords = {
        "frame": np.arange(len(table)),
        "t_s": ("frame", table["t_s"].to_numpy(float)),
        "frame_trajectory": ("frame", np.asarray(codes, dtype=np.int64)),
        "frame_phase": ("frame", frame_phases(table).astype(str)),
        "trajectory": np.arange(len(ids)),
        "trajectory_id": ("trajectory", np.asarray(ids, dtype=str)),
    }
    for c in _UNIT_COLUMNS:
        if c in table and table[c].notna().all():
            coords[f"trajectory_{c}"] = ("trajectory", table[c].to_numpy()[first])
    return xr.Dataset(data, coords=coords)


def _from_observed(obs: xr.Dataset) -> pd.DataFrame | None:
    if "frame_trajectory" not in obs.coords:
        return None
    unit = obs["frame_trajectory"].values
    table = pd.DataFrame({"jump": obs["trajectory_id"].values[unit]})
    for c in _UNIT_COLUMNS:
        name = f"trajectory_{c}"
        if name in obs.coords:
            table[c] = obs[name].values[unit]
    table["t_s"] = obs["t_s"].values.astype(float)
    for c in ("x_foot_mm", "x_rod_mm"):
        if c in obs:
            table[c] = obs[c].values.astype(float)
    table["phi"] = table["phi"].astype(float)
    table["command"] = table["command"].astype(str)
    return table


#: Tracked jumps: one row per video frame of ``trajectories.csv``, each jump a unit.
TRAJECTORIES = Kind(
    name="trajectories",
    file="trajectories.csv",
    description="tracked jumps, one row per video frame (foot and rod positions)",
    unit_column="jump",
    unit_dim="trajectory",
    load=_load,
    block=_block,
    to_observed=_to_observed,
    from_observed=_from_observed,
    cells=stats.trajectory_cells,
    figures={"trajectories": FigureName("plot_tracked_jumps")},
)
