"""Backlash per maintenance visit: the series that drift monitoring follows.

One series per machine and axis, one value per visit:

- ``backlash_um = |mean_tests(B_mean)|`` with ``B_mean`` the mean signed reversal value of a
  test (ISO 230-2, ``features.iso230.axis_figures``); ``B_um`` (mean of the tests' B = max|B_i|)
  is carried alongside.
- ``u_um``: repeatability uncertainty of a reversal value, ``s_B = sqrt(s_up²/n_up +
  s_down²/n_down)`` per target, averaged over the targets and tests of the visit.

Time is counted in months of 30.4375 days (``DAYS_PER_MONTH``) since the first visit.
"""

from __future__ import annotations

import numpy as np
import pandas as pd

from features.readings.errors import InputError

DAYS_PER_MONTH = 30.4375
# Tests of one visit may span a few days (several shifts); more means two visits share an id.
MAX_VISIT_SPAN_DAYS = 14.0
SERIES_KEYS = ("machine_id", "axis")


def visit_backlash(readings: pd.DataFrame) -> pd.DataFrame:
    """Backlash per machine, axis and visit with its repeatability uncertainty.

    Parameters
    ----------
    readings : validated readings table with ``visit`` and ``started_at``

    Returns
    -------
    DataFrame, one row per (machine_id, axis, visit) sorted by date: ``date`` (earliest
    ``started_at``, UTC), ``n_tests``, ``B_um`` (mean of B = max|B_i|) [um],
    ``B_mean_um`` (mean signed B_i) [um], ``backlash_um = |B_mean_um|`` [um] and
    ``u_um`` (mean of sqrt(s_up²/n_up + s_down²/n_down)) [um].
    """
    from features import iso230

    source = readings.attrs.get("source", "readings")
    check_dates(readings, source)
    targets = iso230.per_target(readings)
    figures = iso230.axis_figures(readings, targets)
    keys = [*SERIES_KEYS, "visit"]
    s_b = np.sqrt(targets["s_up"] ** 2 / targets["n_up"]
                  + targets["s_down"] ** 2 / targets["n_down"])
    u = targets.assign(u_um=s_b).groupby(keys, sort=False)["u_um"].mean()
    dates = readings.groupby(keys, sort=False, observed=True)["started_at"].min()
    per_visit = figures.groupby(keys, sort=False).agg(
        n_tests=("test_id", "size"), B_um=("B", "mean"), B_mean_um=("B_mean", "mean"))
    table = per_visit.join(u).join(dates.rename("date")).reset_index()
    table["backlash_um"] = table["B_mean_um"].abs()
    table = table.sort_values([*SERIES_KEYS, "date"], kind="stable").reset_index(drop=True)
    check_visits(table, source)
    return table[[*keys, "date", "n_tests", "B_um", "B_mean_um", "backlash_um", "u_um"]]


def check_dates(readings: pd.DataFrame, source: str = "readings") -> None:
    """Every test needs a ``started_at`` date, and one visit may not span weeks."""
    if "started_at" not in readings.columns:
        raise InputError("drift needs visit dates: no column 'started_at'", file=source,
                         column="started_at")
    missing = readings["started_at"].isna().to_numpy()
    if missing.any():
        i = int(np.argmax(missing))
        raise InputError("drift needs a date on every test: 'started_at' is empty "
                         f"(visit {readings['visit'].iloc[i]!r}, test "
                         f"{readings['test_id'].iloc[i]!r})", file=source, column="started_at")
    span = readings.groupby([*SERIES_KEYS, "visit"], observed=True)["started_at"].agg(
        ["min", "max"])
    days = (span["max"] - span["min"]).dt.total_seconds() / 86400.0
    if (days > MAX_VISIT_SPAN_DAYS).any():
        (machine, axis, visit), d = next(iter(days[days > MAX_VISIT_SPAN_DAYS].items()))
        raise InputError(f"visit {visit!r} of {machine} axis {axis} has tests {d:.0f} days "
                         f"apart (at most {MAX_VISIT_SPAN_DAYS:.0f}): one visit id used for "
                         "two visits? give each visit its own id", file=source, column="visit")


def check_visits(table: pd.DataFrame, source: str = "readings") -> None:
    """Two visit ids starting at the same instant are one visit entered twice."""
    dup = table.duplicated([*SERIES_KEYS, "date"], keep=False)
    if dup.any():
        rows = table[dup]
        machine, axis, date = rows.iloc[0][["machine_id", "axis", "date"]]
        same = rows[(rows["machine_id"] == machine) & (rows["axis"] == axis)
                    & (rows["date"] == date)]["visit"].tolist()
        raise InputError(f"visits {', '.join(map(repr, same))} of {machine} axis {axis} both "
                         f"start at {date.isoformat()}: the same visit entered twice?",
                         file=source, column="visit")
    counts = table.groupby(list(SERIES_KEYS)).size()
    if (counts < 2).all():
        machine, axis = counts.index[0]
        raise InputError(f"drift needs at least two visits per machine and axis; {machine} "
                         f"axis {axis} has {int(counts.iloc[0])}", file=source, column="visit")


def months_between(dates: pd.Series, origin) -> np.ndarray:
    """Elapsed time [month of 30.4375 d] from ``origin`` to each date."""
    return ((pd.to_datetime(dates) - origin).dt.total_seconds() / 86400.0
            / DAYS_PER_MONTH).to_numpy(float)


