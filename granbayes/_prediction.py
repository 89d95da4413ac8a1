"""Predictive jump heights at new settings from a fitted posterior.

:func:`predict` takes a fit (in memory, or read back with :func:`granbayes.load_fit`), a
command and a volume fraction, and the actuator settings (frequency, amplitude, delay,
settle periods; by default the fit's experiment settings), and simulates the jump for
posterior draws of the force law. It reports two predictive distributions per setting:

* the **simulated height** ``height_sim_mm``: the force law's uncertainty only (what the
  robot does on average, the dark band of the fit report's predictive check);
* a **new jump** ``height_mm``: the simulated height plus one draw of the fitted
  trial-to-trial scatter (the noise family of the fit: normal, or Student-t), what one
  more measured jump would show (the light band). A fit that integrated each bed's
  volume fraction (``[bed] phi_sd``, quadratic laws) puts the new jump on a new bed: its
  phi is drawn about the target, its height read from the simulations at the bed
  quadrature's volume fractions (:class:`granbayes._likelihood.BedPhi`).

Both are summarised by their mean, median and the ``ci_prob`` equal-tailed interval.

Where a fit can predict:

* ``per_phi`` fits have a posterior only at the fitted volume fractions; predicting
  elsewhere is refused (the error names the fitted ones). Settings other than the fitted
  ones are allowed at those volume fractions: that is the force law's transfer.
* ``quadratic`` fits predict at any volume fraction; outside the fitted range the laws are
  extrapolated (the prediction notes say so). The scatter at an unfitted volume fraction
  is interpolated linearly between the fitted ones, draw by draw (held constant beyond
  them), unless the fit has one global scatter.

The same posterior draws are used for every setting of one call (common random numbers),
so differences between settings are paired.
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
import pandas as pd

from . import stats
from ._likelihood import JumpModel, Observations
from ._saved import PHI_TOLERANCE, SavedFit, as_saved_fit
from .commands import COMMAND_NAMES
from .commands import SETTINGS as SETTING_COLUMNS

__all__ = ["Prediction", "predict"]


_SETTING_CHECKS = {
    "freq_hz": ("frequency [Hz]", False),
    "amplitude_mm": ("amplitude [mm]", False),
    "delay_ms": ("delay [ms]", True),
    "settle_periods": ("settle time [periods]", True),
}


@dataclass(frozen=True)
class Prediction:
    """Predictive heights at a set of settings.

    Attributes
    ----------
    table : pandas.DataFrame
        One row per setting: ``command``, ``phi`` [-], ``freq_hz`` [Hz], ``amplitude_mm``
        [mm], ``delay_ms`` [ms], ``settle_periods`` [periods]; ``n_draws`` and
        ``n_failed`` (simulations that did not finish, left out of the summaries); the
        simulated height ``height_sim_mm_mean``, ``_median``, ``_lo``, ``_hi`` and a new
        jump ``height_mm_mean``, ``_median``, ``_lo``, ``_hi`` [mm] (``lo``/``hi``: the
        ``ci_prob`` equal-tailed interval); ``sigma_mm_median`` the scatter used [mm].
    height_sim_mm : ndarray, shape (n_draws, n_settings)
        Simulated height per posterior draw and setting (NaN: the jump did not finish).
    height_mm : ndarray, shape (n_draws, n_settings)
        The same plus one draw of the noise: a new measured jump.
    ci_prob : float
        Probability of the reported intervals.
    notes : tuple of str
        Extrapolation and interpolation done, in words.
    """

    table: pd.DataFrame
    height_sim_mm: np.ndarray
    height_mm: np.ndarray
    ci_prob: float
    notes: tuple[str, ...] = ()

    def to_json(self) -> dict:
        """JSON-ready summary: the rows of ``table``, ``ci_prob`` and ``notes``."""
        rows = [
            {
                k: (None if isinstance(v, float) and not math.isfinite(v) else v)
                for k, v in r.items()
            }
            for r in self.table.to_dict("records")
        ]
        for r in rows:
            for k, v in r.items():
                if isinstance(v, np.generic):
                    r[k] = v.item()
        return {
            "interval": f"{self.ci_prob:.0%} equal-tailed",
            "ci_prob": self.ci_prob,
            "predictions": rows,
            "notes": list(self.notes),
        }


def _values(name: str, value: object) -> list:
    if value is None:
        return []
    if isinstance(value, str) or np.ndim(value) == 0:
        return [value]
    out = list(np.asarray(value).ravel()) if not isinstance(value, list | tuple) else list(value)
    if not out:
        raise ValueError(f"{name}: no values given")
    return out


def _settings_grid(
    saved: SavedFit,
    command: str | Sequence[str],
    phi: float | Sequence[float],
    settings: dict[str, float | Sequence[float] | None],
) -> pd.DataFrame:
    """The Cartesian product of the requested values, checked; defaults from the fit."""
    commands = [str(c) for c in _values("command", command)]
    if not commands:
        raise ValueError("command: no command given")
    for c in commands:
        if c not in COMMAND_NAMES:
            raise ValueError(f"command {c!r}: unknown; valid commands: {', '.join(COMMAND_NAMES)}")
    phis = [float(p) for p in _values("phi", phi)]
    if not phis:
        raise ValueError("phi: no volume fraction given")
    for p in phis:
        if not (math.isfinite(p) and 0.0 < p < 1.0):
            raise ValueError(f"phi = {p}: must be a volume fraction in the open interval (0, 1)")
    columns: dict[str, list[float]] = {}
    for name in SETTING_COLUMNS:
        given = [float(v) for v in _values(name, settings.get(name))]
        if not given:
            given = [float(getattr(saved.experiment.command, name))]
        what, zero_ok = _SETTING_CHECKS[name]
        for v in given:
            if not math.isfinite(v) or v < 0 or (v == 0 and not zero_ok):
                bound = ">= 0" if zero_ok else "> 0"
                raise ValueError(f"{name} = {v:g}: the {what} must be {bound}")
        columns[name] = given
    names = ["command", "phi", *SETTING_COLUMNS]
    grid = itertools.product(commands, phis, *(columns[n] for n in SETTING_COLUMNS))
    return pd.DataFrame(list(grid), columns=names)


def _interpolation(
    fitted: np.ndarray, phis: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Left index, right index and right weight of linear interpolation (clamped ends)."""
    x = np.clip(phis, fitted[0], fitted[-1])
    right = np.clip(np.searchsorted(fitted, x), 1, max(1, len(fitted) - 1))
    left = right - 1
    if len(fitted) == 1:
        return np.zeros(len(phis), int), np.zeros(len(phis), int), np.zeros(len(phis))
    w = (x - fitted[left]) / (fitted[right] - fitted[left])
    return left, right, w


def _sigma(model: JumpModel, u: np.ndarray, phis: np.ndarray) -> tuple[np.ndarray, bool]:
    """Scatter [mm] per draw at ``phis`` (interpolated between fitted phis where needed)."""
    sigma = model.parameter_values(u, phis)["sigma_mm"]
    missing = ~np.isfinite(sigma).all(axis=0)
    if not missing.any():
        return sigma, False
    fitted = model.phis
    at_fitted = model.parameter_values(u, fitted)["sigma_mm"]
    left, right, w = _interpolation(fitted, phis[missing])
    sigma[:, missing] = at_fitted[:, left] * (1 - w) + at_fitted[:, right] * w
    return sigma, True


def _summary(values: np.ndarray, ci_prob: float, prefix: str) -> dict[str, np.ndarray]:
    q = stats.eti_probs(ci_prob)
    out = {f"{prefix}_mean": np.full(values.shape[1], np.nan)}
    out.update({f"{prefix}_{k}": np.full(values.shape[1], np.nan) for k in ("median", "lo", "hi")})
    for j in range(values.shape[1]):
        v = values[:, j][np.isfinite(values[:, j])]
        if v.size:
            lo, med, hi = np.quantile(v, q)
            out[f"{prefix}_mean"][j] = v.mean()
            out[f"{prefix}_median"][j], out[f"{prefix}_lo"][j], out[f"{prefix}_hi"][j] = med, lo, hi
    return out


def predict(
    fit: object,
    command: str | Sequence[str],
    phi: float | Sequence[float],
    *,
    freq_hz: float | Sequence[float] | None = None,
    amplitude_mm: float | Sequence[float] | None = None,
    delay_ms: float | Sequence[float] | None = None,
    settle_periods: float | Sequence[float] | None = None,
    n_draws: int | None = 1000,
    ci_prob: float = stats.CI_PROB,
    rng: np.random.Generator | int = 0,
) -> Prediction:
    """Posterior predictive jump heights at new settings (module docstring).

    Every argument may be one value or a sequence; the prediction covers every
    combination (the Cartesian product), one row per setting.

    Parameters
    ----------
    fit : SavedFit, FitResult, xarray.DataTree, str or Path
        A fit (``granbayes.fit``), its DataTree, or ``posterior.nc`` (``load_fit``).
    command : str or sequence of str
        Jump command(s): ``single``, ``preload``, ``stutter``, ``delayed_stutter``,
        ``delayed_stutter_preload``.
    phi : float or sequence of float
        Volume fraction(s) [-]; for a ``per_phi`` fit, fitted ones only.
    freq_hz : float or sequence of float, optional
        Actuator frequency [Hz] (default: the fit's experiment setting).
    amplitude_mm : float or sequence of float, optional
        Actuator amplitude [mm] (default: the fit's experiment setting).
    delay_ms : float or sequence of float, optional
        Hold of the delayed stutter [ms] (default: the fit's experiment setting).
    settle_periods : float or sequence of float, optional
        Hold of the delayed stutter preload [periods] (default: the fit's setting).
    n_draws : int, optional
        Posterior draws to simulate, picked at random without replacement (``None``: all).
    ci_prob : float
        Probability of the equal-tailed intervals, in (0, 1).
    rng : numpy.random.Generator or int
        Source of the draw selection and of the noise (an int seeds a new generator).

    Returns
    -------
    Prediction

    Raises
    ------
    ValueError
        For an unknown command, a value outside its range, or (``per_phi`` fits) a
        volume fraction that was not fitted, naming the fitted ones.

    Examples
    --------
    >>> import granbayes as gb
    >>> p = gb.predict("fit/posterior.nc", "stutter", 0.612, freq_hz=[8, 12])  # doctest: +SKIP
    >>> p.table[["freq_hz", "height_mm_median", "height_mm_lo", "height_mm_hi"]]  # doctest: +SKIP
    """
    if not 0.0 < ci_prob < 1.0:
        raise ValueError(f"ci_prob = {ci_prob}: must be in (0, 1)")
    if n_draws is not None and n_draws < 1:
        raise ValueError(f"n_draws = {n_draws}: must be >= 1")
    rng = rng if isinstance(rng, np.random.Generator) else np.random.default_rng(rng)
    saved = as_saved_fit(fit)
    settings = {
        "freq_hz": freq_hz,
        "amplitude_mm": amplitude_mm,
        "delay_ms": delay_ms,
        "settle_periods": settle_periods,
    }
    grid = _settings_grid(saved, command, phi, settings)
    phis = grid["phi"].to_numpy(float)
    labels = saved.runs_of(phis)
    if saved.settings.phi_mode == "per_phi":  # snap to the fitted values
        grid["phi"] = [saved.phis[np.argmin(np.abs(saved.phis - p))] for p in phis]
        phis = grid["phi"].to_numpy(float)
    models = saved.models()
    n_total = saved.draws(labels[0]).shape[0]
    n = n_total if n_draws is None else min(n_draws, n_total)
    pick = np.sort(rng.choice(n_total, size=n, replace=False)) if n < n_total else np.arange(n)
    sim = np.full((n, len(grid)), np.nan)
    rep = np.full_like(sim, np.nan)
    sigma_used = np.full_like(sim, np.nan)
    notes: list[str] = []
    for label in dict.fromkeys(labels):
        cols = np.flatnonzero(np.array(labels) == label)
        model = models[label]
        u = saved.draws(label)[pick]
        rows = grid.iloc[cols].assign(height_mm=np.nan)
        obs = Observations.from_table(rows)
        heights, _ = model.predict(u, obs)
        sim[:, cols] = heights[:, obs.config_of_obs]
        sigma, interpolated = _sigma(model, u, phis[cols])
        if interpolated:
            notes.append(
                "the scatter at volume fractions that were not fitted is interpolated "
                "linearly between the fitted ones (held constant beyond them)"
            )
        sigma_used[:, cols] = sigma
        bed = model.heights.bed
        if bed.latent:  # a new measurement is on a new bed: its phi drawn about the target
            nodes = rows.loc[rows.index.repeat(bed.size)].assign(phi=bed.nodes(rows["phi"]))
            obs_nodes = Observations.from_table(nodes)
            at_nodes, _ = model.predict(u, obs_nodes)
            at_nodes = at_nodes[:, obs_nodes.config_of_obs].reshape(n, len(cols), bed.size)
            on_bed = bed.interpolate(at_nodes, bed.draw(rng, (n, len(cols))))
            rep[:, cols] = model.add_noise(on_bed, sigma, rng)
            notes.append(
                f"each replicated jump is on a new bed whose phi scatters about the target by "
                f"phi_sd = {bed.phi_sd:g}; the simulated height is the law's at the target phi"
            )
        else:
            rep[:, cols] = model.add_noise(sim[:, cols], sigma, rng)
    if saved.settings.phi_mode == "quadratic":
        lo, hi = saved.phis.min(), saved.phis.max()
        outside = sorted({p for p in phis if p < lo - PHI_TOLERANCE or p > hi + PHI_TOLERANCE})
        if outside:
            notes.append(
                f"phi = {', '.join(f'{p:g}' for p in outside)} lies outside the fitted range "
                f"[{lo:g}, {hi:g}]: the quadratic laws are extrapolated"
            )
    table = grid.copy()
    table["n_draws"] = n
    table["n_failed"] = (~np.isfinite(sim)).sum(axis=0)
    for k, v in (
        _summary(sim, ci_prob, "height_sim_mm") | _summary(rep, ci_prob, "height_mm")
    ).items():
        table[k] = v
    table["sigma_mm_median"] = np.nanmedian(sigma_used, axis=0)
    table.attrs["ci_prob"] = ci_prob
    return Prediction(table, sim, rep, float(ci_prob), tuple(dict.fromkeys(notes)))
