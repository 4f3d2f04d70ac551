"""Find the physical effect a simulation is missing, name it, add it, show the gap shrink.

The simulation model is a set of named effects (``models.physics.effects.EFFECTS``) fitted to
the readings: every effect is linear in its amplitude once its nuisance parameters (screw
pitch, time constants, wear location, number of control points) are fixed, and each run (test)
gets its own offset, the laser's datum. Lost-motion effects enter as -d b/2: on every reading
with an indirect measuring system, only on readings that follow a reversal with a direct one.
The system is decided from the evidence (``system``): lost motion at the interior targets of
the linear tests (their reversal values, t-test against zero, and against the pendulum tests'
values when there are any) means an indirect system; the decision and its test are in the
notes and the result, and hold for the baseline and every candidate.

Loop ([Mechta2022]'s rule: stop when the residual is within the repeatability):

1. fit the model, residual r = measured - model;
2. for every effect not in the model whose inputs the data have: refit model + candidate over
   the candidate's nuisance grid (profile likelihood); general smooth forms (a degree-2
   B-spline along the axis with 3 up to one control point per target, for ``lead_error_profile``,
   for lost motion varying along the axis and for the half-difference between the directions,
   ``reversal_profile``) choose their complexity by BIC. A clearance b(x) >= 0 gives a reversal
   value of one sign at every target: ``reversal_profile`` passes with an indirect system only
   when the measured reversal value changes sign, and yields to a passing lost-motion
   candidate that fits as well;
3. a candidate passes when all hold: delta BIC < -10; cross-validation (leave one run out, or
   one cycle out for a single run) improves the held-out RMSE by > 2 %; its amplitude is
   physically plausible (the record's range, and lost motion never negative) for at least one
   member of the family of nuisance values the data cannot tell apart; and under a bootstrap
   (by run, or by cycle within runs when there are fewer than 8 runs) it holds in >= 80 % of
   resamples (the best, or still needed with the resample's best in the model: the other
   member of a pair) with a 95 % interval that excludes zero;
4. identifiability: passing candidates whose BIC differ by less than 10 (columns collinear on
   this design fit equally well) are reported ``ambiguous`` together, with the tests that would separate them; a general smooth form wins
   over the specific effects only when its BIC is lower by more than 10 (it nests them);
   otherwise the winner is named, added, the nuisance values of the effects named before it
   are re-fitted with it in the model, and the loop repeats (until the gap is within the
   repeatability with no structure left along a factor the model does not act along). A
   nuisance parameter the design
   cannot fix (two dwell levels for a settling time constant, aliased screw pitches) does not
   block the name: the step says which parameter is not identified and which test would fix it.

When nothing passes and the gap stays above the repeatability, ``unexplained`` says how large
the gap is and against what the residual is structured (position, direction, run, time,
temperature, feed, dwell), or that it is noise-dominated. Readings the ISO 230-2 step flags as
outliers are left out of the fit (said in the notes).

The package, by concern: ``terms`` (the effects as design columns, typed nuisance parameters),
``design`` (the least-squares design with the runs' offsets projected out), ``candidates``
(each candidate over its nuisance family), ``verdicts`` (the winner, nesting, bootstrap),
``structure`` (confounding, aliasing and the unexplained gap), ``system`` (the measuring
system from the interior reversal values) and ``search`` (the loop).
"""

from models.discovery.candidates import (
    BIC_THRESHOLD,
    CV_GAIN,
    LOST_MOTION_PROFILE,
    BatchFit,
    CandidateFit,
    Form,
)
from models.discovery.design import Design, bic, cv_rmse, lstsq_fit, rank
from models.discovery.search import (
    COMPENSATE_HINT,
    DEFAULT_BASELINE,
    Discovery,
    Step,
    check_baseline,
    discover,
)
from models.discovery.structure import (
    COLLINEAR,
    FACTOR_INPUTS,
    NOISE_RATIO,
    STOP_RATIO,
    STRUCTURE_P,
    residual_structure,
)
from models.discovery.system import SYSTEM_P, SystemTest, measuring_system
from models.discovery.terms import (
    ALWAYS_PRESENT,
    CONDITION_OF,
    EFFECTS,
    MAX_CONTROL,
    PROFILES,
    Nuisance,
    conditions_of,
    control_counts,
    data_value,
    effect_column,
    missing_inputs,
    nuisance_grid,
    nuisances,
    profile_basis,
    quadrature_pairs,
    repeatability_um,
    reversal_flags,
)
from models.discovery.verdicts import (
    BOOT_AGREEMENT,
    BOOT_MIN_RUNS,
    BOOT_SAMPLES,
    CLOSE_BIC,
    NESTED_SHARE,
    Choice,
)

__all__ = [
    "ALWAYS_PRESENT",
    "BIC_THRESHOLD",
    "BOOT_AGREEMENT",
    "BOOT_MIN_RUNS",
    "BOOT_SAMPLES",
    "CLOSE_BIC",
    "COLLINEAR",
    "COMPENSATE_HINT",
    "CONDITION_OF",
    "CV_GAIN",
    "DEFAULT_BASELINE",
    "EFFECTS",
    "FACTOR_INPUTS",
    "LOST_MOTION_PROFILE",
    "MAX_CONTROL",
    "NESTED_SHARE",
    "NOISE_RATIO",
    "PROFILES",
    "STOP_RATIO",
    "STRUCTURE_P",
    "SYSTEM_P",
    "BatchFit",
    "CandidateFit",
    "Choice",
    "Design",
    "Discovery",
    "Form",
    "Nuisance",
    "Step",
    "SystemTest",
    "bic",
    "check_baseline",
    "conditions_of",
    "control_counts",
    "cv_rmse",
    "data_value",
    "discover",
    "effect_column",
    "lstsq_fit",
    "measuring_system",
    "missing_inputs",
    "nuisance_grid",
    "nuisances",
    "profile_basis",
    "quadrature_pairs",
    "rank",
    "repeatability_um",
    "residual_structure",
    "reversal_flags",
]
