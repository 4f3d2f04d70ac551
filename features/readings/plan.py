"""Plan tables (docs/data-contract.md, section 5): the points and conditions of a visit not measured yet.

One row per point: ``target`` required; ``machine_id, axis, visit, repeat, feed_mm_min,
dwell_s, machine_temp_c, ambient_temp_c, pressure_hpa, humidity_pct, operating_hours,
started_at`` optional, in the units of the readings table. No deviations: a file with
``deviation_um`` or ``measured`` is a readings table (``is_plan`` tells them apart). Validated
by the readings' own rules (numbers finite and plausible, known axis names, whole repeats),
each error one line naming the file, row and column.
"""

from __future__ import annotations

from pathlib import Path

import pandas as pd

from features.readings import schema
from features.readings.errors import InputError
from features.readings.formats import read_table
from features.readings.io import check_readable
from features.readings.validation import (
    PLAUSIBLE,
    ROW,
    check_plausible,
    row_of,
    to_datetime,
    to_float,
    to_int,
    to_label,
)

LABELS = ("machine_id", "axis", "visit")
NUMBERS = ("feed_mm_min", "dwell_s", "machine_temp_c", "ambient_temp_c", "pressure_hpa",
           "humidity_pct", "operating_hours")
COLUMNS = ("target", *LABELS, "repeat", *NUMBERS, "started_at")
READINGS_ONLY = (schema.DEVIATION, schema.MEASURED, "method", "direction", "cycle")


def is_plan(path) -> bool:
    """A CSV/Parquet table with a ``target`` column and neither deviations nor measured
    positions nor test-cycle columns (method, direction, cycle) is a plan."""
    path = Path(path)
    if path.suffix.lower() not in (".csv", ".parquet") or not path.is_file():
        return False
    frame, _ = read_table(path)
    names = {str(c).strip().lower() for c in frame.columns if c != ROW}
    return "target" in names and not names & set(READINGS_ONLY)


def read_plan(path) -> pd.DataFrame:
    """The validated plan: ``COLUMNS`` that the file has, typed; other columns refused."""
    path = Path(path)
    check_readable(path)
    raw, row_base = read_table(path)
    rows = (raw.pop(ROW) if ROW in raw else
            pd.Series(range(row_base, row_base + len(raw)), index=raw.index))
    known = {c.lower(): c for c in COLUMNS}
    raw = raw.rename(columns={c: known.get(c.lower(), c) for c in raw.columns})
    doubled = raw.columns[raw.columns.duplicated()]
    if len(doubled):
        raise InputError("column given twice (names are case-insensitive)", file=path,
                         column=str(doubled[0]))
    for column in raw.columns:
        if column.lower() in READINGS_ONLY:
            raise InputError("a plan has no deviations or test cycles; this looks like a "
                             "readings table", file=path, column=column)
        if column not in COLUMNS:
            raise InputError(f"unknown plan column; expected {', '.join(COLUMNS)}", file=path,
                             column=column)
    plan = plan_points(raw, path, rows)
    keys = [c for c in ("machine_id", "axis", "visit", "repeat", "feed_mm_min", "dwell_s",
                        "target") if c in plan]
    doubled = plan.duplicated(keys, keep="first")
    if doubled.any():
        i = int(doubled.to_numpy().nonzero()[0][0])
        raise InputError(f"the same point twice (same {', '.join(keys)})", file=path,
                         row=row_of(rows, i), column="target")
    plan.attrs["source"] = str(path)
    return plan.reset_index(drop=True)


def plan_points(raw: pd.DataFrame, source, rows=1) -> pd.DataFrame:
    """The plan columns (``COLUMNS``) of ``raw`` typed and checked by the readings' rules
    (numbers finite and plausible, known axis names, whole repeats), other columns kept as
    they are; the first problem is one ``InputError`` naming ``source``, the row and the column.

    Parameters
    ----------
    raw : DataFrame
        Points: a plan's columns as text or numbers (a request to a served model, a plan
        built in code).
    source : str or Path
        What the error lines name (a file, ``request``).
    rows : Series or int
        File row of each point, or the row number of the first one (default 1: row N is the
        N-th point).
    """
    if "target" not in raw:
        raise InputError("missing column; a plan needs the target positions", file=source,
                         column="target")
    plan = pd.DataFrame(index=raw.index)
    plan["target"] = to_float(raw["target"], source, "target", rows)
    for column in LABELS:
        if column in raw:
            plan[column] = to_label(raw[column], source, column, rows)
    if "axis" in plan:
        bad = ~plan["axis"].isin((*schema.LINEAR_AXES, *schema.ROTARY_AXES))
        if bad.any():
            i = int(bad.to_numpy().nonzero()[0][0])
            raise InputError(f"unknown axis {plan['axis'].iloc[i]!r}; expected one of "
                             f"{', '.join((*schema.LINEAR_AXES, *schema.ROTARY_AXES))}",
                             file=source, row=row_of(rows, i), column="axis")
    if "repeat" in raw:
        plan["repeat"] = to_int(raw["repeat"], source, "repeat", rows)
    for column in NUMBERS:
        if column in raw:
            plan[column] = to_float(raw[column], source, column, rows, allow_nan=True)
            checked = plan[[column]].assign(**{ROW: rows if isinstance(rows, pd.Series) else
                                               range(rows, rows + len(plan))}).dropna()
            if column in PLAUSIBLE and not checked.empty:
                check_plausible(checked, column, source)
    if "started_at" in raw:
        plan["started_at"] = to_datetime(raw["started_at"], source, "started_at", rows)
    for column in raw.columns.difference(plan.columns, sort=False):
        plan[column] = raw[column]
    return plan
