"""Which measuring system the readings come from, decided from their own evidence.

In a linear ISO 230-2 test only the first target of the + pass and the last target of the -
pass follow a reversal. A direct measuring system (a linear scale closes the position loop on
the table) hides the lost motion everywhere else, so the reversal values B_i at the interior
targets hold no lost motion; an indirect one (a rotary encoder on the motor) shows it at every
target. A clearance b >= 0 makes B_i = -b at every interior target, one sign along the axis;
a direction-dependent error that changes sign along the axis (``reversal_profile``) averages
out and is seen by either system.

The test: a one-sample t-test of the interior reversal values of the linear tests (one value
per test and interior target, the mean over its cycles, ISO 230-2's B_i) against zero: indirect
when it rejects zero at ``SYSTEM_P``. When the readings also hold pendulum tests, every reading
of which follows a reversal, the indirect system predicts the pendulum's reversal values at
the interior targets of the linear tests and the direct one predicts zero there: a Welch
t-test against the pendulum's values is the second test, and the system is the one whose
prediction the interior values contradict less (the smaller |t|). A direction-dependent error
that is not lost motion (settling against the approach) shows in both kinds of test and
cancels from the comparison.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np
import pandas as pd

from features import iso230
from features.readings import schema

SYSTEM_P = 0.01   # interior reversal values this unlikely under "no lost motion": indirect


class SystemTest(NamedTuple):
    """The measuring-system decision and its test.

    ``system`` is 'indirect', 'direct', or None when the readings hold no linear test with at
    least two interior reversal values (the decision then falls to the baseline's fit)."""

    system: str | None
    statistic: float      # t of the mean interior reversal value against zero
    p_value: float        # two-sided
    mean_um: float        # mean interior reversal value B_i [um]
    n: int                # interior reversal values (tests x interior targets)
    pendulum_statistic: float = math.nan   # Welch t against the pendulum's reversal values
    pendulum_p_value: float = math.nan
    pendulum_mean_um: float = math.nan
    unit: str = "um"      # of the reversal values: arcsec on a rotary axis

    def to_dict(self) -> dict:
        out = {"system": self.system, "test": "t-test of the mean interior reversal value "
               "of the linear tests against zero", "statistic": self.statistic,
               "p_value": self.p_value, "mean_um": self.mean_um, "n": self.n}
        if math.isfinite(self.pendulum_mean_um):
            out.update(pendulum_test="Welch t-test of the interior reversal values against "
                       "the pendulum tests' reversal values",
                       pendulum_statistic=self.pendulum_statistic,
                       pendulum_p_value=self.pendulum_p_value,
                       pendulum_mean_um=self.pendulum_mean_um)
        return out

    def note(self) -> str:
        """One sentence: the decision and its evidence."""
        evidence = (f"mean interior reversal value {self.mean_um:.3g} {self.unit} over {self.n} "
                    f"target(s) of the linear tests, t = {self.statistic:.3g}, "
                    f"p = {self.p_value:.2g} against zero")
        if math.isfinite(self.pendulum_mean_um):
            evidence += (f"; t = {self.pendulum_statistic:.3g}, p = "
                         f"{self.pendulum_p_value:.2g} against the pendulum tests' "
                         f"{self.pendulum_mean_um:.3g} {self.unit}")
        if self.system == "indirect":
            return ("lost motion shows at the interior targets of the linear tests: indirect "
                    f"measuring system (rotary encoder) ({evidence})")
        return ("no lost motion at the interior targets of the linear tests, only where a "
                f"reversal precedes the reading: direct measuring system (linear scale) "
                f"({evidence})")


def reversal_values(readings: pd.DataFrame) -> tuple[np.ndarray, np.ndarray]:
    """ISO 230-2 reversal values B_i [um] of the linear tests at their interior targets (not
    the first or last target of a test, where the pass turns round), and of the pendulum tests
    at every target."""
    targets = iso230.per_target(readings)
    linear = targets[targets["method"] == "linear"]
    by_test = linear.groupby("test_id")["target"]
    interior = ((linear["target"] > by_test.transform("min"))
                & (linear["target"] < by_test.transform("max")))
    pendulum = targets.loc[targets["method"] == "pendulum", "B_i"]
    return (linear.loc[interior, "B_i"].dropna().to_numpy(float),
            pendulum.dropna().to_numpy(float))


def _t_test(a: np.ndarray, b: np.ndarray | None = None) -> tuple[float, float]:
    """Two-sided t-test of mean(a) against zero, or Welch's of mean(a) against mean(b):
    (t, p); values without scatter give t = +-inf and p = 0 unless the means agree."""
    from scipy.stats import ttest_1samp, ttest_ind

    diff = float(a.mean() - (0.0 if b is None else b.mean()))
    scatter = float(a.std()) + (0.0 if b is None else float(b.std()))
    if scatter <= 1e-12 * max(abs(diff), 1.0):
        return (math.copysign(math.inf, diff), 0.0) if abs(diff) > 1e-12 else (0.0, 1.0)
    found = ttest_1samp(a, 0.0) if b is None else ttest_ind(a, b, equal_var=False)
    return float(found.statistic), float(found.pvalue)


def measuring_system(readings: pd.DataFrame) -> SystemTest:
    """Decide the measuring system from the interior reversal values (module docstring).

    Parameters
    ----------
    readings : DataFrame
        Validated readings (the outliers the ISO step flags already left out).

    Returns
    -------
    SystemTest
        Without pendulum tests 'indirect' when the mean interior reversal value differs from
        zero at ``SYSTEM_P`` (two-sided one-sample t-test, n - 1 degrees of freedom), else
        'direct'; with them, the system whose prediction (zero, or the pendulum's values)
        the interior values contradict less.
    """
    interior, pendulum = reversal_values(readings)
    n, unit = len(interior), schema.unit_of(readings["axis"])
    if n < 2:
        return SystemTest(None, math.nan, math.nan, math.nan, n, unit=unit)
    stat, p = _t_test(interior)
    if len(pendulum) < 2:
        return SystemTest("indirect" if p < SYSTEM_P else "direct", stat, p,
                          float(interior.mean()), n, unit=unit)
    stat_p, p_p = _t_test(interior, pendulum)
    system = "indirect" if abs(stat) > abs(stat_p) else "direct"
    return SystemTest(system, stat, p, float(interior.mean()), n, stat_p, p_p,
                      float(pendulum.mean()), unit)
