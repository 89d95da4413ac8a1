"""Model criticism: what the simulation gets wrong, which physics is missing, and the gain.

:func:`diagnose` runs the loop on measured jumps:

1. fit the baseline law (default: the thesis's depth-only law with the bed's default
   unloading), one parameter set per volume fraction shared by all commands;
2. show what it gets wrong: residuals per *cell* (one command at one volume fraction and
   one setting), each with a lack-of-fit z-score against the trial scatter measured from
   the repeats (:func:`granbayes.stats.residual_table`); cells beyond
   :func:`granbayes.stats.misfit_threshold` are *misfit*;
3. name the cause: every other term of the library is screened, and the promising ones
   are added to the current law, warm-started from its posterior, and compared by
   PSIS-LOO; where Pareto k exceeds ArviZ's ``good_k`` and the comparison decides the
   outcome, the flagged jumps are moment matched, and those still flagged recomputed by
   exact refits, or by K-fold of their volume fraction where it holds many;
4. extend, forward, by :func:`decide` while misfit remains;
5. check what is left: the selected law's own misfit cells. Where misfit remains that no
   library term removes, the :class:`Verdict` is ``MISFIT_REMAINS``: the data hold physics
   the library does not have, and the report lists what helped and where the law still
   fails instead of naming a cause.

Every fit the decision rests on must have converged; a fit that did not is rerun once with
twice the step cap, and a candidate whose fit still did not converge cannot be selected.
An extension contains its parent (new parameter "off"), so its ELPD cannot be far below
the parent's: a deficit beyond ``nested_tolerance`` nats plus 2 SE is a sampling failure
and the extension is rerun with another seed.

The selection rule (:func:`decide`; thresholds chosen by the calibration study
``benchmarks/calibrate_verdicts.py``): the best converged candidate of a round is added
when its ELPD gain over the current law exceeds both ``min_gain`` nats and ``se_factor``
standard errors of the difference, **and** the current law shows misfit or the gain
exceeds ``strong_gain`` nats. Naming a term is a claim about the physics, so the chosen
term must also beat every other fitted candidate by the same standard
(:func:`distinguished`); those it does not beat are reported with it as indistinguishable
(:func:`rivals`).

The package is split by job: ``_rule`` (settings, the rule, the verdict and candidate
types), ``_bank`` (the bank of fits, screening and the fallbacks of PSIS-LOO), ``_record``
(the typed record of a diagnosis and its ``diagnosis.json`` form) and ``_loop`` (the
loop itself).
"""

from .._deprecated import alias_getattr
from ._loop import Diagnosis, diagnose
from ._record import DiagnosisRecord
from ._rule import (
    Candidate,
    DiagnoseSettings,
    Estimate,
    Verdict,
    decide,
    distinguished,
    rivals,
    verdict,
)

__all__ = [
    "Candidate",
    "DiagnoseSettings",
    "Diagnosis",
    "DiagnosisRecord",
    "Estimate",
    "Verdict",
    "decide",
    "diagnose",
    "distinguished",
    "rivals",
    "verdict",
]

#: Deprecated alias (old name -> new name): importable, with a DeprecationWarning.
__getattr__ = alias_getattr(__name__, {"DiagnoseConfig": "DiagnoseSettings"})
