"""Conditional influence of each input on backlash, given the others: driver, proxy or none.

The marginal views of ``features.ranking`` (the paper's ANOVA -ln p and weighted k-NN, [BacklashNN]
Fig. 14 / Table 5) measure *association*. In a test plan inputs move together (run order,
visits, warm-up with feed), so an input with no physical path can score high and a real driver
can hide behind a larger one. This module decides per input, given the others:

``driver``
    the input has a physical path to lost motion (an effect record of kind ``lost_motion``
    lists it among its inputs, or operating hours through wear) **and** its partial F-test in
    the effect model is significant. It gets its effect [um] over the observed range with a
    bootstrap interval.
``proxy``
    the input is associated with backlash but has no path of its own (or its path is not
    significant given the others): it stands in for a named driver (``proxy_for``, e.g.
    humidity that follows feed in the run order), for the ``visit`` or ``run`` (it changed only
    between them), or for ``backlash_um`` itself (the deviations the target is computed from).
``none``
    no association, and no influence given the others.
``undecided``
    the design cannot test it (no residual degrees of freedom left, or it is aliased with
    another input); the separating test in the design diagnostics says what would.

An input without a physical path is never a driver, whatever its score.

Effect model (linear in parameters, split-plot strata)
------------------------------------------------------
Points are nested in runs (a linear/pendulum pair at one feed, dwell and repeat), runs in
visits, visits in units (machine and axis). An input is tested in every stratum that holds at
least ``MIN_SHARE`` of its variance, against the error of that stratum (classical split-plot
analysis): within runs (run fixed effects; position, warm-up), between runs within visits (run
means, visit fixed effects; feed, conditions of the run), between visits within units (visit
means, unit fixed effects; operating hours). Each input enters as Legendre polynomials of degree
1..``MAX_DEGREE`` over its observed range, the degree chosen by BIC. The partial F-test of input
j compares the stratum model with and without j:

.. math::

    F = \\frac{(RSS_{-j} - RSS) / d_j}{RSS / (n_{cells} - n_{blocks} - p)}

and the input's p-value is the smallest over its strata times their number (Bonferroni).
Drivers are tested within the *physics model* (the inputs with a path only); an input without
a path is tested by adding it to the physics model. The effect [um] is the peak-to-peak of the
fitted partial effect over the observed values; its interval is the 2.5-97.5 % percentile of a
bootstrap that resamples the stratum's cells (points, runs or visits) within their blocks, or,
where the stratum has too few cells for that, of draws from the coefficients' t distribution.

A second, non-parametric opinion (``dropcolumn_importance``): the increase of the
cross-validated RMSE [um] of a gradient boosting regressor when the input is dropped, with
folds grouped by visit (or run).

The package, by concern: ``paths`` (physical paths from the effect records), ``design``
(strata, variance shares, confounding), ``strata`` (the effect model and its tests), ``sizes``
(effects and their intervals), ``verdicts``, ``prose`` (the physical readings),
``dropcolumn`` and ``explain`` (association and influence together).
"""

from models.influence.design import (
    CONFOUNDED_R,
    LEVEL_WORDS,
    LEVELS,
    Design,
    design_diagnostics,
    design_groups,
    group_mean,
    nested_labels,
    separating_test,
    variance_shares,
)
from models.influence.dropcolumn import dropcolumn_importance
from models.influence.explain import Explanation, explain
from models.influence.paths import LABELS, TARGET_DERIVED, WEAR, WEAR_READING, Path, effect_paths
from models.influence.prose import physical_reading
from models.influence.sizes import FEW_CELLS, effect_sizes
from models.influence.strata import (
    MAX_DEGREE,
    MIN_RESIDUAL_DF,
    MIN_SHARE,
    Stratum,
    StratumFit,
    choose_degrees,
    combine_strata,
    fit_stratum,
    legendre_basis,
    max_degree,
    partial_effect,
    partial_f,
    strata,
    stratum_tests,
)
from models.influence.verdicts import ALPHA, VERDICTS, Influence, conditional_influence

_nested = nested_labels  # the labels per level, by its earlier name

__all__ = [
    "ALPHA", "CONFOUNDED_R", "FEW_CELLS", "LABELS", "LEVELS", "LEVEL_WORDS", "MAX_DEGREE",
    "MIN_RESIDUAL_DF", "MIN_SHARE", "TARGET_DERIVED", "VERDICTS", "WEAR", "WEAR_READING",
    "Design", "Explanation", "Influence", "Path", "Stratum", "StratumFit", "choose_degrees",
    "combine_strata", "conditional_influence", "design_diagnostics", "design_groups",
    "dropcolumn_importance", "effect_paths", "effect_sizes", "explain", "fit_stratum",
    "group_mean", "legendre_basis", "max_degree", "nested_labels", "partial_effect",
    "partial_f", "physical_reading", "separating_test", "strata", "stratum_tests",
    "variance_shares",
]
