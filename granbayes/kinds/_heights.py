"""Jump heights (``jumps.csv``): the kind every experiment has had from the start."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd
import xarray as xr

from .. import stats
from .._experiment import Experiment
from .._likelihood import HeightBlock, Observations, ObservationSettings
from .._measurements import load_jumps
from ..commands import SETTINGS
from ._kind import FigureName, Kind

__all__ = ["HEIGHTS"]


def _load(path: Path, experiment: Experiment) -> pd.DataFrame:
    return load_jumps(path, experiment)


def _block(table: pd.DataFrame, settings: ObservationSettings) -> HeightBlock:
    return HeightBlock(
        Observations.from_table(table),
        noise=settings.noise,
        nu=settings.nu,
        sigma_mode=settings.sigma_mode,
        bed=settings.bed,
    )


def _to_observed(table: pd.DataFrame) -> xr.Dataset:
    """``height_mm`` over ``jump``; every other complete column a coordinate of ``jump``."""
    coords = {"jump": np.arange(len(table))}
    coords |= {
        c: ("jump", table[c].to_numpy())
        for c in table.columns
        if c != "height_mm" and table[c].notna().all()
    }
    return xr.Dataset({"height_mm": ("jump", table["height_mm"].to_numpy(float))}, coords=coords)


def _from_observed(obs: xr.Dataset) -> pd.DataFrame | None:
    if "height_mm" not in obs:
        return None
    cols = {
        str(name): obs[name].values
        for name in obs.coords
        if name != "jump" and obs[name].dims == ("jump",)
    }
    table = pd.DataFrame(cols)
    table["height_mm"] = obs["height_mm"].values.astype(float)
    missing = [c for c in ("phi", "command", *SETTINGS) if c not in table]
    if missing:
        raise KeyError(f"observed_data lacks the jump coordinate(s) {', '.join(missing)}")
    table["phi"] = table["phi"].astype(float)
    table["command"] = table["command"].astype(str)
    return table


#: Jump heights: one row per jump of ``jumps.csv``, each jump a unit.
HEIGHTS = Kind(
    name="heights",
    file="jumps.csv",
    description="jump heights, one row per jump",
    unit_column=None,
    unit_dim="jump",
    load=_load,
    block=_block,
    to_observed=_to_observed,
    from_observed=_from_observed,
    cells=stats.residual_table,
    figures={"predictive": FigureName("plot_predictive")},
)
