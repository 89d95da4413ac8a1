"""Intrusion curves (``intrusions.csv``): force against depth at constant speeds."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd
import xarray as xr

from .. import stats
from .._experiment import Experiment
from .._likelihood import IntrusionBlock, ObservationSettings
from .._measurements import load_intrusions
from ._kind import FigureName, Kind

__all__ = ["INTRUSIONS"]

_UNIT_COLUMNS = ("phi", "speed_mm_s", "foot_radius")


def _load(path: Path, experiment: Experiment) -> pd.DataFrame:
    return load_intrusions(path)


def _block(table: pd.DataFrame, settings: ObservationSettings) -> IntrusionBlock:
    return IntrusionBlock(table, sd_mode=settings.sigma_mode, bed=settings.bed)


def _to_observed(table: pd.DataFrame) -> xr.Dataset:
    """Forces over ``reading``; each test's phi, speed and foot radius over ``test``.

    A reading is one force sample of the rig (ArviZ reserves the name ``sample`` for
    stacked draws).
    """
    codes, ids = pd.factorize(table["test"].astype(str), sort=False)
    first = pd.Series(np.arange(len(table))).groupby(codes).first().to_numpy()
    coords = {
        "reading": np.arange(len(table)),
        "depth_mm": ("reading", table["depth_mm"].to_numpy(float)),
        "reading_test": ("reading", np.asarray(codes, dtype=np.int64)),
        "test": np.arange(len(ids)),
        "test_id": ("test", np.asarray(ids, dtype=str)),
    }
    for c in _UNIT_COLUMNS:
        coords[f"test_{c}"] = ("test", table[c].to_numpy(float)[first])
    if "source" in table and table["source"].notna().all():
        coords["test_source"] = ("test", table["source"].astype(str).to_numpy()[first])
    return xr.Dataset({"force_N": ("reading", table["force_N"].to_numpy(float))}, coords=coords)


def _from_observed(obs: xr.Dataset) -> pd.DataFrame | None:
    if "reading_test" not in obs.coords:
        return None
    unit = obs["reading_test"].values
    table = pd.DataFrame({"test": obs["test_id"].values[unit]})
    for c in _UNIT_COLUMNS:
        table[c] = obs[f"test_{c}"].values[unit].astype(float)
    table["depth_mm"] = obs["depth_mm"].values.astype(float)
    table["force_N"] = obs["force_N"].values.astype(float)
    return table[["test", "phi", "speed_mm_s", "depth_mm", "force_N", "foot_radius"]]


#: Intrusion tests: one row per force sample of ``intrusions.csv``, each test a unit.
INTRUSIONS = Kind(
    name="intrusions",
    file="intrusions.csv",
    description="intrusion tests, one row per force-depth sample",
    unit_column="test",
    unit_dim="test",
    load=_load,
    block=_block,
    to_observed=_to_observed,
    from_observed=_from_observed,
    cells=stats.intrusion_cells,
    figures={"intrusions": FigureName("plot_intrusions")},
)
