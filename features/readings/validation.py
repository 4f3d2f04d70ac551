"""Validation of long readings frames: once, at the edge; everything downstream trusts them.

Every problem is an ``InputError`` naming file, row and column.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd

from features.readings import schema
from features.readings.errors import InputError, note

# Plausible ranges of condition columns; outside them a value is a unit mistake or a typo.
PLAUSIBLE = {
    "feed_mm_min": (0.0, 1e6, "a feed rate > 0 mm/min"),
    "dwell_s": (0.0, 3600.0, "a dwell time of 0-3600 s"),
    "machine_temp_c": (-30.0, 100.0, "a temperature in degC"),
    "ambient_temp_c": (-30.0, 60.0, "a temperature in degC"),
    "pressure_hpa": (500.0, 1200.0, "an air pressure in hPa (500-1200)"),
    "humidity_pct": (0.0, 100.0, "a relative humidity in % (0-100)"),
    "operating_hours": (0.0, 1e7, "operating hours >= 0"),
}
# File row of each reading, carried through validation (a name no input may use).
ROW = "__row__"
# Largest believable positioning deviation: beyond it `measured` is not in mm (deg).
MAX_DEVIATION_POS_UNITS = 1.0
# Below this everywhere in a test, deviation_um was almost surely written in mm.
MIN_PLAUSIBLE_MAX_DEVIATION_UM = 0.05


# --------------------------------------------------------------------------- reading


def looks_absolute(value: pd.Series, position: pd.Series) -> pd.Series:
    """A deviation cell holds an absolute position when it lies within 10 % of a target at
    least 1 mm from zero (real deviations are micrometres to tenths of a millimetre)."""
    return (position.abs() >= 1.0) & ((value - position).abs() < 0.1 * position.abs())


# --------------------------------------------------------------------------- validation


def validate(raw: pd.DataFrame, path: Path, row_base: int | None) -> pd.DataFrame:
    """Check and normalise a long readings frame; raise InputError on the first problem.

    ``row_base`` is the file row of the first data row (None when rows do not map to file
    rows one to one; then the frame carries a ``ROW`` column with file rows).
    """
    frame = raw.copy()
    if ROW not in frame:
        frame[ROW] = np.arange(len(frame)) + (row_base or 1)
    check_header([c for c in frame.columns if c != ROW], path)
    frame = _rename_case_insensitive(frame)
    missing = [c for c in schema.REQUIRED if c not in frame]
    if missing:
        given = [c for c in frame.columns if closest_column(c) == missing[0]]
        hint = f"; is {given[0]!r} meant to be it?" if given else ""
        raise InputError(f"missing required column {missing[0]!r} (required: "
                         f"{', '.join(schema.REQUIRED)}){hint}", file=path, row=1,
                         column=missing[0])
    if schema.DEVIATION not in frame and schema.MEASURED not in frame:
        raise InputError("missing column 'deviation_um' (or 'measured'): one of them is required",
                         file=path, row=1, column="deviation_um")

    for col in ("machine_id", "axis", "test_id"):
        frame[col] = to_label(frame[col], path, col, frame[ROW])
    frame["axis"] = frame["axis"].str.upper()
    _check_allowed(frame, "axis", schema.LINEAR_AXES + schema.ROTARY_AXES, path,
                   "an axis name X, Y, Z, A, B or C")
    frame["method"] = _map_labels(frame, "method", schema.METHOD_ALIASES, path,
                                  "'linear' or 'pendulum' (aliases lin, pend)")
    frame["direction"] = _map_labels(frame, "direction", schema.DIRECTION_ALIASES, path,
                                     "'+' or '-' (aliases fwd/up/1/+1, bwd/down/-1)")
    frame["target"] = to_float(frame["target"], path, "target", frame[ROW])
    frame["cycle"] = to_int(frame["cycle"], path, "cycle", frame[ROW])
    frame["visit"] = to_label(frame["visit"], path, "visit", frame[ROW]) if "visit" in frame else "1"
    frame["repeat"] = to_int(frame["repeat"], path, "repeat", frame[ROW]) \
        if "repeat" in frame else 1
    for col in schema.NUMERIC_OPTIONAL:
        if col in frame:
            frame[col] = to_float(frame[col], path, col, frame[ROW], allow_nan=True)
            check_plausible(frame, col, path)
    for col in schema.DATETIME_OPTIONAL:
        if col in frame:
            frame[col] = to_datetime(frame[col], path, col, frame[ROW])

    # Group by one integer code per test: grouping by the four label columns again and again
    # would hash every label string at every pass.
    test = pd.Series(frame.groupby(list(schema.TEST_KEYS), sort=False).ngroup().to_numpy(),
                     index=frame.index)
    frame["deviation_um"] = _deviation_um(frame, path, test)
    _check_structure(frame, path, test)
    ordered = [c for c in (*schema.REQUIRED, "deviation_um", "measured", *schema.OPTIONAL)
               if c in frame]
    extra = [c for c in frame.columns if c not in ordered and c != ROW]
    typos = [c for c in extra if closest_column(c) is not None]
    if typos:  # kept as given (convert passes them on), but nothing reads them as meant
        note(f"{path}: not in the readings contract, so no figure reads "
             f"{'them' if len(typos) > 1 else 'it'}: {unknown_columns_text(typos)}")
    out = frame[ordered + extra].reset_index(drop=True)
    out.attrs["source"] = str(path)
    for key in (schema.UNSTATED, schema.NAMED_BY):
        if raw.attrs.get(key):
            out.attrs[key] = raw.attrs[key]
    return out


# How alike (difflib's ratio) an unknown column must be to a contract column to be taken for
# a misspelling of it: machine_tmp_c -> machine_temp_c (0.96), humidity -> humidity_pct (0.8).
CLOSE_NAME = 0.8


def contract_columns() -> tuple[str, ...]:
    """Every column the readings contract names (required and optional)."""
    return (*schema.REQUIRED, schema.DEVIATION, schema.MEASURED, *schema.OPTIONAL)


def closest_column(name: str) -> str | None:
    """The contract column ``name`` is most probably a misspelling of, or None."""
    import difflib

    known = contract_columns()
    found = difflib.get_close_matches(str(name).strip().lower(), known, n=1, cutoff=CLOSE_NAME)
    return found[0] if found and found[0] != name else None


def unknown_columns_text(names: list[str]) -> str:
    """Columns outside the contract as a message names them, each with the contract column
    it is closest to: ``machine_tmp_c: did you mean machine_temp_c?``."""
    parts = []
    for name in names:
        close = closest_column(name)
        parts.append(f"{name}: did you mean {close}?" if close else str(name))
    return "; ".join(parts)


def check_header(names: list[str], path: Path) -> None:
    """Refuse column names that differ only in case or surrounding spaces (``target`` and
    ``Target``): which one holds the readings cannot be known."""
    seen: dict[str, str] = {}
    for name in names:
        key = str(name).strip().lower()
        if key == ROW:
            raise InputError(f"column name {ROW!r} is reserved; rename the column", file=path,
                             row=1, column=str(name))
        if key in seen:
            raise InputError(f"columns {seen[key]!r} and {name!r} differ only in case or "
                             "spaces; expected each column once", file=path, row=1,
                             column=str(name))
        seen[key] = str(name)


def _rename_case_insensitive(frame: pd.DataFrame) -> pd.DataFrame:
    known = {c.lower(): c for c in (*schema.REQUIRED, schema.DEVIATION, schema.MEASURED,
                                    *schema.OPTIONAL)}
    return frame.rename(columns={c: known[c.lower()] for c in frame.columns
                                 if c.lower() in known})


def _first_bad(mask: pd.Series) -> int:
    return int(np.flatnonzero(np.asarray(mask))[0])


def row_of(rows, index: int) -> int:
    return int(rows.iloc[index]) if isinstance(rows, pd.Series) else int(rows) + index


def to_label(series: pd.Series, path: Path, col: str, rows) -> pd.Series:
    labels = series.astype(str).str.strip()
    if pd.api.types.is_float_dtype(series):  # Parquet visit 1.0 means visit "1"
        labels = labels.str.removesuffix(".0")
    blank = labels.eq("") | series.isna()
    if blank.any():
        raise InputError(f"empty {col}; expected a name", file=path,
                         row=row_of(rows, _first_bad(blank)), column=col)
    # Control characters (a newline, a tab, NUL) would break every line and file name that
    # shows the label.
    control = labels.str.contains(r"[\x00-\x1f\x7f]", regex=True)
    if control.any():
        i = _first_bad(control)
        raise InputError(f"{col} {labels.iloc[i]!r} holds a control character; expected "
                         "printable text", file=path, row=row_of(rows, i), column=col)
    return labels


def to_float(series: pd.Series, path: Path, col: str, rows, allow_nan: bool = False):
    if pd.api.types.is_bool_dtype(series) or _holds_bools(series):
        i = _first_bad(series.map(lambda v: isinstance(v, (bool, np.bool_))))
        raise InputError(f"{bool(series.iloc[i])} is a boolean; expected a number", file=path,
                         row=row_of(rows, i), column=col)
    if pd.api.types.is_numeric_dtype(series):
        values = series.astype(float)
        bad_text = pd.Series(False, index=series.index)
    else:
        # Parse each distinct text once: a column holds far fewer values than rows.
        codes, distinct = _distinct(series)
        text = distinct.astype(str).str.strip()
        parsed = pd.to_numeric(text, errors="coerce")
        empty = text.eq("") | text.str.lower().isin(["nan", "na", "none"])
        bad_text = (parsed.isna() & ~empty).to_numpy()[codes]
        boolean = text.str.lower().isin(["true", "false"]).to_numpy()[codes]
        if boolean.any():
            i = _first_bad(boolean)
            raise InputError(f"{text.iloc[codes[i]]!r} is a boolean; expected a number",
                             file=path, row=row_of(rows, i), column=col)
        if bad_text.any():
            i = _first_bad(bad_text)
            raise InputError(f"{text.iloc[codes[i]]!r} is not a number", file=path,
                             row=row_of(rows, i), column=col)
        values = pd.Series(parsed.to_numpy(dtype=float, na_value=np.nan)[codes],
                           index=series.index, name=series.name)
    if not allow_nan and values.isna().any():
        i = _first_bad(values.isna())
        raise InputError("missing value (NaN); expected a number", file=path,
                         row=row_of(rows, i), column=col)
    inf = np.isinf(values)
    if inf.any():
        i = _first_bad(inf)
        raise InputError("infinite value; expected a finite number", file=path,
                         row=row_of(rows, i), column=col)
    return values.astype(float)


def _distinct(series: pd.Series) -> tuple[np.ndarray, pd.Series]:
    """Codes and distinct values of a text column, so that ``distinct.iloc[codes]`` is
    ``series`` (missing values kept as one distinct value).

    Only string-dtype columns are folded: in an object column ``1``, ``1.0`` and ``True`` would
    count as one value although their texts differ; there every row is its own value.
    """
    if isinstance(series.dtype, pd.StringDtype):
        codes, uniques = pd.factorize(series, use_na_sentinel=False)
        return codes, pd.Series(uniques, dtype=series.dtype, name=series.name)
    return np.arange(len(series)), series.reset_index(drop=True)


def _holds_bools(series: pd.Series) -> bool:
    """An object column (Parquet, a frame built in code) holding Python/numpy booleans."""
    return series.dtype == object and series.map(
        lambda v: isinstance(v, (bool, np.bool_))).any()


# Cycle and repeat indices beyond this are typos (and would overflow an int64 on the way).
MAX_INDEX = 1_000_000


def to_int(series, path, col, rows) -> pd.Series:
    """Whole numbers 1..MAX_INDEX; a fractional value is refused, never truncated."""
    values = to_float(series, path, col, rows)
    bad = (values != np.round(values)) | (values < 1) | (values > MAX_INDEX)
    if bad.any():
        i = _first_bad(bad)
        raise InputError(f"{values.iloc[i]:g} is not a whole number from 1 to {MAX_INDEX}",
                         file=path, row=row_of(rows, i), column=col)
    return values.astype(int)


def to_datetime(series, path, col, rows) -> pd.Series:
    # Parse each distinct text once, as ``to_float`` does: the readings of a test share its
    # start time, and a reading's time often repeats across tests.
    codes, distinct = _distinct(series)
    given = distinct.notna() & distinct.astype(str).str.strip().ne("")
    parsed = pd.to_datetime(distinct.where(given), errors="coerce", utc=True, format="ISO8601")
    bad = (parsed.isna() & given).to_numpy()[codes]
    if bad.any():
        i = _first_bad(bad)
        raise InputError(f"{series.iloc[i]!r} is not an ISO 8601 date-time", file=path,
                         row=row_of(rows, i), column=col)
    return pd.Series(parsed.array.take(codes), index=series.index, name=series.name)


def _map_labels(frame, col, aliases, path, expected) -> pd.Series:
    key = frame[col].astype(str).str.strip().str.lower()
    mapped = key.map(aliases)
    if mapped.isna().any():
        i = _first_bad(mapped.isna())
        raise InputError(f"unknown {col} {frame[col].iloc[i]!r}; expected {expected}",
                         file=path, row=row_of(frame[ROW], i), column=col)
    return mapped


def _check_allowed(frame, col, allowed, path, expected) -> None:
    bad = ~frame[col].isin(allowed)
    if bad.any():
        i = _first_bad(bad)
        raise InputError(f"unknown {col} {frame[col].iloc[i]!r}; expected {expected}",
                         file=path, row=row_of(frame[ROW], i), column=col)


def check_plausible(frame, col, path) -> None:
    low, high, expected = PLAUSIBLE[col]
    values = frame[col]
    bad = (values < low) | (values > high) | ((values == 0) & (col == "feed_mm_min"))
    if bad.any():
        i = _first_bad(bad)
        raise InputError(f"{values.iloc[i]:g} is not {expected}", file=path,
                         row=row_of(frame[ROW], i), column=col)


def _deviation_um(frame: pd.DataFrame, path: Path, test: pd.Series) -> pd.Series:
    """deviation_um in um (arcsec rotary), from ``measured`` when absent, unit-checked;
    ``test`` numbers the tests (one code per ``schema.TEST_KEYS``)."""
    scale = np.where(frame["axis"].isin(schema.ROTARY_AXES), 3600.0, 1000.0)
    measured = None
    if schema.MEASURED in frame:
        allow_nan = schema.DEVIATION in frame
        measured = to_float(frame["measured"], path, "measured", frame[ROW], allow_nan)
        off = (measured - frame["target"]).abs() > MAX_DEVIATION_POS_UNITS
        if off.any():
            i = _first_bad(off)
            raise InputError(
                f"measured {measured.iloc[i]:g} is {measured.iloc[i] - frame['target'].iloc[i]:+g} "
                "away from its target; expected a position in mm (deg) like the target",
                file=path, row=row_of(frame[ROW], i), column="measured")
        frame["measured"] = measured
    if schema.DEVIATION not in frame:
        return (measured - frame["target"]) * scale

    deviation = to_float(frame["deviation_um"], path, "deviation_um", frame[ROW],
                          allow_nan=measured is not None)
    if measured is not None:
        deviation = deviation.fillna((measured - frame["target"]) * scale)
        if deviation.isna().any():  # both cells empty: no reading at all, never a NaN kept
            i = _first_bad(deviation.isna())
            raise InputError("missing value: 'deviation_um' and 'measured' are both empty; "
                             "expected a number in one of them", file=path,
                             row=row_of(frame[ROW], i), column="deviation_um")
    # Absolute positions in mm: only when a whole test reads like positions, so that a real
    # deviation of, say, 15 um at the 15 mm target is never mistaken for one. Such a test is
    # converted as a whole: its readings near target 0 (where a position in mm and a
    # deviation in mm look alike) are in mm too and get the same conversion.
    near_zero = frame["target"].abs() < 1.0
    looks = looks_absolute(deviation, frame["target"]) | (
        near_zero & ((deviation - frame["target"]).abs() < MAX_DEVIATION_POS_UNITS))
    absolute = (looks.groupby(test, sort=False).transform("all")
                & (~near_zero).groupby(test, sort=False).transform("any"))
    # Every reading at a target reading like a position while the test is not all positions:
    # deviations and positions are mixed (e.g. um at target 0, mm elsewhere); refuse.
    whole_target = looks.groupby([test, frame["target"]], sort=False).transform("all")
    mixed = whole_target & ~near_zero & ~absolute
    if mixed.any():
        i = _first_bad(mixed)
        raise InputError(
            f"the readings at target {frame['target'].iloc[i]:g} hold absolute positions in mm "
            f"while other readings of test {frame['test_id'].iloc[i]!r} hold deviations; "
            "expected one or the other in a test", file=path, row=row_of(frame[ROW], i),
            column="deviation_um")
    if absolute.any():
        note(f"{path}: {int(absolute.sum())} deviation_um values hold absolute positions in mm; "
             "converted to deviations ((value - target) x 1000)")
        deviation = deviation.where(~absolute, (deviation - frame["target"]) * scale)
    too_large = deviation.abs() > MAX_DEVIATION_POS_UNITS * scale
    if too_large.any():
        i = _first_bad(too_large)
        raise InputError(
            f"deviation {deviation.iloc[i]:g} is beyond {MAX_DEVIATION_POS_UNITS:g} mm (deg); "
            "expected a deviation in um (arcsec), positions belong in 'measured'", file=path,
            row=row_of(frame[ROW], i), column="deviation_um")
    _check_deviation_units(frame.assign(deviation_um=deviation), path, measured, scale, test)
    return deviation


def _others_scatter(values: pd.Series, groups) -> pd.Series:
    """Per value, the standard deviation of the other values of its group (0 where fewer than
    two others): s^2 = (S2 - x^2 - (n - 1) m^2) / (n - 2), m = (S1 - x) / (n - 1)."""
    n = groups.transform("size").to_numpy(float)
    s1 = groups.transform("sum").to_numpy(float)
    s2 = (values ** 2).groupby(groups.ngroup(), sort=False).transform("sum").to_numpy(float)
    x = values.to_numpy(float)
    with np.errstate(divide="ignore", invalid="ignore"):
        mean = (s1 - x) / (n - 1)
        var = (s2 - x ** 2 - (n - 1) * mean ** 2) / (n - 2)
    return pd.Series(np.sqrt(np.clip(np.where(n > 2, var, 0.0), 0.0, None)), index=values.index)


def _check_deviation_units(frame, path, measured, scale, test) -> None:
    """Refuse deviations that look like millimetres in a micrometre column."""
    dev = frame["deviation_um"]
    if measured is not None:
        expected = (measured - frame["target"]) * scale
        as_mm = ((dev - expected / scale).abs() < 1e-9) & (expected.abs() > 0.05)
        if as_mm.any():
            i = _first_bad(as_mm)
            raise InputError("deviation_um equals measured - target in mm; expected um "
                             "(x1000)", file=path, row=row_of(frame[ROW], i),
                             column="deviation_um")
        # Both columns given: they must tell the same reading (rounding aside), or which
        # one is right cannot be known.
        differs = (dev - expected).abs() > np.maximum(0.5, 0.01 * expected.abs())
        if differs.any():
            i = _first_bad(differs)
            raise InputError(
                f"deviation_um {dev.iloc[i]:g} disagrees with measured - target = "
                f"{expected.iloc[i]:g}; expected the same reading in both columns (or only one "
                "of them)", file=path, row=row_of(frame[ROW], i), column="deviation_um")
    # A reading 1000x (3600x rotary) smaller than its siblings at the same target and
    # direction: mm among um (deg among arcsec), unless the siblings scatter so much that a
    # reading near 0 is just noise.
    groups = dev.groupby([test, frame["target"], frame["direction"]], sort=False)
    # The median of a pair is its mean, which one mm value drags halfway: use the other one.
    pair = groups.transform("size") == 2
    sibling = groups.transform("median").where(~pair, groups.transform("sum") - dev)
    mm_like = ((sibling.abs() >= 0.5) & (dev.abs() < sibling.abs() / 100)
               & ((dev * scale - sibling).abs() < 0.3 * sibling.abs())
               & ((sibling - dev).abs() > 4 * _others_scatter(dev, groups)))
    if mm_like.any():
        i = _first_bad(mm_like)
        unit, small = (("arcsec", "deg") if scale[i] == 3600.0 else ("um", "mm"))
        raise InputError(
            f"mixed units: {dev.iloc[i]:g} looks like {small} while the other readings at "
            f"this target are about {sibling.iloc[i]:.3g} {unit}", file=path,
            row=row_of(frame[ROW], i), column="deviation_um")
    largest = dev.abs().groupby(test, sort=False).transform("max")
    tiny = largest < MIN_PLAUSIBLE_MAX_DEVIATION_UM
    if tiny.any() and measured is None:
        i = _first_bad(tiny)
        raise InputError(
            f"every |deviation_um| of test {frame['test_id'].iloc[i]!r} is below "
            f"{MIN_PLAUSIBLE_MAX_DEVIATION_UM} um: the values look like mm; expected um "
            "(or give the 'measured' column)", file=path, row=row_of(frame[ROW], i),
            column="deviation_um")


def _check_structure(frame: pd.DataFrame, path: Path, test: pd.Series) -> None:
    """ISO 230-2 structure: one method per test, no duplicate readings, both directions at
    every target, at least two cycles (s needs n-1 >= 1); ``test`` numbers the tests."""
    methods = frame["method"].groupby(test, sort=False).transform("nunique")
    if (methods > 1).any():
        i = _first_bad(methods > 1)
        raise InputError(f"test {frame['test_id'].iloc[i]!r} mixes linear and pendulum "
                         "readings; expected one method per test_id", file=path,
                         row=row_of(frame[ROW], i), column="method")
    reading = pd.DataFrame({"test": test, "target": frame["target"],
                            "direction": frame["direction"], "cycle": frame["cycle"]})
    dup = reading.duplicated(keep="first")
    if dup.any():
        i = _first_bad(dup)
        raise InputError("duplicate reading: same test, target, direction and cycle as an "
                         "earlier row", file=path, row=row_of(frame[ROW], i), column="cycle")
    dirs = frame["direction"].groupby([test, frame["target"]], sort=False).transform("nunique")
    if (dirs < 2).any():
        i = _first_bad(dirs < 2)
        raise InputError(f"target {frame['target'].iloc[i]:g} of test "
                         f"{frame['test_id'].iloc[i]!r} is measured in direction "
                         f"{frame['direction'].iloc[i]!r} only; expected both + and -",
                         file=path, row=row_of(frame[ROW], i), column="direction")
    cycles = frame["cycle"].groupby([test, frame["target"], frame["direction"]],
                                    sort=False).transform("size")
    if (cycles < 2).any():
        i = _first_bad(cycles < 2)
        raise InputError(f"target {frame['target'].iloc[i]:g} direction "
                         f"{frame['direction'].iloc[i]!r} of test {frame['test_id'].iloc[i]!r} "
                         "has 1 reading; expected at least 2 cycles", file=path,
                         row=row_of(frame[ROW], i), column="cycle")


def finite_number(text: str, path, row: int, what: str) -> float:
    """``text`` as a finite float; otherwise one ``InputError`` naming ``what`` and the row."""
    try:
        value = float(text)
    except ValueError:
        raise InputError(f"{what}: {text!r} is not a number", file=path, row=row) from None
    if not np.isfinite(value):
        raise InputError(f"{what}: {text!r} is not a finite number", file=path, row=row)
    return value


# Every column ``validate`` guarantees; ``check_readings`` checks these unless told fewer.
CONTRACT = (*schema.REQUIRED, schema.DEVIATION, "visit", "repeat")


def _holds_text(series: pd.Series) -> bool:
    """Every value is a string (categories of strings, as the twin writes names, count)."""
    if isinstance(series.dtype, pd.CategoricalDtype):
        return (pd.api.types.infer_dtype(series.cat.categories, skipna=False) == "string"
                and not series.isna().any())
    return pd.api.types.infer_dtype(series, skipna=False) == "string"


def check_readings(frame, parameter: str = "readings",
                   columns: tuple[str, ...] = CONTRACT) -> pd.DataFrame:
    """Check that ``frame`` is a readings frame as ``validate`` returns it; return it.

    A library caller may pass a frame it built or changed by hand; a frame that breaks the
    contract (a missing column, labels that are not text, a NaN deviation) would give figures
    named after column headers or NaN, so it is refused here, naming ``parameter``. The check
    is vectorised: cheap next to the figures it guards.

    Parameters
    ----------
    frame : DataFrame
        The frame to check.
    parameter : str
        The caller's parameter that passed it (named in the error).
    columns : tuple of str
        The contract's columns the caller needs (default all of them); only these must be
        present and are checked.

    Raises
    ------
    TypeError
        ``frame`` is not a pandas DataFrame.
    InputError
        ``frame`` breaks the readings contract (``.parameter`` is ``parameter``).
    """
    if not isinstance(frame, pd.DataFrame):
        raise TypeError(f"{parameter} must be a readings DataFrame (from read) or a file path; "
                        f"got {type(frame).__name__}")
    hint = "read it with read() or check it with validate() first"
    missing = [c for c in columns if c not in frame.columns]
    if missing:
        raise InputError(f"not a validated readings frame: no column {missing[0]!r}; {hint}",
                         parameter=parameter)
    if len(frame) == 0:
        raise InputError("holds no readings; expected at least one test", parameter=parameter)
    for col in ("machine_id", "axis", "test_id", "visit"):
        if col in columns and not _holds_text(frame[col]):
            raise InputError(f"not a validated readings frame: column {col!r} holds values "
                             f"that are not text; {hint}", parameter=parameter)
    for col in schema.DATETIME_OPTIONAL:
        if col in frame.columns and not pd.api.types.is_datetime64_any_dtype(frame[col]):
            raise InputError(f"not a validated readings frame: column {col!r} holds "
                             f"{frame[col].dtype} values, not dates; {hint}",
                             parameter=parameter)
    checks = {}
    for col, allowed in (("method", schema.METHODS), ("direction", schema.DIRECTIONS)):
        if col in columns:
            checks[col] = ~frame[col].isin(allowed)
    for col in ("target", schema.DEVIATION, "cycle", "repeat"):
        if col in columns:
            values = pd.to_numeric(frame[col], errors="coerce").to_numpy(dtype=float)
            checks[col] = pd.Series(~np.isfinite(values), index=frame.index)
    for col, bad in checks.items():
        if bad.any():
            i = _first_bad(bad)
            value = frame[col].iloc[i]
            value = value.item() if isinstance(value, np.generic) else value
            raise InputError(f"not a validated readings frame: row {frame.index[i]!r} has "
                             f"{col} {value!r}, outside the readings contract; "
                             f"{hint}", parameter=parameter)
    return frame
