"""Read any accepted layout into the validated readings frame; write it atomically."""

from __future__ import annotations

import errno
import stat
from pathlib import Path

import pandas as pd

from features.readings import layouts  # read at call time: a registered layout counts
from features.readings.errors import InputError
from features.readings.fileio import atomic_path
from features.readings.validation import validate


def read_readings(path, format: str = "auto", **options) -> pd.DataFrame:
    """Read a readings file in any accepted layout into the validated long frame.

    Parameters
    ----------
    path : str or path-like
        The readings file.
    format : str
        A layout name of ``features.readings.layouts.LAYOUTS``, or ``"auto"`` to recognise
        it from the file.
    **options
        Options of a raw log's reader (``channels``, ``reference_scale`` of the ``camonitor``
        layout: ``features.readings.approaches``); None values are not given.

    Raises
    ------
    InputError
        The file cannot be read or breaks the readings contract (naming file, row, column).
    """
    path = Path(path)
    if format not in layouts.FORMATS:
        raise InputError(f"unknown format {format!r}; expected one of "
                         f"{', '.join(layouts.FORMATS)}", file=path, parameter="format")
    check_readable(path)
    if format == "auto":
        format = layouts.detect_format(path)
    return validate(layouts.BY_NAME[format].read(path, **options), path, None)


def check_readable(path: Path) -> None:
    """Refuse a path that is no readable file (missing, a folder, a symbolic-link loop, a
    device) with one line, before any reader sees it."""
    try:
        mode = path.stat().st_mode
    except FileNotFoundError:
        raise InputError("cannot read file: no such file", file=path) from None
    except OSError as err:
        reason = "symbolic link loop" if err.errno == errno.ELOOP else err.strerror
        raise InputError(f"cannot read file: {reason}", file=path) from None
    if stat.S_ISDIR(mode):
        raise InputError("is a folder; expected a readings file", file=path)
    if not stat.S_ISREG(mode):
        raise InputError("cannot read file: not a regular file", file=path)


def read_table_rows(path) -> tuple[pd.DataFrame, Path, pd.Series | int]:
    """A CSV or Parquet table of another contract (circles, probing, loaded circles), checked
    readable: (frame with a fresh index, the file, its rows: the file row of each frame row,
    or the file row of the first when they follow one another) for errors naming the row."""
    from features.readings.formats import read_table
    from features.readings.validation import ROW

    file = Path(path)
    check_readable(file)
    frame, row_base = read_table(file)
    rows = frame.pop(ROW).reset_index(drop=True) if ROW in frame else row_base
    return frame.reset_index(drop=True), file, rows


def write_readings(frame: pd.DataFrame, path) -> Path:
    """Write a readings frame as CSV or Parquet (by suffix), atomically."""
    path = Path(path)
    suffix = path.suffix.lower()
    if suffix not in (".csv", ".parquet"):
        raise InputError("unknown output type; expected a .csv or .parquet file name", file=path)
    with atomic_path(path) as tmp:
        if suffix == ".parquet":
            frame.to_parquet(tmp, index=False)
        else:
            frame.to_csv(tmp, index=False, date_format="%Y-%m-%dT%H:%M:%S.%f%z")
    return path
