"""A kind of measurement registered at run time is loaded, fitted, saved and reported.

The toy kind is a quasi-static load test: the force [N] a rig needs to hold the foot at a
depth, ``F = k z`` for the depth law, with Gaussian noise of a fitted ``load_sd_N``. It is
one :func:`granbayes.kinds.register_kind` call (a loader, a likelihood block, its
observed-data group); nothing else in the package is told about it. The data are SYNTHETIC
(seed 4, made here from ``k`` alone, independent of the kernel).
"""

from __future__ import annotations

import math
from collections.abc import Iterator, Mapping
from pathlib import Path
from typing import ClassVar

import numpy as np
import pandas as pd
import pytest
import xarray as xr

from granbayes._cli import EXIT_OK, main
from granbayes._datatree import read_datatree
from granbayes._experiment import Experiment
from granbayes._likelihood import Block, Coordinate, Law, Simulated
from granbayes._priors import Prior
from granbayes._synthetic import write_experiment
from granbayes.kinds import KINDS, Kind, register_kind
from granbayes.testing import synthetic_jumps

K_TRUE = 2500.0
SD_PRIOR = Prior("loguniform", 0.01, 10.0, unit="N", why="load cell noise")


class StaticLoadBlock(Block):
    """Held loads: ``force_N = k depth + noise`` per row (each row a unit)."""

    kind = "static_loads"
    unit_dim = "load"
    variable = "static_load"
    predictive_dims: ClassVar[Mapping[str, str]] = {"force_N": "load"}

    def __init__(self, table: pd.DataFrame) -> None:
        self._table = table.reset_index(drop=True)
        self._coords: list[Coordinate] = []

    @property
    def table(self) -> pd.DataFrame:
        return self._table

    @property
    def n_units(self) -> int:
        return len(self._table)

    @property
    def phis(self) -> np.ndarray:
        return np.unique(self._table["phi"].to_numpy(float))

    def coordinates(self, priors, phis) -> list[Coordinate]:
        self._coords = [Coordinate("load_sd_N", "load_sd_N", priors.get("load_sd_N", SD_PRIOR))]
        return list(self._coords)

    def with_data(self, table: pd.DataFrame) -> StaticLoadBlock:
        other = StaticLoadBlock(table)
        other._coords = self._coords
        return other

    def values(self, u: np.ndarray, phis: np.ndarray) -> dict[str, np.ndarray]:
        sd = self._coords[0].prior.to_value(u[:, 0])
        return {"load_sd_N": np.repeat(sd[:, None], len(phis), axis=1)}

    def _mean(self, law: Law) -> np.ndarray:
        phis = self.phis
        k = law.values(phis)["k"]  # (n, len(phis))
        col = np.searchsorted(phis, self._table["phi"].to_numpy(float))
        return k[:, col] * 1e-3 * self._table["depth_mm"].to_numpy(float)[None, :]

    def log_lik(self, u: np.ndarray, law: Law, sim: Simulated | None) -> np.ndarray:
        sd = self._coords[0].prior.to_value(u[:, 0])[:, None]
        r = (self._table["force_N"].to_numpy(float)[None, :] - self._mean(law)) / sd
        return -0.5 * r * r - np.log(sd) - 0.5 * math.log(2 * math.pi)

    def predictive(self, u, law, sim, rng) -> dict[str, np.ndarray]:
        mean = self._mean(law)
        sd = self._coords[0].prior.to_value(u[:, 0])[:, None]
        return {"force_N": mean + sd * rng.standard_normal(mean.shape)}


def _load(path: Path, experiment) -> pd.DataFrame:
    return pd.read_csv(path)[["phi", "depth_mm", "force_N"]]


def _to_observed(table: pd.DataFrame) -> xr.Dataset:
    return xr.Dataset(
        {"force_N": ("load", table["force_N"].to_numpy(float))},
        coords={
            "load": np.arange(len(table)),
            "load_depth_mm": ("load", table["depth_mm"].to_numpy(float)),
            "load_phi": ("load", table["phi"].to_numpy(float)),
        },
    )


def _from_observed(obs: xr.Dataset) -> pd.DataFrame | None:
    if "load_depth_mm" not in obs.coords:
        return None
    return pd.DataFrame(
        {
            "phi": obs["load_phi"].values,
            "depth_mm": obs["load_depth_mm"].values,
            "force_N": obs["force_N"].values,
        }
    )


@pytest.fixture
def static_loads() -> Iterator[Kind]:
    kind = register_kind(
        Kind(
            name="static_loads",
            file="static_loads.csv",
            description="held loads at a depth",
            unit_column=None,
            unit_dim="load",
            load=_load,
            block=lambda table, settings: StaticLoadBlock(table),
            to_observed=_to_observed,
            from_observed=_from_observed,
        )
    )
    yield kind
    del KINDS["static_loads"]


def test_a_kind_registered_at_run_time_is_fitted_with_the_heights(
    static_loads: Kind, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """``granbayes fit`` reads the new file, samples its noise with the force law, keeps
    its observed data, log-likelihood and replicates on its own dimension, and its loads
    pin ``k`` down far better than 12 jump heights alone would (the 90% interval of ``k``
    holds the truth and is narrower than 2% of it: 20 loads with 0.2 N noise at 5-30 mm
    give sd(k) of about 2 N/m)."""
    folder = tmp_path / "exp"
    jumps = synthetic_jumps(
        {"k": K_TRUE},
        sigma_mm=1.0,
        seed=4,
        phis=(0.612,),
        commands=("single", "preload"),
        trials=6,
        label="test_kind_registry",
    )
    write_experiment(folder, jumps, Experiment())
    rng = np.random.default_rng(4)
    depth = np.linspace(5.0, 30.0, 20)
    loads = pd.DataFrame(
        {
            "phi": 0.612,
            "depth_mm": depth,
            "force_N": K_TRUE * 1e-3 * depth + 0.2 * rng.standard_normal(20),
        }
    )
    loads.to_csv(folder / "static_loads.csv", index=False)
    out = tmp_path / "OUT"
    code = main(
        [
            "fit",
            str(folder),
            "--out",
            str(out),
            "--terms",
            "depth",
            "--quiet",
            "--seed",
            "1",
            "--data",
            "heights,static_loads",
        ]
    )
    err = capsys.readouterr().err
    assert code == EXIT_OK, err
    dt = read_datatree(out / "posterior.nc")
    assert set(dt["log_likelihood"].data_vars) == {"height_mm", "static_load"}
    assert dt["log_likelihood"]["static_load"].dims[-1] == "load"
    assert dt["posterior_predictive"]["force_N"].dims == ("chain", "draw", "load")
    assert "load_sd_N" in dt["posterior"]
    k = dt["posterior"]["k"].values.ravel()
    lo, hi = np.quantile(k, [0.05, 0.95])
    assert lo < K_TRUE < hi
    assert hi - lo < 0.02 * K_TRUE
