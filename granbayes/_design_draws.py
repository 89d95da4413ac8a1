"""What a design works from: the settings a next jump may have, and a fit's draws there.

Shared by the design of jumps that settle a tie (:mod:`granbayes.design`) and of jumps that
identify a parameter (:mod:`granbayes._identify`).
"""

from __future__ import annotations

import itertools
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
import pandas as pd

from ._likelihood import Observations
from ._saved import SavedFit
from .commands import COMMAND_NAMES, COMMANDS

#: Settings columns of a candidate (and of a plan's rows).
SETTINGS = ("command", "phi", "freq_hz", "delay_ms")


def candidate_settings(
    measured: pd.DataFrame,
    *,
    commands: Sequence[str] | None = None,
    phis: Sequence[float] | None = None,
    freqs_hz: Sequence[float] | None = None,
    delays_ms: Sequence[float] | None = None,
    n_freqs: int = 5,
) -> pd.DataFrame:
    """Settings a next jump may have: by default, within what the lab has measured.

    Parameters
    ----------
    measured : pandas.DataFrame
        The jumps measured so far (``phi``, ``command``, ``freq_hz``, and ``delay_ms`` if
        the table has it).
    commands : sequence of str, optional
        Default: every command.
    phis : sequence of float, optional
        Volume fractions [-] (default: the measured ones; a per-phi fit predicts at those
        only).
    freqs_hz : sequence of float, optional
        Frequencies [Hz] (default: ``n_freqs`` evenly from the lowest measured to the
        highest, the measured ones included: no extrapolation).
    delays_ms : sequence of float, optional
        Holds [ms] of the commands that use ``delay_ms`` (the registry's
        :attr:`granbayes.commands.Command.uses`: the delayed stutter; default: the
        measured ones, or the experiment's setting when the table has no ``delay_ms``
        column: ``NaN``).
    n_freqs : int
        Frequencies of the default grid.

    Returns
    -------
    pandas.DataFrame
        One row per setting: ``command``, ``phi``, ``freq_hz``, ``delay_ms`` (``NaN``:
        the fit's experiment setting; also for commands that do not use it).
    """
    commands = list(commands or COMMAND_NAMES)
    unknown = sorted(set(commands) - set(COMMAND_NAMES))
    if unknown:
        raise ValueError(f"unknown command(s) {unknown}; known: {list(COMMAND_NAMES)}")
    phis = sorted(set(map(float, phis if phis is not None else measured["phi"])))
    if freqs_hz is None:
        f = np.unique(measured["freq_hz"].to_numpy(float))
        grid = np.linspace(f.min(), f.max(), n_freqs) if f.size > 1 else f
        freqs_hz = np.unique(np.round(np.concatenate([grid, f]), 6))
    if delays_ms is None:
        delays_ms = (
            np.unique(measured["delay_ms"].dropna().to_numpy(float))
            if "delay_ms" in measured and measured["delay_ms"].notna().any()
            else [np.nan]
        )
    rows = []
    for command, phi, freq in itertools.product(commands, phis, sorted(map(float, freqs_hz))):
        for delay in delays_ms if "delay_ms" in COMMANDS[command].uses else [np.nan]:
            rows.append({"command": command, "phi": phi, "freq_hz": freq, "delay_ms": delay})
    return pd.DataFrame(rows, columns=list(SETTINGS))


@dataclass(frozen=True)
class LawDraws:
    """One law's posterior draws, as the design uses them.

    Attributes
    ----------
    mean_mm : ndarray, shape (n_draws, n_settings)
        Simulated height of a new jump at every candidate setting, per draw [mm].
    var_mm2 : ndarray, shape (n_draws, n_settings)
        Its noise variance [mm^2] (the scatter squared), per draw.
    log_lik : ndarray, shape (n_draws, n_jumps)
        Pointwise log-likelihood of the jumps measured so far, per draw [nats].
    setting_run, jump_run : ndarray of int
        Which run's draws (``per_phi``: the run of the volume fraction) each setting and
        each measured jump belongs to; a new jump reweights the draws of its run only.
    """

    mean_mm: np.ndarray
    var_mm2: np.ndarray
    log_lik: np.ndarray
    setting_run: np.ndarray
    jump_run: np.ndarray

    @property
    def n_runs(self) -> int:
        """Runs (posteriors updated independently)."""
        return int(max(self.setting_run.max(initial=0), self.jump_run.max(initial=0)) + 1)

    def moments(self) -> tuple[np.ndarray, np.ndarray]:
        """Mean and variance [mm, mm^2] of a new jump at every setting, all draws equal."""
        mean = self.mean_mm.mean(axis=0)
        return mean, (self.var_mm2 + self.mean_mm**2).mean(axis=0) - mean**2


def law_draws(
    fit: SavedFit, candidates: pd.DataFrame, draw_index: np.ndarray
) -> tuple[LawDraws, np.ndarray]:
    """A fitted law's draws at the candidate settings and on its measured jumps.

    Parameters
    ----------
    fit : SavedFit
        A fit with jump heights.
    candidates : pandas.DataFrame
        ``command``, ``phi``, ``freq_hz``, ``delay_ms`` (NaN: the fit's setting).
    draw_index : ndarray of int
        Which posterior draws (flat (chain, draw) index; the same for every run).

    Returns
    -------
    draws : LawDraws
    failed : ndarray of float, shape (n_settings,)
        Share of the draws whose jump did not finish at each setting (their simulated
        height is replaced by the mean of the others).
    """
    cmd = fit.experiment.command
    grid = candidates.assign(
        delay_ms=candidates["delay_ms"].fillna(cmd.delay_ms),
        amplitude_mm=cmd.amplitude_mm,
        settle_periods=cmd.settle_periods,
        height_mm=np.nan,
    )
    labels = list(fit.models())
    runs = fit.runs_of(grid["phi"].to_numpy(float))
    mean = np.full((len(draw_index), len(grid)), np.nan)
    var = mean.copy()
    for label in dict.fromkeys(runs):
        cols = np.flatnonzero(np.array(runs) == label)
        u = fit.draws(label)[draw_index]
        m, sigma, _ = fit.model(label).mean_and_sigma(u, Observations.from_table(grid.iloc[cols]))
        mean[:, cols], var[:, cols] = m, sigma**2
    failed = (~np.isfinite(mean)).mean(axis=0)
    fill = np.nanmean(np.where(np.isfinite(mean), mean, np.nan), axis=0)
    mean = np.where(np.isfinite(mean), mean, fill)
    ll = fit.datatree["log_likelihood"]["height_mm"]
    ll = ll.transpose("chain", "draw", ...).values.reshape(-1, ll.sizes["jump"])[draw_index]
    jump_runs = fit.runs_of(fit.observed()["phi"].to_numpy(float))
    return (
        LawDraws(
            mean_mm=mean,
            var_mm2=var,
            log_lik=ll,
            setting_run=np.array([labels.index(r) for r in runs]),
            jump_run=np.array([labels.index(r) for r in jump_runs]),
        ),
        failed,
    )


def usable_settings(failed: np.ndarray, whose: str, which: str) -> tuple[np.ndarray, list[str]]:
    """The settings a design may use: where at most 5% of the draws' jumps did not finish.

    Parameters
    ----------
    failed : ndarray, shape (n_settings,)
        Share of the draws whose jump did not finish at each setting (:func:`law_draws`).
    whose, which : str
        How the messages name the law(s): ``"the law's"`` / ``"the law"``, or ``"a
        law's"`` / ``"every law"``.

    Returns
    -------
    usable : ndarray of bool
    notes : list of str
        A note on the settings dropped, if any.

    Raises
    ------
    ValueError
        If no setting is usable.
    """
    usable = failed <= 0.05
    notes = []
    if not usable.all():
        notes.append(
            f"{int((~usable).sum())} of {len(failed)} settings dropped: {whose} jump did not "
            "finish in more than 5% of the draws there"
        )
    if not usable.any():
        raise ValueError(f"no setting that {which} predicts: widen the candidates")
    return usable, notes


def plan_of(candidates: pd.DataFrame, counts: np.ndarray) -> pd.DataFrame:
    """The plan's rows: the settings with jumps and their ``trials``, most trials first.

    Parameters
    ----------
    candidates : pandas.DataFrame
        The settings (:data:`SETTINGS` columns).
    counts : ndarray of int
        Jumps per setting.

    Returns
    -------
    pandas.DataFrame
    """
    plan = candidates.loc[counts > 0, list(SETTINGS)].assign(trials=counts[counts > 0])
    return plan.sort_values("trials", ascending=False, kind="stable").reset_index(drop=True)
