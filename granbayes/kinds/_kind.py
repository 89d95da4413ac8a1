"""The entry of a kind of measurement in the registry (:data:`granbayes.kinds.KINDS`)."""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass
from pathlib import Path

import pandas as pd
import xarray as xr

from .._experiment import Experiment
from .._likelihood import Block, ObservationSettings

__all__ = ["FigureName", "Kind"]


@dataclass(frozen=True)
class Kind:
    """Everything about one kind of measurement.

    Attributes
    ----------
    name : str
        Registry key (``"heights"``); the name of ``granbayes fit --data``.
    file : str
        Its file in an experiment folder (``"jumps.csv"``).
    description : str
        One line for help texts and reports.
    unit_column : str or None
        The column naming its units of leave-one-out (``None``: every row is a unit).
    unit_dim : str
        The DataTree dimension of its units (its log-likelihood's).
    load : callable
        ``load(path, experiment) -> DataFrame``: read and validate the file.
    block : callable
        ``block(table, settings) -> Block``: its likelihood block for the measurements of
        one model (:class:`granbayes._likelihood.ObservationSettings`).
    to_observed : callable
        ``to_observed(table) -> xarray.Dataset``: its observed data for a fit's DataTree
        (data variables and their coordinates, on its own dimensions).
    from_observed : callable
        ``from_observed(dataset) -> DataFrame``: the table back from a DataTree's
        ``observed_data`` (``None`` when the kind is absent).
    cells : callable, optional
        ``cells(datatree) -> DataFrame``: its residual cells (:mod:`granbayes.stats`).
    figures : mapping of str to callable
        Figure name (file stem) to ``figure(datatree) -> Figure``; the built-in kinds name
        theirs in :mod:`granbayes.figures` with :class:`FigureName`.
    """

    name: str
    file: str
    description: str
    unit_column: str | None
    unit_dim: str
    load: Callable[[Path, Experiment], pd.DataFrame]
    block: Callable[[pd.DataFrame, ObservationSettings], Block]
    to_observed: Callable[[pd.DataFrame], xr.Dataset]
    from_observed: Callable[[xr.Dataset], pd.DataFrame | None]
    cells: Callable[[xr.DataTree], pd.DataFrame] | None = None
    figures: Mapping[str, Callable] = None  # type: ignore[assignment]

    def __post_init__(self) -> None:
        """Default: no figures."""
        if self.figures is None:
            object.__setattr__(self, "figures", {})


@dataclass(frozen=True)
class FigureName:
    """A figure function of :mod:`granbayes.figures`, imported when first drawn.

    The built-in kinds name their figures with it so that importing the registry does not
    import matplotlib (~1 s): every Dask worker process that only fits imports the registry.
    Picklable (a name, not a function). Called, it is the function it names.

    Parameters
    ----------
    name : str
        The function's name in :mod:`granbayes.figures` (``"plot_predictive"``).
    """

    name: str

    def __call__(self, *args, **kwargs):
        """Draw: ``granbayes.figures.<name>(*args, **kwargs)``."""
        from .. import figures

        return getattr(figures, self.name)(*args, **kwargs)
