"""The result of ``diagnose`` as typed records, and their ``diagnosis.json`` form.

Every field of ``diagnosis.json`` (docs/data-format.md) is a field of one of these frozen
dataclasses; :meth:`DiagnosisRecord.to_json` writes the document and
:meth:`DiagnosisRecord.from_json` reads it back, so code that uses a diagnosis reads
attributes, not string keys.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field, fields
from typing import Any

import pandas as pd

from .. import stats
from ._cells import KIND_CELL_KEYS
from ._rule import Candidate, DiagnoseSettings, Estimate, Verdict, json_number


def _missing(value: Any) -> bool:
    """A key a cell of another kind does not have (NaN after stacking)."""
    return isinstance(value, float) and value != value


def _number(value: Any) -> Any:
    """A cell-key value as written: the command as text, a setting as a float."""
    return value if isinstance(value, str) else float(value)


@dataclass(frozen=True)
class CellResult:
    """One residual cell of a law (``misfit`` and ``residual_misfit`` entries).

    Attributes
    ----------
    key : dict
        The cell: ``command`` and its settings (``phi``, ``freq_hz``, ... of
        :data:`granbayes.stats.CELL_KEYS` the data have); for the kinds beyond heights
        also ``position`` and ``phase`` (tracked jumps) or ``speed_mm_s`` and the depth
        bin (intrusion curves).
    n : int
        Measurements in the cell (jumps, frames or force samples).
    mean_residual : float
        Observed minus simulated mean, in ``unit`` (``mean_residual_<unit>`` in JSON).
    z, p_value : float
        Lack-of-fit z and its p-value (:func:`granbayes.stats.residual_table`,
        :func:`granbayes.stats.predictive_cells`).
    significant : bool
        Whether |z| exceeds the misfit threshold of its kind.
    description : str
        The cell in words.
    kind : str
        Its kind of measurement (:data:`granbayes.kinds.KINDS`).
    unit : str
        Unit of ``mean_residual`` (``mm`` or ``N``).
    """

    key: dict[str, Any]
    n: int
    mean_residual: float
    z: float
    p_value: float
    significant: bool
    description: str
    kind: str = "heights"
    unit: str = "mm"

    @property
    def mean_residual_mm(self) -> float:
        """The mean residual [mm] (NaN for a cell in another unit)."""
        return self.mean_residual if self.unit == "mm" else float("nan")

    @classmethod
    def from_table(
        cls, residuals: pd.DataFrame, z_threshold: float | Mapping[str, float]
    ) -> tuple[CellResult, ...]:
        """The cells of a residual table (:func:`granbayes._criticism.cells_of`).

        Parameters
        ----------
        residuals : pandas.DataFrame
            The table, worst first (a ``kind`` column: heights if absent).
        z_threshold : float or mapping of str to float
            The misfit threshold of |z|, or one per kind.

        Returns
        -------
        tuple of CellResult
        """
        keys = (*stats.CELL_KEYS, *KIND_CELL_KEYS)
        out = []
        for r in residuals.to_dict("records"):
            kind = str(r.get("kind", "heights"))
            thr = z_threshold if not isinstance(z_threshold, Mapping) else z_threshold[kind]
            unit = str(r.get("unit", "mm")) if "mean_residual" in r else "mm"
            value = r["mean_residual"] if "mean_residual" in r else r["mean_residual_mm"]
            out.append(
                cls(
                    key={k: _number(r[k]) for k in keys if k in r and not _missing(r[k])},
                    n=int(r["n"]),
                    mean_residual=float(value),
                    z=float(r["z"]),
                    p_value=float(r["p_value"]),
                    significant=bool(abs(r["z"]) > thr),
                    description=stats.describe_cell(r),
                    kind=kind,
                    unit=unit,
                )
            )
        return tuple(out)

    def to_json(self) -> dict:
        """The JSON form: the key's fields first, then the statistics."""
        kind = {} if self.kind == "heights" else {"kind": self.kind}
        return {
            **kind,
            **self.key,
            "n": self.n,
            f"mean_residual_{self.unit}": self.mean_residual,
            "z": self.z,
            "p_value": self.p_value,
            "significant": self.significant,
            "description": self.description,
        }

    @classmethod
    def from_json(cls, doc: Mapping[str, Any]) -> CellResult:
        """Read the JSON form.

        Parameters
        ----------
        doc : mapping

        Returns
        -------
        CellResult
        """
        residual = next(k for k in doc if k.startswith("mean_residual_"))
        stat = {"n", "z", "p_value", "significant", "description"}
        return cls(
            key={k: v for k, v in doc.items() if k not in stat | {residual, "kind"}},
            mean_residual=doc[residual],
            unit=residual.removeprefix("mean_residual_"),
            kind=doc.get("kind", "heights"),
            **{k: doc[k] for k in stat},
        )


@dataclass(frozen=True)
class CellChange:
    """A cell's residual under the baseline and under the selected law (``per_cell``).

    Attributes
    ----------
    key : dict
        The cell (as :attr:`CellResult.key`).
    residual_before_mm, residual_after_mm : float
        Mean residuals [mm] of the baseline and the selected law.
    z_before, z_after : float
        Their lack-of-fit z.
    """

    key: dict[str, Any]
    residual_before_mm: float
    residual_after_mm: float
    z_before: float
    z_after: float

    def to_json(self) -> dict:
        """The JSON form."""
        return {
            **self.key,
            "residual_before_mm": self.residual_before_mm,
            "residual_after_mm": self.residual_after_mm,
            "z_before": self.z_before,
            "z_after": self.z_after,
        }


@dataclass(frozen=True)
class Tie:
    """A candidate the term added in a round is not distinguished from.

    Attributes
    ----------
    round : int
    selected : str
        The term added.
    term : str
        The rival.
    elpd_diff, elpd_diff_se : float
        Paired ELPD difference selected - rival and its SE [nats].
    converged : bool
        Whether the rival's fit converged.
    """

    round: int
    selected: str
    term: str
    elpd_diff: float
    elpd_diff_se: float
    converged: bool

    def to_json(self) -> dict:
        """The JSON form."""
        return {f.name: getattr(self, f.name) for f in fields(self)}


@dataclass(frozen=True)
class FitRecord:
    """How one fit of the bank went (``diagnosis.json`` ``fits``).

    Attributes
    ----------
    terms : tuple of str
        The law.
    converged : bool
        Whether its (final) fit converged.
    warnings : tuple of str
        What went wrong, and the reruns, in words.
    reruns : int
        Reruns made.
    """

    terms: tuple[str, ...]
    converged: bool
    warnings: tuple[str, ...]
    reruns: int

    def to_json(self) -> dict:
        """JSON-ready record."""
        return {
            "terms": list(self.terms),
            "converged": self.converged,
            "warnings": list(self.warnings),
            "reruns": self.reruns,
        }


@dataclass(frozen=True)
class BaselineResult:
    """The baseline law's fit (``baseline``).

    Attributes
    ----------
    terms : tuple of str
    elpd, elpd_se : float
        Its PSIS-LOO ELPD and SE [nats].
    rmse_mm : float
        Root-mean-square residual [mm].
    """

    terms: tuple[str, ...]
    elpd: float
    elpd_se: float
    rmse_mm: float

    def to_json(self) -> dict:
        """The JSON form."""
        return {
            "terms": list(self.terms),
            "elpd": self.elpd,
            "elpd_se": self.elpd_se,
            "rmse_mm": self.rmse_mm,
        }


@dataclass(frozen=True)
class SelectedResult:
    """The selected law against the baseline (``selected``).

    Attributes
    ----------
    terms, added : tuple of str
        Its terms, and those added to the baseline (in order).
    elpd_gain, elpd_gain_se : float
        ELPD gain over the baseline and its SE [nats].
    elpd_method : str
        How the gain was estimated, in words.
    elpd_gain_cells, elpd_gain_cells_se : float
        The gain as a leave-one-cell-out estimate [nats].
    rmse_before_mm, rmse_after_mm : float
        Root-mean-square residuals of baseline and selected law [mm].
    indistinguishable : tuple of Tie
        Candidates the added terms are not distinguished from.
    parameters : dict
        Per new parameter and volume fraction: its 5%, 50% and 95% posterior quantiles.
    interval : str
        What ``parameters`` holds, in words.
    per_cell : tuple of CellChange
        Every cell's residual before and after.
    """

    terms: tuple[str, ...]
    added: tuple[str, ...]
    elpd_gain: float
    elpd_gain_se: float
    elpd_method: str
    elpd_gain_cells: float
    elpd_gain_cells_se: float
    rmse_before_mm: float
    rmse_after_mm: float
    indistinguishable: tuple[Tie, ...]
    parameters: dict[str, dict[str, list[float]]]
    interval: str
    per_cell: tuple[CellChange, ...]

    def to_json(self) -> dict:
        """The JSON form."""
        return {
            "terms": list(self.terms),
            "added": list(self.added),
            "elpd_gain": self.elpd_gain,
            "elpd_gain_se": self.elpd_gain_se,
            "elpd_method": self.elpd_method,
            "elpd_gain_cells": self.elpd_gain_cells,
            "elpd_gain_cells_se": self.elpd_gain_cells_se,
            "rmse_before_mm": self.rmse_before_mm,
            "rmse_after_mm": self.rmse_after_mm,
            "indistinguishable": [t.to_json() for t in self.indistinguishable],
            "parameters": self.parameters,
            "interval": self.interval,
            "per_cell": [c.to_json() for c in self.per_cell],
        }


@dataclass(frozen=True)
class RuleRecord:
    """The rule the decision was made with (``rule``).

    Attributes
    ----------
    min_gain, se_factor, strong_gain, family_alpha : float
        The thresholds (:class:`DiagnoseSettings`).
    z_threshold : float
        The misfit threshold of |z| of jump-height cells on these data (of the first kind
        when there are no heights).
    screen : bool
    screen_margin : float
    text : str
        The rule in words.
    z_thresholds : dict of str to float
        The threshold of each kind of measurement's cells (``z_threshold_by_kind``).
    lack_of_fit_alpha : float or None
        Level of the omnibus lack-of-fit test when the rule uses it (None: reported only).
    """

    min_gain: float
    se_factor: float
    strong_gain: float
    family_alpha: float
    z_threshold: float
    screen: bool
    screen_margin: float
    text: str
    z_thresholds: dict[str, float] = field(default_factory=dict)
    lack_of_fit_alpha: float | None = None

    @classmethod
    def of(
        cls, settings: DiagnoseSettings, z_thresholds: Mapping[str, float], cells: pd.DataFrame
    ) -> RuleRecord:
        """The record of the rule ``cfg`` applied with threshold ``z_threshold``.

        Parameters
        ----------
        settings : DiagnoseSettings
        z_thresholds : mapping of str to float
            The threshold of each kind's cells.
        cells : pandas.DataFrame
            The cells of the data set (a ``kind`` column).

        Returns
        -------
        RuleRecord
        """
        n_cells = len(cells)
        z_threshold = float(z_thresholds.get("heights", next(iter(z_thresholds.values()), 0.0)))
        by_kind = ", ".join(
            f"{k}: |z| > {v:.2f} over {int((cells['kind'] == k).sum())} cells"
            for k, v in z_thresholds.items()
        )
        threshold_text = (
            f"|z| > {z_threshold:.2f}"
            if len(z_thresholds) <= 1
            else f"{by_kind}; Bonferroni over all kinds"
        )
        text = (
            f"add the best converged candidate when its ELPD gain > {settings.min_gain:g} "
            f"nats and > {settings.se_factor:g} SE, and the current law has a misfit cell "
            f"({threshold_text}: family-wise false-alarm rate {settings.family_alpha:g} "
            f"over {n_cells} cells) or the gain exceeds {settings.strong_gain:g} nats; "
            f"at most {settings.max_added} terms; misfit the selected law leaves gives "
            "'misfit_remains'; a fitted candidate the chosen one does not beat by the "
            f"same margin (> {settings.min_gain:g} nats and > {settings.se_factor:g} SE of the "
            "paired difference) is reported as indistinguishable from it"
        )
        if settings.lack_of_fit_alpha is not None:
            text += (
                "; a law also shows misfit when its omnibus lack-of-fit test (every height "
                f"cell together against the repeats' pure error) rejects at "
                f"{settings.lack_of_fit_alpha:g}"
            )
        if settings.screen:
            text += (
                "; a candidate is fitted only if its screened log-likelihood gain reaches "
                f"{settings.min_gain:g} nats and the best ELPD gain fitted before it less "
                f"{settings.min_gain + settings.screen_margin:g}"
            )
        return cls(
            min_gain=settings.min_gain,
            se_factor=settings.se_factor,
            strong_gain=settings.strong_gain,
            family_alpha=settings.family_alpha,
            z_threshold=z_threshold,
            screen=settings.screen,
            screen_margin=settings.screen_margin,
            text=text,
            z_thresholds=dict(z_thresholds),
            lack_of_fit_alpha=settings.lack_of_fit_alpha,
        )

    def to_json(self) -> dict:
        """The JSON form."""
        return {f.name: getattr(self, f.name) for f in fields(self)}


@dataclass(frozen=True)
class DiagnosisRecord:
    """What ``diagnose`` concluded and why: the content of ``diagnosis.json``.

    Attributes
    ----------
    baseline : BaselineResult
    misfit : tuple of CellResult
        Every cell of the baseline, worst first.
    n_misfit_cells : int
        The baseline's misfit cells.
    candidates : tuple of Candidate
        Every candidate of every round.
    verdict : Verdict
    selected : SelectedResult
    residual_misfit : tuple of CellResult
        The selected law's misfit cells.
    fits : tuple of FitRecord
        Every fit the decision rests on.
    rule : RuleRecord
    seed : int
    data_source : str
    environment : dict
        Package versions and machine (``versions``, ``machine``).
    lack_of_fit : dict
        The omnibus lack-of-fit test (:func:`granbayes.stats.lack_of_fit`) of the
        ``baseline`` and of the ``selected`` law: ``statistic``, ``dof_lack``,
        ``dof_pure``, ``p_value`` (NaN without repeated jumps).
    """

    baseline: BaselineResult
    misfit: tuple[CellResult, ...]
    n_misfit_cells: int
    candidates: tuple[Candidate, ...]
    verdict: Verdict
    selected: SelectedResult
    residual_misfit: tuple[CellResult, ...]
    fits: tuple[FitRecord, ...]
    rule: RuleRecord
    seed: int
    data_source: str
    environment: dict[str, Any] = field(default_factory=dict)
    lack_of_fit: dict[str, dict[str, float]] = field(default_factory=dict)

    @property
    def all_converged(self) -> bool:
        """Whether every fit the decision rests on converged."""
        return all(f.converged for f in self.fits)

    def to_json(self) -> dict:
        """The ``diagnosis.json`` document (docs/data-format.md)."""
        return {
            "baseline": self.baseline.to_json(),
            "misfit": [c.to_json() for c in self.misfit],
            "n_misfit_cells": self.n_misfit_cells,
            "candidates": [c.to_json() for c in self.candidates],
            "verdict": self.verdict.value,
            "selected": self.selected.to_json(),
            "residual_misfit": [c.to_json() for c in self.residual_misfit],
            "lack_of_fit": {
                law: {k: json_number(v) for k, v in test.items()}
                for law, test in self.lack_of_fit.items()
            },
            "fits": [f.to_json() for f in self.fits],
            "all_converged": self.all_converged,
            "rule": self.rule.to_json(),
            "seed": self.seed,
            "data_source": self.data_source,
            # package versions and the machine: what bit-identical results require to match
            **self.environment,
        }

    @classmethod
    def from_json(cls, doc: Mapping[str, Any]) -> DiagnosisRecord:
        """Read a ``diagnosis.json`` document back.

        Parameters
        ----------
        doc : mapping
            The document.

        Returns
        -------
        DiagnosisRecord
        """
        sel = doc["selected"]
        cell_stats = {f.name for f in fields(CellChange)} - {"key"}
        return cls(
            baseline=BaselineResult(
                **{**doc["baseline"], "terms": tuple(doc["baseline"]["terms"])}
            ),
            misfit=tuple(CellResult.from_json(c) for c in doc["misfit"]),
            n_misfit_cells=int(doc["n_misfit_cells"]),
            candidates=tuple(_candidate_from_json(c) for c in doc["candidates"]),
            verdict=Verdict(doc["verdict"]),
            selected=SelectedResult(
                terms=tuple(sel["terms"]),
                added=tuple(sel["added"]),
                elpd_gain=sel["elpd_gain"],
                elpd_gain_se=sel["elpd_gain_se"],
                elpd_method=sel["elpd_method"],
                elpd_gain_cells=sel["elpd_gain_cells"],
                elpd_gain_cells_se=sel["elpd_gain_cells_se"],
                rmse_before_mm=sel["rmse_before_mm"],
                rmse_after_mm=sel["rmse_after_mm"],
                indistinguishable=tuple(Tie(**t) for t in sel["indistinguishable"]),
                parameters=sel["parameters"],
                interval=sel["interval"],
                per_cell=tuple(
                    CellChange(
                        key={k: v for k, v in c.items() if k not in cell_stats},
                        **{k: c[k] for k in cell_stats},
                    )
                    for c in sel["per_cell"]
                ),
            ),
            residual_misfit=tuple(CellResult.from_json(c) for c in doc["residual_misfit"]),
            fits=tuple(
                FitRecord(tuple(f["terms"]), f["converged"], tuple(f["warnings"]), f["reruns"])
                for f in doc["fits"]
            ),
            rule=RuleRecord(**doc["rule"]),
            seed=int(doc["seed"]),
            data_source=doc["data_source"],
            environment={k: doc[k] for k in ("versions", "machine") if k in doc},
            lack_of_fit={
                law: {k: float("nan") if v is None else float(v) for k, v in test.items()}
                for law, test in doc.get("lack_of_fit", {}).items()
            },
        )


def _candidate_from_json(doc: Mapping[str, Any]) -> Candidate:
    """A :class:`Candidate` from its JSON form (nulls back to NaN)."""
    nan = float("nan")

    def num(key: str) -> float:
        value = doc.get(key)
        return nan if value is None else float(value)

    return Candidate(
        term=doc["term"],
        added=tuple(doc["added"]),
        round=int(doc["round"]),
        elpd=num("elpd"),
        gain=num("elpd_diff_vs_current"),
        gain_se=num("elpd_diff_vs_current_se"),
        gain_vs_baseline=num("elpd_diff"),
        gain_vs_baseline_se=num("elpd_diff_se"),
        rmse_mm=num("rmse_mm"),
        max_pareto_k=num("max_pareto_k"),
        method=doc["method"],
        estimate=Estimate(doc["estimate"]),
        converged=bool(doc["converged"]),
        screen_gain=num("screen_gain"),
        vs_selected=num("elpd_diff_vs_selected"),
        vs_selected_se=num("elpd_diff_vs_selected_se"),
    )


def interval_of(values: Sequence[float], ci_prob: float) -> list[float]:
    """``[lo, median, hi]`` of the finite values (the order of ``selected.parameters``).

    Parameters
    ----------
    values : sequence of float
        Draws.
    ci_prob : float
        Probability of the equal-tailed interval.

    Returns
    -------
    list of float
    """
    med, lo, hi = stats.interval(values, ci_prob)
    return [lo, med, hi]
