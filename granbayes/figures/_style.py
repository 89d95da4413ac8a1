"""Shared styling of the figures: colours, labels with units, the SYNTHETIC data label."""

from __future__ import annotations

import textwrap
from collections.abc import Iterable

import numpy as np
import xarray as xr

from .._priors import CALIBRATION_UNITS
from ..forces import parameter

#: Label and unit of the noise parameter; those of the force-term parameters are in the
#: registry (:data:`granbayes.forces.TERMS`).
_NOISE_LABELS: dict[str, tuple[str, str]] = {
    "sigma_mm": ("σ [mm]", "mm"),
    "frame_sd_foot_mm": ("σ_foot [mm]", "mm"),
    "frame_sd_rod_mm": ("σ_rod [mm]", "mm"),
    "frame_tau_ms": ("τ_frame [ms]", "ms"),
    "force_sd_N": ("σ_F [N]", "N"),
}

#: Labels of the robot parameters a calibration leaves uncertain (sampled with the law).
_ROBOT_LABELS: dict[str, tuple[str, str]] = {
    name: (
        "stroke amplitude [mm]"
        if name == "amplitude_mm"
        else f"{name} [{unit.replace('^3', '³')}]",
        unit,
    )
    for name, unit in CALIBRATION_UNITS.items()
}


#: Labels and units of every parameter that is not a force term's.
_OWN_LABELS = _NOISE_LABELS | _ROBOT_LABELS

#: Colours of lines and bands (Okabe-Ito, colour-blind safe).
COLORS = ("#0072B2", "#D55E00", "#009E73", "#CC79A7", "#E69F00")


def data_label(dt: xr.DataTree) -> str:
    """``"SYNTHETIC data (<generator>)"`` if the jumps say so in a ``source`` column, else ``""``.

    Synthetic data sets mark every row (``source = "synthetic: <generator> seed=<n>"``);
    every figure and summary of such data carries this label.

    Parameters
    ----------
    dt : xarray.DataTree
        A fit.

    Returns
    -------
    str
    """
    obs = dt.observed_data.to_dataset()
    names = [c for c in obs.coords if c == "source" or str(c).endswith("_source")]
    return source_label(np.concatenate([obs[c].values for c in names])) if names else ""


def source_label(sources: Iterable[object]) -> str:
    """``"SYNTHETIC data (<generator>)"`` if any of the ``source`` values is synthetic, else ``""``.

    Parameters
    ----------
    sources : iterable
        The ``source`` column of a jumps table (one value per jump).
    """
    synthetic = sorted({str(v) for v in sources if str(v).startswith("synthetic")})
    if not synthetic:
        return ""
    return (
        "SYNTHETIC data ("
        + "; ".join(s.removeprefix("synthetic:").strip() for s in synthetic)
        + ")"
    )


def param_unit(name: str) -> str | None:
    """Unit of a parameter (from the force-term registry), or None if it is unknown.

    Parameters
    ----------
    name : str
        A force-term parameter, an observation model's (``sigma_mm``, ...) or a robot
        parameter sampled with its calibration (``k_spring``, ...).

    Returns
    -------
    str or None
    """
    if name in _OWN_LABELS:
        return _OWN_LABELS[name][1]
    try:
        return parameter(name).unit
    except KeyError:
        return None


def param_label(name: str) -> str:
    """Axis and table label of a parameter, e.g. ``"k2 [N/m²]"`` (from the registry).

    Parameters
    ----------
    name : str
        A force-term parameter, an observation model's (``sigma_mm``, ...) or a robot
        parameter sampled with its calibration (``k_spring [N/m]``, ...).

    Returns
    -------
    str
    """
    if name in _OWN_LABELS:
        return _OWN_LABELS[name][0]
    try:
        return parameter(name).label
    except KeyError:
        return f"{name} []"


def value_with_errors(value: float, minus: float, plus: float) -> str:
    """``value`` with its lower and upper errors as mathtext, to the errors' precision.

    Rounded to two significant digits of the smaller error (``1857^{+81}_{-94}``,
    ``11.8^{+6.3}_{-5.5}``); ``.3g`` where the errors are zero or not finite.

    Parameters
    ----------
    value : float
        The estimate (e.g. a posterior median), in the parameter's unit.
    minus, plus : float
        Distances from ``value`` to the interval's lower and upper ends (>= 0).

    Returns
    -------
    str
        A mathtext string, e.g. ``"$1857^{+81}_{-94}$"``.
    """
    smaller = min(minus, plus)
    if not (np.isfinite(smaller) and smaller > 0 and np.isfinite(value)):
        return f"${value:.3g}^{{+{plus:.3g}}}_{{-{minus:.3g}}}$"
    magnitude = int(np.floor(np.log10(smaller)))
    decimals = max(0, 1 - magnitude)
    step = 10.0 ** (magnitude - 1)  # the last digit kept: ..., 0.1, 1, 10, 100, ...
    text = [f"{round(x / step) * step:.{decimals}f}" for x in (value, plus, minus)]
    return f"${text[0]}^{{+{text[1]}}}_{{-{text[2]}}}$"


def wrap_title(text: str, width_in: float, fontsize: float) -> str:
    """``text`` with each line wrapped to fit a figure ``width_in`` inches wide.

    A figure title wider than its figure is cut at both sides (a residual map of one
    volume fraction is narrow). The width of a character is taken as 0.6 of the font
    size, a bound for DejaVu Sans's average.

    Parameters
    ----------
    text : str
        The title, lines separated by newlines.
    width_in : float
        Width of the figure [inch].
    fontsize : float
        Font size of the title [pt].

    Returns
    -------
    str
    """
    chars = max(20, int(width_in * 72.0 / (0.6 * fontsize)))
    return "\n".join(
        textwrap.fill(line, chars, break_long_words=False) if line else line
        for line in text.split("\n")
    )


def suptitle(fig, text: str, *, fontsize: float = 12.0, **kwargs):
    """Set the title of ``fig`` (a Figure or SubFigure), wrapped to its width.

    Parameters
    ----------
    fig : matplotlib.figure.Figure or matplotlib.figure.SubFigure
        The figure.
    text : str
        The title.
    fontsize : float
        Font size [pt] (matplotlib's default for a figure title is 12).
    **kwargs
        Passed to :meth:`matplotlib.figure.Figure.suptitle`.

    Returns
    -------
    matplotlib.text.Text
    """
    width_in = fig.bbox.width / fig.dpi if fig.dpi else fig.get_size_inches()[0]
    return fig.suptitle(wrap_title(text, width_in, fontsize), fontsize=fontsize, **kwargs)
