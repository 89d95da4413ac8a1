"""The Bayesian fit: joint posteriors of the force law per volume fraction.

:func:`fit` infers the force-term parameters from measured jump heights:

* ``phi_mode="per_phi"`` (default): at every volume fraction one parameter set shared by
  all five commands, plus that volume fraction's scatter, sampled independently;
* ``phi_mode="quadratic"``: every coefficient a quadratic in ``phi - phi_c`` (the thesis's
  ``k(phi)``), fitted jointly over all volume fractions.

A robot known only to its calibration (``experiment.toml``'s ``[robot.uncertainty]``):
with ``calibration="sample"`` (default) each uncertain robot parameter (the robot's own and
the stroke ``amplitude_mm``) is one more coordinate of every sampler run, shared by its
commands and kinds of measurement, with Normal(nominal, sd) as prior. How it is sampled,
and why: in ``quadratic`` mode the run already holds every volume fraction, so the robot is
shared by all of them. In ``per_phi`` mode, ``calibration="sample"`` gives each volume
fraction's run its own copy, the conservative marginal (a volume fraction's law never
borrows what the others say about the spring); ``calibration="pool"`` samples one robot
for all of them: one run whose coordinates are every volume fraction's law and scatter
plus the robot's (:class:`~granbayes._likelihood.JumpModel`'s ``"per_phi_joint"``,
13 dimensions for the depth law at 5 volume fractions and 3 robot parameters), one
emcee ensemble per independent chain with ``4 x ndim`` walkers, started from the Laplace
approximation like every run. Why one ensemble rather than blocks per volume fraction
given the robot (Metropolis-within-Gibbs): the robot and each volume fraction's stiffness
trade against each other (in the pooled posterior of the issue's lab, seed 0, log k at
every volume fraction correlates with the spring by 0.78-0.83, the motor's mass by
0.85-0.89 and the stroke by -0.82 to -0.91), so a Gibbs sweep would move along that ridge
in small steps, while the affine-invariant moves of one ensemble follow it. Its cost
against the copies and the fixed robot is measured in
``benchmarks/results/calibrated_fit.md``; half of it is the start's climbs in 13
dimensions, every climb simulating every jump. Two starts made of the volume fractions'
own starts (each volume fraction's run started as on its own, 15 s) were tried on the
issue's lab (seed 0, one thread) and not kept: their modes combined, then climbed by
L-BFGS-B (14 s more on the simulator's slightly rough log-posterior, to stop 4-5 nats
below the mode the usual climbs reach; the fit then needed 400 steps instead of 150,
148 s against 69 s); and the product of their Laplace approximations with no climb
(the robot's centre 3 posterior sds from the pooled posterior's, the volume fractions'
robot posteriors being far from normal along the spring-stiffness ridge: 250 steps,
81 s). Nor a memo of the start's simulations (a jump whose robot, force parameters and
program a climb has simulated before, e.g. along a scatter or another volume fraction's
coordinate, read back instead of simulated; the same posterior bit for bit): 29% of the
start's rows were repeats, and it took the start from 22.3 s to 19.4 s and the fit from
63.8 s to 61.9 s (the issue's lab, data seed 0, fit seed 1, one thread, a loaded
machine); on the reference data's fixed robot 4% were, and the start was slower. The
robot,
pinned by every volume fraction's jumps, no longer drags the stiffness towards the
nominal robot (``README``, "A robot known only to its calibration"). ``diagnose`` keeps
the copies: its fallbacks refit and cross-validate volume fractions on their own.

A bed's volume fraction known only to its measurement (``[bed] phi_sd``): with
``bed_phi="integrate"`` (default) and ``phi_mode="quadratic"``, each jump's and each
intrusion test's bed has a latent true phi, integrated out of that unit's likelihood
(:mod:`granbayes._likelihood._beds` says how and why). Why only there: the smooth laws are
defined beside the measured volume fractions; per-phi coefficients are not, and a local
slope per coefficient and volume fraction would be identified only by the extra scatter
the beds add to that volume fraction's jumps (in practice by its prior, i.e. by the
neighbouring volume fractions: the smooth law again). So in ``per_phi`` mode a volume
fraction's coefficients are those of the beds prepared at it, and the fit says so.

:func:`compare_commands` answers the thesis's question "one force law for every jump?":
per volume fraction, the shared law against separate laws per command, by PSIS-LOO.

Every fit derives its seeds from one master seed (``numpy.random.SeedSequence``), so the
same seed gives bit-identical posteriors, including after ``resume``.

Length: about 1,470 lines: the fit from measurements to one DataTree (models per run,
sampling, starting points, the mapping of every run's draws, replicates and units onto
the fit's dimensions, provenance), plus the command comparison; the mapping onto the
DataTree is most of it.
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import warnings
from collections.abc import Callable, Iterator, Mapping, Sequence
from dataclasses import dataclass, field
from functools import partial
from pathlib import Path
from typing import Literal

import numpy as np
import pandas as pd
import xarray as xr
from scipy import optimize
from threadpoolctl import threadpool_limits

from . import _datatree as gdt
from . import stats
from ._deprecated import alias_getattr, renamed_keyword, warn_alias
from ._experiment import Experiment
from ._likelihood import (
    CALIBRATED_KEYS,
    BedPhi,
    HeightBlock,
    JumpModel,
    NoiseFamily,
    Observations,
    ObservationSettings,
    PhiMode,
    SigmaMode,
    evaluate_models,
)
from ._measurements import Measurements
from ._priors import Prior, calibration_priors, default_priors
from ._provenance import environment
from ._sampler import (
    START_NOTE,
    ProgressInfo,
    RunSpec,
    SamplerRun,
    SamplerSettings,
    run_side_by_side,
)
from ._search import drive, in_thread, nelder_mead
from ._simulator import SolverSettings
from .commands import COMMAND_NAMES
from .forces import PARAMETERS, terms_of
from .kinds import KINDS, blocks_for

#: The "off" value of every force parameter (its term absent).
PARAMETER_ABSENT: dict[str, float | None] = {p.name: p.absent for p in PARAMETERS}

__all__ = [
    "CommandComparison",
    "FitSettings",
    "FitPart",
    "FitResult",
    "compare_commands",
    "data_hash",
    "find_starts",
    "fit",
    "part_models",
    "screen",
]

#: Deprecated alias (old name -> new name): importable, with a DeprecationWarning.
__getattr__ = alias_getattr(__name__, {"FitConfig": "FitSettings"})


@dataclass(frozen=True)
class FitSettings:
    """What to fit and how (formerly ``FitConfig``, now a deprecated alias).

    Parameters
    ----------
    terms : tuple of str
        Force terms (``depth`` always included).
    phi_mode : {"per_phi", "quadratic"}
        Independent parameters per volume fraction, or quadratic laws in ``phi - phi_c``.
    noise : {"normal", "student_t"}
        Noise family (Student-t: heavy-tailed, ``nu`` degrees of freedom).
    nu : float
        Student-t degrees of freedom.
    sigma_mode : {"per_phi", "global"}
        Scatter per volume fraction or one for all (``per_phi`` mode always per phi).
    sampler : SamplerSettings
        Ensemble size, chain-length rule, kept draws.
    fixed : mapping of str to float
        Parameters held at given values instead of their ``absent`` value.
    options : SolverSettings
        Integrator settings.
    n_threads : int, optional
        numba threads for the simulator.
    n_prior_draws : int
        Prior draws (and their simulated heights) stored in the DataTree's ``prior`` and
        ``prior_predictive`` groups (0: none).
    calibration : {"sample", "pool", "nominal"}
        ``"sample"``: the robot parameters ``experiment.toml`` gives an uncertainty
        (``[robot.uncertainty]``; the robot's own and ``amplitude_mm``) are parameters of
        the fit with their calibration as prior, one value per sampler run (``quadratic``:
        one for all volume fractions; ``per_phi``: each volume fraction integrates over its
        own, see the module docstring); ``"pool"``: one value for every volume fraction
        also in ``per_phi`` mode (one sampler run over every volume fraction's law; the
        same as ``"sample"`` in ``quadratic`` mode); ``"nominal"``: take the nominal values
        as exact (the fit warns). Without uncertainties the three are the same fit, bit for
        bit.
    bed_phi : {"integrate", "measured"}
        ``"integrate"``: with ``[bed] phi_sd > 0`` and ``phi_mode="quadratic"``, each
        jump's and each intrusion test's bed has a latent volume fraction
        ``Normal(measured, phi_sd)``, integrated out by Gauss-Hermite quadrature
        (:class:`granbayes._likelihood.BedPhi`; ``phi_nodes`` simulations per
        configuration); tracked jumps take the measured phi. In ``per_phi`` mode a
        volume fraction's coefficients are those of the beds prepared at it (a law
        defined only at the measured value cannot be evaluated beside it), and the fit
        warns. ``"measured"``: every bed's phi as measured (the fit warns when
        ``phi_sd > 0``). Without ``phi_sd`` both are the same fit, bit for bit.
    phi_nodes : int
        Gauss-Hermite nodes of a bed's latent volume fraction.
    """

    terms: tuple[str, ...] = ("depth",)
    phi_mode: Literal["per_phi", "quadratic"] = "per_phi"
    noise: NoiseFamily = "normal"
    nu: float = 4.0
    sigma_mode: SigmaMode = "per_phi"
    sampler: SamplerSettings = field(default_factory=SamplerSettings)
    fixed: Mapping[str, float] = field(default_factory=dict)
    options: SolverSettings = field(default_factory=SolverSettings)
    n_threads: int | None = None
    n_prior_draws: int = 200
    calibration: Literal["sample", "pool", "nominal"] = "sample"
    bed_phi: Literal["integrate", "measured"] = "integrate"
    phi_nodes: int = 9

    def __post_init__(self) -> None:
        """Put the terms in canonical order and check the modes."""
        object.__setattr__(self, "terms", terms_of(self.terms))
        if self.phi_mode not in ("per_phi", "quadratic"):
            raise ValueError(f"phi_mode must be 'per_phi' or 'quadratic', got {self.phi_mode!r}")
        if self.calibration not in ("sample", "pool", "nominal"):
            raise ValueError(
                f"calibration must be 'sample', 'pool' or 'nominal', got {self.calibration!r}"
            )
        if self.bed_phi not in ("integrate", "measured"):
            raise ValueError(f"bed_phi must be 'integrate' or 'measured', got {self.bed_phi!r}")
        BedPhi(0.0, self.phi_nodes)  # checks the node count

    def to_dict(self) -> dict:
        """JSON-ready description (stored in the DataTree attributes)."""
        d = dataclasses.asdict(self)
        d["terms"] = list(self.terms)
        d["fixed"] = dict(self.fixed)
        return d

    @classmethod
    def from_dict(cls, d: Mapping[str, object]) -> FitSettings:
        """The configuration described by :meth:`to_dict` (keys it does not know are ignored).

        Parameters
        ----------
        d : mapping
            A ``to_dict`` document, e.g. the ``config`` attribute of a saved fit.

        Returns
        -------
        FitSettings
        """

        def known(kind: type, values: object) -> dict:
            names = {f.name for f in dataclasses.fields(kind)}
            return {k: v for k, v in dict(values or {}).items() if k in names}

        fields = known(cls, d)
        fields.setdefault("bed_phi", "measured")  # a fit saved before beds were latent
        fields["terms"] = tuple(fields.get("terms", ("depth",)))
        fields["fixed"] = {str(k): float(v) for k, v in dict(fields.get("fixed", {})).items()}
        if "sampler" in fields:
            fields["sampler"] = SamplerSettings(**known(SamplerSettings, fields["sampler"]))
        if "options" in fields:
            fields["options"] = SolverSettings(**known(SolverSettings, fields["options"]))
        return cls(**fields)


@dataclass
class FitPart:
    """One sampler run of a fit: a model and its samples.

    Attributes
    ----------
    label : str
        Run label (``"phi=0.602"`` or ``"all"``).
    model : JumpModel
        Its log-posterior.
    run : SamplerRun
        The pooled ensembles.
    units : ndarray of int
        The units of leave-one-out the run fits, numbered over the fit's measurements
        (:class:`~granbayes.Measurements`; for jump heights alone, rows of the jumps
        table), in the order of the model's blocks.
    data : Measurements, optional
        The measurements the run fits.
    """

    label: str
    model: JumpModel
    run: SamplerRun
    units: np.ndarray
    data: Measurements | None = None

    @property
    def jumps(self) -> np.ndarray:
        """The run's units (former name, from when every unit was a jump)."""
        return self.units

    @property
    def log_lik(self) -> np.ndarray:
        """Pointwise log-likelihood of the kept draws, shape (chain, draw, n_units)."""
        return self.run.blobs[..., : self.model.n_units]

    @property
    def config_heights_mm(self) -> np.ndarray:
        """Simulated height of each configuration at the kept draws [mm], (chain, draw, m)."""
        start = self.model.n_units
        for block in self.model.blocks:
            if block is self.model.heights:
                return self.run.blobs[..., start : start + block.n_extras()]
            start += block.n_extras()
        raise AttributeError("this fit has no jump heights")


@dataclass
class FitResult:
    """A finished fit.

    Attributes
    ----------
    datatree : xarray.DataTree
        Posterior, log-likelihood, posterior predictive, observed data, sample stats and
        provenance attributes.
    parts : list of FitPart
        The ensemble runs (one per volume fraction, or one).
    settings : FitSettings
        The settings of the fit (``config``: a deprecated alias).
    seed : int
    warnings : list of str
        Convergence problems, in words.
    """

    datatree: xr.DataTree
    parts: list[FitPart]
    settings: FitSettings
    seed: int
    warnings: list[str]

    @property
    def config(self) -> FitSettings:
        """Deprecated alias of :attr:`settings`."""
        warn_alias(type(self).__name__, "config", "settings")
        return self.settings

    @property
    def converged(self) -> bool:
        """Whether every run met the stopping rule (``granbayes._sampler``)."""
        return all(p.run.converged for p in self.parts)

    def diagnostics(self) -> pd.DataFrame:
        """Per run: autocorrelation times, R-hat, ESS, chain length, convergence."""
        return stats.run_diagnostics(self.datatree)

    def log_predictive_density(self, data: pd.DataFrame | Measurements) -> np.ndarray:
        """Log predictive density of units the fit has not seen [nats], one per unit.

        ``log mean_s p(y_i | theta_s)`` over every posterior draw of the run that fitted
        the unit's volume fraction (the observation model of
        :meth:`granbayes._likelihood.JumpModel.log_predictive_density`): held-out units of
        a cross-validation, or a new experiment at the fitted volume fractions.

        Parameters
        ----------
        data : pandas.DataFrame or Measurements
            Jumps (``load_jumps`` columns; one unit per row), or measurements of the kinds
            the fit has.

        Returns
        -------
        ndarray, shape (n_units,)
            NaN for a unit at a volume fraction no run of the fit covers.
        """
        data = _as_measurements(data)
        out = np.full(data.n_units, np.nan)
        phi = data.units["phi"].to_numpy(dtype=float)
        for part in self.parts:
            units = np.flatnonzero(np.isin(phi, np.asarray(part.model.phis, dtype=float)))
            if len(units):
                flat = part.run.samples.reshape(-1, part.run.samples.shape[-1])
                held_out = _held_out(part.model, data.select(units))
                out[units] = part.model.log_predictive_density(flat, held_out)
        return out

    def save(self, path: str | Path) -> Path:
        """Write the DataTree as netCDF (``posterior.nc``; read back with ``load_fit``).

        Parameters
        ----------
        path : str or Path
            The file to write.

        Returns
        -------
        Path
        """
        gdt.write_datatree(self.datatree, Path(path))
        return Path(path)


# ----------------------------------------------------------------------------------------
def find_starts(
    model: JumpModel,
    rng: np.random.Generator,
    n_ensembles: int,
    n_walkers: int,
    warm: np.ndarray | None = None,
) -> list[np.ndarray]:
    """Dispersed, optimised starting positions: one array per independent ensemble.

    A batch of prior draws is split into ``n_ensembles`` disjoint groups; each ensemble
    starts from the best draw of its own group, so the ensembles begin in different parts
    of the prior. Each start is then improved by a batched local search (every round
    evaluates 24 Gaussian proposals per ensemble in one simulator call and shrinks the
    proposal scale when nothing improves), and the walkers are placed in a ball of the
    final proposal scale around it. With ``warm`` (draws of a nested parent's posterior,
    the new coordinates at their "off" values), ensemble 0 starts from those draws.

    Parameters
    ----------
    model : JumpModel
        The log-posterior.
    rng : numpy.random.Generator
        Source of randomness.
    n_ensembles, n_walkers : int
        Number of ensembles and walkers per ensemble.
    warm : ndarray, shape (n, ndim), optional
        Warm-start positions for ensemble 0.

    Returns
    -------
    list of ndarray, each of shape (n_walkers, ndim)
    """
    return _find_starts_many([model], [rng], n_ensembles, [n_walkers], [warm])[0]


def _find_starts_many(
    models: Sequence[JumpModel],
    rngs: Sequence[np.random.Generator],
    n_ensembles: int,
    n_walkers: Sequence[int],
    warms: Sequence[np.ndarray | None],
    start: str = "search",
    mode_gap: float = 5.0,
    notes: dict[int, list[str]] | None = None,
    climbs: int = 1,
    climb_ends: dict[tuple[int, int], list[float]] | None = None,
    extra: Sequence[np.ndarray | None] | None = None,
) -> list[list[np.ndarray]]:
    """:func:`find_starts` for several models at once, their simulations in one batch.

    Each model draws from its own generator in the order :func:`find_starts` does, so its
    starts are those of :func:`find_starts` alone. ``start`` is
    :attr:`SamplerSettings.start`: with ``laplace`` or ``auto`` each ensemble's point is
    polished and its walkers drawn from the Laplace approximation there
    (:func:`_laplace_starts`; ``mode_gap`` as the sampler's, and what it did is appended to
    ``notes[model index]``), climbing from ``climbs`` points per ensemble where the model
    has measurements beyond heights (its searched point and the next best of its own prior
    draws) and from its searched point alone otherwise (:func:`_climbs`); ``extra[i]``, a
    point of model ``i`` (sampling coordinates), is one more climb of its ensemble 0.
    """
    k = len(models)
    ndims = [m.ndim for m in models]
    bounds = [m.bounds_u.T for m in models]
    n_prior = [max(32, 16 * d) * n_ensembles for d in ndims]
    draws = [m.sample_prior(rng, n) for m, rng, n in zip(models, rngs, n_prior, strict=True)]
    lps = [ev.log_prob for ev in evaluate_models(models, draws)]
    with_warm = [i for i in range(k) if warms[i] is not None]
    warm_lps = dict(
        zip(
            with_warm,
            (
                ev.log_prob
                for ev in evaluate_models(
                    [models[i] for i in with_warm], [warms[i] for i in with_warm]
                )
            ),
            strict=True,
        )
    )
    x, f, scale = [], [], []
    others: dict[tuple[int, int], np.ndarray] = {}  # further climbs' starts (Laplace)
    for i in range(k):
        best_x, best_lp = [], []
        for e in range(n_ensembles):
            group = np.arange(e, n_prior[i], n_ensembles)
            order = group[np.argsort(-lps[i][group], kind="stable")]
            j = order[0]
            best_x.append(draws[i][j].copy())
            best_lp.append(lps[i][j])
            others[i, e] = draws[i][order[1 : _climbs(models[i], climbs)]].copy()
        if i in warm_lps:
            w = warm_lps[i]
            best_x[0], best_lp[0] = warms[i][int(np.argmax(w))].copy(), float(np.max(w))
        x.append(np.array(best_x))
        f.append(np.array(best_lp))
        lo, hi = bounds[i]
        scale.append(np.tile(0.05 * (hi - lo), (n_ensembles, 1)))
    n_prop = 24
    for _ in range(12):
        props = []
        for i in range(k):
            lo, hi = bounds[i]
            step = rngs[i].standard_normal((n_ensembles, n_prop, ndims[i]))
            props.append(np.clip(x[i][:, None, :] + scale[i][:, None, :] * step, lo, hi))
        evs = evaluate_models(models, [p.reshape(-1, d) for p, d in zip(props, ndims, strict=True)])
        for i, ev in enumerate(evs):
            f_prop = ev.log_prob.reshape(n_ensembles, n_prop)
            j = np.argmax(f_prop, axis=1)
            better = f_prop[np.arange(n_ensembles), j] > f[i]
            x[i][better] = props[i][better, j[better]]
            f[i][better] = f_prop[better, j[better]]
            scale[i][~better] *= 0.5
    laplace = list(range(k)) if start != "search" else []  # auto and laplace climb
    drawn = _laplace_starts(
        models, rngs, x, n_walkers, laplace, warms, mode_gap, notes, others, climb_ends, extra
    )
    out = []
    for i, model in enumerate(models):
        lo, hi = bounds[i]
        width = hi - lo
        rng, nw, ndim = rngs[i], n_walkers[i], ndims[i]
        starts = []
        for e in range(n_ensembles):
            if (i, e) in drawn:
                starts.append(drawn[i, e])
                continue
            if e == 0 and warms[i] is not None:
                warm = warms[i]
                pick = rng.choice(len(warm), size=nw, replace=len(warm) < nw)
                ball = warm[pick] + 1e-3 * width * np.abs(rng.standard_normal((nw, ndim)))
                starts.append(np.clip(ball, lo, hi))
                continue
            sd = np.maximum(scale[i][e], 1e-3 * width)
            pos = np.empty((0, ndim))
            while len(pos) < nw:
                ball = x[i][e] + sd * rng.standard_normal((2 * nw, ndim))
                pos = np.concatenate([pos, ball[np.isfinite(model.log_prior(ball))]])
            starts.append(pos[:nw])
        out.append(starts)
    return out


#: ``-log p`` the climb of a Laplace start gives a point outside the support or whose
#: simulation failed: far above any log-posterior here, and small enough that Powell's
#: line-search arithmetic cannot overflow (1e300 did, in fits with intrusion tests).
_INFEASIBLE = 1e10

#: Evaluations per dimension that Powell's polish of a Laplace start may spend: 100, as
#: L-BFGS-B finishes the climb (3 climbs per ensemble; Powell spent up to 3,000 evaluations
#: on a ridge of a mode 575 nats below the best; capped, the same climbs ended in the same
#: modes). Less is not cheaper: on the extended reference set with every kind (36 climbs
#: side by side), a cap of 30 left 4 climbs 3-28 nats below their volume fraction's mode
#: (none with 100) and the climbs took 22.6 s instead of 16.3 s (L-BFGS-B then climbs
#: longer); L-BFGS-B alone left 17 below it, by up to 588 nats (all three climbs of one
#: ensemble 40 nats or more), in 29.4 s.
_POLISH_EVALS = 100

#: Powell's ``xtol`` [sampling coordinates] and ``ftol`` [relative] in that polish: loose,
#: as L-BFGS-B finishes the climb.
_POWELL_TOL = (1e-3, 1e-7)

#: The local optimisers that polish a Laplace start, in turn (:func:`_laplace_starts`).
_POLISH: tuple[str, ...] = ("powell", "lbfgs")

#: BLAS threads while the Laplace starts climb: one. Each L-BFGS-B iteration calls LAPACK on
#: matrices of a few rows (SciPy's ``setulb``), where OpenBLAS's own threads only cost: on a
#: 2-core machine running other work, 2-9 ms per iteration with its 2 threads against 50 us
#: with one, and the climbs of the extended reference set's joint fit spent 22 s between
#: their simulator calls instead of 2 s (the whole fit 95 s against 60 s; every posterior
#: and start the same to the last bit). On an idle machine the second thread only burns
#: CPU (the joint fit 0.92x CPU, 1.02x wall). Dask's workers already run with one
#: (``OPENBLAS_NUM_THREADS=1`` from its nanny), so a study's fits and the command line's
#: now do the same arithmetic the same way.
_CLIMB_BLAS_THREADS = 1

#: Largest standard deviation of a Laplace start, as a fraction of the prior's width in
#: the sampling coordinate (a flat or non-concave direction starts this wide).
_LAPLACE_MAX_SD = 0.05


def _climbs(model: JumpModel, climbs: int) -> int:
    """Climbs per ensemble of a Laplace start: ``climbs`` beyond heights, else one.

    The posteriors of tracked jumps can have separated modes that one climb per ensemble
    misses by luck (:func:`_laplace_starts`); none was seen in fits of jump heights alone,
    whose one climb starts at the point the search start would have started the ensemble
    from, and where two more climbs cost more than the steps they save (reference data,
    depth + drag + compaction, seed 1: 17.2 s with three climbs, 12.2 s with one, 22.3 s
    from the searched point's ball).
    """
    return climbs if any(block.kind != "heights" for block in model.blocks) else 1


def _batched_log_probs(
    models: Sequence[JumpModel], requests: Sequence[tuple[int, np.ndarray]]
) -> list[np.ndarray]:
    """Log-posteriors of ``[(model index, points (n, d))]``, one simulator call for all."""
    groups = _grouped(requests)
    order = list(groups)
    evs = evaluate_models([models[i] for i in order], [np.array(groups[i]) for i in order])
    return _split({i: ev.log_prob for i, ev in zip(order, evs, strict=True)}, requests)


def _batched(
    value: Callable[[int, np.ndarray], np.ndarray], requests: Sequence[tuple[int, np.ndarray]]
) -> list[np.ndarray]:
    """``value(i, points)`` of ``[(model index, points (n, d))]``, one call per model."""
    groups = _grouped(requests)
    return _split({i: value(i, np.array(pts)) for i, pts in groups.items()}, requests)


def _grouped(requests: Sequence[tuple[int, np.ndarray]]) -> dict[int, list[np.ndarray]]:
    """The points of ``[(model index, points (n, d))]`` concatenated per model, in order."""
    groups: dict[int, list[np.ndarray]] = {}
    for i, points in requests:
        groups.setdefault(i, []).extend(points)
    return groups


def _split(
    values: Mapping[int, np.ndarray], requests: Sequence[tuple[int, np.ndarray]]
) -> list[np.ndarray]:
    """Each request's slice of its model's values (requests concatenated in order)."""
    out, seen = [], dict.fromkeys(values, 0)
    for i, points in requests:
        out.append(values[i][seen[i] : seen[i] + len(points)])
        seen[i] += len(points)
    return out


def _hessian_points(x: np.ndarray, h: np.ndarray) -> np.ndarray:
    """``x``, ``x +/- h_i e_i`` and ``x +/- h_i e_i +/- h_j e_j`` (i < j): central differences."""
    d = len(x)
    pts = [x]
    for i in range(d):
        for sign in (1.0, -1.0):
            p = x.copy()
            p[i] += sign * h[i]
            pts.append(p)
    for i in range(d):
        for j in range(i + 1, d):
            for si, sj in ((1.0, 1.0), (1.0, -1.0), (-1.0, 1.0), (-1.0, -1.0)):
                p = x.copy()
                p[i] += si * h[i]
                p[j] += sj * h[j]
                pts.append(p)
    return np.array(pts)


def _hessian(values: np.ndarray, h: np.ndarray) -> np.ndarray:
    """The Hessian from the values at :func:`_hessian_points` (NaN where not finite)."""
    d = len(h)
    f0, k = values[0], 1 + 2 * d
    H = np.empty((d, d))
    for i in range(d):
        H[i, i] = (values[1 + 2 * i] - 2.0 * f0 + values[2 + 2 * i]) / h[i] ** 2
    for i in range(d):
        for j in range(i + 1, d):
            fpp, fpm, fmp, fmm = values[k : k + 4]
            k += 4
            H[i, j] = H[j, i] = (fpp - fpm - fmp + fmm) / (4.0 * h[i] * h[j])
    H[~np.isfinite(H)] = np.nan
    return H


def _laplace_cov(H: np.ndarray, width: np.ndarray) -> np.ndarray:
    """Covariance of the Laplace approximation, every sd at most ``_LAPLACE_MAX_SD`` width.

    In coordinates scaled by the prior's width, the precision ``-H`` is made symmetric
    positive definite by raising its eigenvalues to ``1 / _LAPLACE_MAX_SD^2`` (a direction
    that is flat, not concave, or unmeasurable because a difference left the support, starts
    that wide instead of nowhere or everywhere).
    """
    d = len(width)
    P = -np.nan_to_num(H, nan=0.0) * np.outer(width, width)
    bad = np.isnan(np.diag(H))
    P[bad, :] = 0.0
    P[:, bad] = 0.0
    lam, V = np.linalg.eigh(0.5 * (P + P.T))
    lam = np.maximum(lam, 1.0 / _LAPLACE_MAX_SD**2)
    cov_scaled = (V / lam) @ V.T
    return cov_scaled * np.outer(width, width) + 1e-300 * np.eye(d)


#: Rounds of the batched evolution strategy before a Laplace start's polish.
_EVOLVE_ROUNDS = 40


def _evolve(
    models: Sequence[JumpModel],
    rngs: Sequence[np.random.Generator],
    bounds: Mapping[int, np.ndarray],
    points: dict[tuple[int, ...], np.ndarray],
    point_rngs: Mapping[tuple[int, ...], np.random.Generator] | None = None,
) -> None:
    """Move every ``points[(i, ...)]`` uphill by a (1+24) evolution strategy, in place.

    ``i`` is the model's index; a point's steps are drawn from ``point_rngs[key]`` if
    given, else from ``rngs[i]``. All points' proposals are one simulator call per round.
    The step grows by 1.5 after a success (to at most a quarter of the prior's width) and
    shrinks by 0.6 after a failure (the search of :func:`find_starts` only shrinks, and
    stalls where a narrow posterior needs long moves along a ridge: 68-530 nats below the
    mode on a tracked jump, where a local optimiser from there is lost).
    """
    pairs = list(points)
    n_prop = 24
    scale = {p: 0.05 * (bounds[p[0]][1] - bounds[p[0]][0]) for p in pairs}
    values = _batched_log_probs(models, [(p[0], points[p][None, :]) for p in pairs])
    value = {p: v[0] for p, v in zip(pairs, values, strict=True)}
    for _ in range(_EVOLVE_ROUNDS):
        props = {}
        for p in pairs:
            lo, hi = bounds[p[0]]
            rng = point_rngs[p] if point_rngs and p in point_rngs else rngs[p[0]]
            step = rng.standard_normal((n_prop, len(lo)))
            props[p] = np.clip(points[p] + scale[p] * step, lo, hi)
        values = _batched_log_probs(models, [(p[0], props[p]) for p in pairs])
        for p, f in zip(pairs, values, strict=True):
            k = int(np.argmax(f))
            better = f[k] > value[p]
            if better:
                points[p], value[p] = props[p][k], f[k]
            scale[p] = _adapted_step(scale[p], better, bounds[p[0]][1] - bounds[p[0]][0])


def _adapted_step(scale: np.ndarray, better, width: np.ndarray) -> np.ndarray:
    """A (1+lambda) evolution strategy's step after a round (:func:`_evolve`, screening).

    Grown by 1.5 where the round improved the point (to at most a quarter of the prior's
    ``width``), shrunk by 0.6 where it did not; ``better`` is one flag per point (a row of
    ``scale``) or a single one.
    """
    better = np.asarray(better)
    if better.ndim:
        better = better[:, None]
    return np.where(better, np.minimum(scale * 1.5, 0.25 * width), scale * 0.6)


def _value_and_gradient(ask, lo: np.ndarray, hi: np.ndarray):
    """``-log p`` and its central-difference gradient, the ``2 d + 1`` points in one request.

    ``ask(points)`` returns the log-posterior of ``points`` ``(n, d)``. Steps of 1e-6 of
    the prior's width, one-sided at a bound; a component whose difference leaves the
    support is 0.
    """
    h = 1e-6 * (hi - lo)
    d = len(lo)

    def fg(u: np.ndarray) -> tuple[float, np.ndarray]:
        u = np.clip(u, lo, hi)
        up, down = np.minimum(u + h, hi), np.maximum(u - h, lo)
        pts = np.repeat(u[None, :], 2 * d + 1, axis=0)
        pts[1 + 2 * np.arange(d), np.arange(d)] = up
        pts[2 + 2 * np.arange(d), np.arange(d)] = down
        lp = ask(pts)
        if not np.isfinite(lp[0]):
            return _INFEASIBLE, np.zeros(d)
        a, b = lp[1::2], lp[2::2]
        ok = np.isfinite(a) & np.isfinite(b) & (up > down)
        grad = np.where(ok, (a - b) / np.where(ok, up - down, 1.0), 0.0)
        return -float(lp[0]), -grad

    return fg


def _polish(ask, u: np.ndarray, lo: np.ndarray, hi: np.ndarray) -> tuple[float, np.ndarray]:
    """``(log p, point)`` at the end of ``_POLISH``'s local optimisers from ``u``.

    ``ask(points)`` returns the log-posterior of ``points`` ``(n, d)`` (one climb of
    :func:`granbayes._search.in_thread`).
    """

    def objective(u: np.ndarray) -> float:
        lp = ask(np.clip(u, lo, hi)[None, :])[0]
        return -lp if np.isfinite(lp) else _INFEASIBLE

    value = objective(u)
    bounds = list(zip(lo, hi, strict=True))
    for method in _POLISH:
        if method == "powell":
            res = optimize.minimize(
                objective,
                u,
                method="Powell",
                bounds=bounds,
                options={
                    "xtol": _POWELL_TOL[0],
                    "ftol": _POWELL_TOL[1],
                    "maxfev": _POLISH_EVALS * len(lo),
                },
            )
        else:  # a batched central-difference gradient: one request an iteration
            res = optimize.minimize(
                _value_and_gradient(ask, lo, hi),
                u,
                jac=True,
                method="L-BFGS-B",
                bounds=bounds,
                options={"maxiter": 200},
            )
        if res.fun < value:
            u, value = np.clip(res.x, lo, hi), float(res.fun)
    return -value, u


def _separation(model: JumpModel, mode_gap: float) -> float:
    """Nats below a mode beyond which a point is in a worse-supported mode [nats].

    The sampler's ``mode_gap``, or three standard deviations of a ``d``-dimensional
    normal's log-density (``sqrt(d / 2)``), whichever is larger.
    """
    return max(mode_gap, 3.0 * np.sqrt(model.ndim / 2.0))


def _closed_form_anchors(
    models: Sequence[JumpModel],
    bounds: Mapping[int, np.ndarray],
    points: Mapping[tuple[int, int, int], np.ndarray],
) -> dict[tuple[int, int, int], np.ndarray]:
    """One more start per ensemble of a model with intrusion curves: a global phase.

    The intrusion curves' posterior (:meth:`JumpModel.closed_form_log_prob`: the law,
    the calibrated robot and the force noise; no simulation) is climbed (``_POLISH``)
    from the coordinates it depends on of every climb's start, side by side; the best
    end replaces those coordinates of each ensemble's searched point
    (``points[i, e, 0]``). A constant-speed intrusion pins the law's coefficients (the
    force is linear in them for depth, drag and added mass), so this start lies in the
    basin the curves select, where the jump-by-jump climbs can all end in a mode that
    fits the tracked jumps' noise instead (``benchmarks/start_modes.py``).

    Returns
    -------
    dict
        ``(model index, ensemble, climb) -> start``, ``climb`` one past the ensemble's
        last; empty for models without intrusion curves.
    """
    jobs = [(i, u) for (i, _, _), u in points.items() if models[i].closed_form_columns.any()]
    if not jobs:
        return {}

    def climb(ask, i: int, u: np.ndarray):
        mask = models[i].closed_form_columns
        lo, hi = bounds[i]

        def expand(v: np.ndarray) -> np.ndarray:
            full = np.repeat(u[None, :], len(v), axis=0)
            full[:, mask] = v
            return full

        return _polish(lambda v: ask(expand(v)), u[mask], lo[mask], hi[mask])

    ends = drive(
        [in_thread(partial(climb, i=i, u=u)) for i, u in jobs],
        lambda requests, which: _batched(
            lambda i, u: models[i].closed_form_log_prob(u),
            [(jobs[w][0], full) for w, full in zip(which, requests, strict=True)],
        ),
    )
    best: dict[int, tuple[float, np.ndarray]] = {}
    for (i, _), (value, v) in zip(jobs, ends, strict=True):
        if i not in best or value > best[i][0]:
            best[i] = (value, v)
    out = {}
    for (i, e, c), u in points.items():
        if c == 0 and i in best:
            anchor = u.copy()
            anchor[models[i].closed_form_columns] = best[i][1]
            out[i, e, sum(1 for key in points if key[:2] == (i, e))] = anchor
    return out


@threadpool_limits.wrap(limits=_CLIMB_BLAS_THREADS, user_api="blas")
def _laplace_starts(
    models: Sequence[JumpModel],
    rngs: Sequence[np.random.Generator],
    x: Sequence[np.ndarray],
    n_walkers: Sequence[int],
    which: Sequence[int],
    warms: Sequence[np.ndarray | None],
    mode_gap: float = 5.0,
    notes: dict[int, list[str]] | None = None,
    others: Mapping[tuple[int, int], np.ndarray] | None = None,
    climb_ends: dict[tuple[int, int], list[float]] | None = None,
    extra: Sequence[np.ndarray | None] | None = None,
) -> dict[tuple[int, int], np.ndarray]:
    """Walkers from the Laplace approximation at each ensemble's polished point.

    1. **Climb.** Each ensemble's best point ``x[i][e]`` (its own prior draws, then the
       random local search of :func:`find_starts`), and each of ``others[i, e]`` (further
       points of its own, :attr:`SamplerSettings.start_climbs` in all), is moved uphill
       by a batched evolution strategy (:func:`_evolve`), then polished (``_POLISH``) by
       SciPy's Powell method and L-BFGS-B with a central-difference gradient
       (:func:`_value_and_gradient`, its ``2 d + 1`` points one request) in
       :func:`_polish`. Measured on tracked jumps: Powell reached the best mode's basin
       from most points in 600-2,000 evaluations (now capped at ``_POLISH_EVALS`` per
       dimension, L-BFGS-B finishing), where the Nelder-Mead of :mod:`granbayes._search`
       stopped two of four ensembles in modes 150-300 nats worse; L-BFGS-B alone stopped
       after one line search from most points, but after Powell it finished ridges Powell
       had left 140-2,900 nats below the mode. Every climb of every ensemble and model
       runs side by side (:func:`granbayes._search.in_thread`, :func:`~granbayes._search.drive`):
       each round of their requests is one simulator call, and each climb visits the
       points it visits alone. One point per call, the climbs of the added-mass set's fit
       with every kind took 95 s of 110 s; side by side, 31 s of 46 s, the same modes to
       the last digit.
    2. **Curvature.** The Hessian at the mode comes from central differences (steps of
       1e-4 of the prior's width, then half of the standard deviation so found, so that
       the curvature is measured at the posterior's own scale; a mode on a bound of the
       prior is differenced just inside it, and its own coordinate starts at the floor
       of :func:`_laplace_cov`).
    3. **Walkers** are drawn from the normal with the inverse as covariance
       (:func:`_laplace_cov`), kept inside the prior.

    With intrusion curves, each ensemble climbs once more, from its searched point with the
    coordinates the curves inform at the curves' own posterior mode
    (:func:`_closed_form_anchors`: a global phase, cheap as the curves need no
    simulation), where the climbs from searched points and prior draws can all end in one
    mode of the tracked jumps' (``benchmarks/start_modes.py``).

    The ensemble starts from the highest of its climbs' modes. Several climbs because a
    posterior of tracked jumps can have separated modes whose basins the climb reaches
    by luck: on a SBC replicate of heights + tracked jumps (``benchmarks/sbc_joint.py``'s
    design, replicate 17, intrusions left out), 11 of 16 climbs from prior draws ended in
    a mode of strong drag and little added mass 184 nats below the truth's (5 of 16 in
    the truth's); with one climb per ensemble all four ensembles ended there, and the run
    passed every convergence check with c_d 112 posterior sd from the truth. With ``c``
    climbs per ensemble and a basin caught by a fraction ``p`` of them, all ``4 c`` climbs
    miss it with probability ``(1 - p)^(4 c)``: 0.24 for ``c = 1`` at ``p = 0.3``, 0.014
    for ``c = 3``. Climbs of one ensemble that end more than the gap below apart are
    reported in ``notes`` (a posterior with separated modes).

    The ensembles stay independent (each climbs from its own points: different modes stay
    different, for the sampler's mode checks), except that an ensemble whose climb ends
    more than ``max(mode_gap, 3 sqrt(d / 2))`` nats below another's mode (the sampler's
    rule for a worse-supported mode, with the spread of a d-dimensional normal's
    log-density) starts from that mode's approximation, as the sampler's first check
    would restart it, and ``notes`` says so. An ensemble warm-started from a parent's
    posterior (``x[i][0]`` is then the parent's best draw, the parameters it lacks "off")
    climbs from there, so it starts no lower than its parent and at the extension's own
    scale: in ``diagnose`` the warm ensemble, started as the parent's draws with no spread
    in the new parameter, was the one the runs waited for (the reference data, seed 0:
    the fits 74 s before it climbed, 52 s after; the same verdict).

    ``extra[i]``, if given, is one more climb of model ``i``'s ensemble 0, its evolution
    steps from a generator of its own as the global phase's: in ``diagnose``, a candidate's
    best point of its screening search (:func:`screen_many`), which searched from levels
    across the new parameters' ranges where the warm start sits at their "off" values.
    Measured on a case of the verdict study (unloading, r_unload = 2.23 against "off" at
    20, phi = 0.597, where ``k`` and ``r_unload`` trade along a curved ridge with a second
    mode at r_unload 4.95 and a scatter of 9 mm against 2.4): 6 of 10 fits warm-started
    from the depth law ended all four ensembles in that mode, 27 nats below the truth's,
    and passed every convergence check (``test_a_candidate_fit_climbs_from_its_screen``).

    ``climb_ends``, if given, receives every climb's final log-posterior, in order, per
    ``(model index, ensemble)`` (``benchmarks/start_modes.py`` measures with it how often
    the climbs miss the truth's mode).

    Returns
    -------
    dict
        ``(model index, ensemble) -> walkers (n_walkers, ndim)``, for the models ``which``.
    """
    pairs = [(i, e) for i in which for e in range(len(x[i]))]
    if not pairs:
        return {}
    bounds = {i: models[i].bounds_u.T for i in which}
    points = {}
    for i, e in pairs:
        starts = [x[i][e], *(others.get((i, e), ()) if others is not None else ())]
        for c, point in enumerate(starts):
            points[i, e, c] = np.clip(point, *bounds[i])
    # the global phase of models with intrusion curves: one more climb per ensemble, its
    # evolution steps from a generator of its own (the other climbs' draws are unchanged)
    anchors = _closed_form_anchors(models, bounds, points)
    for i in which:
        if extra is not None and extra[i] is not None and (i, 0) in pairs:
            count = sum(1 for key in [*points, *anchors] if key[:2] == (i, 0))
            anchors[i, 0, count] = np.clip(np.asarray(extra[i], dtype=float), *bounds[i])
    own = {i: rngs[i].spawn(1)[0] for i in sorted({key[0] for key in anchors})}
    points.update(anchors)
    _evolve(models, rngs, bounds, points, {key: own[key[0]] for key in anchors})
    keys = list(points)
    ends = drive(
        [
            in_thread(partial(_polish, u=points[key], lo=bounds[key[0]][0], hi=bounds[key[0]][1]))
            for key in keys
        ],
        lambda requests, which: _batched_log_probs(
            models, [(keys[w][0], points) for w, points in zip(which, requests, strict=True)]
        ),
    )
    climbed: dict[tuple[int, int], list[tuple[float, np.ndarray]]] = {}
    for (i, e, _), end in zip(keys, ends, strict=True):
        climbed.setdefault((i, e), []).append(end)
    if climb_ends is not None:
        climb_ends.update({pair: [value for value, _ in ends] for pair, ends in climbed.items()})
    modes = {}
    for (i, e), ends in climbed.items():
        top = max(value for value, _ in ends)
        modes[i, e] = next(u for value, u in ends if value == top)
        gap = _separation(models[i], mode_gap)
        lower = sorted(value for value, _ in ends if value < top - gap)
        if lower and notes is not None:
            notes.setdefault(i, []).append(
                START_NOTE + f"ensemble {e}: {len(lower)} of {len(ends)} climbs ended more than "
                f"{gap:.1f} nats below its best mode (log-probability of the best {top:.1f}; "
                + "of the lower "
                + ", ".join(f"{value:.1f}" for value in lower)
                + "): the posterior has separated modes; the best is kept"
            )
    steps = {pair: 1e-4 * (bounds[pair[0]][1] - bounds[pair[0]][0]) for pair in pairs}
    hessians = {}
    centre_values: dict[tuple[int, int], np.ndarray] = {}
    for _ in range(2):  # the second pass at half the standard deviation the first found
        requests = []
        for pair in pairs:
            lo, hi = bounds[pair[0]]
            # a mode on a bound of the prior: the differences are taken just inside it
            # (the other coordinates' curvature there)
            centre = np.clip(modes[pair], lo + steps[pair], hi - steps[pair])
            requests.append((pair[0], _hessian_points(centre, steps[pair])))
        for pair, values in zip(pairs, _batched_log_probs(models, requests), strict=True):
            lo, hi = bounds[pair[0]]
            centre_values[pair] = values
            with np.errstate(invalid="ignore"):  # a difference that left the support
                H = _hessian(values, steps[pair])
            # a coordinate whose mode is on a bound of its prior has no curvature to invert
            # (the posterior piles on the bound): it starts at the floor's width
            edge = (modes[pair] - lo < steps[pair]) | (hi - modes[pair] < steps[pair])
            H[edge, :] = np.nan
            H[:, edge] = np.nan
            hessians[pair] = H
            curv = -np.diag(H)
            sd = np.where(curv > 0, 1.0 / np.sqrt(np.where(curv > 0, curv, 1.0)), np.inf)
            steps[pair] = np.clip(0.5 * sd, 1e-7 * (hi - lo), 1e-2 * (hi - lo))
    # an ensemble whose polish ended far below another's mode is in a worse-supported
    # region by the sampler's own rule (its first check would restart it from the best
    # ensemble): it starts from the best mode's approximation now, and the run says so
    heights = {pair: float(values[0]) for pair, values in centre_values.items()}
    source = {pair: pair for pair in pairs}
    for i in which:
        mine = [pair for pair in pairs if pair[0] == i]
        if len(mine) < 2:
            continue
        best = max(mine, key=lambda pair: heights[pair])
        gap = _separation(models[i], mode_gap)
        low = [pair for pair in mine if heights[pair] < heights[best] - gap]
        for pair in low:
            source[pair] = best
        if low and notes is not None:
            notes.setdefault(i, []).append(
                START_NOTE
                + "ensemble(s) "
                + ", ".join(f"{e} (log-probability {heights[i, e]:.1f})" for _, e in low)
                + f" polished to points more than {gap:.1f} nats below ensemble {best[1]}'s "
                f"mode ({heights[best]:.1f}); started from that mode's Laplace approximation"
            )
    out = {}
    for i, e in pairs:
        lo, hi = bounds[i]
        cov = _laplace_cov(hessians[source[i, e]], hi - lo)
        chol = np.linalg.cholesky(cov)
        nw, model = n_walkers[i], models[i]
        pos = np.empty((0, model.ndim))
        while len(pos) < nw:
            ball = modes[source[i, e]] + rngs[i].standard_normal((2 * nw, model.ndim)) @ chol.T
            pos = np.concatenate([pos, ball[np.isfinite(model.log_prior(ball))]])
        out[i, e] = pos[:nw]
    return out


def _seeds(seed: int, n: int) -> list[int]:
    return [int(s.generate_state(1)[0]) for s in np.random.SeedSequence(seed).spawn(n)]


def _sampling_fn(models: Sequence[JumpModel]):
    """The batched log-probability of runs side by side (:func:`run_side_by_side`).

    Each walker's blob is its pointwise log-likelihood followed by the simulated height of
    every configuration [mm], so the kept draws carry their simulated heights and the
    posterior predictive needs no second simulation.
    """

    def evaluate(xs: Mapping[int, np.ndarray]) -> dict[int, tuple[np.ndarray, np.ndarray]]:
        order = list(xs)
        evs = evaluate_models([models[i] for i in order], [xs[i] for i in order])
        return {
            i: (ev.log_prob, np.concatenate([ev.log_lik, ev.extras], axis=1))
            for i, ev in zip(order, evs, strict=True)
        }

    return evaluate


def _run_parts(
    specs: Sequence[tuple[str, JumpModel, np.ndarray]],
    settings: FitSettings | Sequence[FitSettings],
    seeds: Sequence[int],
    checkpoint: Path | None,
    resume: bool,
    warms: Sequence[np.ndarray | None] | None = None,
    progress: Callable[[str, ProgressInfo], None] | None = None,
    extra: Sequence[np.ndarray | None] | None = None,
) -> list[FitPart]:
    """Sample runs side by side (one simulator call per round for all).

    ``config`` is the settings of every run, or one per run (the fingerprint of a run's
    checkpoint); the sampler settings must be the same for all runs. ``extra``: per run,
    a point its ensemble 0 climbs from as well (:func:`_laplace_starts`).
    """
    configs = [settings] * len(specs) if isinstance(settings, FitSettings) else list(settings)
    s = configs[0].sampler
    if any(c.sampler != s for c in configs):
        raise ValueError("runs sampled side by side share their sampler settings")
    warms = list(warms) if warms is not None else [None] * len(specs)
    extra = list(extra) if extra is not None else [None] * len(specs)
    models = [model for _, model, _ in specs]
    checkpoints = [
        None if checkpoint is None else Path(checkpoint) / f"{label}.h5" for label, _, _ in specs
    ]
    fresh = [i for i, c in enumerate(checkpoints) if not (resume and c is not None and c.exists())]
    start_notes: dict[int, list[str]] = {}
    starts = _find_starts_many(
        [models[i] for i in fresh],
        [np.random.default_rng(seeds[i]) for i in fresh],
        s.n_ensembles,
        [s.walkers_for(models[i].ndim) for i in fresh],
        [warms[i] for i in fresh],
        s.start,
        s.mode_gap,
        start_notes,
        s.start_climbs,
        extra=[extra[i] for i in fresh],
    )
    notes_of = {i: start_notes.get(j, []) for j, i in enumerate(fresh)}
    initial = {i: st for i, st in zip(fresh, starts, strict=True)}
    runs = []
    for i, (label, model, _) in enumerate(specs):
        n_walkers = s.walkers_for(model.ndim)
        if checkpoints[i] is not None:
            checkpoints[i].parent.mkdir(parents=True, exist_ok=True)
        runs.append(
            RunSpec(
                initial.get(i, [np.zeros((n_walkers, model.ndim))] * s.n_ensembles),
                model.n_units + model.n_extras,
                seed=seeds[i],
                checkpoint=checkpoints[i],
                resume=resume,
                fingerprint=_fingerprint(model, configs[i], seeds[i]),
                progress=None if progress is None else _labelled(progress, label),
                notes=tuple(notes_of.get(i, ())),
            )
        )
    sampled = run_side_by_side(_sampling_fn(models), runs, s)
    return [
        FitPart(label, model, run, jumps)
        for (label, model, jumps), run in zip(specs, sampled, strict=True)
    ]


def _labelled(progress: Callable[[str, ProgressInfo], None], label: str):
    return lambda info: progress(label, info)


def _fingerprint(model: JumpModel, settings: FitSettings, seed: int) -> str:
    """What a checkpoint must match to be resumed: data, priors, model and settings."""
    h = hashlib.sha256()
    for block in model.blocks:
        h.update(f"[{block.kind}]".encode())
        h.update(data_hash(model.experiment, block.table).encode())
    h.update(repr(sorted((k, dataclasses.astuple(v)) for k, v in model.priors.items())).encode())
    h.update(repr((model.coordinate_names, settings.to_dict(), seed)).encode())
    h.update(b"blobs: log-likelihood per unit, then each block's kept values")
    return h.hexdigest()


def _as_measurements(data: pd.DataFrame | Measurements) -> Measurements:
    """Measurements as they are; a jumps table as jump heights (one unit per row)."""
    if isinstance(data, Measurements):
        return data
    return Measurements.from_jumps(data.reset_index(drop=True))


def _held_out(model: JumpModel, data: Measurements) -> list:
    """Blocks of ``data`` under ``model``'s coordinates, one per kind (unit order)."""
    out = []
    for kind in data.kinds:
        own = next((b for b in model.blocks if b.kind == kind), None)
        if own is None:
            raise ValueError(f"the fit has no {kind!r} measurements to score these with")
        out.append(own.with_data(data.tables[kind]))
    return out


def _observation_settings(
    settings: FitSettings, phi_mode: PhiMode, experiment: Experiment
) -> ObservationSettings:
    return ObservationSettings(
        noise=settings.noise,
        nu=settings.nu,
        sigma_mode=settings.sigma_mode if phi_mode == "quadratic" else "per_phi",
        bed=_bed(experiment, settings, phi_mode),
    )


def _bed(experiment: Experiment, settings: FitSettings, phi_mode: PhiMode) -> BedPhi:
    """A bed's latent volume fraction as the fit treats it (``FitSettings.bed_phi``)."""
    if settings.bed_phi == "integrate" and phi_mode == "quadratic" and experiment.phi_sd > 0:
        return BedPhi(experiment.phi_sd, settings.phi_nodes)
    return BedPhi()


def _make_model(
    data: Measurements | Observations,
    experiment: Experiment,
    settings: FitSettings,
    priors,
    phi_mode: PhiMode,
) -> JumpModel:
    observation = _observation_settings(settings, phi_mode, experiment)
    if isinstance(data, Observations):
        blocks = [
            HeightBlock(
                data,
                noise=observation.noise,
                nu=observation.nu,
                sigma_mode=observation.sigma_mode,
                bed=observation.bed,
            )
        ]
    else:
        blocks = blocks_for(data, observation)
    return JumpModel(
        blocks,
        experiment,
        settings.terms,
        priors=priors,
        phi_mode=phi_mode,
        fixed=settings.fixed,
        settings=settings.options,
        n_threads=settings.n_threads,
        calibrated=_calibrated(experiment, settings),
    )


def pooled(experiment: Experiment, settings: FitSettings) -> bool:
    """Whether a ``per_phi`` fit samples every volume fraction in one run.

    With ``calibration="pool"`` and a robot parameter with an uncertainty: the robot is
    then one value for every volume fraction (the module docstring says how it is
    sampled). Without an uncertainty there is nothing to pool and the runs stay per volume
    fraction (the same fit as ``"sample"``, bit for bit).
    """
    return (
        settings.phi_mode == "per_phi"
        and settings.calibration == "pool"
        and bool(_calibrated(experiment, settings))
    )


def _calibrated(experiment: Experiment, settings: FitSettings) -> dict[str, Prior]:
    """Priors of the robot parameters the fit samples (their calibration), by name."""
    if settings.calibration == "nominal":
        return {}
    sd = {k: v for k, v in experiment.uncertainty.items() if k in CALIBRATED_KEYS}
    return calibration_priors(experiment.robot_values, sd)


def part_models(
    experiment: Experiment,
    data: pd.DataFrame | Measurements,
    settings: FitSettings,
    priors: Mapping[str, Prior],
) -> list[tuple[str, JumpModel, np.ndarray]]:
    """The sampler runs a fit consists of: label, log-posterior and the units of each.

    ``per_phi``: one run per volume fraction (label ``"phi=<phi>"``, one parameter set
    shared by every command and every kind of measurement); ``quadratic``: one run of all
    measurements (label ``"all"``). The fit and a saved fit read back
    (:func:`granbayes.load_fit`) build their models here.

    Parameters
    ----------
    experiment : Experiment
    data : pandas.DataFrame or Measurements
        Validated jumps (row ``i`` is jump ``i``), or measurements of several kinds.
    settings : FitSettings
    priors : mapping of str to Prior

    Returns
    -------
    list of (str, JumpModel, ndarray of int)
        Label, model and the units (:class:`~granbayes.Measurements` numbering; rows of a
        jumps table) each run fits, in run order.
    """
    data = _as_measurements(data)
    if settings.phi_mode == "quadratic":
        model = _make_model(data, experiment, settings, priors, "quadratic")
        return [("all", model, np.arange(data.n_units))]
    if pooled(experiment, settings) and len(data.phis) > 1:
        model = _make_model(data, experiment, settings, priors, "per_phi_joint")
        return [("all", model, np.arange(data.n_units))]
    return [
        (
            f"phi={phi:g}",
            _make_model(data.at_phi(phi), experiment, settings, priors, "per_phi"),
            data.units_at_phi(phi),
        )
        for phi in data.phis
    ]


@renamed_keyword("config")
@renamed_keyword("backend", "checkpoint")
def fit(
    experiment: Experiment,
    table: pd.DataFrame | Measurements,
    settings: FitSettings | None = None,
    *,
    seed: int = 0,
    priors: Mapping[str, Prior] | None = None,
    checkpoint: str | Path | None = None,
    resume: bool = False,
    data_source: str = "",
    warm_start: xr.DataTree | None = None,
    progress: Callable[[str, ProgressInfo], None] | None = None,
    start_points: Mapping[float, Mapping[str, float]] | None = None,
) -> FitResult:
    """Fit a force law to measured jump heights and every other kind of measurement.

    Parameters
    ----------
    experiment : Experiment
        Robot, command defaults and ``phi_c``.
    table : pandas.DataFrame or Measurements
        Validated jumps (:func:`granbayes.load_jumps`), or measurements of several kinds
        (:func:`granbayes.load_measurements`): every kind enters one joint posterior.
    settings : FitSettings, optional
        Terms, parametrisation, noise, sampler settings.
    seed : int
        Master seed; recorded in the result.
    priors : mapping of str to Prior, optional
        Priors (default: :func:`granbayes.default_priors`).
    checkpoint : str or Path, optional
        Folder of HDF5 checkpoints (one file per run, ``<label>.h5``).
    resume : bool
        Continue the runs stored in ``checkpoint``.
    data_source : str
        Where the data came from (recorded).
    warm_start : xarray.DataTree, optional
        The posterior of a nested law (``per_phi`` mode): one ensemble per volume fraction
        starts from its best draw, parameters it lacks at their "off" values (climbed from
        there with a Laplace start; with ``start="search"``, about its draws), so an
        extension cannot get lost below its parent.
    progress : callable, optional
        ``progress(label, info)`` after every sampler chunk of every run.
    start_points : mapping of float to mapping of str to float, optional
        ``per_phi`` mode, Laplace start: per volume fraction, a point of the run's
        parameters [their units] that its first ensemble climbs from as well (``diagnose``
        gives a candidate the best point of its screening search); a volume fraction
        without one, or a point that lacks a parameter, climbs as usual.

    Returns
    -------
    FitResult
    """
    settings = settings or FitSettings()
    priors = dict(priors if priors is not None else default_priors())
    data = _as_measurements(table)
    checkpoint = Path(checkpoint) if checkpoint is not None else None
    specs = part_models(experiment, data, settings, priors)
    warms = [
        _warm_positions(model, warm_start, float(model.phis[0]))
        if warm_start is not None and model.phi_mode == "per_phi"
        else None
        for _, model, _ in specs
    ]
    extra = [_start_point(model, start_points) for _, model, _ in specs]
    parts = _run_parts(
        specs, settings, _seeds(seed, len(specs)), checkpoint, resume, warms, progress, extra
    )
    return _assemble(parts, experiment, data, settings, priors, seed, data_source)


def _start_point(
    model: JumpModel, points: Mapping[float, Mapping[str, float]] | None
) -> np.ndarray | None:
    """A run's point of ``points`` (by its volume fraction) in its sampling coordinates."""
    if not points or len(model.phis) != 1:
        return None
    phi = float(model.phis[0])
    point = next((p for key, p in points.items() if np.isclose(float(key), phi)), None)
    if point is None or any(c.parameter not in point for c in model.coordinates):
        return None
    u = np.array([float(c.prior.to_u(np.asarray(point[c.parameter]))) for c in model.coordinates])
    return u if np.all(np.isfinite(u)) and np.isfinite(model.log_prior(u[None])[0]) else None


def _warm_positions(
    model: JumpModel, parent: xr.DataTree, phi: float, best: int | None = None
) -> np.ndarray | None:
    """A nested parent's posterior draws at ``phi`` in the model's sampling coordinates.

    Parameters the parent does not have take their "off" value (``fixed`` or the term's
    ``absent``), pushed inside the prior's support; ``None`` if the parent has no draws at
    ``phi`` or lacks a parameter that has no "off" value. With ``best``, only the ``best``
    draws of highest log-likelihood at ``phi`` (best first).
    """
    post = parent["posterior"]
    if "phi" not in post.coords or not np.any(np.isclose(post["phi"].values, phi)):
        return None
    at = post.sel(phi=phi, method="nearest")
    n = at.sizes["chain"] * at.sizes["draw"]
    rows = np.arange(n)
    if best is not None:
        ll_units, unit_phi = stats.unit_log_likelihood(parent)
        ll = ll_units[..., np.isclose(unit_phi, phi)].sum(axis=-1)
        rows = np.argsort(-np.nan_to_num(ll.reshape(-1), nan=-np.inf), kind="stable")[:best]
    columns = []
    for c in model.coordinates:
        pname, coord = c.parameter, c.prior
        if pname in at:
            values = at[pname].values.reshape(-1)[rows]
        else:
            off = model.fixed.get(pname, PARAMETER_ABSENT.get(pname))
            if off is None and pname in model.calibrated:  # the calibration's value
                off = model.calibrated[pname].mu
            if off is None:
                return None
            values = np.full(len(rows), float(off))
        lo, hi = coord.bounds_u
        with np.errstate(divide="ignore"):
            u = coord.to_u(values)
        # just inside the support: an "off" value may sit on the prior's bound
        inner = lo + 1e-6 * (hi - lo)
        columns.append(np.clip(np.nan_to_num(u, nan=inner, neginf=inner, posinf=hi), inner, hi))
    out = np.column_stack(columns)
    return out[np.isfinite(model.log_prior(out))] if len(out) else None


# ----------------------------------------------------------------------------------------
def screen(
    experiment: Experiment,
    table: pd.DataFrame,
    settings: FitSettings,
    parent: xr.DataTree,
    *,
    seed: int = 0,
    priors: Mapping[str, Prior] | None = None,
    n_rounds: int = 30,
) -> float:
    """Largest log-likelihood gain [nats] a law achieves over its fitted nested parent.

    A cheap upper bound on what a candidate term can gain, used to decide which candidates
    need a full posterior. In every volume fraction the search starts from the parent's
    best posterior draws with the new parameters at their "off" values (so the gain is
    never below zero) and at three further levels across their prior ranges, and improves
    them by the batched local search of :func:`find_starts` (proposals for the parent's
    parameters at the scale of its posterior, for the new ones at a tenth of their prior
    range, shrunk when nothing improves). The gain is the summed difference of the best
    log-likelihoods found with and without the new parameters.

    Why it bounds the decision: the PSIS-LOO ELPD of a law is, to leading order, its
    maximised log-likelihood minus its effective number of parameters, so the ELPD gain of
    an extension over its parent is about this gain minus what the new parameters cost,
    and an extension whose best in-sample gain is below a threshold cannot earn an ELPD
    gain above it. A search that stops short of the maximum only lowers the gain (the
    parent's maximum is taken from its draws, which can only underestimate it, so that
    error raises the gain).

    Parameters
    ----------
    experiment : Experiment
    table : pandas.DataFrame
        Validated jumps.
    settings : FitSettings
        The extended law (``per_phi`` mode).
    parent : xarray.DataTree
        The fitted nested parent law.
    seed : int
        Seed of the search.
    priors : mapping of str to Prior, optional
    n_rounds : int
        Rounds of the local search per volume fraction.

    Returns
    -------
    float
        Log-likelihood gain [nats], summed over volume fractions (``nan`` if the parent
        has no draws at some volume fraction).
    """
    return screen_many(
        experiment, table, [settings], parent, seeds=[seed], priors=priors, n_rounds=n_rounds
    )[0]


def screen_many(
    experiment: Experiment,
    table: pd.DataFrame,
    configs: Sequence[FitSettings],
    parent: xr.DataTree,
    *,
    seeds: Sequence[int],
    priors: Mapping[str, Prior] | None = None,
    n_rounds: int = 30,
    points: list[dict[float, dict[str, float]]] | None = None,
) -> list[float]:
    """:func:`screen` for several extensions of one parent, their searches side by side.

    Every (extension, volume fraction) search is the one :func:`screen` makes alone (its
    own seed and random stream); their evaluations share one simulator call per round
    (the evolution strategy's rounds, then the Nelder-Mead polish, :mod:`granbayes._search`).

    Parameters
    ----------
    experiment : Experiment
    table : pandas.DataFrame
        Validated jumps.
    configs : sequence of FitSettings
        The extended laws (``per_phi`` mode).
    parent : xarray.DataTree
        The fitted nested parent law.
    seeds : sequence of int
        Seed of each extension's search.
    priors : mapping of str to Prior, optional
    n_rounds : int
        Rounds of the local search per volume fraction.
    points : list, optional
        If given, receives per extension the best point its searches found: volume
        fraction -> parameter -> value [its unit] (:func:`fit`'s ``start_points``).

    Returns
    -------
    list of float
        Log-likelihood gain [nats] of each extension, summed over volume fractions
        (``nan`` if the parent has no draws at some volume fraction).
    """
    if any(c.phi_mode != "per_phi" for c in configs):
        raise ValueError("screening needs phi_mode='per_phi'")
    priors = dict(priors if priors is not None else default_priors())
    table = _as_measurements(table)
    if any(pooled(experiment, c) for c in configs):
        raise ValueError(
            "screening fits each volume fraction on its own: calibration='pool' samples "
            "them in one run (use 'sample' or 'nominal')"
        )
    names = parent.attrs.get("parameters", "[]")  # JSON text (netCDF attributes)
    parent_names = set(json.loads(names) if isinstance(names, str) else names)
    problems, owner, failed = [], [], set()
    for c, (config, seed) in enumerate(zip(configs, seeds, strict=True)):
        specs = part_models(experiment, table, config, priors)
        for (_, model, _), part_seed in zip(specs, _seeds(seed, len(specs)), strict=True):
            warm = _warm_positions(model, parent, float(model.phis[0]), best=8)
            if warm is None or len(warm) == 0:
                failed.add(c)
                continue
            new = np.array(
                [
                    j < model.n_law and c.parameter not in parent_names
                    for j, c in enumerate(model.coordinates)
                ]
            )
            problems.append((model, warm, new, np.random.default_rng(part_seed)))
            owner.append(c)
    gains, best = _screen_searches(problems, n_rounds)
    total = [0.0] * len(configs)
    for c, g in zip(owner, gains, strict=True):
        total[c] += g
    if points is not None:
        points[:] = [{} for _ in configs]
        for c, (model, *_), u in zip(owner, problems, best, strict=True):
            points[c][float(model.phis[0])] = {
                co.parameter: float(co.prior.to_value(np.asarray(u[j])))
                for j, co in enumerate(model.coordinates)
            }
    return [float("nan") if c in failed else t for c, t in enumerate(total)]


def _screen_searches(
    problems: Sequence[tuple], n_rounds: int
) -> tuple[list[float], list[np.ndarray]]:
    """Gains [nats] over the parent's best draws and best points, searched side by side.

    Returns the gains and each search's best point (sampling coordinates). Per problem
    ``(model, warm, new, rng)``: a (1+12) evolution strategy from the parent's best draws
    with the new coordinates at "off" and at three levels across their prior ranges (a
    level below an "off" value inside the range is a start of its own), step size by
    success, then Nelder-Mead from its best point (see ``screen``).
    """
    if not problems:
        return [], []
    models = [p[0] for p in problems]

    def log_lik(us: Sequence[np.ndarray], which: Sequence[int] | None = None) -> list:
        """Summed log-likelihood (-inf outside the prior) of positions, one batch."""
        evs = evaluate_models(models if which is None else [models[i] for i in which], us)
        return [np.where(np.isfinite(ev.log_prob), ev.log_lik.sum(axis=1), -np.inf) for ev in evs]

    f_parent = [float(np.max(v)) for v in log_lik([p[1] for p in problems])]
    xs, fs, scales, bounds, n_main, rngs_below = [], [], [], [], [], []
    for model, warm, new, rng in problems:
        lo, hi = model.bounds_u.T
        width = hi - lo
        starts, below = [], []
        for level in (0.0, 0.1, 0.3, 0.6):
            x = warm[:2].copy()
            x[:, new] = np.maximum(x[:, new], lo[new] + level * width[new])
            starts.append(x)
            # a new parameter whose "off" value lies inside its range (unloading's r_unload
            # = 20 in [1, 200]: the effect grows as r falls) starts at the level too, below
            # "off", where the search from above can stall in a local optimum
            lower = new & (warm[0] > lo + level * width + 1e-9 * width)
            if level > 0.0 and lower.any():
                y = warm[:2].copy()
                y[:, lower] = lo[lower] + level * width[lower]
                below.append(y)
        n_main.append(sum(len(x) for x in starts))
        xs.append(np.concatenate(starts + below))
        # the starts below "off" draw their steps from a stream of their own, so that the
        # other starts follow the very same path whether or not there are any
        rngs_below.append(rng.spawn(1)[0] if below else None)
        spread = np.std(warm, axis=0) if len(warm) > 1 else np.zeros(model.ndim)
        base = np.where(new, 0.1 * width, np.maximum(spread, 1e-3 * width))
        # from below "off" the parent's coordinates must move too (the law's optimum
        # there can be far from the parent's: unloading's r_unload and k trade along a
        # curved ridge), so those starts step a tenth of every prior range
        scales.append(
            np.vstack(
                [
                    np.tile(base, (n_main[-1], 1)),
                    np.tile(0.1 * width, (len(xs[-1]) - n_main[-1], 1)),
                ]
            )
        )
        bounds.append((lo, hi, width))
    fs = log_lik(xs)
    n_prop = 12
    for _ in range(n_rounds):  # (1+12) evolution strategy, step size by success
        props = []
        for (model, _, _, rng), x, scale, (lo, hi, _), m, extra in zip(
            problems, xs, scales, bounds, n_main, rngs_below, strict=True
        ):
            step = rng.standard_normal((m, n_prop, model.ndim))
            if extra is not None:
                more = extra.standard_normal((len(x) - m, n_prop, model.ndim))
                step = np.concatenate([step, more])
            props.append(np.clip(x[:, None, :] + scale[:, None, :] * step, lo, hi))
        f_props = log_lik([p.reshape(-1, p.shape[-1]) for p in props])
        for i, (prop, fp) in enumerate(zip(props, f_props, strict=True)):
            x, f, scale, (_, _, width) = xs[i], fs[i], scales[i], bounds[i]
            fp = fp.reshape(len(x), n_prop)
            j = np.argmax(fp, axis=1)
            better = fp[np.arange(len(x)), j] > f
            x[better] = prop[better, j[better]]
            f[better] = fp[better, j[better]]
            scales[i] = _adapted_step(scale, better, width)
    best = [int(np.argmax(f)) for f in fs]
    searches = [
        nelder_mead(x[b], maxfev=60 * model.ndim, xatol=1e-4, fatol=1e-3, adaptive=True)
        for (model, *_), x, b in zip(problems, xs, best, strict=True)
    ]

    def objective(points: list[np.ndarray], which: list[int]) -> np.ndarray:
        clipped = [
            np.clip(p, bounds[i][0], bounds[i][1])[None] for p, i in zip(points, which, strict=True)
        ]
        return -np.array([v[0] for v in log_lik(clipped, which)])

    polished = drive(searches, objective)
    gains, points = [], []
    for x, f, b, pol, fp, (lo, hi, _) in zip(xs, fs, best, polished, f_parent, bounds, strict=True):
        better = -float(pol[1]) > float(f[b])
        gains.append(max(max(float(f[b]), -float(pol[1])) - fp, 0.0))
        points.append(np.clip(np.asarray(pol[0], dtype=float), lo, hi) if better else x[b].copy())
    return gains, points


def data_hash(experiment: Experiment, table: pd.DataFrame | Measurements) -> str:
    """SHA-256 of the experiment settings and the measurements (provenance).

    Parameters
    ----------
    experiment : Experiment
        Robot, command defaults and ``phi_c``.
    table : pandas.DataFrame or Measurements
        The jumps, or the measurements of every kind.

    Returns
    -------
    str
        Hexadecimal digest.
    """
    text = table.hash_text() if isinstance(table, Measurements) else table.to_csv(index=False)
    h = hashlib.sha256()
    h.update(repr((experiment.robot, experiment.command, experiment.phi_c)).encode())
    h.update(text.encode())
    return h.hexdigest()


def _to_shape(a: np.ndarray, n_chain: int, n_draw: int) -> np.ndarray:
    """Draws of shape (chain, draw, ...) as ``(n_chain, n_draw, ...)``.

    A run that kept all its chains keeps its last ``n_draw`` draws per chain; one that kept
    fewer (ensembles of a worse-supported mode dropped) is flattened in draw order and cut
    into ``n_chain`` chains of ``n_draw`` draws.
    """
    if a.shape[0] == n_chain:
        return a[:, a.shape[1] - n_draw :]
    flat = np.swapaxes(a, 0, 1).reshape(-1, *a.shape[2:])[-n_chain * n_draw :]
    return np.swapaxes(flat.reshape(n_draw, n_chain, *a.shape[2:]), 0, 1)


def _common_shape(parts: list[FitPart]) -> tuple[int, int]:
    """(chains, draws) that every run's kept draws can fill."""
    n_chain = max(p.run.samples.shape[0] for p in parts)
    n_draw = min(
        p.run.samples.shape[1]
        if p.run.samples.shape[0] == n_chain
        else (p.run.samples.shape[0] * p.run.samples.shape[1]) // n_chain
        for p in parts
    )
    return n_chain, n_draw


def _variable_attrs(
    names: tuple[str, ...], calibrated: Mapping[str, Prior] | None = None
) -> dict[str, dict[str, str]]:
    """Units and descriptions of the posterior variables.

    Parameters
    ----------
    names : tuple of str
        The fitted force-term parameters; their ``units`` and ``long_name`` are read from
        the force-term registry (:data:`granbayes.forces.TERMS`) at each call.
    calibrated : mapping of str to Prior, optional
        The robot parameters sampled with their calibration as prior.

    Returns
    -------
    dict of str to dict
        Variable name to its attributes, for ``names``, ``sigma_mm`` [mm] and the heights
        [mm].
    """
    from .forces import parameter  # at call time: a term registered at run time is seen

    out = {n: {"units": parameter(n).unit, "long_name": parameter(n).description} for n in names}
    for n, prior in (calibrated or {}).items():
        out[n] = {
            "units": prior.unit,
            "long_name": f"robot's {n} (calibration {prior.mu:g} +/- {prior.sigma:g} {prior.unit})",
        }
    out["sigma_mm"] = {"units": "mm", "long_name": "trial-to-trial scatter of jump heights"}
    out["height_mm"] = {"units": "mm", "long_name": "jump height"}
    out["height_sim_mm"] = {"units": "mm", "long_name": "simulated jump height (no noise)"}
    return out


def _run_record(part: FitPart) -> dict:
    """Diagnostics of one run, for the DataTree attributes (and the reports)."""
    r = part.run
    return {
        "label": part.label,
        "coordinates": part.model.coordinate_names,
        "n_ensembles": len(r.tau),
        "n_chains": int(r.samples.shape[0]),
        "tau": r.tau.tolist(),
        "rhat": r.rhat.tolist(),
        "ess_bulk": r.ess_bulk.tolist(),
        "ess_tail": r.ess_tail.tolist(),
        "n_steps": r.n_steps,
        "burn": r.burn.tolist(),
        "thin": r.thin,
        "acceptance": float(np.mean(r.acceptance)),
        "converged": r.converged,
        "warnings": list(r.warnings),
    }


def _bed_warnings(parts: list[FitPart], settings: FitSettings, phi_sd: float) -> list[str]:
    """What a fit does not integrate of ``[bed] phi_sd`` (``FitSettings.bed_phi``)."""
    given = f"experiment.toml gives [bed] phi_sd = {phi_sd:g}; "
    if settings.bed_phi == "measured":
        return [
            given + "this fit takes each bed's phi as exact (the measured value): its "
            "intervals do not include that uncertainty"
        ]
    if settings.phi_mode == "per_phi":
        return [
            given + "in per_phi mode a volume fraction's coefficients are those of the beds "
            "prepared at it (the law is not defined beside the measured value): the beds' "
            "scatter about it is absorbed into them and into the scatter, not integrated "
            "out (--phi-mode quadratic integrates it)"
        ]
    kinds = {b.kind for p in parts for b in p.model.blocks}
    if "trajectories" in kinds:
        return [
            given + "the tracked jumps take the measured phi (jump heights and intrusion "
            "tests integrate their bed's phi)"
        ]
    return []


def _warnings(
    parts: list[FitPart], settings: FitSettings, experiment: Experiment | None = None
) -> list[str]:
    out = []
    if experiment is not None and experiment.uncertain:
        sampled = set(_calibrated(experiment, settings))
        exact = [k for k, v in experiment.uncertainty.items() if v > 0 and k not in sampled]
        if exact:
            out.append(
                f"experiment.toml gives an uncertainty of {', '.join(exact)} "
                "([robot.uncertainty]); this fit takes "
                + ("them" if len(exact) > 1 else "it")
                + " as exact (nominal values): its intervals do not include "
                + ("those uncertainties" if len(exact) > 1 else "that uncertainty")
                + (
                    ""
                    if settings.calibration == "nominal"
                    else " (a fit samples the robot's own parameters and amplitude_mm only)"
                )
            )
        if experiment.phi_sd > 0:
            out.extend(_bed_warnings(parts, settings, experiment.phi_sd))
    for p in parts:
        out.extend(f"run {p.label}: {w}" for w in p.run.warnings)
        if not p.run.converged and not p.run.warnings:
            out.append(f"run {p.label}: not converged after {p.run.n_steps} steps")
    return out


def _block_rows(data: Measurements, model: JumpModel) -> list[np.ndarray]:
    """For each block of ``model`` (fitted to ``data``), the rows of its table in the fit's."""
    return [data.origin[block.kind] for block in model.blocks]


def _unit_columns(full: Measurements, units: np.ndarray, model: JumpModel) -> list[np.ndarray]:
    """For each block of ``model``, its units numbered within its kind in the whole fit."""
    out, start = [], 0
    for block in model.blocks:
        mine = units[start : start + block.n_units]
        out.append(mine - full.offset(block.kind))
        start += block.n_units
    return out


def _predictive_arrays(
    full: Measurements,
    shape: tuple[int, ...],
    names: Sequence[tuple[str, str, str, bool]],
    thinned: bool = False,
) -> dict[str, tuple[list[str], np.ndarray]]:
    """NaN arrays (shape + one element axis) of every (variable, kind, dimension).

    ``thinned``: those of the thinned blocks, on ``(predictive_draw, element)``; otherwise
    the others, on ``(chain, draw, element)`` (the dims list omits chain and draw).
    """
    lead = ["predictive_draw"] if thinned else []
    return {
        name: ([*lead, dim], np.full((*shape, len(full.tables[kind])), np.nan))
        for name, kind, dim, thin in names
        if thin == thinned
    }


def _predictive_names(parts: list[FitPart]) -> list[tuple[str, str, str, bool]]:
    """(variable, kind, dimension, thinned) of every block's predictive variables."""
    seen: dict[str, tuple[str, str, str, bool]] = {}
    for part in parts:
        for block in part.model.blocks:
            thin = block.max_predictive_draws is not None
            for name, dim in block.predictive_dims.items():
                seen.setdefault(name, (name, block.kind, dim, thin))
    return list(seen.values())


def _thin_index(parts: list[FitPart], n_total: int) -> np.ndarray:
    """Flat (chain, draw) indices of the draws the thinned blocks replicate (even spacing)."""
    wanted = [
        b.max_predictive_draws
        for p in parts
        for b in p.model.blocks
        if b.max_predictive_draws is not None
    ]
    if not wanted or n_total == 0:
        return np.empty(0, dtype=np.int64)
    m = min(max(wanted), n_total)
    return np.unique(np.linspace(0, n_total - 1, m).round().astype(np.int64))


def _replicate(
    part: FitPart,
    u: np.ndarray,
    seed: int,
    extras: np.ndarray | None,
    thin: np.ndarray,
    full_out: dict,
    thin_out: dict,
    lead: tuple[int, ...],
) -> None:
    """Replicates of a part's measurements into ``full_out`` and (thinned) ``thin_out``.

    Blocks replicated for every draw use ``default_rng(seed)`` (a heights-only fit's
    replicates are those of every earlier version, bit for bit); the thinned blocks use
    ``default_rng([seed, 1])`` on the draws ``thin``.
    """
    model = part.model
    everywhere = [i for i, b in enumerate(model.blocks) if b.max_predictive_draws is None]
    thinned = [i for i, b in enumerate(model.blocks) if b.max_predictive_draws is not None]
    rows = _block_rows(part.data, model)
    if everywhere:
        reps = model.predictive(u, np.random.default_rng(seed), extras, blocks=everywhere)
        for i in everywhere:
            for name, rep in reps[i].items():
                if name in full_out:
                    full_out[name][1][..., rows[i]] = rep.reshape(*lead, -1)
    if thinned and len(thin):
        reps = model.predictive(
            u[thin],
            np.random.default_rng([seed, 1]),
            None if extras is None else extras[thin],
            blocks=thinned,
        )
        for i in thinned:
            for name, rep in reps[i].items():
                if name in thin_out:
                    thin_out[name][1][:, rows[i]] = rep


def _thinned_dataset(
    variables: Mapping[str, tuple[list[str], np.ndarray]], thin: np.ndarray, n_draw: int
) -> xr.Dataset:
    """Thinned replicates with the (chain, draw) of each ``predictive_draw``."""
    if not variables:
        return xr.Dataset()
    return xr.Dataset(
        {name: (dims, a) for name, (dims, a) in variables.items()},
        coords={
            "predictive_draw": np.arange(len(thin)),
            "predictive_chain": ("predictive_draw", thin // max(n_draw, 1)),
            "predictive_chain_draw": ("predictive_draw", thin % max(n_draw, 1)),
        },
    )


def _prior_draws(
    parts: list[FitPart], phis: np.ndarray, full: Measurements, settings: FitSettings, seed: int
) -> tuple[dict, dict, dict]:
    """Prior draws per volume fraction [SI] and the measurements simulated from them.

    Returns the prior, its replicates on (chain, draw) and its thinned replicates.
    """
    n = settings.n_prior_draws
    values_of = [p.model.parameter_values(np.zeros((1, p.model.ndim)), phis) for p in parts]
    names = list(dict.fromkeys(k for v in values_of for k in v))
    prior = {name: np.full((1, n, len(phis)), np.nan) for name in names}
    replicated = [v for v in _predictive_names(parts) if "_sim_" not in v[0]]
    thin = _thin_index(parts, n)
    prior_pred = _predictive_arrays(full, (1, n), replicated)
    prior_thin = _predictive_arrays(full, (len(thin),), replicated, thinned=True)
    for part, part_seed in zip(parts, _seeds(seed + 2, len(parts)), strict=True):
        rng = np.random.default_rng(part_seed)
        u = part.model.sample_prior(rng, n)
        values = part.model.parameter_values(u, phis)
        cols = np.searchsorted(phis, part.model.phis)
        for name, v in values.items():
            prior[name][0][:, cols] = v[:, cols]
        rows = _block_rows(part.data, part.model)
        model = part.model
        everywhere = [i for i, b in enumerate(model.blocks) if b.max_predictive_draws is None]
        thinned = [i for i, b in enumerate(model.blocks) if b.max_predictive_draws is not None]
        # the replicates continue the stream of the prior draws (as before thinning existed)
        reps = model.predictive(u, rng, blocks=everywhere) if everywhere else []
        for i in everywhere:
            for name, rep in reps[i].items():
                if name in prior_pred:
                    prior_pred[name][1][0][:, rows[i]] = rep
        if thinned and len(thin):
            reps = model.predictive(u[thin], np.random.default_rng([part_seed, 1]), blocks=thinned)
            for i in thinned:
                for name, rep in reps[i].items():
                    if name in prior_thin:
                        prior_thin[name][1][:, rows[i]] = rep
    return prior, prior_pred, prior_thin


@dataclass(frozen=True)
class _Draws:
    """The kept draws of every run of a fit on one (chain, draw) grid (:func:`_draws`)."""

    posterior: dict[str, np.ndarray]  # parameter [SI] -> (chain, draw, phi) or (..., order)
    dims: dict[str, list[str]]  # the dimension after (chain, draw) of each posterior variable
    log_likelihood: dict[str, tuple[list[str], np.ndarray]]  # per kind: (chain, draw, unit)
    predictive: dict[str, tuple[list[str], np.ndarray]]  # (chain, draw, row of its kind)
    thinned: dict[str, tuple[list[str], np.ndarray]]  # (predictive_draw, row of its kind)
    thin: np.ndarray  # flat (chain, draw) index of each predictive_draw
    lp: np.ndarray  # (chain, draw, run): log-probability of each run's walkers
    log_prior: np.ndarray  # (chain, draw): prior density of the values, summed over runs


def _draws(
    parts: list[FitPart], phis: np.ndarray, full: Measurements, settings: FitSettings, seed: int
) -> _Draws:
    """Every run's kept draws mapped onto the fit's volume fractions and units.

    A run fills the columns of its own volume fractions (``per_phi``: one each) and its own
    units and rows; the replicated measurements of run ``i`` use the ``i``-th seed derived
    from ``seed``.
    """
    n_chain, n_draw = _common_shape(parts)
    values_of = [p.model.parameter_values(np.zeros((1, p.model.ndim)), phis) for p in parts]
    names = list(dict.fromkeys(k for v in values_of for k in v))
    post: dict[str, np.ndarray] = {n: np.full((n_chain, n_draw, len(phis)), np.nan) for n in names}
    dims: dict[str, list[str]] = {n: ["phi"] for n in post}
    loglik: dict[str, tuple[list[str], np.ndarray]] = {}
    for part in parts:
        for block in part.model.blocks:
            loglik.setdefault(
                block.variable,
                (
                    [block.unit_dim],
                    np.full((n_chain, n_draw, full.n_units_of(block.kind)), np.nan),
                ),
            )
    names_pp = _predictive_names(parts)
    predictive = _predictive_arrays(full, (n_chain, n_draw), names_pp)
    thin = _thin_index(parts, n_chain * n_draw)
    thinned = _predictive_arrays(full, (len(thin),), names_pp, thinned=True)
    lp = np.full((n_chain, n_draw, len(parts)), np.nan)
    log_prior = np.zeros((n_chain, n_draw))
    for i, (part, rep_seed) in enumerate(zip(parts, _seeds(seed + 1, len(parts)), strict=True)):
        r = part.run
        samples = _to_shape(r.samples, n_chain, n_draw)
        flat = samples.reshape(-1, samples.shape[-1])
        values = part.model.parameter_values(flat, phis)
        cols = np.searchsorted(phis, part.model.phis)
        for n, v in values.items():
            post[n][..., cols] = v.reshape(n_chain, n_draw, len(phis))[..., cols]
        ll = _to_shape(part.log_lik, n_chain, n_draw)
        start = 0
        for block, units in zip(
            part.model.blocks, _unit_columns(full, part.units, part.model), strict=True
        ):
            loglik[block.variable][1][..., units] = ll[..., start : start + block.n_units]
            start += block.n_units
        blobs = _to_shape(r.blobs, n_chain, n_draw)
        extras = blobs.reshape(n_chain * n_draw, -1)[:, part.model.n_units :]
        _replicate(part, flat, rep_seed, extras, thin, predictive, thinned, (n_chain, n_draw))
        lp[..., i] = _to_shape(r.log_prob, n_chain, n_draw)
        log_prior += part.model.log_prior_density(flat).reshape(n_chain, n_draw)
        if settings.phi_mode == "quadratic":
            _add_coefficients(post, dims, part.model.coordinate_names, samples)
    return _Draws(post, dims, loglik, predictive, thinned, thin, lp, log_prior)


def _add_coefficients(
    post: dict[str, np.ndarray],
    dims: dict[str, list[str]],
    coordinate_names: list[str],
    samples: np.ndarray,
) -> None:
    """Add the quadratic coefficients of a run to ``post`` as ``<parameter>_coef``.

    Coordinates named ``<parameter>:c<order>`` (sampling coordinates, e.g. ``log k``) fill
    the ``order`` dimension (0, 1, 2) of ``<parameter>_coef``.
    """
    n_chain, n_draw = samples.shape[:2]
    for j, cname in enumerate(coordinate_names):
        if ":c" in cname:
            pname, order = cname.split(":c")
            key = f"{pname}_coef"
            post.setdefault(key, np.zeros((n_chain, n_draw, 3)))[..., int(order)] = samples[..., j]
            dims[key] = ["order"]


def _fit_attrs(
    parts: list[FitPart],
    experiment: Experiment,
    observed: Measurements,
    settings: FitSettings,
    priors: Mapping[str, Prior],
    seed: int,
    data_source: str,
) -> dict:
    """The DataTree attributes of a fit: provenance, settings, priors and run diagnostics."""
    calibrated = parts[0].model.calibrated
    return {
        "seed": int(seed),
        # package versions and the machine: what bit-identical results require to match
        **environment(),
        "config": settings.to_dict(),
        "priors": {k: dataclasses.asdict(v) for k, v in {**priors, **calibrated}.items()},
        # robot parameters sampled with their calibration as prior (FitSettings.calibration)
        "calibrated": {
            k: {"nominal": p.mu, "sd": p.sigma, "unit": p.unit} for k, p in calibrated.items()
        },
        "data_sha256": data_hash(experiment, observed),
        "data_source": data_source,
        "experiment": {
            "robot": dataclasses.asdict(experiment.robot),
            "command": dataclasses.asdict(experiment.command),
            "phi_c": experiment.phi_c,
            "uncertainty": experiment.uncertainty,
            "phi_sd": experiment.phi_sd,
        },
        "parameters": list(parts[0].model.parameters),
        "runs": [_run_record(p) for p in parts],
        "converged": all(p.run.converged for p in parts),
        "warnings": _warnings(parts, settings, experiment),
        "interval": f"{stats.CI_PROB:.0%} equal-tailed",
        "log_prior": "density of the reported parameter values, summed over runs",
    }


def _observed(data: Measurements) -> xr.Dataset:
    """The observed data of every kind, each on its own dimensions (:data:`KINDS`)."""
    return xr.merge([KINDS[k].to_observed(t) for k, t in data.tables.items()])


def _assemble(
    parts: list[FitPart],
    experiment: Experiment,
    data: Measurements,
    settings: FitSettings,
    priors: Mapping[str, Prior],
    seed: int,
    data_source: str,
) -> FitResult:
    """The :class:`FitResult` of the runs.

    Their draws, prior draws and attributes in one DataTree
    (:func:`granbayes._datatree.build_datatree`).
    """
    for part in parts:
        part.data = data.select(part.units)
    phis = data.phis
    draws = _draws(parts, phis, data, settings, seed)
    prior, prior_pred, prior_thin = {}, {}, {}
    if settings.n_prior_draws > 0:
        prior, prior_pred, prior_thin = _prior_draws(parts, phis, data, settings, seed)
    n_draw = draws.lp.shape[1]
    thinned = {
        "posterior_predictive": _thinned_dataset(draws.thinned, draws.thin, n_draw),
        "prior_predictive": _thinned_dataset(
            prior_thin, _thin_index(parts, settings.n_prior_draws), settings.n_prior_draws
        ),
    }
    dt = gdt.build_datatree(
        draws.posterior,
        dims=draws.dims,
        coords={
            "phi": phis,
            "order": np.arange(3),
            "run": [p.label for p in parts],
        },
        log_likelihood=draws.log_likelihood,
        posterior_predictive=draws.predictive,
        observed=_observed(data),
        sample_stats={"lp": draws.lp},
        attrs=_fit_attrs(parts, experiment, data, settings, priors, seed, data_source),
        stats_dims={"lp": ["run"]},
        prior=prior,
        prior_predictive=prior_pred,
        log_prior={"log_prior": draws.log_prior},
        var_attrs=_variable_attrs(parts[0].model.parameters, parts[0].model.calibrated),
        thinned=thinned,
    )
    return FitResult(dt, parts, settings, seed, _warnings(parts, settings, experiment))


# ----------------------------------------------------------------------------------------
@dataclass(frozen=True)
class CommandComparison:
    """One force law for all commands, or one per command (:func:`compare_commands`).

    Attributes
    ----------
    table : pandas.DataFrame
        One row per volume fraction: ``elpd_shared``, ``elpd_per_command``, ``elpd_diff``
        (shared minus per-command) [nats], ``elpd_diff_se`` [nats], max Pareto k of both,
        the preferred model, ``per_command_converged``, and per parameter whether the
        per-command intervals overlap (``<parameter>_intervals_overlap``).
    intervals : pandas.DataFrame
        One row per volume fraction, command and parameter with the posterior ``median``,
        ``lo`` and ``hi`` (``ci_prob`` equal-tailed) of the per-command fit [SI].

    Unpacking gives ``table, intervals``, as ``compare_commands(..., details=True)`` did.
    """

    table: pd.DataFrame
    intervals: pd.DataFrame

    def __iter__(self) -> Iterator[pd.DataFrame]:
        """Unpack as ``table, intervals``."""
        return iter((self.table, self.intervals))


def compare_commands(
    experiment: Experiment,
    table: pd.DataFrame,
    shared: FitResult,
    *,
    seed: int = 0,
    priors: Mapping[str, Prior] | None = None,
    ci_prob: float = stats.CI_PROB,
    details: bool | None = None,
    max_steps: int = 4000,
) -> CommandComparison:
    """One force law for all commands, or one per command? Per volume fraction.

    For every volume fraction fitted in ``shared`` (``per_phi`` mode), fits each command
    separately with the same terms and priors and compares the two models by PSIS-LOO.
    Posterior overlap: whether the per-command ``ci_prob`` intervals of each parameter
    share a common value.

    A command alone often cannot separate the coefficients (10 jumps for 3 parameters), and
    such posteriors mix slowly: the per-command fits are capped at ``max_steps`` steps, and
    the table says for every volume fraction whether all of them converged
    (``per_command_converged``); an unconverged comparison is approximate.

    Parameters
    ----------
    experiment : Experiment
    table : pandas.DataFrame
        The jumps that ``shared`` was fitted to.
    shared : FitResult
        A ``per_phi`` fit.
    seed : int
        Master seed of the per-command fits.
    priors : mapping, optional
    ci_prob : float
        Interval probability for the overlap check.
    details : bool, optional
        Deprecated, without effect (a ``DeprecationWarning`` says so): the per-command
        intervals are always returned.
    max_steps : int
        Step cap of each per-command fit.

    Returns
    -------
    CommandComparison
        The comparison per volume fraction (``.table``) and the per-command posterior
        intervals (``.intervals``); unpacks as ``table, intervals``.
    """
    if details is not None:
        warnings.warn(
            "compare_commands(details=...) is deprecated and has no effect: it returns a "
            "CommandComparison (.table, .intervals; unpacks as `table, intervals`)",
            DeprecationWarning,
            stacklevel=2,
        )
    if shared.settings.phi_mode != "per_phi" or any(
        len(part.model.phis) != 1 for part in shared.parts
    ):
        raise ValueError(
            "compare_commands needs a per_phi fit with one run per volume fraction (not "
            "calibration='pool')"
        )
    priors = dict(priors if priors is not None else default_priors())
    table = table.reset_index(drop=True)
    table = table.assign(jump=np.arange(len(table)))
    config = dataclasses.replace(
        shared.settings,
        sampler=dataclasses.replace(
            shared.settings.sampler, max_steps=min(max_steps, shared.settings.sampler.max_steps)
        ),
    )
    rows = []
    per_command_rows = []
    seeds = iter(_seeds(seed + 7, 5 * len(shared.parts)))
    # every command of every volume fraction: one run each, all sampled side by side
    specs, spec_seeds, owner = [], [], []
    for k, part in enumerate(shared.parts):
        phi = float(part.model.phis[0])
        for command in COMMAND_NAMES:
            sub = table[(table["phi"] == phi) & (table["command"] == command)]
            if sub.empty:
                continue
            obs = Observations.from_table(sub)
            model = _make_model(obs, experiment, config, priors, "per_phi")
            specs.append((command, model, sub["jump"].to_numpy()))
            spec_seeds.append(next(seeds))
            owner.append(k)
    fitted = _run_parts(specs, config, spec_seeds, None, False)
    for k, part in enumerate(shared.parts):
        phi = float(part.model.phis[0])
        sub_parts = [(p.label, p) for p, o in zip(fitted, owner, strict=True) if o == k]
        n_chain, n_draw = _common_shape([part, *(p for _, p in sub_parts)])
        order = np.concatenate([p.jumps for _, p in sub_parts])
        ll_sep = np.concatenate(
            [_to_shape(p.log_lik, n_chain, n_draw) for _, p in sub_parts], axis=-1
        )
        pos = {j: i for i, j in enumerate(part.jumps)}
        ll_shared = _to_shape(part.log_lik, n_chain, n_draw)[..., [pos[j] for j in order]]
        models = {"shared": ll_shared, "per_command": ll_sep}
        loo = {k: stats.loo(v) for k, v in models.items()}
        diff, diff_se = stats.elpd_difference(loo["shared"]["elpd_i"], loo["per_command"]["elpd_i"])
        row = {
            "phi": phi,
            "elpd_shared": loo["shared"]["elpd"],
            "elpd_per_command": loo["per_command"]["elpd"],
            "elpd_diff": diff,
            "elpd_diff_se": diff_se,
            "max_pareto_k_shared": loo["shared"]["max_pareto_k"],
            "max_pareto_k_per_command": loo["per_command"]["max_pareto_k"],
            "preferred": "shared" if diff > -2.0 * diff_se else "per_command",
            "per_command_converged": all(p.run.converged for _, p in sub_parts),
        }
        lo_q, _, hi_q = stats.eti_probs(ci_prob)
        for pname in part.model.parameters:
            lows, highs = [], []
            for command, p in sub_parts:
                idx = p.model.coordinate_names.index(pname)
                v = p.model.priors[pname].to_value(p.run.samples[..., idx].ravel())
                lows.append(np.quantile(v, lo_q))
                highs.append(np.quantile(v, hi_q))
                per_command_rows.append(
                    {
                        "phi": phi,
                        "command": command,
                        "parameter": pname,
                        "median": float(np.median(v)),
                        "lo": float(lows[-1]),
                        "hi": float(highs[-1]),
                    }
                )
            row[f"{pname}_intervals_overlap"] = bool(max(lows) <= min(highs))
        rows.append(row)
    return CommandComparison(pd.DataFrame(rows), pd.DataFrame(per_command_rows))
