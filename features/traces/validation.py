"""Validation of a trace table (docs/data-contract.md section 10), once at the edge.

Refused, each with one line naming the file, the row and the column: a required channel
missing (as a column, or as an empty value), a column named after a channel in a unit the
contract does not know (``load_um``), a time that is no date-time, a time going back within a
machine axis, an unknown axis, a value that is no finite number, a machine axis's time given
twice with different values. The same sample written twice (same machine axis, time and
values) is dropped, with a note saying how many. Label columns are checked per
distinct value and numeric columns as whole arrays, so validating costs little beside reading.
"""

from __future__ import annotations

import numpy as np
import pandas as pd

from features.readings.errors import InputError, note
from features.readings.schema import LINEAR_AXES, ROTARY_AXES, is_rotary
from features.readings.validation import to_datetime, to_float, to_label
from features.traces import contract as c


def check_trace(frame: pd.DataFrame, source, row_base: int = 2) -> pd.DataFrame:
    """The validated trace frame (module docstring), in the input's row order.

    Parameters
    ----------
    frame : DataFrame
        The table as read: the contract's columns (names case-insensitive), others kept.
    source : str or path
        Named in errors (the file, or the caller's parameter for a frame).
    row_base : int
        The row number of the first data row (2 for CSV below its header, 1 for Parquet).

    Raises
    ------
    InputError
        Naming the first problem (module docstring).
    """
    if frame.empty:
        raise InputError("no samples: the trace has a header but no data rows", file=source)
    frame = _named(frame, source)
    out = {}
    for col in ("machine_id", "axis"):
        out[col] = _labels(frame[col], source, col, row_base)
    axes = out["axis"].cat.categories
    unknown = [a for a in axes if a not in (*LINEAR_AXES, *ROTARY_AXES)]
    if unknown:
        i = int(np.flatnonzero(out["axis"].astype(str).to_numpy() == unknown[0])[0])
        raise InputError(f"unknown axis {unknown[0]!r}; expected one of X, Y, Z, A, B, C",
                         file=source, row=row_base + i, column="axis")
    out[c.TIME] = _times(frame[c.TIME], source, row_base)
    for col in c.CHANNELS:
        if col in frame:
            out[col] = _channel(frame[col], source, col, row_base, col in c.OPTIONAL)
    _check_deg_names(frame, out["axis"], source, row_base)
    checked = pd.DataFrame(out, columns=[k for k in c.COLUMNS if k in out], copy=False)
    _check_order(checked, source, row_base)
    return _without_repeats(checked, source, row_base)


def _named(frame: pd.DataFrame, source) -> pd.DataFrame:
    """The contract's columns under their own names: case-insensitive, ``_deg`` for a rotary
    axis's positions; refuses unknown units and missing required columns."""
    renames, seen = {}, {}
    for name in frame.columns:
        key = str(name).strip().lower()
        stem, _, unit = key.rpartition("_")
        if key in c.COLUMNS:
            renames[name] = key
        elif stem in c.UNITS and unit == c.ROTARY_ALIAS and c.UNITS[stem] == "mm":
            renames[name] = f"{stem}_mm"
            seen[f"{stem}_mm"] = str(name)
        elif stem in c.UNITS:
            raise InputError(f"unknown unit {unit!r}; the trace contract names this channel "
                             f"{stem}_{c.UNITS[stem]}" + (" (deg on a rotary axis)"
                                                         if c.UNITS[stem] == "mm" else ""),
                             file=source, column=str(name))
    frame = frame.rename(columns=renames)
    if frame.columns.duplicated().any():
        twice = frame.columns[frame.columns.duplicated()][0]
        raise InputError(f"column {twice!r} given twice", file=source, column=twice)
    missing = [col for col in c.REQUIRED if col not in frame]
    if missing:
        raise InputError(f"missing column {missing[0]!r}; a trace needs "
                         f"{', '.join(c.REQUIRED)}", file=source)
    frame.attrs["deg_names"] = seen
    return frame


def _labels(series: pd.Series, source, col: str, row_base: int) -> pd.Series:
    """A label column as a categorical, each distinct value checked once (``to_label``)."""
    codes = series.array.codes if isinstance(series.dtype, pd.CategoricalDtype) \
        else None
    if codes is not None and codes.min() >= 0:  # no missing label (code -1)
        uniques = series.cat.categories.to_numpy(object)
    else:
        codes, uniques = pd.factorize(series, use_na_sentinel=False)
    present, first = _first_rows(np.asarray(codes))  # a dictionary may hold unused values
    if len(present) < len(uniques):
        codes = np.searchsorted(present, codes)
    labels = to_label(pd.Series(np.asarray(uniques, object)[present], dtype=object), source, col,
                      pd.Series(first + row_base))
    if col == "axis":
        labels = labels.str.upper()
    codes, categories = _recoded(codes, labels.to_numpy())
    # the codes index the categories by construction: no second pass to check them
    return pd.Series(pd.Categorical.from_codes(codes, categories, validate=False))


def _first_rows(codes: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The distinct codes, sorted, and the row where each first occurs: found among the starts
    of the runs of equal codes (a label repeats over long runs), without sorting every row."""
    starts = np.r_[0, np.flatnonzero(codes[1:] != codes[:-1]) + 1] if len(codes) \
        else np.zeros(0, int)
    present, at = np.unique(codes[starts], return_index=True)
    return present, starts[at]


def _recoded(codes: np.ndarray, labels: np.ndarray):
    """Codes and categories with equal labels (``x`` and ``X``) merged."""
    categories, inverse = np.unique(labels.astype(str), return_inverse=True)
    if (inverse == np.arange(len(inverse))).all():  # already distinct and sorted
        return np.asarray(codes), categories
    return inverse[codes], categories


def _times(series: pd.Series, source, row_base: int) -> np.ndarray:
    """Sample times as UTC datetimes; a number is refused (its unit and epoch are unknown)."""
    if pd.api.types.is_datetime64_any_dtype(series):
        times = pd.Series(series)
        times = (times.dt.tz_localize("UTC") if times.dt.tz is None
                 else times.dt.tz_convert("UTC"))
    elif pd.api.types.is_numeric_dtype(series):
        raise InputError(f"{series.iloc[0]!r} is a number of unknown unit and epoch; expected "
                         "an ISO 8601 date-time (UTC)", file=source, row=row_base,
                         column=c.TIME)
    else:
        times = to_datetime(series.reset_index(drop=True), source, c.TIME,
                            pd.Series(np.arange(len(series)) + row_base))
    out = times.to_numpy(dtype="datetime64[ns]")
    missing = np.isnat(out)
    if missing.any():
        raise InputError("missing value; expected an ISO 8601 date-time (UTC)", file=source,
                         row=row_base + int(np.flatnonzero(missing)[0]), column=c.TIME)
    return out


def _channel(series: pd.Series, source, col: str, row_base: int, optional: bool) -> np.ndarray:
    """A channel as float64: one pass when it is already all finite numbers, else
    ``to_float``, whose messages name the first bad row."""
    if pd.api.types.is_float_dtype(series.dtype) or pd.api.types.is_integer_dtype(series.dtype):
        values = series.to_numpy(dtype=float, na_value=np.nan)
        # a NaN or an infinity makes the sum one; a finite sum is all finite numbers (only
        # values near 1e308 overflow it, and then the samples are checked one by one)
        if np.isfinite(values.sum()) or np.isfinite(values).all():
            return values
    return to_float(series.reset_index(drop=True), source, col, row_base,
                    allow_nan=optional).to_numpy()


def _check_deg_names(frame: pd.DataFrame, axis: pd.Series, source, row_base: int) -> None:
    """Positions named in deg belong to rotary axes only."""
    for col, given in frame.attrs.get("deg_names", {}).items():
        linear = ~axis.map(is_rotary).astype(bool).to_numpy()
        if linear.any():
            raise InputError(f"positions in deg on linear axis {axis.iloc[int(np.argmax(linear))]}"
                             f"; expected {col} (mm)", file=source,
                             row=row_base + int(np.argmax(linear)), column=given)


def _check_order(frame: pd.DataFrame, source, row_base: int) -> None:
    """Time never goes back within a machine axis (rows of other axes may interleave)."""
    machine = frame["machine_id"].array.codes
    axis = frame["axis"].array.codes
    t = frame[c.TIME].to_numpy().view(np.int64)
    step = (machine[1:] != machine[:-1]) | (axis[1:] != axis[:-1])
    starts = np.r_[0, np.flatnonzero(step) + 1]
    pairs = machine[starts].astype(np.int64) * 64 + axis[starts]
    if len(pairs) == len(np.unique(pairs)):  # each axis in one block: no sort
        back = t[1:] < t[:-1]
        back &= ~step
        rows = np.flatnonzero(back) + 1
    else:
        group = machine.astype(np.int64) * 64 + axis
        order = np.argsort(group, kind="stable")
        g, ts = group[order], t[order]
        back = np.flatnonzero((np.diff(ts) < 0) & (g[1:] == g[:-1]))
        rows = order[back + 1]
    if len(rows):
        i = int(rows.min())
        raise InputError(f"time goes back ({pd.Timestamp(t[i], tz='UTC').isoformat()} after a "
                         f"later sample of {frame['machine_id'].iloc[i]} {frame['axis'].iloc[i]})"
                         "; expected samples sorted by time within a machine axis",
                         file=source, row=row_base + i, column=c.TIME)


def _without_repeats(frame: pd.DataFrame, source, row_base: int) -> pd.DataFrame:
    """The frame without samples repeated (a logger writing a sample twice, two exports
    joined with an overlap); refused when a repeated time holds other values, since which one
    the axis had cannot be known."""
    earlier, later = _repeated_times(frame)
    if not len(later):
        return frame
    for col in (k for k in c.CHANNELS if k in frame):
        a, b = frame[col].to_numpy()[earlier], frame[col].to_numpy()[later]
        differ = np.flatnonzero((a != b) & ~(np.isnan(a) & np.isnan(b)))
        if len(differ):
            i, j = int(earlier[differ[0]]), int(later[differ[0]])
            when = pd.Timestamp(frame[c.TIME].to_numpy()[j], tz="UTC").isoformat()
            raise InputError(f"{frame['machine_id'].iloc[j]} {frame['axis'].iloc[j]} at {when} "
                             f"is given twice with different values ({a[differ[0]]!r} in row "
                             f"{row_base + i}, {b[differ[0]]!r} here); expected one sample "
                             "per time", file=source, row=row_base + j, column=col)
    note(f"{source}: {len(later)} repeated sample(s) (same machine axis, time and values) "
         "dropped")
    keep = np.ones(len(frame), bool)
    keep[later] = False
    return frame[keep].reset_index(drop=True)


def _repeated_times(frame: pd.DataFrame) -> tuple[np.ndarray, np.ndarray]:
    """Row pairs (earlier, later) of one machine axis at the same time; the times are in
    order within each machine axis (``_check_order``), so repeats are neighbours there."""
    machine = frame["machine_id"].array.codes.astype(np.int64)
    group = machine * 64 + frame["axis"].array.codes
    t = frame[c.TIME].to_numpy().view(np.int64)
    step = group[1:] != group[:-1]
    starts = np.r_[0, np.flatnonzero(step) + 1]
    if len(starts) == len(np.unique(group[starts])):  # each machine axis in one block
        hit = np.flatnonzero((t[1:] == t[:-1]) & ~step)
        return hit, hit + 1
    order = np.argsort(group, kind="stable")  # axes interleaved: their rows put together
    hit = np.flatnonzero((np.diff(t[order]) == 0) & (np.diff(group[order]) == 0))
    return order[hit], order[hit + 1]
