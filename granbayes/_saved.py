"""A finished fit read back from its ``posterior.nc``: :func:`load_fit` -> :class:`SavedFit`.

A fit *is* its DataTree. Besides the posterior, log-likelihood, predictive and prior groups,
the DataTree's attributes (JSON text) carry everything needed to rebuild the model it was
sampled with: the configuration (``config``), the priors (``priors``), the robot, command
settings and ``phi_c`` (``experiment``), the force parameters (``parameters``) and one
record per sampler run (``runs``). :class:`SavedFit` gives them back as granbayes objects,
rebuilds each run's :class:`~granbayes._likelihood.JumpModel` and converts the posterior
draws back to that model's sampling coordinates, so that prediction
(:func:`granbayes.predict`), residuals (:func:`granbayes.residual_table`),
PSIS-LOO comparison (:func:`granbayes._datatree.loo`, :func:`granbayes._datatree.compare`)
and reports (:func:`granbayes.report.write_fit_report`) work the same on a fit in memory
(``SavedFit.from_datatree(result.datatree)``) and on one read from disk.

What is not stored, and so not available after loading: the full chains (only the kept
draws are saved) and the sampler's random state; a saved fit cannot be resumed (use
``fit(..., checkpoint=..., resume=True)`` with the checkpoint folder for that).
"""

from __future__ import annotations

import json
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import pandas as pd
import xarray as xr

from . import _datatree as gdt
from . import stats
from ._deprecated import warn_alias
from ._errors import InputError
from ._experiment import Experiment, Robot
from ._fitting import FitSettings, part_models
from ._likelihood import JumpModel
from ._measurements import Measurements
from ._priors import Prior
from .commands import CommandSettings
from .kinds import KINDS, measurements

__all__ = ["SavedFit", "as_saved_fit", "load_fit"]

#: Attributes a granbayes fit's DataTree must have.
_REQUIRED_ATTRS = ("config", "priors", "experiment", "parameters", "runs")
#: Groups a granbayes fit's DataTree must have.
_REQUIRED_GROUPS = ("posterior", "log_likelihood", "observed_data")

#: Tolerance when matching a volume fraction to a fitted one [-].
PHI_TOLERANCE = 1e-9


def _json_attr(dt: xr.DataTree, name: str) -> object:
    value = dt.attrs[name]
    return json.loads(value) if isinstance(value, str) else value


@dataclass(frozen=True)
class SavedFit:
    """A fit as saved in its DataTree, with the objects to reuse it.

    Build one with :func:`load_fit` (from ``posterior.nc``) or
    :meth:`SavedFit.from_datatree` (from ``FitResult.datatree``).

    Attributes
    ----------
    datatree : xarray.DataTree
        The fit's DataTree: ``posterior`` (force parameters [SI] and ``sigma_mm`` [mm] over
        ``phi``), ``log_likelihood``, ``posterior_predictive``, ``observed_data``,
        ``sample_stats`` and, if drawn, ``prior``, ``prior_predictive``, ``log_prior``.
    settings : FitSettings
        Terms, ``phi_mode``, noise family and sampler settings of the fit (``config``: a
        deprecated alias).
    experiment : Experiment
        Robot, default command settings and ``phi_c`` the fit used.
    priors : dict of str to Prior
        The priors of the fit.
    seed : int
        The fit's master seed.
    warnings : tuple of str
        Convergence problems of the fit, in words.
    source : pathlib.Path, optional
        The file it was read from (``None`` for a fit in memory).
    """

    datatree: xr.DataTree
    settings: FitSettings
    experiment: Experiment
    priors: dict[str, Prior]
    seed: int
    warnings: tuple[str, ...] = ()
    source: Path | None = None
    _models: dict[str, JumpModel] = field(default_factory=dict, repr=False, compare=False)

    @property
    def config(self) -> FitSettings:
        """Deprecated alias of :attr:`settings`."""
        warn_alias(type(self).__name__, "config", "settings")
        return self.settings

    # ------------------------------------------------------------------------------------
    @classmethod
    def from_datatree(cls, dt: xr.DataTree, source: str | Path | None = None) -> SavedFit:
        """Read the configuration, priors and experiment stored in a fit's DataTree.

        Parameters
        ----------
        dt : xarray.DataTree
            A DataTree written by :func:`granbayes.fit` (``FitResult.datatree``).
        source : str or Path, optional
            Where it was read from (for messages).

        Returns
        -------
        SavedFit

        Raises
        ------
        InputError
            If the DataTree lacks a group or attribute of a granbayes fit (naming it).
        """
        where = None if source is None else Path(source)
        for group in _REQUIRED_GROUPS:
            if group not in dt.children:
                raise InputError(
                    f"not a granbayes fit: no '{group}' group (written by granbayes.fit?)",
                    file=where,
                )
        for name in _REQUIRED_ATTRS:
            if name not in dt.attrs:
                raise InputError(
                    f"not a granbayes fit: no '{name}' attribute (written by granbayes.fit?)",
                    file=where,
                )
        try:
            config = FitSettings.from_dict(_json_attr(dt, "config"))
            priors = {k: Prior(**v) for k, v in _json_attr(dt, "priors").items()}
            exp = _json_attr(dt, "experiment")
            experiment = Experiment(
                robot=Robot(**exp["robot"]),
                command=CommandSettings(**exp["command"]),
                phi_c=float(exp["phi_c"]),
                calibration_sd=tuple(exp.get("uncertainty", {}).items()),
                phi_sd=float(exp.get("phi_sd", 0.0)),
                source=str(where) if where is not None else None,
            )
        except (TypeError, KeyError, ValueError) as exc:
            raise InputError(f"unreadable fit attributes: {exc}", file=where) from None
        warnings = tuple(_json_attr(dt, "warnings")) if "warnings" in dt.attrs else ()
        return cls(dt, config, experiment, priors, int(dt.attrs.get("seed", 0)), warnings, where)

    # ------------------------------------------------------------------------------------
    @property
    def converged(self) -> bool:
        """Whether every sampler run of the fit met the stopping rule."""
        return (
            bool(_json_attr(self.datatree, "converged"))
            if "converged" in self.datatree.attrs
            else False
        )

    @property
    def parameters(self) -> tuple[str, ...]:
        """Force parameters of the fitted law (``sigma_mm`` not included)."""
        return tuple(_json_attr(self.datatree, "parameters"))

    @property
    def phis(self) -> np.ndarray:
        """Volume fractions with a posterior [-] (those of the data), sorted."""
        return np.asarray(self.datatree["posterior"]["phi"].values, dtype=float)

    @property
    def labels(self) -> tuple[str, ...]:
        """Labels of the sampler runs (``"phi=0.602"``, ... or ``"all"``)."""
        return tuple(run["label"] for run in _json_attr(self.datatree, "runs"))

    def observed(self) -> pd.DataFrame:
        """The fitted jumps table.

        One row per jump: ``phi``, ``command``, the settings, ``height_mm`` and the other
        columns of ``jumps.csv``.

        Raises
        ------
        InputError
            If the fit has no jump heights, or their coordinates are incomplete.
        """
        table = self.measurements().tables.get("heights")
        if table is None:
            raise InputError("the fit has no jump heights", file=self.source)
        return table

    def measurements(self) -> Measurements:
        """Every measurement the fit was made of, read back from ``observed_data``.

        Returns
        -------
        Measurements

        Raises
        ------
        InputError
            If a kind's observed data lack a coordinate it needs.
        """
        obs = self.datatree["observed_data"].to_dataset()
        tables = {}
        for name, kind in KINDS.items():
            try:
                table = kind.from_observed(obs)
            except KeyError as exc:
                raise InputError(str(exc).strip("'\""), file=self.source) from None
            if table is not None:
                tables[name] = table
        return measurements(tables)

    def diagnostics(self) -> pd.DataFrame:
        """Per run: autocorrelation times, R-hat, ESS, chain length, convergence."""
        return stats.run_diagnostics(self.datatree)

    def loo(self) -> dict[str, object]:
        """PSIS-LOO of the fit (:func:`granbayes._datatree.loo`)."""
        return stats.loo(self.datatree)

    # ------------------------------------------------------------------------------------
    def models(self) -> dict[str, JumpModel]:
        """The log-posterior of every sampler run, rebuilt as the fit built it.

        Returns
        -------
        dict of str to JumpModel
            Keyed by run label, in run order.

        Raises
        ------
        InputError
            If a rebuilt model's coordinates differ from the ones the run recorded (a fit
            saved by an incompatible granbayes version).
        """
        if not self._models:
            specs = part_models(self.experiment, self.measurements(), self.settings, self.priors)
            runs = _json_attr(self.datatree, "runs")
            for (label, model, _), run in zip(specs, runs, strict=False):
                if label != run["label"] or list(model.coordinate_names) != run["coordinates"]:
                    raise InputError(
                        f"cannot rebuild run {run['label']}: its recorded coordinates "
                        f"{run['coordinates']} differ from the rebuilt model's "
                        f"{model.coordinate_names}",
                        file=self.source,
                    )
                self._models[label] = model
            if len(self._models) != len(runs):
                raise InputError(
                    f"the fit records {len(runs)} runs, the data give {len(specs)}",
                    file=self.source,
                )
        return dict(self._models)

    def model(self, label: str) -> JumpModel:
        """The rebuilt log-posterior of run ``label`` (see :meth:`models`).

        Parameters
        ----------
        label : str
            Run label (``"phi=0.602"`` or ``"all"``).

        Returns
        -------
        JumpModel

        Raises
        ------
        KeyError
            If the fit has no such run.
        """
        models = self.models()
        if label not in models:
            raise KeyError(f"no run {label!r}; the fit's runs are {', '.join(models)}")
        return models[label]

    def runs_of(self, phis: Sequence[float]) -> list[str]:
        """The run whose posterior predicts each volume fraction.

        Parameters
        ----------
        phis : sequence of float
            Volume fractions [-].

        Returns
        -------
        list of str
            Run labels: the one run of a ``quadratic`` fit; for a ``per_phi`` fit, the run
            of each fitted volume fraction (the one run of them all with a pooled robot).

        Raises
        ------
        ValueError
            For a ``per_phi`` fit, a volume fraction that was not fitted (naming those that
            were).
        """
        labels = list(self.models())
        if self.settings.phi_mode == "quadratic":
            return [labels[0]] * len(phis)
        fitted = self.phis
        out = []
        for p in phis:
            i = int(np.argmin(np.abs(fitted - p)))
            if abs(fitted[i] - p) > PHI_TOLERANCE:
                raise ValueError(
                    f"phi = {p:g}: this per_phi fit has a posterior only at the fitted volume "
                    f"fractions phi = {', '.join(f'{f:g}' for f in fitted)}; predict at one of "
                    "them, or fit with phi_mode='quadratic' to predict between them"
                )
            # one run per fitted volume fraction, or one for all (calibration="pool")
            out.append(labels[i] if len(labels) == len(fitted) else labels[0])
        return out

    def draws(self, label: str) -> np.ndarray:
        """The posterior draws of run ``label`` in its model's sampling coordinates.

        Parameters
        ----------
        label : str
            Run label (``"phi=0.602"`` or ``"all"``).

        Returns
        -------
        ndarray, shape (n_chain * n_draw, ndim)
            Rows in (chain, draw) order; columns ``model(label).coordinate_names``: the
            value (or its log for a log-scale prior) of each parameter at the run's volume
            fraction, the quadratic coefficients (``"k:c1"``) in ``quadratic`` mode, and
            the scatter ``sigma_mm`` per fitted volume fraction (or once).
        """
        model = self.model(label)
        post = self.datatree["posterior"].to_dataset()
        n = post.sizes["chain"] * post.sizes["draw"]
        phi_run = float(model.phis[0]) if model.phi_mode == "per_phi" else None
        columns = []
        for name, prior in zip(model.coordinate_names, model.coordinate_priors, strict=True):
            if ":c" in name:  # quadratic coefficient, stored in sampling coordinates
                pname, order = name.split(":c")
                values = post[f"{pname}_coef"].sel(order=int(order)).values.reshape(n)
                columns.append(values.astype(float))
                continue
            pname, _, at = name.partition("[")
            phi = float(at.rstrip("]")) if at else phi_run
            var = post[pname]
            if "phi" in var.dims:
                var = var.sel(phi=phi, method="nearest") if phi is not None else var.isel(phi=0)
            columns.append(np.asarray(prior.to_u(var.values.reshape(n)), dtype=float))
        return np.column_stack(columns)


def load_fit(path: str | Path) -> SavedFit:
    """Read a finished fit from its ``posterior.nc`` (or the folder holding it).

    Parameters
    ----------
    path : str or Path
        ``posterior.nc`` written by ``granbayes fit`` / :func:`granbayes.report.write_fit_report`,
        or the output folder that contains it.

    Returns
    -------
    SavedFit
        The DataTree with the fit's configuration, experiment and priors, able to rebuild
        its models (:meth:`SavedFit.models`) and their draws (:meth:`SavedFit.draws`).

    Raises
    ------
    InputError
        If the file does not exist, cannot be read as netCDF, or is not a granbayes fit.

    Examples
    --------
    >>> import granbayes as gb
    >>> saved = gb.load_fit("fit/posterior.nc")  # doctest: +SKIP
    >>> saved.settings.terms, saved.phis  # doctest: +SKIP
    """
    path = Path(path)
    if path.is_dir():
        path = path / "posterior.nc"
    if not path.is_file():
        raise InputError(
            "no such file (expected a posterior.nc written by granbayes fit)", file=path
        )
    try:
        dt = gdt.read_datatree(path)
    except (OSError, ValueError) as exc:
        raise InputError(f"cannot read as a netCDF DataTree ({exc})", file=path) from None
    return SavedFit.from_datatree(dt, source=path)


def as_saved_fit(fit: object) -> SavedFit:
    """A :class:`SavedFit` from a SavedFit, a ``FitResult``, a DataTree or a path.

    Parameters
    ----------
    fit : SavedFit, FitResult, xarray.DataTree, str or Path

    Returns
    -------
    SavedFit
    """
    if isinstance(fit, SavedFit):
        return fit
    if isinstance(fit, xr.DataTree):
        return SavedFit.from_datatree(fit)
    if isinstance(fit, str | Path):
        return load_fit(fit)
    dt = getattr(fit, "datatree", None)
    if isinstance(dt, xr.DataTree):
        return SavedFit.from_datatree(dt)
    raise TypeError(
        "expected a SavedFit, FitResult, DataTree or path to posterior.nc, "
        f"got {type(fit).__name__}"
    )
