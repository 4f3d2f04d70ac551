"""Reading and writing traces: one table (CSV or Parquet) or a Parquet dataset partitioned by
machine, axis and date (Hive-style folders ``machine_id=M/axis=X/date=YYYY-MM-DD/``).

A dataset is read one partition at a time (``partitions`` lists them, ``read_partition`` reads
one), so work on a dataset needs memory for one partition only, wherever it runs.
"""

from __future__ import annotations

import itertools
import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pandas as pd

from features.readings.errors import InputError
from features.readings.fileio import atomic_path
from features.readings.io import check_readable
from features.traces import contract as c
from features.traces.validation import check_trace

SUFFIXES = (".csv", ".parquet")


def read_trace(path) -> pd.DataFrame:
    """Read and validate one trace table (CSV or Parquet, by suffix).

    Raises
    ------
    InputError
        The file cannot be read or breaks the trace contract (file, row, column).
    """
    path = Path(path)
    check_readable(path)
    suffix = path.suffix.lower()
    if suffix not in SUFFIXES:
        raise InputError("unknown trace file type; expected .csv or .parquet", file=path)
    if suffix == ".parquet":
        return check_trace(_parquet(path), path, row_base=1)
    try:  # typed columns from the C parser: validation then works on arrays
        raw = pd.read_csv(path, skip_blank_lines=False, skipinitialspace=True)
    except (pd.errors.ParserError, UnicodeDecodeError) as err:
        raise InputError(f"malformed CSV: {' '.join(str(err).split())}", file=path) from None
    except pd.errors.EmptyDataError:
        raise InputError("empty file; expected a header row and samples", file=path) from None
    return check_trace(raw, path, row_base=2)


def _parquet(path: Path) -> pd.DataFrame:
    """A Parquet file with its label columns as categories (read as dictionaries: a label
    repeats on every sample, and validation then checks each distinct value once)."""
    import pyarrow.parquet as pq

    try:
        names = pq.read_schema(path).names
        labels = [n for n in names if n.strip().lower() in ("machine_id", "axis")]
        return pq.read_table(path, read_dictionary=labels).to_pandas()
    except Exception as err:  # noqa: BLE001 - pyarrow raises many types for a broken file
        raise InputError(f"cannot read Parquet file: {' '.join(str(err).split())}",
                         file=path) from None


@dataclass(frozen=True)
class Partition:
    """One partition of a trace dataset: its keys (from the folder names; None where the
    layout does not partition by that key) and its Parquet files, in name order."""

    machine_id: str | None
    axis: str | None
    date: str | None
    files: tuple[str, ...]


def is_dataset(path) -> bool:
    return os.path.isdir(path)


def partitions(folder) -> list[Partition]:
    """Every partition of the dataset under ``folder``, in key order.

    Raises
    ------
    InputError
        No Parquet file under ``folder``, or a folder name ``key=value`` with another key than
        machine_id, axis and date.
    """
    folder = Path(folder)
    found: dict[Path, list[str]] = {}
    for root, dirs, files in os.walk(folder):
        dirs[:] = sorted(d for d in dirs if not d.startswith("."))
        parquet = sorted(f for f in files if f.endswith(".parquet") and not f.startswith("."))
        if parquet:
            found[Path(root)] = [str(Path(root) / f) for f in parquet]
    if not found:
        raise InputError("no Parquet file in this folder; expected a trace dataset "
                         "(machine_id=M/axis=X/date=YYYY-MM-DD/*.parquet)", file=folder)
    return [Partition(**_keys(leaf.relative_to(folder), folder), files=tuple(files))
            for leaf, files in sorted(found.items())]


def _keys(relative: Path, folder: Path) -> dict:
    keys = dict.fromkeys(c.PARTITION_KEYS)
    for part in relative.parts:
        key, sep, value = part.partition("=")
        if not sep or key not in keys:
            raise InputError(f"folder {part!r} is no partition; expected machine_id=, axis= "
                             "or date= folders", file=folder / relative)
        keys[key] = value
    return keys


def read_partition(part: Partition) -> pd.DataFrame:
    """The validated samples of one partition; its key columns filled in from the folder
    names where the files do not hold them (checked where they do)."""
    frames = []
    for file in part.files:
        frame = _parquet(Path(file))
        for key in ("machine_id", "axis"):
            value = getattr(part, key)
            if value is None:
                continue
            if key not in frame:
                frame[key] = value
            elif frame[key].astype(str).ne(value).any():
                raise InputError(f"holds {key} other than {value!r}, the partition's",
                                 file=file, column=key)
        frames.append(check_trace(frame, file, row_base=1))
    return frames[0] if len(frames) == 1 else _concat(frames, part)


def _concat(frames: list[pd.DataFrame], part: Partition) -> pd.DataFrame:
    """The files of one partition as one frame, in file order (time must not go back)."""
    from pandas.api.types import union_categoricals

    out = pd.concat(frames, ignore_index=True)
    for key in ("machine_id", "axis"):
        out[key] = union_categoricals([f[key] for f in frames])
    check_trace(out, Path(part.files[0]).parent, row_base=1)
    return out


def write_dataset(trace: pd.DataFrame, folder) -> list[Path]:
    """Write ``trace`` as a dataset partitioned by machine, axis and UTC date, one Parquet file
    per partition (each written atomically); the key columns stay in the files too.
    Returns the files written."""
    folder = Path(folder)
    date = pd.DatetimeIndex(trace[c.TIME]).strftime("%Y-%m-%d")
    written = []
    for (machine, axis, day), part in trace.groupby(
            [trace["machine_id"].astype(str), trace["axis"].astype(str), date], sort=True):
        path = folder / f"machine_id={machine}" / f"axis={axis}" / f"date={day}" / "part-0.parquet"
        with atomic_path(path) as tmp:
            part.reset_index(drop=True).to_parquet(tmp, index=False)
        written.append(path)
    return written


def write_trace(trace: pd.DataFrame, path) -> Path:
    """Write a trace table as CSV or Parquet (by suffix), atomically: the readings table's
    writer, whose CSV times carry microseconds and the UTC offset."""
    from features.readings.io import write_readings

    return write_readings(trace, path)


def groups(trace: pd.DataFrame, by_day: bool = False) -> list[pd.DataFrame]:
    """The machine axes (and with ``by_day`` their UTC days) of a validated trace, each a
    frame in time order. A trace written axis after axis is cut into slices without copying
    or sorting; otherwise its rows are put in order once."""
    machine = trace["machine_id"].array.codes
    axis = trace["axis"].array.codes
    step = (machine[1:] != machine[:-1]) | (axis[1:] != axis[:-1])  # on the small codes
    if by_day:
        day = trace[c.TIME].to_numpy().view(np.int64) // DAY_NS
        step |= day[1:] != day[:-1]
    cuts = np.flatnonzero(step) + 1

    def key(rows):  # one number per machine axis (and day) at the given rows
        out = machine[rows].astype(np.int64) * 64 + axis[rows]
        return out * 1_000_000 + day[rows] if by_day else out

    if len(cuts) + 1 != len(np.unique(key(np.r_[0, cuts]))):  # a key in two blocks: sort once
        order = np.argsort(key(slice(None)), kind="stable")
        trace = trace.iloc[order]
        cuts = np.flatnonzero(np.diff(key(order))) + 1
    bounds = [0, *cuts.tolist(), len(trace)]
    return [trace.iloc[a:b] for a, b in itertools.pairwise(bounds)]


DAY_NS = 86_400 * 10**9
