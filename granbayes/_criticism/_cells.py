"""The residual cells of every kind of measurement in a fit, and their misfit thresholds.

Each kind's cells come from its registry entry (:data:`granbayes.kinds.KINDS`): a jump
height's cell is a command setting, a tracked jump's a phase per position, command and
setting, an intrusion curve's a depth bin per volume fraction and speed. One family of
cells is judged at once: the family-wise false-alarm rate is split (Bonferroni) over all
cells of all kinds, and each kind's threshold uses its own reference distribution
(Student-t of the pooled scatter for heights, normal for the predictive z of the others).
With heights alone the threshold is :func:`granbayes.stats.misfit_threshold`'s.
"""

from __future__ import annotations

import numpy as np
import pandas as pd
import xarray as xr
from scipy import stats as sps

from ..kinds import KINDS

__all__ = ["KIND_CELL_KEYS", "cells_of", "kind_thresholds", "misfit_mask"]

#: Columns that key the cells of the kinds beyond heights (with the command settings).
KIND_CELL_KEYS = ("position", "phase", "speed_mm_s", "depth_from_mm", "depth_to_mm")


def cells_of(dt: xr.DataTree) -> pd.DataFrame:
    """Residual cells of every kind of measurement a fit holds, worst first per kind.

    Parameters
    ----------
    dt : xarray.DataTree
        A fit.

    Returns
    -------
    pandas.DataFrame
        The kinds' cell tables stacked, with a ``kind`` column (heights first).
    """
    dims = set(dt["log_likelihood"].to_dataset().dims)
    tables = []
    for kind in KINDS.values():
        if kind.unit_dim in dims and kind.cells is not None:
            table = kind.cells(dt).copy()
            if "kind" in table.columns:
                table = table.drop(columns="kind")
            table.insert(0, "kind", kind.name)
            tables.append(table)
    return pd.concat(tables, ignore_index=True) if tables else pd.DataFrame()


def kind_thresholds(cells: pd.DataFrame, family_alpha: float) -> dict[str, float]:
    """|z| beyond which a cell of each kind is misfit (family-wise over all cells).

    Parameters
    ----------
    cells : pandas.DataFrame
        :func:`cells_of` (columns ``kind`` and ``dof``).
    family_alpha : float
        Family-wise false-alarm rate over every cell of every kind.

    Returns
    -------
    dict of str to float
    """
    q = family_alpha / (2.0 * max(len(cells), 1))
    out = {}
    for kind, part in cells.groupby("kind", sort=False):
        dof = float(part["dof"].min())
        out[str(kind)] = float(sps.t.isf(q, dof) if dof > 0 else sps.norm.isf(q))
    return out


def misfit_mask(cells: pd.DataFrame, thresholds: dict[str, float]) -> np.ndarray:
    """Whether each cell's |z| exceeds its kind's threshold.

    Parameters
    ----------
    cells : pandas.DataFrame
        :func:`cells_of`.
    thresholds : dict of str to float
        :func:`kind_thresholds` (a kind without one is never misfit).

    Returns
    -------
    ndarray of bool
    """
    if cells.empty:
        return np.zeros(0, dtype=bool)
    thr = cells["kind"].map(thresholds).astype(float).fillna(np.inf).to_numpy()
    return np.abs(cells["z"].to_numpy(float)) > thr
